"""What a global operator could cost if it were amortized across steps: measured on settled piles
before any such method is built (docs/results.md, "Amortizing the body-space operator").

The body-space solve works on A = M + J^T D J over the moving bodies' degrees of freedom (M their
masses and inertias, J the contact rows, D a penalty per row that acts: ten times the row's own
mass, as the native solve starts, on the normal rows that push and the tangent rows that stick).
A settled pile changes little between steps, so a factor of an earlier step's A could serve this
one. Per pile, on consecutive steps stepped by Box2D 2.4.1 (in memory, after it has settled):

1. one factorization of A (SuperLU, symmetric mode, minimum-degree ordering of A + A^T: scipy has
   no sparse Cholesky, so this bounds one from above) against one Box2D step at 8 iterations;
2. how many contact points change state from one step to the next: new, gone, and of those that
   persist, those that start or stop pushing and those that start or stop sliding (Box2D's own
   impulses judge the state);
3. preconditioned conjugate gradients on this step's A with the factor of the step 1, 4 and 16
   steps before (iterations to a relative residual of 1e-8; the right-hand side M v*);
4. the rows a low-rank update must carry (those whose D changed) and the time of the Woodbury
   solve with the previous step's factor, against a new factorization and solve.

`run` returns a result that writes itself (amortize.md, amortize.csv); nothing is printed.
"""
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .. import atomic
from ..escape import CsvWriter
from ..simulate.problems import recorded_between, step_problem
from ..simulate.source import SceneSource
from ..solver.local import jacobian
from ..solver.problem import contact_keys

AMORTIZE_FILES = atomic.Owned("amortize study folder", [r"amortize\.md", r"amortize\.csv"])
PENALTY = 10.0        # D per acting row: its own mass (1 / k) times this, as the native solve's first rho
LAGS = (1, 4, 16)     # steps between the factor and the matrix it preconditions
PCG_TOLERANCE = 1e-8  # relative residual
PCG_CAP = 2000

# label: (generator parameters, steps until settled, steps measured)
FULL = {"pile 1,000": ({"count": "1000", "box": "95", "sigma": "19"}, 1500, 40),
        "pile 10,000": ({"count": "10000", "box": "300", "sigma": "60"}, 2000, 24)}
FAST = {"pile 100": ({}, 400, 20)}


@dataclass
class PileMeasures:
    """What one pile measured, per step (lists) and once (the Box2D step's time)."""
    label: str
    bodies: int
    box2d_ms: float                           # one Box2D step, median (8 iterations, unrecorded)
    dofs: int = 0                             # the moving bodies' degrees of freedom
    points: list = field(default_factory=list)        # contact points per step
    factor_ms: list = field(default_factory=list)     # one factorization of A
    solve_ms: list = field(default_factory=list)      # one solve with that factor
    pcg_ms: list = field(default_factory=list)        # the PCG solve with the factor of the step before
    fill: list = field(default_factory=list)          # nonzeros of L + U over nonzeros of A
    changes: dict = field(default_factory=lambda: {k: [] for k in ("new", "gone", "push", "slide", "any")})
    pcg: dict = field(default_factory=lambda: {lag: [] for lag in LAGS})   # iterations, per lag
    rank: list = field(default_factory=list)          # rows whose D changed since the step before
    woodbury_ms: list = field(default_factory=list)   # the update's solve with the previous factor
    refactor_ms: list = field(default_factory=list)   # a new factorization and solve
    woodbury_error: list = field(default_factory=list)   # its relative residual on this step's A
    lagged_error: list = field(default_factory=list)     # the previous factor's plain solve's, beside it


@dataclass
class AmortizeResult:
    """The study's measures, per pile; `write(folder)` puts amortize.md and amortize.csv there."""
    piles: list
    protocol: str = ""

    def rows(self):
        """(label, measure, median, p90) for every measure of every pile."""
        out = []
        for p in self.piles:
            per_step = {"contact points": p.points, "factorization ms": p.factor_ms, "solve with the factor ms": p.solve_ms,
                        "PCG ms, factor 1 step old": p.pcg_ms, "fill (L+U / A)": p.fill,
                        **{f"points {k} per step": v for k, v in p.changes.items()},
                        **{f"PCG iterations, factor {lag} step{'s' if lag > 1 else ''} old": v
                           for lag, v in p.pcg.items()},
                        "update rank (rows)": p.rank, "Woodbury solve ms": p.woodbury_ms,
                        "refactor + solve ms": p.refactor_ms, "Woodbury relative residual": p.woodbury_error,
                        "previous factor alone: relative residual": p.lagged_error}
            out.append((p.label, "Box2D step ms (8 iterations)", p.box2d_ms, p.box2d_ms))
            for name, values in per_step.items():
                v = np.asarray(values, np.float64)
                out.append((p.label, name, float(np.median(v)) if len(v) else math.nan,
                            float(np.quantile(v, 0.9)) if len(v) else math.nan))
        return out

    def write(self, folder):
        import io
        from pathlib import Path
        folder = Path(folder)
        buf = io.StringIO()
        w = CsvWriter(buf, lineterminator="\n")
        w.writerow(["pile", "measure", "median", "p90"])
        for label, name, median, p90 in self.rows():
            w.writerow([label, name, f"{median:.6g}", f"{p90:.6g}"])
        atomic.write_text(folder / "amortize.csv", buf.getvalue())
        lines = ["# Amortizing the body-space operator: what it would cost", "", self.protocol, "",
                 "| pile | measure | median | p90 |", "| --- | --- | ---: | ---: |"]
        lines += [f"| {label} | {name} | {median:.4g} | {p90:.4g} |" for label, name, median, p90 in self.rows()]
        lines += ["", "Per pile: " + "; ".join(
            f"{p.label}: {p.bodies:,} bodies, {p.dofs:,} degrees of freedom, one factorization "
            f"{np.median(p.factor_ms) / p.box2d_ms:.1f}x a Box2D step" for p in self.piles if p.factor_ms), ""]
        atomic.write_text(folder / "amortize.md", "\n".join(lines))


def run(piles=None, progress=None) -> AmortizeResult:
    """The measures of each pile (FULL by default; FAST for the suite). progress(n): n more steps."""
    piles = FULL if piles is None else piles
    return AmortizeResult([_measure(label, *spec, progress) for label, spec in piles.items()])


def _measure(label, params, settle, samples, progress):
    # one pile: unrecorded until settled, the measured steps recorded, then 8 unrecorded steps timed
    scene = SceneSource("pile", params, settle + samples + 8)(0)
    out = PileMeasures(label, len(scene.bodies), math.nan)
    history, before, box2d = [], None, []
    for done in recorded_between(scene, settle, settle + samples):
        if progress and done.index < settle + samples:
            progress(1)
        if done.index >= settle + samples:
            box2d.append(done.seconds)
        if not settle <= done.index < settle + samples:
            continue
        step = _body_space(scene, done)
        out.dofs = step.size
        out.points.append(step.points)
        t0 = time.perf_counter()
        factor = _factor(step.A)
        out.factor_ms.append(1e3 * (time.perf_counter() - t0))
        t0 = time.perf_counter()
        factor.solve(step.b)
        out.solve_ms.append(1e3 * (time.perf_counter() - t0))
        out.fill.append((factor.L.nnz + factor.U.nnz) / max(step.A.nnz, 1))
        if before is not None:
            for key, n in _changes(before, step).items():
                out.changes[key].append(n)
            _update(before, history[-1], step, out)   # (the factor of the step before)
        history.append(factor)
        for lag in LAGS:
            if len(history) > lag:
                t0 = time.perf_counter()
                out.pcg[lag].append(_pcg_iterations(step, history[-1 - lag]))
                if lag == 1:
                    out.pcg_ms.append(1e3 * (time.perf_counter() - t0))
        history = history[-(max(LAGS) + 1):]
        before = step
    out.box2d_ms = 1e3 * float(np.median(box2d))
    return out


@dataclass
class _Step:
    """One step in body space: A, the right-hand side, the rows and what they say of the state."""
    A: object
    b: np.ndarray
    J: object          # the contact rows over the moving dofs
    d: np.ndarray      # D per row
    keys: list         # a key per contact point (its rows are 2i, 2i+1)
    pushing: np.ndarray
    sliding: np.ndarray
    points: int
    size: int


def _body_space(scene, done):
    """A = M + J^T D J of a recorded step, over its moving bodies' degrees of freedom."""
    import scipy.sparse as sp
    contacts = done.contacts
    J, inv_m, v, rows, points = jacobian(step_problem(scene, done))
    moving = inv_m > 0
    J = J.tocsc()[:, moving].tocsr()
    mass = 1.0 / inv_m[moving]
    k = np.asarray(J.multiply(J) @ (1.0 / mass)).ravel()   # each row's own inverse mass, J M^-1 J^T's diagonal
    normal = contacts["normal_impulse"].astype(np.float64)[points]
    tangent = contacts["tangent_impulse"].astype(np.float64)[points]
    mu = contacts["friction"].astype(np.float64)[points]
    pushing = normal > 0
    sliding = pushing & (np.abs(tangent) >= mu * normal * (1 - 1e-6))
    acting = np.empty(2 * len(points), bool)
    acting[0::2], acting[1::2] = pushing, pushing & ~sliding
    d = np.where(acting & (k > 0), PENALTY / np.where(k > 0, k, 1.0), 0.0)
    A = (sp.diags(mass) + J.T @ sp.diags(d) @ J).tocsc()
    every_key = contact_keys(contacts)
    keys = [every_key[i] for i in points]
    return _Step(A=A, b=mass * v[moving], J=J, d=d, keys=keys, pushing=pushing, sliding=sliding,
                 points=len(points), size=A.shape[0])


def _factor(A):
    from scipy.sparse.linalg import splu
    return splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})


def _changes(before, now):
    """Contact points that changed state from one step to the next."""
    old = {key: i for i, key in enumerate(before.keys)}
    kept = [(old[key], i) for i, key in enumerate(now.keys) if key in old]
    a = np.array([i for i, _ in kept], int)
    b = np.array([j for _, j in kept], int)
    push = int(np.sum(before.pushing[a] != now.pushing[b])) if len(kept) else 0
    slide = int(np.sum(before.sliding[a] != now.sliding[b])) if len(kept) else 0
    new, gone = len(now.keys) - len(kept), len(before.keys) - len(kept)
    return {"new": new, "gone": gone, "push": push, "slide": slide, "any": new + gone + push + slide}


def _pcg_iterations(step, factor):
    """Iterations of CG on step.A x = step.b preconditioned by an earlier step's factor."""
    from scipy.sparse.linalg import LinearOperator, cg
    count = [0]

    def counted(_):
        count[0] += 1
    M = LinearOperator(step.A.shape, matvec=factor.solve, dtype=np.float64)
    _, info = cg(step.A, step.b, rtol=PCG_TOLERANCE, atol=0.0, maxiter=PCG_CAP, M=M, callback=counted)
    return count[0] if info == 0 else PCG_CAP


def _update(before, factor_before, now, out):
    """The rows whose state changed (D, new and gone contacts among them) as a low-rank correction
    of the previous step's A: the Woodbury solve with its factor, timed against a new factorization.
    A persisting row whose state held is not carried, though its geometry moved a little: the
    update is then a near solve, and its relative residual on this step's A says how near."""
    import scipy.sparse as sp
    old = {key: i for i, key in enumerate(before.keys)}
    changed_now, changed_before = [], []
    for i, key in enumerate(now.keys):
        j = old.pop(key, None)
        for r in (0, 1):
            same = j is not None and (now.d[2 * i + r] > 0) == (before.d[2 * j + r] > 0)
            if not same:
                if now.d[2 * i + r]:
                    changed_now.append(2 * i + r)
                if j is not None and before.d[2 * j + r]:
                    changed_before.append(2 * j + r)
    for j in old.values():   # gone
        changed_before += [2 * j + r for r in (0, 1) if before.d[2 * j + r]]
    U = sp.vstack([now.J[changed_now], before.J[changed_before]]).T.tocsc()
    c = np.concatenate([now.d[changed_now], -before.d[changed_before]])
    out.rank.append(len(c))
    t0 = time.perf_counter()
    x = factor_before.solve(now.b)
    out.lagged_error.append(float(np.linalg.norm(now.A @ x - now.b) / np.linalg.norm(now.b)))
    if len(c):
        Z = np.column_stack([factor_before.solve(U[:, i].toarray().ravel()) for i in range(U.shape[1])])
        small = np.diag(1.0 / c) + U.T @ Z
        x = x - Z @ np.linalg.solve(small, U.T @ x)
    out.woodbury_ms.append(1e3 * (time.perf_counter() - t0))
    out.woodbury_error.append(float(np.linalg.norm(now.A @ x - now.b) / np.linalg.norm(now.b)))
    t0 = time.perf_counter()
    _factor(now.A).solve(now.b)
    out.refactor_ms.append(1e3 * (time.perf_counter() - t0))
