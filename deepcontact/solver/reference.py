"""The reference solution of a step: the "Copy" oracle and the ground truth for errors.

Float64 PGS from zero, run until the normalised min-map residual falls below 1e-12, or 100,000
sweeps; the residual it reached is part of the answer (PGS converges slowly on stacked, redundant
contacts: some steps end at the cap, and reports count them rather than pretending). It starts
from zero so that it does not depend on any start being compared: with redundant contacts the
impulses of an exact solution are not unique (the body velocities after the solve are), and a
reference started from one of the starts would favour it.
"""
import numpy as np

from .pgs import Solution, solve

TOLERANCE = 1e-12
CAP = 100_000


def reference_solution(problem, tolerance=TOLERANCE, cap=CAP, relaxation=1.0) -> Solution:
    """Solve from zero to the tolerance (plain PGS, float64)."""
    zero = np.zeros(problem.points)
    return solve(problem, zero, zero, mode="float64", max_iterations=cap, tolerance=tolerance, stop_on="residual",
                 relaxation=relaxation)
