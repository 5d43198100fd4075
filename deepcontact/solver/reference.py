"""The reference solution of a step: the "Copy" oracle and the ground truth for errors.

Float64 PGS run until the normalised min-map residual falls below 1e-12, or 100,000 sweeps;
the residual it reached is part of the answer (PGS converges slowly on stacked, redundant
contacts: some steps end at the cap, and the report says so rather than pretending).
"""
from .pgs import Solution, solve

TOLERANCE = 1e-12
CAP = 100_000


def reference_solution(problem, tolerance=TOLERANCE, cap=CAP, relaxation=1.0) -> Solution:
    """Solve from Box2D's own warm start (the best cheap start there is) to the tolerance."""
    return solve(problem, mode="float64", max_iterations=cap, tolerance=tolerance, stop_on="residual",
                 relaxation=relaxation)
