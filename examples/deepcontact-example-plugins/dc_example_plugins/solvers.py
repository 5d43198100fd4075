"""A solver method as a plug-in: damped projected Jacobi on the step's local problem.

The contract (docs/api.md, "Bring your own solver method"): a class the registry calls with no
arguments; the instance is called once per solve with the step's problem, a start (one float64
normal and one tangent impulse per contact point, N·s) and a `deepcontact.SolveSettings`, and
returns a `deepcontact.MethodResult`: the impulses and the residual after each iteration. The
whole call is timed as solving. deepcontact checks the answer (shapes, finite, the friction cone)
and judges it by its own residual, whatever the method reports.
"""
import numpy as np

from deepcontact import MethodResult, local_problem, local_residual


class ProjectedJacobi:
    """Every row updated from the same iterate (so a step could run in parallel), each update
    scaled by `damping` < 1: Jacobi without damping oscillates on stacked contacts."""

    def __init__(self, damping=0.5):
        self.damping = damping

    def __call__(self, problem, start_normal, start_tangent, settings):
        lp = local_problem(problem)   # u = W r + q, per contact point its (normal, tangent) pair
        diagonal = lp.W.diagonal()
        diagonal = np.where(diagonal > 0, diagonal, np.inf)   # (rows no body can move: never updated)
        r = lp.reaction(start_normal, start_tangent)
        residuals = []
        for _ in range(settings.max_iterations):
            x = r - self.damping * (lp.W @ r + lp.q) / diagonal
            normal = np.maximum(x[0::2], 0.0)
            r[0::2], r[1::2] = normal, np.clip(x[1::2], -lp.mu * normal, lp.mu * normal)
            residuals.append(local_residual(lp, r))   # (deepcontact judges the answer again, natively)
            if residuals[-1] < settings.tolerance:
                break
        normal, tangent = lp.impulses(r, problem.points)
        return MethodResult(normal=normal, tangent=tangent, residuals=np.array(residuals))
