"""The reference solution of a step: the "Copy" oracle and the ground truth for errors.

Float64, from zero, to a normalised min-map residual below 1e-12 or 100,000 sweeps: a few PGS
sweeps, then proximal semismooth Newton steps on the whole step (accelerate="newton",
native/newton.hpp), back to sweeps whenever a Newton step fails. On some stacked, redundant steps
Newton stalls near, not at, an exact solution; there (up to PIVOT_POINTS contact points) Lemke's
pivoting (solver/pivoting.py) and Newton from its answer take over, and the better answer is
kept (Solution.pivoted says so). The residual reached, the factorizations and the fallbacks are
part of the answer: reports count the steps that still miss 1e-12 rather than pretending. It starts from zero so that it does not depend on any start being
compared. Exact solutions of a frictional step need not be unique, in impulses nor in body
velocities (tests/test_peer.py: Siconos's Lemke solution of the same step can differ): judge a
solution by its residual.
"""
import numpy as np

from .pgs import Solution, solve

TOLERANCE = 1e-12
CAP = 100_000
PIVOT_POINTS = 250   # a dense tableau of 4 x points rows: beyond this Lemke costs more than it gives


def reference_solution(problem, tolerance=TOLERANCE, cap=CAP, relaxation=1.0, accelerate="newton",
                       pivot=True) -> Solution:
    """Solve from zero to the tolerance (float64; accelerate="none" is plain PGS, the reference
    before Newton; pivot: Lemke where Newton stalls)."""
    zero = np.zeros(problem.points)
    s = solve(problem, zero, zero, mode="float64", max_iterations=cap, tolerance=tolerance, stop_on="residual",
              relaxation=relaxation, accelerate=accelerate)
    if not pivot or accelerate != "newton":
        return s
    return finish_by_pivoting(problem, s, tolerance)


def finish_by_pivoting(problem, s: Solution, tolerance=TOLERANCE) -> Solution:
    """Where Newton's solution s misses the tolerance (and the step has at most PIVOT_POINTS
    points): Lemke's pivoting, then Newton from its answer; the better of that and s."""
    if s.residual < tolerance or problem.points > PIVOT_POINTS:
        return s
    from .pivoting import pivoted_impulses
    pair = pivoted_impulses(problem)
    if pair is None:
        return s
    polished = solve(problem, *pair, mode="float64", max_iterations=2000, tolerance=tolerance, stop_on="residual",
                     accelerate="newton")
    if polished.residual >= s.residual:
        return s
    polished.pivoted = True
    polished.iterations += s.iterations
    polished.factorizations += s.factorizations
    polished.newton_fallbacks += s.newton_fallbacks
    return polished
