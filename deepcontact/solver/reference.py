"""The reference solution of a step: the "Copy" oracle and the ground truth for errors.

Float64, from zero, to a normalised min-map residual below 1e-12: a few PGS sweeps, then proximal
semismooth Newton steps on the whole step (accelerate="newton", native/newton.hpp), back to sweeps
whenever a Newton step fails. On some stacked, redundant steps Newton stalls near a point that is
not a solution (an exact one exists with other contacts separating and sliding). After
FIRST_SWEEPS without an exact answer the reference pivots (solver/pivoting.py): Lemke's method on
the neighbourhood of the contacts that carry the residual, the others held, then Newton from
there; a wider neighbourhood; the whole step (up to PIVOT_POINTS contact points), as it is and
with q slightly perturbed (a degenerate step's ties end Lemke on a ray or a wrong basis); and
last the solve in body space (accelerate="bodyspace") from zero to the cap, which is exact on most
of the settling pyramid steps too wide to pivot. The best answer is kept (Solution.pivoted says that a
pivot led to it). The residual reached, the sweeps, factorizations and fallbacks are part of the
answer: reports count the steps that still miss 1e-12 rather than pretending. It starts from
zero so that it does not depend on any start being compared. Exact solutions of a frictional step
need not be unique, in impulses nor in body velocities (tests/test_peer.py: Siconos's Lemke
solution of the same step can differ): judge a solution by its residual.
"""
from typing import TYPE_CHECKING

import numpy as np

from .. import arguments
from .pgs import Solution, require_problem, solve

if TYPE_CHECKING:   # (for the annotations only)
    from .problem import StepProblem

TOLERANCE = 1e-12
CAP = 100_000
FIRST_SWEEPS = 2048     # Newton's sweeps before pivoting: most steps are exact within a few hundred
POLISH_SWEEPS = 3000    # Newton after each pivot
# (rings, share): the contacts carrying at least `share` of the largest residual, and `rings` rings
# of contacts around them, tried in turn, each around the residual of the best answer so far (so a
# neighbourhood tried again is another one once a pivot has moved the residual)
NEIGHBOURHOODS = ((0, 0.1), (1, 0.1), (0, 0.1), (1, 0.1), (1, 0.03), (2, 1e-2))
PIVOT_POINTS = 250      # a dense tableau of 4 x points rows: beyond this Lemke costs more than it gives
PERTURBATIONS = (0.0, 1e-12, 1e-10, 1e-8)   # of q, for the whole step's Lemke: degenerate steps need one


def reference_solution(problem: "StepProblem", tolerance: float = TOLERANCE, cap: int = CAP, relaxation: float = 1.0,
                       accelerate: str = "newton", pivot: bool = True) -> Solution:
    """Solve from zero to the tolerance (float64; accelerate="none" is plain PGS, the reference
    before Newton; pivot: Lemke where Newton stalls)."""
    require_problem(problem)
    cap = arguments.whole(cap, "cap")
    relaxation = arguments.number(relaxation, "relaxation", 0.0, 2.0)   # (the native rule: in (0, 2))
    zero = np.zeros(problem.points)
    pivoting = pivot and accelerate == "newton"
    s = _newton(problem, zero, zero, min(cap, FIRST_SWEEPS) if pivoting else cap, tolerance,
                relaxation=relaxation, accelerate=accelerate)
    return finish_by_pivoting(problem, s, tolerance, cap) if pivoting else s


def _newton(problem, normal, tangent, sweeps, tolerance, relaxation=1.0, accelerate="newton"):
    return solve(problem, normal, tangent, mode="float64", max_iterations=sweeps, tolerance=tolerance,
                 stop_on="residual", relaxation=relaxation, accelerate=accelerate)


def finish_by_pivoting(problem, s: Solution, tolerance=TOLERANCE, cap=CAP) -> Solution:
    """From Newton's answer s, if it misses the tolerance: pivots (local, wider, whole), each
    followed by Newton, then the solve in body space from zero to the cap; the best answer, its
    work summed."""
    from .pivoting import StepPivots, lemke_tableau  # (scipy: imported where a step pivots)
    if s.residual < tolerance:
        return s
    step = StepPivots(problem)
    best, work = s, [s]
    attempts = [lambda b, rings=rings, share=share: step.local(b.normal_impulse, b.tangent_impulse, rings, share)
                for rings, share in NEIGHBOURHOODS]
    if problem.points <= PIVOT_POINTS:   # the whole step, natively, then on the tableau (its path can differ)
        attempts += [lambda b, method=method, perturb=perturb: step.whole(method, perturb)
                     for perturb in PERTURBATIONS for method in (None, lemke_tableau)]
        attempts += attempts[:len(NEIGHBOURHOODS)]   # the neighbourhoods again, around what is left
    for attempt in attempts:
        pair = attempt(best)
        if pair is None:
            continue
        t = _newton(problem, *pair, POLISH_SWEEPS, tolerance)
        work.append(t)
        if _better(t, best):
            best = t
            best.pivoted = True
        if best.residual < tolerance:
            return _summed(best, work)
    left = cap - sum(w.iterations for w in work)
    if left > 0:   # last, the solve in body space from zero: it is exact on steps too wide to pivot
        zero = np.zeros(problem.points)
        t = _newton(problem, zero, zero, left, tolerance, accelerate="bodyspace")
        work.append(t)
        if _better(t, best):
            best = t
    return _summed(best, work)


def _better(t: Solution, best: Solution) -> bool:
    """t's residual below best's, any number below none (a NaN residual, an iterate that left float
    range: compared, no answer ever replaced it)."""
    return t.residual < best.residual or (np.isnan(best.residual) and not np.isnan(t.residual))


def _summed(best: Solution, work) -> Solution:
    """best, carrying the iterations, factorizations and fallbacks of every solve that led to it."""
    best.iterations = sum(w.iterations for w in work)
    best.factorizations = sum(w.factorizations for w in work)
    best.newton_fallbacks = sum(w.newton_fallbacks for w in work)
    best.newton_iterations = sum(w.newton_iterations for w in work)
    best.outer_iterations = sum(w.outer_iterations for w in work)
    return best
