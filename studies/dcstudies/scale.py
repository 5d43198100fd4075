"""How the project's solver methods scale with the size of a pile: time and iterations per step
to a residual of 1e-4 at 100, 1000 and 10,000 circles, and the fitted exponent of time against
body count (the baseline any new global method is measured against).

Each pile is stepped by Box2D 2.4.1 (in memory) until it has settled (the step counts below), and
its last --samples steps are solved by: PGS (sweeps), PSOR at w = 1.7, NNCG (conjugate
directions), sweeps then Newton steps, sweeps then subspace minimization, sweeps then the solve
in body space (its iterations: sweeps plus outer iterations); float64, one thread,
cap --cap iterations. Twice: from zero (the pile's own difficulty: a sweep carries information
about one contact further, and a settled pile of N circles is about sqrt(N) layers deep) and from
Box2D's warm start (what the loop sees at rest, where the warm start is nearly the answer).
Reported per start, method and size: the median time, iterations and (global methods) sparse
factorizations over the samples, and how many reached the tolerance; the exponent is the slope of
log(median time) on log(bodies) over the sizes where every sample converged.

Run as `dc study scale [--samples N] [--cap N] [--quick] [--methods PGS,...] [--sizes 100,1000]`.
"""
import math
import statistics
import time

import numpy as np

from deepcontact.simulate.problems import recorded_between, step_problem
from deepcontact.simulate.source import SceneSource
from deepcontact.solver.methods import solve
from deepcontact.solver.settings import TOLERANCE
from .text import StudyText, progress as said

# name: (bodies, generator parameters, steps until settled)
FULL = {
    "pile 100": (100, {}, 1000),
    "pile 1,000": (1000, {"count": "1000", "box": "95", "sigma": "19"}, 1500),
    "pile 10,000": (10000, {"count": "10000", "box": "300", "sigma": "60"}, 2000),
}
QUICK = {"pile 100": (100, {}, 600), "pile 1,000": (1000, {"count": "1000", "box": "95", "sigma": "19"}, 800)}
STARTS = ("zero", "Box2D's warm start")
# label: (accelerate, relaxation)
METHODS = {"PGS": ("none", 1.0), "PSOR 1.7": ("none", 1.7), "NNCG": ("nncg", 1.0), "Newton": ("newton", 1.0),
           "subspace": ("subspace", 1.0), "body space": ("bodyspace", 1.0)}


def settled_problems(params, steps, samples):
    """The contact problems of the last `samples` of `steps` Box2D steps of the pile (seed 0),
    stepped in memory (a 10,000-circle run's files would be 12 GB), unrecorded until then."""
    scene = SceneSource("pile", params, steps)(0)
    return [step_problem(scene, done) for done in recorded_between(scene, steps - samples, steps, steps)
            if done.index >= steps - samples]


def piles(quick=False, sizes=None):
    """{name: (bodies, parameters, steps)} of the piles run: `sizes` their body counts (default all)."""
    chosen = QUICK if quick else FULL
    return {name: size for name, size in chosen.items() if not sizes or size[0] in set(sizes)}


def rows_work(quick=False, methods=tuple(METHODS), sizes=None):
    """(rows measured, what they weigh: bodies x settling steps each), what progress counts."""
    chosen = piles(quick, sizes)
    rows = len(STARTS) * len(methods)
    return rows * len(chosen), rows * sum(bodies * steps for bodies, _, steps in chosen.values())


def run(samples=3, cap=100_000, quick=False, methods=tuple(METHODS), sizes=None, out=None,
        progress=None) -> StudyText:
    """The tables (a StudyText; `out` one to add to): per start, method and pile size, the median
    time, iterations and factorizations to TOLERANCE, and the fitted exponent. `sizes`: body
    counts to keep (default all). progress(1, work) as each row is measured (rows_work)."""
    out = StudyText() if out is None else out
    progress = progress or (lambda n, work: None)
    methods = {label: METHODS[label] for label in methods}
    sizes = piles(quick, sizes)
    table = {}   # (start, method, size) -> (median ms, median iterations, converged, samples)
    contacts = {}
    for name, (bodies, params, steps) in sizes.items():
        problems = settled_problems(params, steps, samples)
        contacts[name] = statistics.median(len(p.start_normal) for p in problems)
        for start in STARTS:
            for label, (accelerate, w) in methods.items():
                times, iterations, factorizations, converged = [], [], [], 0
                for p in problems:
                    n, t = (np.zeros_like(p.start_normal), np.zeros_like(p.start_tangent)) if start == "zero" \
                        else (p.start_normal, p.start_tangent)
                    t0 = time.perf_counter()
                    s = solve(p, n, t, accelerate=accelerate, relaxation=w, max_iterations=cap,
                              tolerance=TOLERANCE)
                    times.append(time.perf_counter() - t0)
                    iterations.append(s.iterations)
                    factorizations.append(s.factorizations)
                    converged += bool(s.residual <= TOLERANCE)
                row = (1e3 * statistics.median(times), statistics.median(iterations), converged, len(problems),
                       statistics.median(factorizations))
                table[start, label, name] = row
                said(f"{name}, from {start}, {label}: {row[0]:.1f} ms, {row[1]:.0f} iterations, "
                     f"{converged}/{len(problems)} converged")
                progress(1, bodies * steps)
    names = list(sizes)
    for start in STARTS:
        out(f"\nFrom {start}: time per step to a residual of {TOLERANCE:g} (median of {samples} settled "
            f"steps; cap {cap:,} iterations):\n")
        out("| method | " + " | ".join(f"{n} ({contacts[n]:,.0f} contact points)" for n in names) +
              " | exponent (time ~ bodies^k) |")
        out("| --- |" + " ---: |" * (len(names) + 1))
        for label in methods:
            cells, xs, ys = [], [], []
            for n in names:
                ms, its, ok, total, fact = table[start, label, n]
                cells.append(f"{ms:.1f} ms, {its:.0f} it" + (f", {fact:.0f} fact" if fact else "") +
                             ("" if ok == total else f" ({ok}/{total} converged)"))
                if ok == total and ms > 0:
                    xs.append(math.log(sizes[n][0]))
                    ys.append(math.log(ms))
            k = f"{np.polyfit(xs, ys, 1)[0]:.2f}" if len(xs) >= 2 else "n/a"
            out(f"| {label} | " + " | ".join(cells) + f" | {k} |")
    return out
