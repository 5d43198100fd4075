"""The step's contact problem as an explicit LCP, and a slow textbook PGS on it: the pure-Python
reference the native assembly and solver are tested against (written from Box2D's sources and the
thesis, independently of deepcontact/native and deepcontact/solver/local.py). In impulse form
(Box2D's units), with v* the velocities after gravity and damping:

    A = J M^-1 J^T,    b = J v* - bias,
    normal rows:  0 <= l_n  complementary to  (A l + b)_n >= 0
    tangent rows: -mu l_n <= l_t <= mu l_n, with (A l + b)_t = 0 inside the bounds

The thesis writes it in forces (its eq. 2.28): A_thesis = J M^-1 J^T dt and
b_thesis = J (dt M^-1 F_ext + v); its multipliers are these impulses divided by dt.
Rows are ordered as Box2D visits them: per manifold, the tangent rows of its points, then
its normal rows.
"""
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:   # (for the annotations only)
    from .problem import StepProblem

FLT_EPSILON = float(np.finfo(np.float32).eps)


def _rot(angle):
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


def world_manifold(mtype, local_normal, local_point, point_local, xf_a, xf_b, radius_a, radius_b):
    """Box2D's b2WorldManifold::Initialize in float64: (normal, [points])."""
    (qa, pa), (qb, pb) = xf_a, xf_b
    if mtype == 0:
        point_a = qa @ local_point + pa
        point_b = qb @ point_local[0] + pb
        normal = np.array([1.0, 0.0])
        d = point_b - point_a
        if d @ d > FLT_EPSILON ** 2:
            normal = d / np.linalg.norm(d)
        ca = point_a + radius_a * normal
        cb = point_b - radius_b * normal
        return normal, [0.5 * (ca + cb)]
    if mtype == 1:   # face of A: B's points clipped against it
        return _face(xf_a, xf_b, local_normal, local_point, point_local, radius_a, radius_b)
    normal, pts = _face(xf_b, xf_a, local_normal, local_point, point_local, radius_b, radius_a)
    return -normal, pts   # (face of B: the normal points from A to B all the same)


def _face(xf_ref, xf_inc, local_normal, local_point, point_local, radius_ref, radius_inc):
    """A face manifold: the reference body's face normal, and per point the midpoint between the
    incident body's clip point and its projection onto the reference face."""
    (q_ref, p_ref), (q_inc, p_inc) = xf_ref, xf_inc
    normal = q_ref @ local_normal
    plane = q_ref @ local_point + p_ref
    pts = []
    for lp in point_local:
        clip = q_inc @ lp + p_inc
        on_ref = clip + (radius_ref - (clip - plane) @ normal) * normal
        on_inc = clip - radius_inc * normal
        pts.append(0.5 * (on_ref + on_inc))
    return normal, pts


@dataclass
class LCP:
    """A step's contact problem as an explicit LCP (module docstring): one row per normal or
    tangent impulse, in Box2D's order."""
    A: np.ndarray            # (rows, rows)
    b: np.ndarray            # (rows,)
    kind: np.ndarray         # 0 normal, 1 tangent
    point: np.ndarray        # the contact point (row of the problem) of each row
    normal_row: np.ndarray   # for tangent rows: the row of the same point's normal impulse
    friction: np.ndarray
    J: np.ndarray            # (rows, 3 * bodies)
    inv_mass: np.ndarray     # (3 * bodies,) the diagonal of M^-1
    v_free: np.ndarray       # (3 * bodies,) v* as (vx, vy, w) per body


def velocities_after_gravity(problem):
    bodies = problem.bodies
    n = len(bodies["angle"])
    v = np.zeros(3 * n)
    g = np.array(problem.gravity, dtype=np.float64)
    h = float(problem.dt)
    for i in range(n):
        vel = bodies["velocity"][i].astype(np.float64)
        w = float(bodies["omega"][i])
        if bodies["type"][i] == 2:
            vel = vel + h * float(bodies["inv_mass"][i]) * float(bodies["gravity_scale"][i]) * float(bodies["mass"][i]) * g
            vel = vel / (1.0 + h * float(bodies["linear_damping"][i]))
            w = w / (1.0 + h * float(bodies["angular_damping"][i]))
        v[3 * i:3 * i + 2] = vel
        v[3 * i + 2] = w
    return v


def build_lcp(problem: "StepProblem", prune: bool = True) -> LCP:
    """The explicit LCP of the step, in float64, from the problem's float32 data (dense: for
    analysis, references and plug-in methods on small steps; rows as the module docstring says)."""
    bodies, c = problem.bodies, problem.contacts
    nb = len(bodies["angle"])
    inv_m = np.zeros(3 * nb)
    xf = []
    for i in range(nb):
        inv_m[3 * i:3 * i + 2] = float(bodies["inv_mass"][i])
        inv_m[3 * i + 2] = float(bodies["inv_inertia"][i])
        q = _rot(float(bodies["angle"][i]))
        xf.append((q, bodies["center"][i].astype(np.float64) - q @ bodies["local_center"][i].astype(np.float64)))
    v_free = velocities_after_gravity(problem)
    rows_j, bias, kind, point, friction, normal_row = [], [], [], [], [], []
    k = 0
    while k < problem.points:
        count = int(c["point_count"][k])
        a, b = int(c["row_a"][k]), int(c["row_b"][k])
        normal, pts = world_manifold(int(c["manifold_type"][k]), c["local_normal"][k].astype(np.float64),
                                     c["local_point"][k].astype(np.float64),
                                     [c["point_local"][k + j].astype(np.float64) for j in range(count)],
                                     xf[a], xf[b], float(c["radius_a"][k]), float(c["radius_b"][k]))
        tangent = np.array([normal[1], -normal[0]])
        ca, cb = bodies["center"][a].astype(np.float64), bodies["center"][b].astype(np.float64)
        mu = float(c["friction"][k])
        e, threshold = float(c["restitution"][k]), float(c["restitution_threshold"][k])

        def row(direction, p):
            ra, rb = p - ca, p - cb
            j = np.zeros(3 * nb)
            j[3 * a:3 * a + 2] -= direction
            j[3 * a + 2] -= _cross(ra, direction)
            j[3 * b:3 * b + 2] += direction
            j[3 * b + 2] += _cross(rb, direction)
            return j

        first_normal = len(rows_j) + (count if (mu > 0 or not prune) else 0)
        if mu > 0 or not prune:
            for j in range(count):
                rows_j.append(row(tangent, pts[j]))
                bias.append(0.0)
                kind.append(1)
                point.append(k + j)
                friction.append(mu)
                normal_row.append(first_normal + j)
        for j in range(count):
            jn = row(normal, pts[j])
            vrel = jn @ v_free
            rows_j.append(jn)
            bias.append(-e * vrel if vrel < -threshold else 0.0)
            kind.append(0)
            point.append(k + j)
            friction.append(mu)
            normal_row.append(-1)
        k += count
    J = np.array(rows_j).reshape(len(rows_j), 3 * nb)
    A = (J * inv_m) @ J.T
    b = J @ v_free - np.array(bias)
    return LCP(A=A, b=b, kind=np.array(kind), point=np.array(point), normal_row=np.array(normal_row),
               friction=np.array(friction), J=J, inv_mass=inv_m, v_free=v_free)


def pgs(lcp: LCP, start_normal, start_tangent, iterations):
    """Textbook projected Gauss-Seidel on the explicit LCP (thesis Algorithm 1, with friction
    boxes), one row at a time in Python. Slow; the reference for the native solver."""
    lam = np.where(lcp.kind == 0, np.asarray(start_normal, float)[lcp.point],
                   np.asarray(start_tangent, float)[lcp.point])
    A, b = lcp.A, lcp.b
    for _ in range(iterations):
        for i in range(len(b)):
            if A[i, i] <= 0:
                continue
            x = lam[i] - (A[i] @ lam + b[i]) / A[i, i]
            if lcp.kind[i] == 0:
                lam[i] = max(x, 0.0)
            else:
                bound = lcp.friction[i] * lam[lcp.normal_row[i]]
                lam[i] = min(max(x, -bound), bound)
    n = np.zeros(len(start_normal))
    t = np.zeros(len(start_normal))
    n[lcp.point[lcp.kind == 0]] = lam[lcp.kind == 0]
    t[lcp.point[lcp.kind == 1]] = lam[lcp.kind == 1]
    return n, t


def natural_residual(lcp: LCP, normal, tangent):
    """max over rows of the min-map residual in velocity units, as the native solver defines it
    (before its normalisation)."""
    lam = np.where(lcp.kind == 0, np.asarray(normal, float)[lcp.point], np.asarray(tangent, float)[lcp.point])
    w = lcp.A @ lam + lcp.b
    k = np.diag(lcp.A)
    r = np.zeros(len(lam))
    nrm = lcp.kind == 0
    r[nrm] = np.minimum(k[nrm] * lam[nrm], w[nrm])
    tan = ~nrm
    hi = lcp.friction[tan] * lam[lcp.normal_row[tan]] * k[tan]
    x = k[tan] * lam[tan]
    r[tan] = x - np.clip(x - w[tan], -hi, hi)
    return float(np.max(np.abs(r))) if len(r) else 0.0
