"""What a converged step of a settled pile costs, engine beside engine, in one run.

The pile (seed 9: 1000 circles, box 95, sigma 19; 10,000: box 300, sigma 60, the frontier's) is settled by Box2D 2.4.1's own
solver for --settle steps; from that state each contestant steps --steps more, the worlds stepped
in turn (a change of the machine's load falls on all of them alike), each step timed on its own:

  Box2D 2.4.1      its own solver at the scene's 8 iterations: the baseline of the ratios
  PSOR 1.7 / 1e-4  the project's sweeps in Box2D's loop, to a residual of 1e-4, cap 1000
  lagged / 1e-4    the project's solve in body space with a lagged factor, to 1e-4, cap 1000
  MuJoCo Newton    MuJoCo's Newton to 1e-8 (its default, its own soft problem: a penalty of
                   9-19 effective masses), its world settled by itself for the same --settle
                   steps (its dynamics are not 2.4.1's); then the same at impedances 0.99 and
                   0.999 (penalties of 99 and 999: nearer the rigid problem the others solve)

The project's loops start from Box2D's settled world (its first --warm steps untimed: the lagged
factor and penalty are built there). Per contestant: the median and p90 of its time per step
against Box2D's in the same round, and how many steps reached their tolerance (ours: the
project's residual of the step's answer; MuJoCo: its own `converged`).

Usage: python benchmarks/bench_converged_piles.py [--count N] [--settle N] [--steps N] [--warm N] [--stiffer D,D]
"""
import argparse
import time

import numpy as np

from deepcontact.protocol import current, protocol_line
from deepcontact.scene.generators import generate
from deepcontact.simulate.engines import Box2D, engine_named
from deepcontact.simulate.stepping import steps
from deepcontact.solver.settings import SolveSettings

TOLERANCE = 1e-4
STIFFER = "0.99,0.999"   # MuJoCo's impedances d on the stiffer rows: a penalty of d / (1 - d) effective masses


def stepped(world, scene, stepper, count):
    """The world stepped `count` times by stepper (untimed)."""
    for _ in steps(world, scene, stepper, count=count):
        pass


def contestants(scene, settle, warm, stiffer=()):
    """[(label, step function, reached(done) -> bool | None)]: every world settled and warmed."""
    out = []
    box2d = Box2D()
    world = box2d.build(scene)
    stepped(world, scene, box2d.stepper(world, scene, record=False), settle + warm)
    out.append(("Box2D 2.4.1, 8 iterations", world, box2d.stepper(world, scene, record=False), lambda done: None))
    for label, settings in (("PSOR 1.7 to 1e-4", SolveSettings(tolerance=TOLERANCE, relaxation=1.7)),
                            ("lagged to 1e-4", SolveSettings(tolerance=TOLERANCE, accelerate="lagged"))):
        world = box2d.build(scene)
        stepped(world, scene, box2d.stepper(world, scene, record=False), settle)
        loop = Box2D(solver=settings)
        stepper = loop.stepper(world, scene, record=False)
        stepped(world, scene, stepper, warm)
        out.append((label, world, stepper,
                    lambda done: None if done.solution is None else bool(done.solution.residual <= TOLERANCE)))
    for impedance in (0.0, *stiffer):
        mujoco = engine_named("mujoco", {"solver": "newton", "impedance": impedance})
        world = mujoco.build(scene)
        stepper = mujoco.stepper(world, scene, record=False)
        stepped(world, scene, stepper, settle + warm)
        problem = "its soft problem" if not impedance else f"impedance {impedance:g}, penalty {impedance / (1 - impedance):.0f}"
        out.append((f"MuJoCo Newton to 1e-8 ({problem})", world, stepper,
                    lambda done: None if not done.engine_stats else bool(done.engine_stats["converged"])))
    return out


def iterations(done):
    """The step's solver iterations, where the engine says (MuJoCo), else None."""
    return done.engine_stats["iterations"] if done.engine_stats else None


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=1000)
    ap.add_argument("--settle", type=int, default=400)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--warm", type=int, default=3)
    ap.add_argument("--stiffer", default=STIFFER, help="MuJoCo's stiffer impedances, comma-separated ('' for none)")
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")
    # (the frontier's piles: 1,000 circles in a 95 m box, 10,000 in a 300 m one)
    params = {"count": args.count, "box": 95.0 if args.count <= 1000 else 300.0,
              "sigma": 19.0 if args.count <= 1000 else 60.0} if args.count > 100 else {"count": args.count}
    scene = generate("pile", 9, {**params, "steps": args.settle + args.warm + args.steps + 1})
    stiffer = [float(d) for d in args.stiffer.split(",") if d.strip()]
    rows = contestants(scene, args.settle, args.warm, stiffer)
    walks = [iter(steps(world, scene, stepper, count=10 ** 9)) for _, world, stepper, _ in rows]
    ms = np.zeros((len(rows), args.steps))
    reached = [[] for _ in rows]
    iters = [[] for _ in rows]
    for k in range(args.steps):   # (in turn, each step timed on its own)
        for i, walk in enumerate(walks):
            t = time.perf_counter()
            done = next(walk)
            ms[i, k] = 1e3 * (time.perf_counter() - t)
            reached[i].append(rows[i][3](done))
            iters[i].append(iterations(done))
    print(f"pile of {args.count} circles, seed 9, settled {args.settle} steps; {args.steps} steps timed, "
          f"the worlds stepped in turn\n")
    print("| contestant | ms / step (median) | p90 | x Box2D (median of the rounds) | p90 | steps to its tolerance "
          "| its iterations (median / max) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for i, (label, *_rest) in enumerate(rows):
        ratio = ms[i] / ms[0]
        done = [r for r in reached[i] if r is not None]
        share = f"{sum(done)} of {len(done)}" if done else "-"
        counted = [n for n in iters[i] if n is not None]
        its = f"{np.median(counted):.0f} / {max(counted)}" if counted else "-"
        print(f"| {label} | {np.median(ms[i]):.2f} | {np.percentile(ms[i], 90):.2f} | {np.median(ratio):.1f}x | "
              f"{np.percentile(ratio, 90):.1f}x | {share} | {its} |", flush=True)


if __name__ == "__main__":
    main()
