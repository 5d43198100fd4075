"""How far storing a step's impulses as float32 can move its residual.

A step file holds each impulse as float32, as Box2D does, so the answer of a float64 solve is
rounded as it is written: each stored impulse lies within half a float32 spacing of the one the
solve measured its residual on. `rounding_bound` is the most the residual (docs/solver.md,
"Measuring convergence") can differ between any two sets of impulses that close, derived row by
row (min, max and clamp move by at most the largest move of their arguments):

    normal row    |d min(k_n n, v_n)|                 <= max(k_n |dn|, |dv_n|)
    tangent row   |d (x - clamp(x - v_t, -h, h))|      <= k_t |dt| + max(k_t |dt| + |dv_t|, mu k_t |dn|)

with x = k_t t, h = mu k_t n, and the rows' velocity changes bounded through the bodies they touch,
|dv| <= |J| M^-1 |J|^T |d lambda|; divided by the residual's scale, as the residual is. It counts
the rounding of the impulses only: float64's own rounding (1e-16 of each value) is not in it.
"""
from typing import TYPE_CHECKING

import numpy as np

from .._box2d import contact_rows
from ..errors import InputError

if TYPE_CHECKING:   # (for the annotations only)
    from .problem import StepProblem


def half_spacing(values: np.ndarray) -> np.ndarray:
    """Half the float32 spacing at each value (float64): the most rounding to float32 moved it."""
    stored = np.abs(np.asarray(values, dtype=np.float64).astype(np.float32))
    return np.spacing(stored).astype(np.float64) / 2


def rounding_bound(problem: "StepProblem", normal: np.ndarray, tangent: np.ndarray) -> float:
    """The most the step's normalised residual can change when each impulse moves by up to half a
    float32 spacing at the given (stored) impulses (module docstring), on the rows the solver
    measures (the same assembly as solver.pgs.solve's)."""
    try:
        rows = contact_rows(problem.bodies, problem.contacts, problem.settings(prune=True))
    except ValueError as e:   # (the native checks of the step's values, as solve's)
        raise InputError(str(e)) from None
    active = rows["active"]
    friction = rows["friction_row"] & active
    dn = np.where(active, half_spacing(normal), 0.0)
    dt = np.where(friction, half_spacing(tangent), 0.0)
    jac = np.abs(rows["jacobian"]).reshape(-1, 2, 6)   # per point: normal row, tangent row; a's dofs, b's
    dv_n, dv_t = _row_velocity_changes(jac, dn, dt, rows["row_a"], rows["row_b"], problem.bodies)
    kn, kt = rows["k_normal"], rows["k_tangent"]
    normal_row = np.maximum(kn * dn, dv_n)
    tangent_row = np.where(friction, kt * dt + np.maximum(kt * dt + dv_t, rows["friction"] * kt * dn), 0.0)
    worst = np.where(active, np.maximum(normal_row, tangent_row), 0.0).max(initial=0.0)
    return float(worst / rows["scale"])


def _row_velocity_changes(jac, dn, dt, row_a, row_b, bodies):
    """Bounds of each point's normal and tangent relative-velocity change when its step's impulses
    move by dn, dt: |J| M^-1 |J|^T |d lambda|, summed per body dof (vx, vy, w)."""
    inverse = np.asarray(bodies["inv_mass"], np.float64), np.asarray(bodies["inv_inertia"], np.float64)
    push = jac[:, 0, :] * dn[:, None] + jac[:, 1, :] * dt[:, None]   # |J^T| |d lambda|, per point's 6 dofs
    count = len(inverse[0])
    per_dof = np.stack([(np.bincount(row_a, push[:, c], count) + np.bincount(row_b, push[:, 3 + c], count))
                        * inverse[c // 2] for c in range(3)], axis=1)
    moved = np.concatenate([per_dof[row_a], per_dof[row_b]], axis=1)
    return (jac[:, 0, :] * moved).sum(axis=1), (jac[:, 1, :] * moved).sum(axis=1)
