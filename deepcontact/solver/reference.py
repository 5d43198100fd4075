"""The reference solution of a step: the "Copy" oracle and the ground truth for errors.

Float64, from zero, to a normalised min-map residual below 1e-12 or 100,000 sweeps: a few PGS
sweeps, then proximal semismooth Newton steps on the whole step (accelerate="newton",
native/newton.hpp), back to sweeps whenever a Newton step fails. The residual it reached, the
factorizations and the fallbacks are part of the answer: on some stacked, redundant steps
Newton stalls near, not at, an exact solution and the sweeps run to the cap (reports count them
rather than pretending). It starts from zero so that it does not depend on any start being
compared. Exact solutions of a frictional step need not be unique, in impulses nor in body
velocities (tests/test_peer.py: Siconos's Lemke solution of the same step can differ): judge a
solution by its residual.
"""
import numpy as np

from .pgs import Solution, solve

TOLERANCE = 1e-12
CAP = 100_000


def reference_solution(problem, tolerance=TOLERANCE, cap=CAP, relaxation=1.0, accelerate="newton") -> Solution:
    """Solve from zero to the tolerance (float64; accelerate="none" is plain PGS, the reference
    before Newton)."""
    zero = np.zeros(problem.points)
    return solve(problem, zero, zero, mode="float64", max_iterations=cap, tolerance=tolerance, stop_on="residual",
                 relaxation=relaxation, accelerate=accelerate)
