"""Projected Gauss-Seidel on a StepProblem: the thin Pythonic face of the native solver.

Modes:
  exact      float32, Box2D's arithmetic and order, starts used as given: Box2D's velocity
             solver, bit for bit (checked by `dc validate --replay`).
  float32    the same arithmetic, but starts are sanitised first.
  float64    double precision; with relaxation w != 1 it is PSOR.

Acceleration (float32/float64): `nncg` adds to each sweep's result beta times the last search
direction (Fletcher-Reeves beta = |change|^2 / |last change|^2, restarting when beta > 1); the
next sweep projects it back. It costs two more passes over the contact points per sweep (about
1.5x a plain sweep, docs/results.md, "Faster to the same accuracy").

Stopping: a fixed count (tolerance 0) or the first sweep whose chosen measure falls below the
tolerance, capped at max_iterations. Measures (per sweep, see docs/solver.md, "Measuring convergence"):
  thesis     max over contact points of |(d ln, d lt)|, the change of the iterate in the sweep
  velocity   max over rows of |d lambda| * k, the change of contact velocity it causes (m/s)
  residual   max over rows of the min-map residual of the LCP in velocity units, divided by the
             largest free relative velocity of the step (dimensionless)
"""
from dataclasses import dataclass

import numpy as np

from .._box2d import solve_contacts

MEASURES = ("thesis", "velocity", "residual")
# none: plain (P)SOR sweeps. nncg: after each sweep the iterate also moves along a conjugate
# direction (nonsmooth nonlinear conjugate gradient, Silcowitz, Niebe and Erleben 2010).
ACCELERATIONS = ("none", "nncg")
# Box2D moves a body at most b2_maxTranslation = 2 m per step; a start that alone would change a
# contact's velocity by more than twice that speed is not an impulse the step could need.
MAX_TRANSLATION = 2.0


@dataclass
class Solution:
    normal_impulse: np.ndarray
    tangent_impulse: np.ndarray
    velocity: np.ndarray       # body velocities after the solve (v* plus the impulses)
    omega: np.ndarray
    iterations: int
    history: np.ndarray        # (iterations, 3): thesis, velocity, residual per sweep (if asked)
    residual: float            # normalised residual at the end
    sanitized: dict
    stats: dict
    relaxation_fallback: int = 0   # the sweep after which over-relaxation fell back to w = 1 (0: never)
    relaxation: float = 1.0        # the w it was asked to use

    def measure(self, name):
        return self.history[:, MEASURES.index(name)]


def solve(problem, start_normal=None, start_tangent=None, *, mode="float64", max_iterations=None,
          tolerance=0.0, stop_on="residual", relaxation=1.0, history=False, prune=True,
          final_residual=True, guard=True, accelerate="none") -> Solution:
    """Solve the step's contact problem from a start (default: Box2D's own warm start).

    With relaxation w != 1 (PSOR) or accelerate="nncg", and guard, a solve whose residual climbs
    tenfold above its best continues as plain PGS (checked every 4 sweeps;
    Solution.relaxation_fallback says when). A solve always ends on a sweep's projected iterate."""
    if mode not in ("exact", "float32", "float64"):
        raise ValueError(f"mode must be exact, float32 or float64, not {mode!r}")
    if mode == "exact" and relaxation != 1.0:
        raise ValueError("exact mode is Box2D's PGS: relaxation must be 1")
    if accelerate not in ACCELERATIONS:
        raise ValueError(f"accelerate must be one of {', '.join(ACCELERATIONS)}, not {accelerate!r}")
    if mode == "exact" and accelerate != "none":
        raise ValueError("exact mode is Box2D's PGS: no acceleration")
    n = problem.start_normal if start_normal is None else start_normal
    t = problem.start_tangent if start_tangent is None else start_tangent
    out = solve_contacts(
        problem.bodies, problem.contacts, np.asarray(n, dtype=np.float64), np.asarray(t, dtype=np.float64),
        dt=problem.dt, gravity=problem.gravity, block_solve=problem.block_solve, prune=prune,
        precision="float64" if mode == "float64" else "float32",
        max_iterations=problem.velocity_iterations if max_iterations is None else max_iterations,
        tolerance=tolerance, stop_on=stop_on if tolerance > 0 else "none", relaxation=relaxation,
        history=history, sanitize=mode != "exact",
        max_velocity=2.0 * MAX_TRANSLATION / problem.dt, final_residual=final_residual, guard=guard,
        conjugate=accelerate == "nncg")
    return Solution(normal_impulse=out["normal_impulse"], tangent_impulse=out["tangent_impulse"],
                    velocity=out["velocity"], omega=out["omega"], iterations=out["iterations"],
                    history=out["history"], residual=out["residual"], sanitized=out["sanitized"],
                    stats=out["stats"], relaxation_fallback=out["relaxation_fallback"],
                    relaxation=float(relaxation))
