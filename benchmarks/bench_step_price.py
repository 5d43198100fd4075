"""What the project's step costs against Box2D 2.4.1's own, for the same sweeps (the step's price,
docs/results/step-price.md): a settled pile (seed 9; 1,000 circles in a box of 95, or 10,000 in a
box of 300 with --count 10000) is built three times (and a fourth, below) and each copy settled
by Box2D at its 8 iterations (the same steps, so the same state). Then the copies step in turn,
one step each per round: Box2D's own step at 8 iterations, the loop's step at 8 sweeps in
float64, and the loop's step at 8 sweeps in Box2D's exact float32 arithmetic (each one native
call: Collide, the islands found once, the solve, the islands stepped with the impulses written).
Each round's ratio is a loop step over the Box2D step of the same round (the same load on both);
a step's time is the CPU time of the thread that steps (so a busy machine's other work is not
counted; one thread does it all). Printed: the median ratio and its interquartile range, and each
world's median step. Unrecorded.

The loop's first step of a world carries what Box2D carried, times the dtRatio Box2D's own next
step would use, so a settled copy stepped by the loop stays the pile Box2D's copies are. A fourth
copy, stepped once by the loop (float64) and then by Box2D at 8 iterations, checks that (its last
line: about 1.00x; when the loop's first step started from zero, the pile it shook cost Box2D
1.18-1.22x for some 200 steps). --warm N: all four step N rounds untimed first.

--base N prices the same on a pyramid of boxes of base N (seed 9) instead.

--block N: each world steps N times in a row a round, its first step untimed (its data back in
the cache), the other N - 1 timed together, as a world stepped alone steps: what the step costs
warm, where one step each a round (the default, 1) asks each world's data back every step.

--glue N: what a step costs around its work, on a world of two circles resting in a box (a step
of almost nothing): each stepper called N times in turn, Box2D's own at 1 iteration and the loop's
at 1 sweep, exact and float64; the median wall microseconds of a call.

Usage: python benchmarks/bench_step_price.py [--count 1000] [--base 0] [--settle 500] [--warm 0] [--steps 200] [--sweeps 8]
       [--glue 0] [--block 1]
"""
import sys
import time
from pathlib import Path

import numpy as np

from deepcontact.scene.generators import generate
from deepcontact.simulate import stepping
from deepcontact.simulate.engines import Box2D
from deepcontact.solver.settings import SolveSettings

sys.path.insert(0, str(Path(__file__).parent))
from common import arguments, block_seconds  # noqa: E402


def settled(scene, settle):
    """A world of the scene after `settle` steps of Box2D's own solver at 8 iterations."""
    box2d = Box2D(velocity_iterations=8)
    world = box2d.build(scene)
    for _ in stepping.steps(world, scene, box2d.stepper(world, scene, record=False), settle):
        pass
    return world


def shaken(scene, args):
    """Box2D's own step of a settled copy whose next step the loop took."""
    world = settled(scene, args.settle)
    Box2D(solver=SolveSettings(max_iterations=args.sweeps, tolerance=0)).stepper(world, scene, record=False)()
    return Box2D(velocity_iterations=args.sweeps).stepper(world, scene, record=False)


def glue(calls):
    """Median wall microseconds of a step of two resting circles (see --glue)."""
    scene = generate("pile", 0, dict(count=2, box=12.0, sigma=1.0, steps=calls + 202))
    steppers = {"Box2D 2.4.1, 1 iteration": Box2D(velocity_iterations=1)}
    for mode in ("exact", "float64"):
        steppers[f"the loop, 1 sweep, {mode}"] = Box2D(solver=SolveSettings(max_iterations=1, tolerance=0, mode=mode))
    steppers = {name: engine.stepper(engine.build(scene), scene, record=False) for name, engine in steppers.items()}
    times = {name: [] for name in steppers}
    for k in range(calls + 200):   # (the first 200 untimed: the circles come to rest)
        for name, step in steppers.items():
            t = time.perf_counter()
            step()
            if k >= 200:
                times[name].append(time.perf_counter() - t)
    print(f"a step of two resting circles, {calls:,} calls each, in turn (median wall us a call)")
    for name, values in times.items():
        print(f"{name:36s} {np.median(values) * 1e6:8.2f}")


def main():
    args = arguments(__doc__, count=1000, base=0, settle=500, warm=0, steps=200, sweeps=8, glue=0, block=1,
                     at_least_one=("block",))
    if args.glue:
        return glue(args.glue)
    steps = args.settle + args.warm + args.steps * args.block + 2
    if args.base:   # a pyramid of boxes: two-point manifolds and Box2D's block solver
        scene = generate("pyramid", 9, dict(base=args.base, steps=steps))
    else:
        big = args.count > 1000
        scene = generate("pile", 9, dict(count=args.count, box=300.0 if big else 95.0, sigma=60.0 if big else 19.0,
                                         steps=steps))
    steppers = {}
    for name, settings in ((f"Box2D 2.4.1, {args.sweeps} iterations", None),
                           (f"the loop, {args.sweeps} sweeps, float64", "float64"),
                           (f"the loop, {args.sweeps} sweeps, exact", "exact")):
        world = settled(scene, args.settle)
        engine = Box2D(velocity_iterations=args.sweeps) if settings is None else Box2D(
            solver=SolveSettings(max_iterations=args.sweeps, tolerance=0, mode=settings))
        steppers[name] = engine.stepper(world, scene, record=False)
    steppers["Box2D, a copy the loop stepped once"] = shaken(scene, args)
    for _ in range(args.warm):   # untimed
        for step in steppers.values():
            step()
    times = {name: [] for name in steppers}
    for _ in range(args.steps):   # each world in turn, one step (or --block) each a round
        for name, step in steppers.items():
            times[name].append(block_seconds(step, args.block))
    base_name = next(iter(times))
    base = np.array(times[base_name])
    warmed = f", then {args.warm} rounds untimed" if args.warm else ""
    what = f"the pyramid of base {args.base}" if args.base else f"the {args.count:,}-circle pile"
    blocks = f", {args.block} steps a world a round (the first untimed)" if args.block > 1 else ""
    print(f"{what} (seed 9), settled for {args.settle} steps{warmed}; {args.steps} rounds{blocks}")
    print(f"{'':36s} {'median CPU ms':>13s} {'x Box2D (median of rounds)':>27s} {'IQR':>15s}")
    for name, values in times.items():
        ratio = np.array(values) / base
        q1, med, q3 = np.percentile(ratio, [25, 50, 75])
        print(f"{name:36s} {np.median(values) * 1e3:13.3f} {med:26.3f}x {q1:7.3f}-{q3:.3f}x")


if __name__ == "__main__":
    main()
