"""A solver method as a plug-in: damped projected Jacobi on the step's explicit LCP.

The contract (docs/api.md, "Bring your own solver method"): a class the registry calls with no
arguments; the instance is called once per solve with the step's problem, a start (one float64
normal and one tangent impulse per contact point, N·s) and a `deepcontact.SolveSettings`, and
returns a `deepcontact.MethodResult`: the impulses and the residual after each iteration. The
whole call is timed as solving. deepcontact checks the answer (shapes, finite, the friction cone)
and judges it by its own residual, whatever the method reports.
"""
import numpy as np

from deepcontact import MethodResult, build_lcp, judge


class ProjectedJacobi:
    """Every row updated from the same iterate (so a step could run in parallel), each update
    scaled by `damping` < 1: Jacobi without damping oscillates on stacked contacts."""

    def __init__(self, damping=0.5):
        self.damping = damping

    def __call__(self, problem, start_normal, start_tangent, settings):
        lcp = build_lcp(problem)
        normal_rows = lcp.kind == 0
        lam = np.where(normal_rows, start_normal[lcp.point], start_tangent[lcp.point])
        diagonal = np.where(np.diag(lcp.A) > 0, np.diag(lcp.A), np.inf)   # (rows no body can move: never updated)
        n, t = np.array(start_normal), np.array(start_tangent)
        residuals = []
        for _ in range(settings.max_iterations):
            step = lam - self.damping * (lcp.A @ lam + lcp.b) / diagonal
            lam = np.where(normal_rows, np.maximum(step, 0.0), step)
            bound = lcp.friction * lam[np.maximum(lcp.normal_row, 0)]
            lam = np.where(normal_rows, lam, np.clip(lam, -bound, bound))
            n[lcp.point[normal_rows]] = lam[normal_rows]
            t[lcp.point[~normal_rows]] = lam[~normal_rows]
            residuals.append(judge(problem, n, t).residual)
            if residuals[-1] < settings.tolerance:
                break
        return MethodResult(normal=n, tangent=t, residuals=np.array(residuals))
