"""Does stepping pymunk and MuJoCo through the project cost what stepping them bare costs, and
what does recording their steps add?

For each engine, on a pile (the 1000-circle pile by default: seed 9, its settled second half), in
the same run, one thread, best of --repeats, the same model both ways:
  bare      the engine's own step called in a loop: pymunk's `space.step(dt)`, MuJoCo's
            `mj_step(model, data)` on the space and model the project built from the scene
  project   the same world stepped through the project's loop (simulate.stepping.steps, the
            engine's step function without recording): what the studies time
  recording the project's loop recording every step (the arrays a step file holds), as
            `dc simulate` steps (without rendering and writing the XML)
Box2D 2.4.1 at 8 iterations is stepped beside them as the baseline of the ratios. The goal: the
project's time within 1.2x of the bare one.

Usage: python benchmarks/bench_peers.py [--repeats N] [--count N] [--steps N]
"""
import argparse
import time

from deepcontact.protocol import current, protocol_line
from deepcontact.scene.generators import generate
from deepcontact.simulate.engines import engine_named
from deepcontact.simulate.stepping import steps


def settled(scene, engine, first):
    """The engine's world stepped `first` steps (to the settled part of the run)."""
    world = engine.build(scene)
    for _ in steps(world, scene, engine.stepper(world, scene, record=False), count=first):
        pass
    return world


def bare_step(name, world):
    if name == "pymunk":
        space, dt = world.space, world.dt
        return lambda: space.step(dt)
    if name == "mujoco":
        import mujoco
        model, data = world.model, world.data
        return lambda: mujoco.mj_step(model, data)
    return None


def timed(step, n):
    t = time.perf_counter()
    for _ in range(n):
        step()
    return (time.perf_counter() - t) / n


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--count", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=100, help="steps timed, from step 400 (the settled pile)")
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")
    params = {"count": args.count, "box": 95.0, "sigma": 19.0} if args.count > 100 else {"count": args.count}
    scene = generate("pile", 9, {**params, "steps": 400 + args.steps * (2 * args.repeats + 2)})
    print(f"pile of {args.count} circles, seed 9, {args.steps} steps from step 400, best of {args.repeats}\n")
    print("| engine | bare ms / step | through the project | project / bare | recording | x Box2D 2.4.1 (8 it.) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    base = None
    for name in ("box2d", "pymunk", "mujoco"):
        engine = engine_named(name)
        world = settled(scene, engine, 400)
        loop = engine.stepper(world, scene, record=False)
        through = iter(steps(world, scene, loop, count=10 ** 9))
        project = min(timed(lambda: next(through), args.steps) for _ in range(args.repeats))
        raw = bare_step(name, world)
        bare = min(timed(raw, args.steps) for _ in range(args.repeats)) if raw else float("nan")
        recording = iter(steps(world, scene, engine.stepper(world, scene, record=True), count=10 ** 9))
        record = min(timed(lambda: next(recording), args.steps) for _ in range(args.repeats))
        base = project if base is None else base
        print(f"| {engine.label} {engine.version()} | {1e3 * bare:.3f} | {1e3 * project:.3f} | "
              f"{project / bare:.2f}x | {1e3 * record:.3f} | {project / base:.1f}x |", flush=True)


if __name__ == "__main__":
    main()
