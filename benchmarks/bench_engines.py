"""Does stepping a Box2D v3 world through the project cost what stepping it bare costs, and does
writing its step files cost what writing 2.4.1's costs?

1. The thesis pile (100 circles in a box, 600 steps at dt = 0.01, 4 substeps, sleeping and continuous
collision off, one thread) stepped two ways in the same run, best of --repeats: through the
project (simulate.build.build_world3, native/world3.cpp, the soft step called from Python once a
step) and bare through pyb2d3's own Python API, built from the same scene. The goal: the project's
time within 1.2x of the bare one. The final positions are compared too (the same engine, the same
bodies: the same trajectory, or nearly: pyb2d3 sets its own defaults).

2. The same pile simulated into step files (simulate.run.run_simulation, as `dc simulate` writes
them) under each engine, and stepped without recording; the writing cost is the difference
(recording the state, rendering the XML, writing the file), per step and per MB written (the
engines see different contact points: v3 keeps speculative ones). The goal: v3's cost per MB
within 1.2x of 2.4.1's.

Usage: python benchmarks/bench_engines.py [--repeats N] [--steps N]
"""
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
import pyb2d3 as b2

from deepcontact._box2d import polygon_radius
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world3
from deepcontact.simulate.engines import Box2D, Box2D3
from deepcontact.simulate.run import run_simulation
from deepcontact.simulate.engines import SoftStep

from common import arguments


def bare_world(scene):
    """The scene's bodies through pyb2d3's API (the pile has circles and edges; each edge a capsule
    of 2.4.1's skin, as the project builds it: the same world)."""
    world = b2.World(gravity=tuple(scene.effects.gravity))
    world.sleeping_enabled = False
    world.continuous_enabled = False
    bodies = []
    for body in scene.bodies:
        if body.type == "static":
            made = world.create_static_body(position=(body.x, body.y))
        else:
            made = world.create_dynamic_body(position=(body.x, body.y), linear_velocity=(body.vx, body.vy))
        for s in body.shapes:
            sd = b2.shape_def(density=getattr(s, "density", 0.0),
                              material=b2.surface_material(friction=scene.friction_of(s),
                                                           restitution=scene.restitution_of(s)))
            if s.kind == "circle":
                c = b2.Circle()
                c.center, c.radius = (s.x, s.y), s.radius
                made.create_circle_shape(sd, c)
            elif s.kind == "edge":   # with 2.4.1's skin, as the project's v3 world builds it
                cap = b2.Capsule()
                cap.center1, cap.center2, cap.radius = (s.x1, s.y1), (s.x2, s.y2), polygon_radius
                made.create_capsule_shape(sd, cap)
            else:
                raise SystemExit(f"this benchmark builds circles and edges, not {s.kind}")
        bodies.append(made)
    return world, bodies


def timed(step, steps):
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    return time.perf_counter() - t0


def main():
    args = arguments(__doc__, repeats=3, steps=600)
    scene = generate("pile", 0)
    ours, bare = [], []
    for _ in range(args.repeats):   # interleaved: both see the same machine
        world = build_world3(scene, SoftStep(substeps=4))
        ours.append(timed(lambda: world.step(scene.dt), args.steps))
        mine = world.bodies()["position"]
        bw, bodies = bare_world(scene)
        bare.append(timed(lambda: bw.step(scene.dt, 4), args.steps))
        theirs = np.array([[p.x, p.y] for p in (body.position for body in bodies)])
    o, t = min(ours), min(bare)
    print(f"the pile, {args.steps} steps, 4 substeps, best of {args.repeats}:")
    print(f"  through the project   {1e3 * o / args.steps:.3f} ms a step")
    print(f"  bare pyb2d3           {1e3 * t / args.steps:.3f} ms a step")
    print(f"  ratio                 {o / t:.2f}x (goal: at most 1.2x)")
    print(f"  largest difference of a final position: {np.abs(mine - theirs).max():.3g} m")
    writing(scene, args)


def writing(scene, args):
    """The cost of writing step files under each engine, against stepping alone, same run."""
    soft = SoftStep(substeps=4)
    engines = {"Box2D 2.4.1": Box2D(), "Box2D v3": Box2D3(soft)}
    costs = {name: [] for name in engines}
    sizes = {}
    scene = dataclasses.replace(scene, steps=args.steps)
    for _ in range(args.repeats):
        for name, engine in engines.items():
            world = engine.build(scene)
            step = engine.stepper(world, scene, record=False)
            bare = timed(step, args.steps)
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                run_simulation(scene, tmp, 0, engine=engine)
                full = time.perf_counter() - t0
                sizes[name] = sum(f.stat().st_size for f in Path(tmp).glob("step-*.xml"))
            costs[name].append((full - bare, bare, full))
    print(f"\nwriting the pile's {args.steps} step files (simulate.run.run_simulation), best of {args.repeats}:")
    per_mb = {}
    for name in engines:
        cost, bare, full = min(costs[name])
        mb = sizes[name] / 1e6
        per_mb[name] = cost / mb
        print(f"  {name:12s} stepping {1e3 * bare / args.steps:.3f} ms, with files {1e3 * full / args.steps:.3f} ms a "
              f"step: writing {1e3 * cost / args.steps:.3f} ms a step, {mb / args.steps * 1e3:.1f} kB a step, "
              f"{1e3 * per_mb[name]:.1f} ms per MB")
    print(f"  ratio of the cost per MB, v3 / 2.4.1: {per_mb['Box2D v3'] / per_mb['Box2D 2.4.1']:.2f}x "
          "(goal: at most 1.2x)")


if __name__ == "__main__":
    main()
