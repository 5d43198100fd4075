"""A step of the loop at 1,000 circles, step by step: the time each step of the 1000-circle pile
(seed 9, 800 steps) takes under Box2D 2.4.1's own solver at 8 iterations and under the project's
solver in the loop from Box2D's warm start to a residual of 1e-4 (cap 1,000 sweeps) with each
method named, unrecorded, one thread. Per method: the median and 90th-percentile step, the whole
run, their ratios to Box2D's in the same run, and the steps the cap stopped above the tolerance
(the goal at scale: every step at 1e-4, the median within 3x Box2D's step, the p90 within 6x).

Usage: python benchmarks/bench_loop_steps.py [--methods none,lagged] [--steps 800]
"""
import sys
import time
from pathlib import Path

import numpy as np

from deepcontact.scene.generators import generate
from deepcontact.simulate.engines import Box2D
from deepcontact.solver.settings import SolveSettings

sys.path.insert(0, str(Path(__file__).parent))
from common import arguments  # noqa: E402

TOLERANCE, CAP = 1e-4, 1000


def step_times(method, steps):
    """(per-step wall seconds, steps stopped above the tolerance) of one whole run."""
    scene = generate("pile", 9, dict(count=1000, box=95.0, sigma=19.0, steps=steps))
    engine = Box2D() if method == "box2d" else Box2D(
        solver=SolveSettings(tolerance=TOLERANCE, max_iterations=CAP, accelerate=method))
    world = engine.build(scene)
    step = engine.stepper(world, scene, record=False)
    times, capped = [], 0
    for _ in range(scene.steps):
        t = time.perf_counter()
        done = step()
        times.append(time.perf_counter() - t)
        capped += done.solution is not None and done.solution.residual >= TOLERANCE
    return np.array(times), capped


def main():
    args = arguments(__doc__, methods="none,lagged", steps=800)
    base, _ = step_times("box2d", args.steps)
    print("| solver in the loop | median ms (x Box2D) | p90 ms (x Box2D) | whole run s (x Box2D) | steps at the cap |")
    print("| --- | ---: | ---: | ---: | ---: |")

    def line(label, times, capped):
        ms = times * 1e3
        parts = [(np.median(ms), np.median(base) * 1e3), (np.percentile(ms, 90), np.percentile(base, 90) * 1e3),
                 (times.sum(), base.sum())]
        cells = " | ".join(f"{v:.2f} ({v / b:.1f})" for v, b in parts)
        print(f"| {label} | {cells} | {capped} of {len(times)} |", flush=True)
    line("Box2D's own, 8 iterations", base, 0)
    for method in args.methods.split(","):
        line(method, *step_times(method, args.steps))


if __name__ == "__main__":
    sys.exit(main())
