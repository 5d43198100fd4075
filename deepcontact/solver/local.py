"""A step's contact problem as a local problem: u = W r + q over the contact points the solver
uses (per point its normal row, then its tangent row), with Coulomb's law per point. W = J M^-1 J^T
and q = J v* - bias come from the native assembly (deepcontact._box2d.contact_rows: lever arms,
effective masses, restitution bias, the points Box2D drops left out), in float64: the one
assembly every global method, the FCLIB export and the solver loss use. `residual` is the
solver's own measure (the normalised min-map residual, docs/solver.md) on it.

Coulomb's law in 2D, as PGS solves it: 0 <= r_n complementary to u_n >= 0; |r_t| <= mu r_n,
u_t = 0 inside the bound and r_t = -mu r_n sign(u_t) when sliding.
"""
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from .. import arguments
from .._box2d import contact_rows
from .pgs import native_refusal, require_problem

if TYPE_CHECKING:   # (for the annotations only)
    from .problem import StepProblem


@dataclass
class LocalProblem:
    """A step's contact problem as u = W r + q (module docstring); r and u are per contact point
    (normal, tangent) pairs, the point of each pair is `points[j]`, a row of StepProblem.contacts."""
    W: sp.csc_matrix      # (2m, 2m), per contact point its normal row, then its tangent row
    q: np.ndarray         # (2m,)
    mu: np.ndarray        # (m,)
    points: np.ndarray    # (m,) the problem's contact point (row of StepProblem.contacts) of each contact

    def reaction(self, normal, tangent):
        """Per-point impulses of the StepProblem as FCLIB's r."""
        r = np.empty(2 * len(self.points))
        r[0::2] = np.asarray(normal, np.float64)[self.points]
        r[1::2] = np.asarray(tangent, np.float64)[self.points]
        return r

    def impulses(self, r, count):
        """FCLIB's r back as per-point (normal, tangent) arrays of length count (0 where left out)."""
        normal, tangent = np.zeros(count), np.zeros(count)
        normal[self.points] = r[0::2]
        tangent[self.points] = r[1::2]
        return normal, tangent


def jacobian(problem: "StepProblem"):
    """The step's contact rows in body space, from the native assembly (float64):
    (J, inv_m, v, rows, points). J (sparse, 2m x 3 bodies) maps the bodies' velocities (vx, vy, w
    per body) to the rows' relative velocities, per contact point its normal row, then its tangent
    row; inv_m the dofs' inverse masses and inertias; v the velocities before the contact impulses
    (v*); rows the native assembly; points the problem's contact points solved."""
    try:
        rows = contact_rows(problem.bodies, problem.contacts, problem.settings(prune=False))
    except (ValueError, TypeError, KeyError, IndexError) as e:   # (the native checks of the step's arrays, as solve's)
        raise native_refusal(e) from None
    points = np.nonzero(rows["active"])[0]
    m, nb = len(points), len(problem.bodies["inv_mass"])
    jac = rows["jacobian"][points].reshape(m, 2, 6)   # (native/body_rows.hpp: normal, tangent rows)
    a, b = rows["row_a"][points], rows["row_b"][points]
    J_rows, J_cols, J_vals = [], [], []
    for k in (0, 1):
        for c in range(6):
            J_rows.append(2 * np.arange(m) + k)
            J_cols.append(3 * (a if c < 3 else b) + c % 3)
            J_vals.append(jac[:, k, c])
    J = sp.csr_matrix((np.concatenate(J_vals), (np.concatenate(J_rows), np.concatenate(J_cols))),
                      shape=(2 * m, 3 * nb))
    inv_m = np.repeat(problem.bodies["inv_mass"].astype(np.float64), 3)
    inv_m[2::3] = problem.bodies["inv_inertia"].astype(np.float64)
    v = np.zeros(3 * nb)
    v[0::3], v[1::3], v[2::3] = rows["velocity"][:, 0], rows["velocity"][:, 1], rows["omega"]
    return J, inv_m, v, rows, points


def local_problem(problem: "StepProblem", body_rows: tuple | None = None) -> LocalProblem:
    """The step's problem as a local problem (float64; sparse W), from the native assembly;
    body_rows: jacobian(problem), where the caller has it already."""
    require_problem(problem)
    J, inv_m, v, rows, points = jacobian(problem) if body_rows is None else body_rows
    W = (J @ sp.diags(inv_m) @ J.T).tocsc()
    W.sort_indices()
    q = J @ v
    q[0::2] -= rows["bias"][points]
    return LocalProblem(W=W, q=q, mu=rows["friction"][points].astype(np.float64), points=points)


def point_residuals(lp: LocalProblem, r: np.ndarray) -> np.ndarray:
    """Per contact, the larger |F| of its normal and tangent rows (velocity units, unnormalised)."""
    u = lp.W @ r + lp.q
    k = lp.W.diagonal()
    kn, kt = k[0::2], k[1::2]
    rn, rt, un, ut = r[0::2], r[1::2], u[0::2], u[1::2]
    fn = np.minimum(kn * rn, un)
    hi = lp.mu * kt * rn
    ft = kt * rt - np.clip(kt * rt - ut, -hi, hi)
    ft = np.where(lp.mu > 0, ft, kt * rt)
    return np.maximum(np.abs(fn), np.abs(ft))


def residual_scale(lp: LocalProblem) -> float:
    """The residual's denominator: the step's largest free relative velocity (of the rows solved)."""
    return max(np.abs(lp.q[0::2]).max(initial=0.0), np.abs(np.where(lp.mu > 0, lp.q[1::2], 0.0)).max(initial=0.0), 1e-30)


def residual(lp: LocalProblem, r: np.ndarray) -> float:
    """The solver's normalised min-map residual of r on the local problem (docs/solver.md)."""
    arguments.instance(lp, "lp", LocalProblem, "a LocalProblem (local_problem returns one)")
    r = arguments.vector(r, "r", len(lp.q))
    return float(point_residuals(lp, r).max(initial=0.0) / residual_scale(lp))
