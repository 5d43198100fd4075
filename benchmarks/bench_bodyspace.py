"""The solve in body space (accelerate="bodyspace", and "lagged": the same with a lagged factor)
on the problems it was built for, against the method each is measured by, in one run:

1. exact: the base-20 pyramid's 14 settling steps (8-10, 15-18, 32-36, 52-53) on which no other
   method of the project reaches 1e-12 (docs/results/), from zero, cap 100,000 iterations,
   against the contact-space Newton with the same cap;
2. the first five steps with contacts of a base-40 pyramid (820 boxes) from zero to 1e-4,
   against subspace minimization (the method that meets it today);
3. the 100-circle pile settled (its last steps of 1,000) from zero and from Box2D's warm start to
   1e-4, against PSOR at w = 1.7 (the fastest there today);
4. the 1000-circle pile (seed 9) at steps 300, 500 and 700 (stepped by Box2D 2.4.1) from Box2D's
   warm start to 1e-4 with a cap of 1,000, against PGS: a step of the loop at scale;
5. the 10,000-circle pile of the frontier study (seed 9), settled by Box2D (steps 1,500 and 1,900,
   about 22,000 contact points), the same way: PGS and lagged alone (bodyspace's LU factorizations
   would take minutes a step there);
6. the base-40 pyramid's steps 300, 375, 450 and 525 stepped by Box2D at its 8 iterations (the
   frontier study's samples, states its criteria fail) from Box2D's warm start to 1e-8, with the
   frontier's cap of 1,000 iterations and with 10,000: lagged and bodyspace against NNCG.

Per method: steps that reach the tolerance, median and total time, and the work: iterations
(sweeps plus outer iterations), factorizations, Newton iterations, outer iterations and fallbacks
to sweeps. float64, one thread.

Usage: python benchmarks/bench_bodyspace.py [--part exact|pyramid40|pile100|pile1000|pile10000|pyramid40-late|all]
                                           [--methods LABEL,...]
(--methods: only these rows, e.g. `--methods lagged` under `perf record` to profile one method)
"""
import argparse
import statistics
import sys
import time

import numpy as np

from deepcontact.protocol import current, protocol_line
from deepcontact.scene.generators import generate
from deepcontact.solver.methods import solve
from deepcontact.simulate.problems import problems

SETTLING = (8, 9, 10, 15, 16, 17, 18, 32, 33, 34, 35, 36, 52, 53)


def methods_table(title, problems, methods, tolerance, cap, start="zero"):
    print(f"\n{title}: {len(problems)} steps, {statistics.mean(p.points for p in problems):.0f} contact points "
          f"on average; from {start} to {tolerance:g}, cap {cap:,} iterations\n")
    print("| method | reach it | worst residual | median ms | total s | iterations (median) | factorizations "
          "(median) | Newton iterations (median) | outer iterations (median) | fallbacks (total) |")
    print("| --- |" + " ---: |" * 9)
    for label, (accelerate, w) in methods.items():
        runs = []
        for p in problems:
            n, t = (np.zeros(p.points), np.zeros(p.points)) if start == "zero" else (p.start_normal, p.start_tangent)
            t0 = time.perf_counter()
            s = solve(p, n, t, accelerate=accelerate, relaxation=w, max_iterations=cap, tolerance=tolerance)
            runs.append((time.perf_counter() - t0, s))
            print(f"  {label} step {p.index}: {runs[-1][0]:.3f} s, residual {s.residual:.1e}", file=sys.stderr, flush=True)
        times = [t for t, _ in runs]
        sols = [s for _, s in runs]

        def med(f):
            return statistics.median(f(s) for s in sols)
        print(f"| {label} | {sum(s.residual < tolerance for s in sols)} of {len(sols)} | "
              f"{max(s.residual for s in sols):.1e} | {1e3 * statistics.median(times):.1f} | {sum(times):.2f} | "
              f"{med(lambda s: s.iterations):.0f} | {med(lambda s: s.factorizations):.0f} | "
              f"{med(lambda s: s.newton_iterations):.0f} | {med(lambda s: s.outer_iterations):.0f} | "
              f"{sum(s.newton_fallbacks for s in sols)} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", choices=("exact", "pyramid40", "pile100", "pile1000", "pile10000", "pyramid40-late", "all"),
                    default="all")
    ap.add_argument("--methods", help="only these method labels, comma-separated (e.g. lagged)")
    args = ap.parse_args()
    only = None if args.methods is None else set(args.methods.split(","))

    def table(title, problems, methods, *rest):
        """The module's table, of the methods --methods keeps."""
        kept = {label: m for label, m in methods.items() if only is None or label in only}
        return methods_table(title, problems, kept, *rest)

    print(protocol_line(current(jobs=1)))
    body = {"bodyspace": ("bodyspace", 1.0), "lagged": ("lagged", 1.0)}
    if args.part in ("exact", "all"):
        scene = generate("pyramid", 0, {"base": 20, "steps": max(SETTLING) + 1})
        settling = [p for _, p in problems(scene) if p.index in SETTLING]
        table("Base-20 pyramid, its settling steps", settling, {"Newton": ("newton", 1.0), **body}, 1e-12, 100_000)
    if args.part in ("pyramid40", "all"):
        first = [p for _, p in problems(generate("pyramid", 0, {"base": 40, "steps": 5}))]
        table("Base-40 pyramid, its first steps", first, {"subspace": ("subspace", 1.0), **body}, 1e-4, 100_000)
    if args.part in ("pile100", "all"):
        settled = [p for _, p in problems(generate("pile", 0, {"steps": 1000}), first=997)]   # (steps 997-999)
        for start in ("zero", "Box2D's warm start"):
            table("100-circle pile, settled", settled, {"PSOR 1.7": ("none", 1.7), **body}, 1e-4, 100_000, start)
    if args.part in ("pile1000", "all"):
        scene = generate("pile", 9, {"count": 1000, "box": 95.0, "sigma": 19.0, "steps": 701})
        steps = [p for _, p in problems(scene, first=300, every=200)]   # (300, 500, 700)
        table("1000-circle pile", steps, {"PGS": ("none", 1.0), **body}, 1e-4, 1000, "Box2D's warm start")
    if args.part in ("pile10000", "all"):
        scene = generate("pile", 9, {"count": 10000, "box": 300.0, "sigma": 60.0, "steps": 1901})
        steps = [p for _, p in problems(scene, first=1500, every=400)]   # (1,500, 1,900)
        table("10,000-circle pile", steps, {"PGS": ("none", 1.0), "lagged": body["lagged"]}, 1e-4, 1000,
              "Box2D's warm start")
    if args.part in ("pyramid40-late", "all"):
        late = [p for _, p in problems(generate("pyramid", 0, {"base": 40}), first=300, every=75)][:4]
        for cap in (1000, 10_000):
            table("Base-40 pyramid, the frontier study's samples", late, {"NNCG": ("nncg", 1.0), **body}, 1e-8, cap,
                  "Box2D's warm start")


if __name__ == "__main__":
    sys.exit(main())
