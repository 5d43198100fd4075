"""The exact solve of a step: float64 PGS from zero (the reference until the global step) against
the proximal semismooth Newton solver (accelerate="newton"), both from zero to a residual of
1e-12, at most 100,000 sweeps, and the reference (solver/reference.py): Newton for 2048 sweeps,
then, where it has not reached 1e-12, Lemke's pivoting on neighbourhoods of the contacts carrying
the residual and on the whole step, each followed by Newton.

Problems: the held-out pile (seeds 1000-1001, every 5th step with contacts) and the pyramid
(base 20, every 5th step). Reported per scene: how many steps reach 1e-12, the worst residual,
the median and total time, and the same on the steps where PGS stops at its cap (the hard ones),
as ratios to PGS in the same run; for Newton also the sparse factorizations and the fallbacks to
sweeps. With --siconos, Siconos's Lemke solver (fc2d_lexicolemke, Debian's python3-siconos run
as a subprocess on the problems exported in FCLIB's format) is timed on the same steps.

With --scene hard, the reference alone on every `--every`-th step of each scene of the stability
study (`dc study stability`): how many steps it solves exactly, how many it pivoted, the worst
residual and the time.

    dc study exact [--scene pile|pyramid|both|hard] [--every 5] [--siconos]
"""
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from deepcontact.scene.generators import generate
from deepcontact.simulate.problems import problems as step_problems
from deepcontact.solver.pgs import solve
from deepcontact.solver.reference import CAP, TOLERANCE, reference_solution   # (the reference's own exactness)
from .stability import FULL
from .text import StudyText


def problems(name, every, scenes=None):
    if scenes is None:
        scenes = [generate("pile", s, {}) for s in (1000, 1001)] if name == "pile" else [generate("pyramid", 0, {"base": 20})]
    return [problem for scene in scenes for _, problem in step_problems(scene, every=every)]


def timed(problem, accelerate, tolerance=TOLERANCE, cap=CAP):
    """Our solver from zero to the tolerance: (Solution, seconds)."""
    zero = np.zeros(problem.points)
    t0 = time.perf_counter()
    s = solve(problem, zero, zero, mode="float64", max_iterations=cap, tolerance=tolerance, stop_on="residual",
              accelerate=accelerate)
    return s, time.perf_counter() - t0


def referenced(problem):
    t0 = time.perf_counter()
    s = reference_solution(problem, TOLERANCE, CAP)
    return s, time.perf_counter() - t0


def siconos_times(steps):
    """Seconds Siconos's Lemke takes per problem, and its residual by our measure."""
    from deepcontact.exchange import fclib, peer
    with tempfile.TemporaryDirectory() as tmp:
        paths = [fclib.write_problem(p, Path(tmp) / f"step-{i:04d}.hdf5") for i, p in enumerate(steps)]
        return peer.solve_files(paths, solver="lemke")


def report(name, steps, use_siconos, out):
    pgs = [timed(p, "none") for p in steps]
    newton = [timed(p, "newton") for p in steps]
    hard = [i for i, (s, _) in enumerate(pgs) if s.iterations >= CAP]
    out(f"\n{name}: {len(steps)} steps, {sum(p.points for p in steps) / len(steps):.0f} contact points on average, "
          f"{len(hard)} where PGS stops at its cap")
    out("| solver | reach 1e-12 | worst residual | median ms | total s | on PGS's capped steps: median ms | "
          "factorizations (median) | fallbacks (total) |")
    out("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    base_median = statistics.median(t for _, t in pgs)
    base_hard = statistics.median(pgs[i][1] for i in hard) if hard else float("nan")
    rows = [("PGS from zero (reference until now)", pgs), ("proximal Newton (accelerate newton)", newton),
            ("reference: Newton, then local pivots where it stalls", [referenced(p) for p in steps])]
    for label, runs in rows:
        med = statistics.median(t for _, t in runs)
        hard_ms = statistics.median(runs[i][1] for i in hard) if hard else float("nan")
        reached = sum(s.residual < TOLERANCE for s, _ in runs)
        worst = max(s.residual for s, _ in runs)
        fact = statistics.median(s.factorizations for s, _ in runs)
        falls = sum(s.newton_fallbacks for s, _ in runs)
        out(f"| {label} | {reached} | {worst:.1e} | {med * 1e3:.2f} ({med / base_median:.2f}x) | "
              f"{sum(t for _, t in runs):.2f} | {hard_ms * 1e3:.1f} ({hard_ms / base_hard:.3f}x) | {fact:.0f} | {falls} |")
    if use_siconos:
        times, residuals = siconos_times(steps)
        med = statistics.median(times)
        hard_ms = statistics.median(times[i] for i in hard) if hard else float("nan")
        reached = sum(r < TOLERANCE for r in residuals)
        out(f"| Siconos fc2d Lemke (subprocess; solve time only) | {reached} | {max(residuals):.1e} | "
              f"{med * 1e3:.2f} ({med / base_median:.2f}x) | {sum(times):.2f} | {hard_ms * 1e3:.1f} "
              f"({hard_ms / base_hard:.3f}x) | | |")


def report_hard(every, out, progress=lambda n: None):
    """The reference on every `every`-th step of each scene of the stability study; progress(1)
    as each is done."""
    which = "every step" if every == 1 else f"one step in {every}"
    out(f"\nthe reference on {which} of the stability study's scenes (to 1e-12, from zero)")
    out("| scene | steps | contact points (mean) | reach 1e-12 | pivoted | worst residual | total s |")
    out("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for case in FULL:
        steps = problems(case.generator, every, [generate(case.generator, 0, case.params)])
        runs = [referenced(p) for p in steps]
        misses = [f"step {p.index}: {s.residual:.1e}" for p, (s, _) in zip(steps, runs) if s.residual >= TOLERANCE]
        out(f"| {case.label} | {len(steps)} | {statistics.mean(p.points for p in steps):.0f} | "
              f"{len(steps) - len(misses)} | {sum(s.pivoted for s, _ in runs)} | {max(s.residual for s, _ in runs):.1e} | "
              f"{sum(t for _, t in runs):.3f} |" + (f" misses: {'; '.join(misses[:5])}" if misses else ""))
        progress(1)


def scenes(scene="both"):
    """How many scenes the study solves (what its progress counts)."""
    return len(FULL) if scene == "hard" else 2 if scene == "both" else 1


def run(scene="both", every=5, siconos=False, out=None, progress=None) -> StudyText:
    """The study's tables (a StudyText; `out` one to add to): the pile and the pyramid (or one of
    them), or the hard scenes. progress(1) as each scene is done."""
    out = StudyText() if out is None else out
    progress = progress or (lambda n: None)
    if scene == "hard":
        report_hard(every, out, progress)
        return out
    for name in (["pile", "pyramid"] if scene == "both" else [scene]):
        report(name, problems(name, every), siconos, out)
        progress(1)
    return out
