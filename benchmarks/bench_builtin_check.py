"""What holding a built-in method's answers to the judge's own run of it costs the judge.

In replay a built-in method's solve runs in the contestant's process; every answer it gives (its one
solve call a step, builtin's second for the A/A, each fixed sweep budget) is held to the judge's own run of that
method from the same start, bit for bit (deepcontact/evaluate/replay.py, same_as_traced). The run
for a solve to the tolerance the judge made before too (its convergence history): the check adds
one comparison an answer. A budget's run is new: the judge solves each budget again. None of it is
on the contestant's clock (it runs in the judge's process, between calls). Measured per step and
method, one thread, on the steps of a thesis pile (100 circles), from builtin's start, at
dc evaluate's settings (tolerance, cap), each part the median of --repeats timings:

  solve      one solve to the tolerance, as the contestant's process makes it (one timed call's work)
  compare    same_as_traced on ANSWERS answers of a step, the most a variant gives (new)
  budgets    the judge's own runs of the budget calls (new where budgets are measured)

and for scale the whole replay of the same steps (replay.evaluate, builtin with each method, the
contestants' sandboxes included), with budgets and without, interleaved, the least of --runs each.

    python benchmarks/bench_builtin_check.py [--steps 600] [--every 20] [--repeats 5] [--runs 2]
"""
import tempfile
import time
from pathlib import Path

import numpy as np

from common import arguments, timed
from deepcontact.evaluate.replay import BUDGETS, evaluate, same_as_traced
from deepcontact.solver.methods import solve
from deepcontact.solver.problem import StepProblem
from deepcontact.solver.settings import SolveSettings
from deepcontact.step.run_folder import read_run
from deepcontact.warmstart.starts import make_starts

METHODS = ("none", "nncg")
ANSWERS = 2   # a step's solve answers of builtin: its one call, and its second for the A/A


def best(fn, repeats):
    """The median of `repeats` timings of fn() (seconds), and its last result."""
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def parts(problem, asked, repeats):
    """(solve, compare, budgets) seconds for one step and method (see the module's docstring)."""
    n, t = problem.start_normal, problem.start_tangent
    solve_s, s = best(lambda: solve(problem, n, t, settings=asked, final_residual=False), repeats)
    traced = solve(problem, n, t, history=True, settings=asked)
    answer = ({"iterations": int(s.iterations), "fallback": int(s.relaxation_fallback > 0),
               "factorizations": int(getattr(s, "factorizations", 0))},
              {"normal": np.asarray(s.normal_impulse, np.float64), "tangent": np.asarray(s.tangent_impulse, np.float64)})
    compare_s, _ = best(lambda: [same_as_traced("builtin", asked.accelerate, *answer, traced)
                                 for _ in range(ANSWERS)], repeats)
    budgets_s, _ = best(lambda: [solve(problem, n, t, settings=asked.but(max_iterations=b, tolerance=0.0),
                                       final_residual=False) for b in (BUDGETS[0], *BUDGETS)], repeats)
    return solve_s, compare_s, budgets_s


def main():
    args = arguments(__doc__.split("\n\n")[0], steps=600, every=20, repeats=5, runs=2)
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        timed(["simulate", "pile", "--seeds", "1000..1000", "--steps", str(args.steps), "-q", "-o", str(run)])
        files = read_run(run).simulations[0].files[::args.every]
        settings = SolveSettings()
        print(f"{'method':8s} {'steps':>5s} {'solve ms':>9s} {'compare ms':>11s} {'budgets ms':>11s}  (medians a step)")
        for method in METHODS:
            asked = settings.but(accelerate=method)
            rows = [parts(p, asked, args.repeats) for p in map(StepProblem.from_step_file, files) if p.points]
            med = np.median(np.array(rows), axis=0) * 1e3
            print(f"{method:8s} {len(rows):5d} {med[0]:9.3f} {med[1]:11.4f} {med[2]:11.3f}")
        whole = {True: [], False: []}
        for _ in range(args.runs):
            for budgets in whole:
                t = time.perf_counter()
                evaluate([run], make_starts(["builtin"]), settings=settings, every=args.every, budgets=budgets,
                         accelerations=METHODS)
                whole[budgets].append(time.perf_counter() - t)
        print(f"\nthe replay of these steps: {min(whole[True]):.2f} s with budgets, {min(whole[False]):.2f} s without")

if __name__ == "__main__":
    main()
