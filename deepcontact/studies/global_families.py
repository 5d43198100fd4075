"""Two more global families, by the work they need to reach 1e-4 on the loop's 1000-circle pile.

The solve in body space (accelerate="bodyspace") needs tens to hundreds of factorizations a step
(docs/results.md). Two other families answer the obvious questions about that; they are numpy
prototypes here, not solvers of the project, and count work rather than time:

1. ADMM on the impulses (as in Tasora et al. 2021 and Carpentier et al. 2024): its linear step
   (W + R) r = ... is solved in body space by Woodbury, (W + R)^-1 = R^-1 - R^-1 J (M + J^T R^-1 J)^-1
   J^T R^-1, with one factorization of a symmetric positive definite matrix for the whole solve;
   each iteration is a substitution with that factor and a projection on the friction cones.
   Coulomb's law by De Saxce's shift (mu |u_t| added to the normal velocity), updated every
   iteration. R per point is rho k (k: the point's normal effective inverse mass). Plain, and with
   Anderson acceleration (memory 5) on the iteration's fixed point.
2. An augmented Lagrangian in body space like the solver's, but with the friction cone projected
   and De Saxce's shift held for an outer iteration: each inner problem is then the minimisation
   of a convex C1 function, its Newton systems are symmetric positive definite (Cholesky's case
   always, where the solver's own are not wherever a point slides), and its line search is exact.
   A fixed penalty c (rho = c / k per point; on these steps 100 to 300 took the fewest
   factorizations of 10 to 3000), at most 60 outer iterations of at most 60 Newton iterations.

The problems: the 1000-circle pile of the loop (`pile --param count=1000 --param box=95 --param
sigma=19 --seed 9`) stepped by Box2D 2.4.1 at its 8 iterations, steps 300 to 800 every 100, each
from Box2D's warm start, against PSOR at w = 1.7 and the solver's own solve in body space
(native, float64). Residual: the project's (solver/local.py).

Part 2 takes the cone AL to the base-20 pyramid's settling steps 8, 15, 32 and 52 from zero to
1e-12, where the solver's own solve in body space is the reference's last stage.

Part 3 (two-level) asks where PGS's residual on the same pile steps stalls, and whether a second
level mends it, without a factorization of the whole step:

3. A coarse correction: bodies grouped into aggregates by square cells of side AGGREGATE, one
   coarse unknown per pair of aggregates (and per aggregate, inside) scaling the current impulses
   of the contact points between them; the Galerkin system on the rows that must hold (active
   normal rows, sticking tangent rows) solved densely, the result projected on the friction cones,
   kept only where it lowers the residual (at full, half or quarter length). After every
   COARSE_EVERY sweeps.
4. A local exact solve: Lemke's method on the contact points above the tolerance and one ring of
   contacts around them, the rest held (solver/pivoting.py, StepPivots.local, the reference's
   fallback), kept only where it lowers the residual. After every POLISH_EVERY sweeps.

Run as `dc study global-families [--part pile|exact|two-level|all] [--steps 300,400,...] [--cap 3000]`.
"""
import math
import statistics
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl

from ..scene.generators import generate
from ..simulate.problems import problems as step_problems
from ..solver import pgs
from ..solver.local import jacobian, local_problem, point_residuals, residual, residual_scale
from ..solver.methods import judge, solve
from ..solver.pivoting import StepPivots
from ..solver.settings import TOLERANCE
from .text import StudyText
PILE = {"count": 1000, "box": 95, "sigma": 19}


def loop_problems(steps, seed=9):
    """The pile's contact problems at `steps`, stepped by Box2D 2.4.1 at its 8 iterations."""
    scene = generate("pile", seed, {**PILE, "steps": max(steps) + 1})
    return [p for _, p in step_problems(scene, every=math.gcd(*steps)) if p.index in steps]


class Rows:
    """A step in body space: u = J x + q for x = v - v* on the dofs that can move, the local
    problem lp (W, q, mu) and each point's normal effective inverse mass k."""

    def __init__(self, problem):
        body_rows = jacobian(problem)
        J, inv_m = body_rows[:2]
        movable = inv_m > 0
        self.J, self.inv_m = J[:, movable].tocsc(), inv_m[movable]
        self.mass = 1.0 / self.inv_m
        self.lp = local_problem(problem, body_rows)
        self.mu = self.lp.mu
        self.k = self.lp.W.diagonal()[0::2]

    def velocity(self, x):
        return self.J @ x + self.lp.q

    def shift(self, u):
        """De Saxce's shift: mu |u_t| on each normal row."""
        s = np.zeros_like(u)
        s[0::2] = self.mu * np.abs(u[1::2])
        return s


def cone(w, mu):
    """Euclidean projection of w (per point normal, tangent) onto {|t| <= mu n}, and per point the
    piece it falls on (0: the polar cone, 1: an edge, 2: inside) and the sign of its tangent."""
    n, t = w[0::2], w[1::2]
    inside = np.abs(t) <= mu * n
    polar = mu * np.abs(t) <= -n
    edge = (n + mu * np.abs(t)) / (1 + mu * mu)
    sign = np.where(t >= 0, 1.0, -1.0)
    p = np.empty_like(w)
    p[0::2] = np.where(inside, n, np.where(polar, 0.0, edge))
    p[1::2] = np.where(inside, t, np.where(polar, 0.0, mu * edge * sign))
    return p, np.where(inside, 2, np.where(polar, 0, 1)), sign


def admm(rows, start, rho=1.0, relax=1.6, anderson=0, cap=3000, check=5, tolerance=TOLERANCE):
    """ADMM from the impulses `start`: (reached, iterations, factorizations, residual)."""
    lp, J = rows.lp, rows.J
    R = rho * np.repeat(rows.k, 2)
    factor = admm_factor(rows, R)

    def linear(b):     # (W + R)^-1 b, by Woodbury in body space
        y = b / R
        return y - (J @ factor.solve(J.T @ y)) / R

    def iterate(state):   # one ADMM iteration on (z, y); y ends as minus the shifted velocity
        z, y = state[:len(R)], state[len(R):]
        u = lp.W @ z + lp.q
        r = linear(R * z - y - (lp.q + rows.shift(u)))
        r = relax * r + (1 - relax) * z
        z_next = cone(r + y / R, rows.mu)[0]
        return np.concatenate([z_next, y + R * (r - z_next)])

    z = cone(start, rows.mu)[0]
    u = lp.W @ z + lp.q
    state = np.concatenate([z, -(u + rows.shift(u))])
    metric = np.concatenate([np.sqrt(R), 1 / np.sqrt(R)])   # ADMM's own norm
    xs, gs = [], []
    for it in range(1, cap + 1):
        image = iterate(state)
        if anderson:
            xs.append(state)
            gs.append((image - state) * metric)
            del xs[:-anderson - 1], gs[:-anderson - 1]
        if len(gs) > 1:   # Anderson (type II) on the last few residuals
            dg = np.stack([b - a for a, b in zip(gs, gs[1:])], 1)
            dx = np.stack([b - a for a, b in zip(xs, xs[1:])], 1)
            gamma = np.linalg.lstsq(dg, gs[-1], rcond=None)[0]
            state = image - (dx + dg / metric[:, None]) @ gamma
        else:
            state = image
        state[:len(R)] = cone(state[:len(R)], rows.mu)[0]
        if it % check == 0 and residual(lp, state[:len(R)]) <= tolerance:
            return True, it, 1, residual(lp, state[:len(R)])
    return False, cap, 1, residual(lp, state[:len(R)])


def cone_lagrangian(rows, start, c=100.0, outer_cap=60, inner_cap=60, tolerance=TOLERANCE):
    """The augmented Lagrangian with the cone projected, from `start`:
    (reached, outer iterations, factorizations, residual)."""
    lp, J, mass, mu = rows.lp, rows.J, rows.mass, rows.mu
    rho = np.repeat(c / rows.k, 2)
    lam = start.copy()
    x = rows.inv_m * (J.T @ lam)
    res, factorizations, outer = residual(lp, lam), 0, 0
    while res > tolerance and outer < outer_cap:
        outer += 1
        lam_k, s = lam, rows.shift(rows.velocity(x))

        def impulses(x):
            return cone(lam_k - rho * (rows.velocity(x) + s), mu)

        def value(x, p):   # the inner problem's objective
            return 0.5 * x @ (mass * x) + 0.5 * np.sum(p * p / rho)

        p, piece, sign = impulses(x)
        f = value(x, p)
        for _ in range(inner_cap):
            g = mass * x - J.T @ p
            dx = -spl.splu(hessian(rows, rho, piece, sign)).solve(g)
            factorizations += 1
            alpha = exact_step(rows, x, dx, g, impulses, rho)
            x_next = x + alpha * dx
            p_next, piece_next, sign_next = impulses(x_next)
            f_next = value(x_next, p_next)
            if f_next > f:
                break
            same = np.array_equal(piece_next, piece)
            x, p, piece, sign, f = x_next, p_next, piece_next, sign_next, f_next
            if same and abs(alpha - 1) < 1e-6:
                break   # the same pieces and a full step: the piecewise quadratic's minimum
        lam = p
        res = residual(lp, lam)
    return res <= tolerance, outer, factorizations, res


def hessian(rows, rho, piece, sign):
    """M + J^T D J, D per point rho times the Jacobian of the cone's projection on its piece."""
    mu, m = rows.mu, len(rows.mu)
    on_edge = piece == 1
    nn = np.where(piece == 2, 1.0, np.where(on_edge, 1 / (1 + mu ** 2), 0.0))
    tt = np.where(piece == 2, 1.0, np.where(on_edge, mu ** 2 / (1 + mu ** 2), 0.0))
    nt = np.where(on_edge, sign * mu / (1 + mu ** 2), 0.0)
    n, t, r = 2 * np.arange(m), 2 * np.arange(m) + 1, rho[0::2]
    D = sp.csr_matrix((np.concatenate([r * nn, r * tt, r * nt, r * nt]),
                       (np.concatenate([n, t, n, t]), np.concatenate([n, t, t, n]))), shape=(2 * m, 2 * m))
    return (sp.diags(rows.mass) + rows.J.T @ D @ rows.J).tocsc()


def exact_step(rows, x, dx, g, impulses, rho):
    """The minimum along dx of the convex piecewise quadratic: safeguarded Newton on its slope."""
    Jdx, mu = rows.J @ dx, rows.mu
    jn, jt = Jdx[0::2], Jdx[1::2]

    def slope(a):
        p, piece, sign = impulses(x + a * dx)
        edge = (jn + sign * mu * jt) ** 2 / (1 + mu * mu)
        curvature = dx @ (rows.mass * dx) + np.sum(rho[0::2] * np.where(piece == 2, jn * jn + jt * jt,
                                                                        np.where(piece == 1, edge, 0.0)))
        return dx @ (rows.mass * (x + a * dx)) - Jdx @ p, curvature

    lo, hi, a = 0.0, None, 1.0
    for _ in range(60):
        d1, d2 = slope(a)
        if abs(d1) <= 1e-10 * abs(g @ dx):
            break
        if d1 < 0:
            lo = a
        else:
            hi = a
        if hi is None:
            a = max(a - d1 / d2, 2 * a)
            continue
        newton = a - d1 / d2
        a = newton if lo < newton < hi else 0.5 * (lo + hi)
        if hi - lo < 1e-12 * hi:
            break
    return a


PARTS = ("pile", "exact", "two-level", "all")
PILE_STEPS = (300, 400, 500, 600, 700, 800)


def run(part="all", steps=PILE_STEPS, cap=3000, out=None) -> StudyText:
    """The tables (a StudyText; `out` one to add to): part 1 on the pile's `steps` (PSOR and ADMM
    at most `cap` iterations), part 2 on the pyramid's settling steps, part 3 (two-level) on the
    pile's `steps` (at most `cap` sweeps)."""
    out = StudyText() if out is None else out
    if part in ("pile", "all"):
        pile(list(steps), cap, out)
    if part in ("exact", "all"):
        exact(out)
    if part in ("two-level", "all"):
        two_level(list(steps), cap, out)
    return out


def pile(steps, cap, out):
    """Part 1: the loop's pile to 1e-4 from Box2D's warm start."""
    problems = loop_problems(steps)
    methods = {
        "PSOR 1.7 (sweeps)": lambda p, rows, r0: psor(p, cap),
        "bodyspace, the solver's (sweeps and outer iterations)": lambda p, rows, r0: bodyspace(p, cap),
        "ADMM, rho 1 (iterations)": lambda p, rows, r0: admm(rows, r0, cap=cap),
        "ADMM + Anderson 5 (iterations)": lambda p, rows, r0: admm(rows, r0, anderson=5, cap=cap),
        "cone AL, c 100 (outer iterations)": lambda p, rows, r0: cone_lagrangian(rows, r0, c=100.0),
        "cone AL, c 300 (outer iterations)": lambda p, rows, r0: cone_lagrangian(rows, r0, c=300.0),
    }
    rows = [Rows(p) for p in problems]
    factors = [admm_factor(r, np.repeat(r.k, 2)) for r in rows]
    out(f"The 1000-circle pile, steps {','.join(map(str, steps))} ({statistics.median(len(r.mu) for r in rows):.0f} "
          f"contact points, median), from Box2D's warm start to {TOLERANCE:g}.\n")
    out(f"Work per iteration (median nonzeros): a sweep reads and writes along each of J's "
          f"{statistics.median(r.J.nnz for r in rows):,.0f} once each; an ADMM iteration, done in body space, "
          f"would use each 4 times (W z as J M^-1 J^T z, and Woodbury's two products) and substitute "
          f"forward and back through the factor's {statistics.median(f.L.nnz + f.U.nnz for f in factors):,.0f} "
          f"(L and U, minimum degree on the symmetric pattern).\n")
    report(problems, rows, methods, lambda rows, p: rows.lp.reaction(p.start_normal, p.start_tangent), out)


def exact(out):
    """Part 2: the base-20 pyramid's settling steps from zero to 1e-12, where the solver's own
    solve in body space is the reference's last stage (docs/results.md)."""
    steps = (8, 15, 32, 52)
    scene = generate("pyramid", 0, {"base": 20, "steps": max(steps) + 1})
    problems = [p for _, p in step_problems(scene) if p.index in steps]
    zero = (lambda p: (np.zeros_like(p.start_normal), np.zeros_like(p.start_tangent)))
    methods = {
        "bodyspace, the solver's (sweeps and outer iterations)":
            lambda p, rows, r0: bodyspace(p, 100_000, zero(p), tolerance=1e-12),
        "cone AL, c 100 (outer iterations)":
            lambda p, rows, r0: cone_lagrangian(rows, r0, c=100.0, outer_cap=200, tolerance=1e-12),
        "cone AL, c 1000 (outer iterations)":
            lambda p, rows, r0: cone_lagrangian(rows, r0, c=1000.0, outer_cap=200, tolerance=1e-12),
    }
    out(f"\nThe base-20 pyramid, settling steps {', '.join(map(str, steps))}, from zero to 1e-12 "
          f"(the solver's cap 100,000 iterations; the cone AL's 200 outer iterations).\n")
    report(problems, [Rows(p) for p in problems], methods, lambda rows, p: np.zeros(2 * len(rows.mu)), out)


def report(problems, body_rows, methods, start, out):
    """Runs every method on every problem (its Rows in body_rows) and adds the table to `out`."""
    results = {name: [] for name in methods}
    for p, rows in zip(problems, body_rows):
        r0 = start(rows, p)
        for name, run in methods.items():
            results[name].append(run(p, rows, r0))
    out("| method | reach it | iterations (median; per step) | factorizations (median) | worst residual |")
    out("| --- | ---: | --- | ---: | ---: |")
    for name, rs in results.items():
        reached = sum(r[0] for r in rs)
        its = ", ".join(str(r[1]) for r in rs)
        out(f"| {name} | {reached} of {len(rs)} | {statistics.median(r[1] for r in rs):.0f}; {its} | "
              f"{statistics.median(r[2] for r in rs):.0f} | {max(r[3] for r in rs):.1e} |")


def admm_factor(rows, R):
    """The factorization of ADMM's body-space matrix M + J^T R^-1 J (minimum degree on its
    symmetric pattern)."""
    return spl.splu((sp.diags(rows.mass) + rows.J.T @ sp.diags(1.0 / R) @ rows.J).tocsc(),
                    permc_spec="MMD_AT_PLUS_A")


def psor(problem, cap):
    s = pgs.solve(problem, tolerance=TOLERANCE, max_iterations=cap, relaxation=1.7)
    return s.residual <= TOLERANCE, s.iterations, 0, s.residual


def bodyspace(problem, cap, start=(None, None), tolerance=TOLERANCE):
    s = solve(problem, *start, accelerate="bodyspace", tolerance=tolerance, max_iterations=cap)
    return s.residual <= tolerance, s.iterations, s.factorizations, s.residual



# --- Part 3: two levels ---------------------------------------------------------------------------
AGGREGATE = 6.0      # m: the side of the cells grouping bodies into aggregates (3 of the pile's circles across)
COARSE_EVERY = 8     # sweeps between two coarse corrections
POLISH_EVERY = 200   # sweeps between two local exact solves
POLISH_MOST = 200    # contact points at most in a local exact solve (a pivot costs (4 x points)^2)
STALL = 1000         # the sweeps after which the residual's spread is shown


def two_level(steps, cap, out):
    """Part 3: where PGS stalls on the pile, and a coarse correction or a local exact solve after
    its sweeps (module docstring), each kept only where it lowers the residual."""
    problems = loop_problems(steps)
    stall = min(STALL, cap)
    out(f"\nThe 1000-circle pile, steps {','.join(map(str, steps))}, from Box2D's warm start to {TOLERANCE:g}, "
        f"at most {cap} sweeps; the second levels are numpy prototypes (their times are not the native solver's).\n")
    plain = [second_level(p, cap, None, stall, stall) for p in problems]   # (also the methods table's PGS row)
    stall_table(problems, plain, stall, cap, out)
    runs = {"PGS": plain,
            "PGS + coarse correction on aggregates":
                [second_level(p, cap, CoarseCorrection(p), COARSE_EVERY, stall) for p in problems],
            "PGS + Lemke on the worst neighbourhood":
                [second_level(p, cap, LocalExact(p), POLISH_EVERY, stall) for p in problems]}
    out("")
    out(f"| method | reach it | sweeps (per step) | second-level tries, kept (all steps) | "
        f"residual after {stall} sweeps (median) | worst residual | time a step (median) |")
    out("| --- | ---: | --- | ---: | ---: | ---: | ---: |")
    for name, rs in runs.items():
        out(f"| {name} | {sum(r.reached for r in rs)} of {len(rs)} | {', '.join(str(r.sweeps) for r in rs)} | "
            f"{sum(r.tries for r in rs)}, {sum(r.kept for r in rs)} | "
            f"{statistics.median(r.at_stall for r in rs):.1e} | {max(r.residual for r in rs):.1e} | "
            f"{_ms(statistics.median(r.seconds for r in rs))} |")


def stall_table(problems, plain, stall, cap, out):
    """Where PGS's residual sits on each step after `stall` sweeps and at the end (of `cap`): the
    points above the tolerance, the worst, and their height in the pile. plain: PGS's Outcomes."""
    out(f"| step | contact points | above {TOLERANCE:g} after {stall} sweeps | after {cap} | "
        f"worst after {stall} (x {TOLERANCE:g}) | where (height, median; the pile's top) |")
    out("| ---: | ---: | ---: | ---: | ---: | --- |")
    for p, run in zip(problems, plain):
        lp = local_problem(p)
        at_stall, at_end = (point_residuals(lp, lp.reaction(*impulses)) / residual_scale(lp)
                            for impulses in (run.stalled, run.impulses))
        above = at_stall > TOLERANCE
        height = p.bodies["center"][:, 1].astype(np.float64)
        at = height[p.contacts["row_a"][lp.points]]
        out(f"| {p.index} | {len(lp.points)} | {above.sum()} | {(at_end > TOLERANCE).sum()} | "
            f"{at_stall.max() / TOLERANCE:.1f} | {np.median(at[above]) if above.any() else 0:.1f} m; "
            f"{height.max():.1f} m |")


def _ms(seconds):
    ms = seconds * 1e3
    return f"{ms:,.0f} ms" if ms >= 10 else f"{ms:.2g} ms"


def _sweeps(problem, count, start=(None, None)):
    """(normal, tangent, residual, sweeps done) after at most `count` float64 PGS sweeps from
    `start` (Box2D's warm start), stopping at the tolerance."""
    s = solve(problem, *start, tolerance=TOLERANCE, max_iterations=count)
    return s.normal_impulse.astype(np.float64), s.tangent_impulse.astype(np.float64), s.residual, s.iterations


@dataclass
class Outcome:
    """One step's run of second_level: whether it reached the tolerance, the sweeps, the second
    level's tries and how many were kept, the residual at the stall count and at the end, the
    time (s), and the (normal, tangent) impulses at the stall count and at the end."""
    reached: bool
    sweeps: int
    tries: int
    kept: int
    at_stall: float
    residual: float
    seconds: float
    stalled: tuple
    impulses: tuple


def second_level(problem, cap, level, every, stall=STALL):
    """PGS in runs of `every` sweeps from Box2D's warm start, `level(normal, tangent)` (a better
    (normal, tangent) or None) between two runs, until the tolerance or `cap` sweeps; the
    residual is also taken as `stall` sweeps are passed."""
    t0 = time.perf_counter()
    normal, tangent = problem.start_normal, problem.start_tangent
    sweeps = tries = kept = 0
    at_stall = stalled = None
    while True:
        normal, tangent, res, done = _sweeps(problem, min(every, cap - sweeps), (normal, tangent))
        sweeps += done
        if at_stall is None and (sweeps >= stall or res <= TOLERANCE):
            at_stall, stalled = res, (normal, tangent)
        if res <= TOLERANCE or sweeps >= cap:
            break
        if level is None:
            continue
        tries += 1
        better = level(normal, tangent)
        if better is not None and judge(problem, *better).residual < res:
            normal, tangent = better
            kept += 1
    return Outcome(res <= TOLERANCE, sweeps, tries, kept, at_stall, res, time.perf_counter() - t0, stalled,
                   (normal, tangent))


class CoarseCorrection:
    """A Galerkin correction on aggregates of bodies (module docstring, 3): one unknown per pair of
    aggregates scaling the current impulses of the points between them."""

    def __init__(self, problem, cell=AGGREGATE):
        self.problem = problem
        self.lp = lp = local_problem(problem)
        center = problem.bodies["center"].astype(np.float64)
        key = np.floor(center / cell).astype(np.int64)
        _, aggregate = np.unique(key, axis=0, return_inverse=True)
        aggregate = np.where(problem.bodies["type"] == 2, aggregate.ravel() + 1, 0)   # static bodies: one group
        a, b = aggregate[problem.contacts["row_a"][lp.points]], aggregate[problem.contacts["row_b"][lp.points]]
        _, self.pair = np.unique(np.minimum(a, b) * (aggregate.max() + 1) + np.maximum(a, b), return_inverse=True)

    def __call__(self, normal, tangent):
        lp, m = self.lp, len(self.lp.points)
        r = lp.reaction(normal, tangent)
        rn, rt = r[0::2], r[1::2]
        active = np.nonzero(rn > 0)[0]
        sticking = np.nonzero((rn > 0) & (np.abs(rt) < lp.mu * rn * (1 - 1e-9)))[0]
        # a column per pair: the current impulses of its active points, normal and tangent together
        P = sp.csr_matrix((np.concatenate([rn[active], rt[active]]),
                           (np.concatenate([2 * active, 2 * active + 1]), np.concatenate([self.pair[active]] * 2))),
                          shape=(2 * m, self.pair.max() + 1))
        P = P[:, np.unique(self.pair[active])]
        held = np.zeros(2 * m)
        held[2 * active], held[2 * sticking + 1] = 1.0, 1.0   # the rows whose velocity must vanish
        Ps = sp.diags(held) @ P
        y = np.linalg.lstsq((Ps.T @ (lp.W @ P)).toarray(), -(Ps.T @ (lp.W @ r + lp.q)), rcond=None)[0]
        d, before = P @ y, residual(lp, r)
        for length in (1.0, 0.5, 0.25):   # the first length that lowers the residual
            trial = cone_clamped(r + length * d, lp.mu)
            if residual(lp, trial) < before:
                return lp.impulses(trial, self.problem.points)
        return None


def cone_clamped(r, mu):
    """r with negative normals set to 0 and tangents clamped to the friction bound."""
    out = np.empty_like(r)
    out[0::2] = np.maximum(r[0::2], 0.0)
    out[1::2] = np.clip(r[1::2], -mu * out[0::2], mu * out[0::2])
    return out


class LocalExact:
    """Lemke's method on the points above the tolerance and one ring around them, the rest held
    (module docstring, 4)."""

    def __init__(self, problem):
        self.pivots = StepPivots(problem)

    def __call__(self, normal, tangent):
        lp = self.pivots.lp
        f = point_residuals(lp, lp.reaction(normal, tangent))
        share = TOLERANCE * residual_scale(lp) / max(f.max(), 1e-300)   # the points above the tolerance
        return self.pivots.local(normal, tangent, rings=1, share=share, most=POLISH_MOST)
