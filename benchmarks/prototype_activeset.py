"""The gate of a warm-started active-set solve, measured before any native code:
does the converged rigid pile's contact state change little enough from step to step that a
solve starting from the previous step's active set finishes in a few passes?

The 1000-circle pile (seed 9) settles under Box2D at its 8 iterations for --settle steps; then
the loop steps it (collide, solve, write the impulses, Box2D's Step with 0 velocity iterations)
for --steps steps, each solved by this prototype from the previous step's converged state:

  per contact point: open (r = 0), sticking (u = 0), sliding with r_t = +mu r_n (u_t <= 0) or
  r_t = -mu r_n (u_t >= 0); a pass solves the equality system those states make of u = W r + q
  (scipy's sparse LU of the 2m x 2m system, W from the step's local problem: solver/local.py),
  then flips every point whose state its answer violates (an open point pressed, an active point
  pulled, a sticking point past its friction cone, a sliding point moving against its friction);
  until the project's residual is below --tolerance (or --most passes). A new point starts as
  sticking. A step it does not finish is solved by PGS from Box2D's warm start to the tolerance
  (cap 100,000) so that the trajectory goes on, and counted.

With --space body the step is instead the bodies' velocities minimising a stiff convex energy
(BodySpace), by Newton's method with a backtracking line search (a pass: one Newton step); with
--space augmented, its augmented Lagrangian with one factored matrix a step from the carried
active set, passes changing only the right-hand side (Augmented).

With --space facets, the step as a convex QP of the bodies' velocities with Coulomb's cone as two
facet rows a point (exact in 2D) and De Saxce's shift, by the augmented Lagrangian: Newton's
method with an exact line search inside, the multipliers and the shift updated where it has
converged (Facets; --continuation: stiffer each update). With --space ipm --diagnose, the same
QP on one step by a primal-dual interior point method (InteriorPoint), the shift updated
between solves (--shift fixed, --rounds) or within one (lagged, linearised).

The gate: go if the median step needs at most 4 passes and 50 flips, and at least 95% of
the steps reach the tolerance within 8 passes (docs/results/bodyspace.md, "A warm-started active set"). Times are scipy's (a Python prototype), not what
native code would cost.

Usage: python benchmarks/prototype_activeset.py [--settle N] [--steps N] [--most N] [--tolerance T] [--penalty P]
                                               [--space impulse|body|augmented|facets] [--stiffness K] [--diagnose]
"""
import argparse
import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from deepcontact.protocol import current, protocol_line
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.solver.local import local_problem, residual, residual_scale
from deepcontact.solver.methods import solve
from deepcontact.solver.problem import StepProblem, contact_keys
from deepcontact.solver.settings import SolveSettings

OPEN, STICK, PLUS, MINUS = 0, 1, 2, 3   # PLUS: r_t = +mu r_n (sliding with u_t <= 0); MINUS: r_t = -mu r_n


def equality_solve(lp, state, penalty):
    """r solving the equalities the states make of u = W r + q, W made definite by a stiff
    penalty (a rigid pile has more contact rows than the bodies have degrees of freedom: W alone
    is singular wherever too many points stick)."""
    n2 = len(lp.q)
    m = n2 // 2
    uses_w = np.zeros(n2)
    uses_w[0::2] = state != OPEN
    uses_w[1::2] = state == STICK
    S = sp.diags(uses_w)
    own = 1.0 - uses_w                  # rows that are not W's: r_n = 0 (open), r_t = 0 (open) or r_t - c mu r_n = 0
    rows = np.arange(n2)
    T = sp.csr_matrix((own, (rows, rows)), shape=(n2, n2))
    sliding = np.flatnonzero((state == PLUS) | (state == MINUS))
    c = np.where(state[sliding] == PLUS, 1.0, -1.0)
    F = sp.csr_matrix((-c * lp.mu[sliding], (2 * sliding + 1, 2 * sliding)), shape=(n2, n2))
    W = lp.W + sp.diags(penalty * lp.W.diagonal())
    A = (S @ W.tocsr() + T + F).tocsc()
    b = -(uses_w * lp.q)
    return splu(A, permc_spec="COLAMD").solve(b), m


class BodySpace:
    """The step as a convex energy of the dynamic bodies' velocities v, with a stiff penalty
    (MuJoCo's soft-contact form made stiff): E(v) = 1/2 |v - v*|_M^2 + sum k_n/2 min(0, u_n)^2
    + sum huber_b(u_t), u = J v + c, where a point's tangential term is k_t/2 u_t^2 inside its
    friction bound b = mu r_n (from the previous pass) and b |u_t| beyond. r = k_n max(0, -u_n),
    r_t = -clip(k_t u_t, -b, b). Minimised by Newton's method with a backtracking line search: the
    velocities are unique whatever the contacts' redundancy, and the active set (pressed points,
    sticking points) is read from v, never flipped by hand."""

    def __init__(self, problem, lp, stiffness):
        from deepcontact.solver.local import jacobian
        J, inv_m, v_star, rows, _ = jacobian(problem)
        c = np.zeros(J.shape[0])
        c[0::2] = -rows["bias"][lp.points]
        free = inv_m > 0
        c = c + J[:, ~free] @ v_star[~free]   # (static bodies' velocities are what they are)
        self.J, self.c, self.v_star = J[:, free].tocsr(), c, v_star[free]
        self.mass = 1.0 / inv_m[free]
        self.k = stiffness / np.maximum(lp.W.diagonal(), 1e-30)   # (per row, in its own effective mass)
        self.inv_m = inv_m[free]

    exact = False   # (the line search: exact on the piecewise quadratic, as MuJoCo's, or backtracking)

    def slope(self, v, d, alpha, bound):
        """dE/dalpha at v + alpha d (increasing in alpha: E is convex along any line)."""
        w = v + alpha * d
        r, _ = self.impulses(w, bound)
        return d @ (self.mass * (w - self.v_star)) - (self.J @ d) @ r

    def line_search(self, v, d, bound, rounds=60):
        """The alpha minimising E along d, to a relative 1e-12: bracketed, then bisected on the
        slope (a piecewise-linear increasing function of alpha)."""
        high = 1.0
        while self.slope(v, d, high, bound) < 0 and high < 1e6:
            high *= 2.0
        low = 0.0
        for _ in range(rounds):
            mid = 0.5 * (low + high)
            if self.slope(v, d, mid, bound) < 0:
                low = mid
            else:
                high = mid
        return 0.5 * (low + high)

    def velocities(self, r):
        """v after impulses r (the warm start's velocities)."""
        return self.v_star + self.inv_m * (self.J.T @ r)

    def impulses(self, v, bound):
        u = self.J @ v + self.c
        r = np.empty_like(u)
        r[0::2] = self.k[0::2] * np.maximum(0.0, -u[0::2])
        r[1::2] = -np.clip(self.k[1::2] * u[1::2], -bound, bound)
        return r, u

    def energy(self, v, bound):
        u = self.J @ v + self.c
        dv = v - self.v_star
        un, ut, kn, kt = u[0::2], u[1::2], self.k[0::2], self.k[1::2]
        inside = np.abs(kt * ut) <= bound
        huber = np.where(inside, 0.5 * kt * ut ** 2, bound * np.abs(ut) - 0.5 * bound ** 2 / np.maximum(kt, 1e-300))
        return 0.5 * dv @ (self.mass * dv) + 0.5 * kn @ np.minimum(0.0, un) ** 2 + huber.sum()

    def newton(self, v, bound):
        """One Newton step with a backtracking line search: (v, the pattern of pressed and
        sticking points at the new v)."""
        r, u = self.impulses(v, bound)
        grad = self.mass * (v - self.v_star) - self.J.T @ r
        d = np.zeros(len(u))
        d[0::2] = self.k[0::2] * (u[0::2] < 0)
        d[1::2] = self.k[1::2] * (np.abs(self.k[1::2] * u[1::2]) < bound)
        H = (sp.diags(self.mass) + self.J.T @ sp.diags(d) @ self.J).tocsc()
        step = -splu(H, permc_spec="COLAMD").solve(grad)
        if self.exact:
            alpha = self.line_search(v, step, bound)
        else:
            e0, slope, alpha = self.energy(v, bound), grad @ step, 1.0
            while alpha > 1e-8 and self.energy(v + alpha * step, bound) > e0 + 1e-4 * alpha * slope:
                alpha *= 0.5
        v = v + alpha * step
        _, u = self.impulses(v, bound)
        return v, (u[0::2] < 0).astype(int) + 2 * (np.abs(self.k[1::2] * u[1::2]) < bound)


class Augmented(BodySpace):
    """The step's augmented Lagrangian in body space, its matrix made once a step from the active
    set carried from the previous step's answer (pressed points' normal rows, sticking points'
    tangent rows): H = M + J_A^T K J_A, factored once. A pass solves H v = M v* + J_A^T (lam_A -
    K c_A) + J_I^T lam_I and updates every multiplier by its projection, lam <- proj(lam - K u):
    passes change only the right-hand side, and converge to the rigid answer (the multipliers
    make a moderate K exact)."""

    def __init__(self, problem, lp, stiffness, active):
        super().__init__(problem, lp, stiffness)
        self.active = active                      # rows in the matrix (2m booleans)
        K = sp.diags(self.k * active)
        self.lu = splu((sp.diags(self.mass) + self.J.T @ K @ self.J).tocsc(), permc_spec="COLAMD")
        self.mu = lp.mu

    def passes(self, lam):
        """One pass: the new multipliers."""
        K = self.k * self.active
        rhs = self.mass * self.v_star + self.J.T @ np.where(self.active, lam - K * self.c, lam)
        v = self.lu.solve(rhs)
        trial = lam - self.k * (self.J @ v + self.c)
        new = np.empty_like(lam)
        new[0::2] = np.maximum(trial[0::2], 0.0)
        b = self.mu * new[0::2]
        new[1::2] = np.clip(trial[1::2], -b, b)
        return new


class Facets(BodySpace):
    """The step as a convex QP of the bodies' velocities, its friction cone in the constraints:
    in 2D Coulomb's cone is two facets, so per point two rows a+- = J_n +- mu J_t with
    a+- v + c_n +- mu c_t + s >= 0 and multipliers lam+- >= 0 (r_n = lam+ + lam-, r_t =
    mu (lam+ - lam-)). s = mu |u_t| (De Saxce's shift, from the last iterate) makes its answer
    Coulomb's, not the convex relaxation's (a sliding point lifting off by mu |u_t|). Solved by the
    augmented Lagrangian: inner, min 1/2 |v - v*|_M^2 + sum 1/(2 rho) max(0, lam_bar - rho g(v))^2
    by Newton's method with an exact line search (the energy is piecewise quadratic and convex;
    its Hessian M + A_act^T rho A_act is symmetric and definite, whatever the redundancy); outer,
    lam_bar <- max(0, lam_bar - rho g(v)) and s <- mu |u_t(v)|. A pass is one Newton step (one
    factorization)."""

    def __init__(self, problem, lp, stiffness):
        super().__init__(problem, lp, stiffness)
        mu = np.repeat(lp.mu, 2) * np.tile([1.0, -1.0], len(lp.mu))   # (+mu, -mu per point)
        Jn, Jt = self.J[0::2], self.J[1::2]
        A = sp.vstack([Jn, Jt]).tocsr()
        m = len(lp.mu)
        # facet rows interleaved: 2i = plus, 2i+1 = minus
        P = sp.csr_matrix((np.concatenate([np.ones(2 * m), mu]),
                           (np.concatenate([np.arange(2 * m), np.arange(2 * m)]),
                            np.concatenate([np.repeat(np.arange(m), 2), m + np.repeat(np.arange(m), 2)]))),
                          shape=(2 * m, 2 * m))
        self.A = (P @ A).tocsr()
        self.e0 = P @ np.concatenate([self.c[0::2], self.c[1::2]])
        self.signed_mu = mu
        self.mu = lp.mu
        eff = np.asarray(self.A.multiply(self.A) @ self.inv_m).ravel()
        self.rho = stiffness / np.maximum(eff, 1e-30)
        self.M = sp.diags(self.mass)

    def r_of(self, lam):
        r = np.empty_like(lam)
        r[0::2] = lam[0::2] + lam[1::2]
        r[1::2] = self.mu * (lam[0::2] - lam[1::2])
        return r

    def lam_of(self, r):
        rn, rt = np.maximum(r[0::2], 0.0), r[1::2]
        ratio = np.where(self.mu > 0, rt / np.where(self.mu > 0, self.mu, 1.0), 0.0)
        ratio = np.clip(ratio, -rn, rn)
        lam = np.empty_like(r)
        lam[0::2], lam[1::2] = 0.5 * (rn + ratio), 0.5 * (rn - ratio)
        return lam

    def g(self, v, s):
        return self.A @ v + self.e0 + np.repeat(s, 2)

    def slide(self, v):
        return self.mu * np.abs((self.J @ v + self.c)[1::2])

    def inner_newton(self, v, lam_bar, s):
        """One Newton step with an exact line search: (v, the active rows it factored)."""
        g = self.g(v, s)
        z = lam_bar - self.rho * g
        act = z > 0
        grad = self.mass * (v - self.v_star) - self.A.T @ np.where(act, z, 0.0)
        H = (self.M + self.A[act].T @ sp.diags(self.rho[act]) @ self.A[act]).tocsc()
        d = -splu(H, permc_spec="MMD_AT_PLUS_A").solve(grad)
        # exact line search: slope(a) = d.M(v + a d - v*) - (Ad).max(0, z - a rho Ad), piecewise linear
        Ad = self.A @ d
        b0 = d @ (self.mass * (v - self.v_star))
        b1 = d @ (self.mass * d)
        w = self.rho * Ad
        def slope(a):
            on = (z - a * w) > 0
            return b0 + a * b1 - Ad[on] @ (z[on] - a * w[on]), b1 + Ad[on] @ w[on]
        lo, hi = 0.0, None
        alpha = 1.0
        for _ in range(100):   # Newton on the piecewise-linear increasing slope, kept in its bracket
            sl, der = slope(alpha)
            if sl == 0.0:
                break
            if sl < 0:
                lo = alpha
            else:
                hi = alpha
            new = alpha - sl / der
            if new <= lo or (hi is not None and new >= hi):
                new = 0.5 * (lo + hi) if hi is not None else 2.0 * alpha
            if abs(new - alpha) <= 1e-15 * max(1.0, abs(alpha)):
                break
            alpha = new
        return v + alpha * d, act, float(np.linalg.norm(grad))


class InteriorPoint(Facets):
    """The facets' convex QP (Facets) by a primal-dual interior point method (Mehrotra's predictor
    and corrector): slacks w = A v + e >= 0 and multipliers lam >= 0 driven together to w lam = 0;
    each pass factors M + A^T (lam / w) A, symmetric and definite whatever the contacts'
    redundancy. Its iterations do not grow with the distance from the start (its start is not
    carried: interior point methods do not warm-start), so a pass count is a factorization count.
    De Saxce's shift s is updated where a solve has converged (an outer round)."""

    shift = "fixed"   # De Saxce's shift: fixed for a solve (outer rounds), from each pass's iterate
                      # ("lagged"), or linearised in each pass ("linearised": a nonsymmetric system)

    def solve(self, v, s, lam0, tol_gap=1e-10, most=60):
        """(v, lam, passes) after at most `most` passes, the shift s held where it is fixed."""
        A, M = self.A, self.M
        n = A.shape[0]
        if self.shift != "fixed":
            m = n // 2
            twice = sp.csr_matrix((np.ones(n), (np.arange(n), np.repeat(np.arange(m), 2))), shape=(n, m))
            Jt = self.J[1::2]

            def shifted(v):
                ut = Jt @ v + self.c[1::2]
                s = self.mu * np.abs(ut)
                if self.shift == "lagged":   # (its derivative left out)
                    return self.e0 + np.repeat(s, 2), A
                G = (A + sp.diags(twice @ (self.mu * np.sign(ut))) @ twice @ Jt).tocsr()
                return self.e0 + np.repeat(s, 2), G
        else:
            def shifted(v):
                return self.e0 + np.repeat(s, 2), A
        e, G = shifted(v)
        w = A @ v + e
        scale_w = max(np.abs(w).max(), 1e-12)
        scale_l = max(np.abs(lam0).max(), 1e-12)
        w = np.maximum(w, 1e-2 * scale_w)
        lam = np.maximum(lam0, 1e-2 * scale_l)
        for p in range(1, most + 1):
            e, G = shifted(v)
            r_d = self.mass * (v - self.v_star) - A.T @ lam
            r_p = A @ v + e - w
            mu = w @ lam / n
            D = lam / w
            H = (M + A.T @ sp.diags(D) @ G).tocsc()
            lu = splu(H, permc_spec="MMD_AT_PLUS_A" if G is A else "COLAMD")

            def direction(r_c):
                rhs = -r_d - A.T @ (D * r_p) - A.T @ (r_c / w)
                dv = lu.solve(rhs)
                dl = -D * (r_p + G @ dv) - r_c / w
                dw = (-r_c - w * dl) / lam
                return dv, dw, dl

            def longest(x, dx):
                neg = dx < 0
                return min(1.0, float(np.min(-x[neg] / dx[neg]))) if neg.any() else 1.0
            # predictor (affine), then the corrector with Mehrotra's centring
            dv, dw, dl = direction(w * lam)
            a_p, a_d = longest(w, dw), longest(lam, dl)
            mu_aff = (w + a_p * dw) @ (lam + a_d * dl) / n
            sigma = (mu_aff / mu) ** 3
            dv, dw, dl = direction(w * lam + dw * dl - sigma * mu)
            a_p, a_d = 0.99 * longest(w, dw), 0.99 * longest(lam, dl)
            a = min(a_p, a_d)   # (one step length: the primal and dual are coupled through v)
            v, w, lam = v + a * dv, w + a * dw, lam + a * dl
            if mu < tol_gap * scale_w * scale_l:
                return v, lam, p
        return v, lam, most


def flips(lp, r, state, scale):
    """The states r violates, changed: (new state, how many changed)."""
    u = lp.W @ r + lp.q
    rn, rt, un, ut = r[0::2], r[1::2], u[0::2], u[1::2]
    eps_u, eps_r = 1e-9 * scale, 1e-9 * max(np.abs(rn).max(initial=0.0), 1e-12)
    new = state.copy()
    new[(state == OPEN) & (un < -eps_u)] = STICK
    active = state != OPEN
    new[active & (rn < -eps_r)] = OPEN
    stick = (state == STICK) & (rn >= -eps_r)
    bound = lp.mu * np.maximum(rn, 0.0)
    new[stick & (rt > bound + eps_r)] = PLUS
    new[stick & (rt < -bound - eps_r)] = MINUS
    new[(state == PLUS) & (rn >= -eps_r) & (ut > eps_u)] = STICK
    new[(state == MINUS) & (rn >= -eps_r) & (ut < -eps_u)] = STICK
    return new, int(np.count_nonzero(new != state))


def state_of(lp, r, scale, slip):
    """The contact state a converged r shows (what the next step starts from): open where r_n is
    0, sliding where the tangential velocity is above slip (x the step's scale), else sticking."""
    u = lp.W @ r + lp.q
    rn, ut = r[0::2], u[1::2]
    eps_r = 1e-9 * max(np.abs(rn).max(initial=0.0), 1e-12)
    state = np.full(len(rn), STICK)
    moving = np.abs(ut) > slip * scale
    state[moving & (ut < 0)] = PLUS
    state[moving & (ut > 0)] = MINUS
    state[rn <= eps_r] = OPEN
    return state


def diagnose(world, scene, args):
    """One pass from the very state of the step's own answer: if the states determined the
    impulses, it would land on that answer (a residual at the tolerance, no flip)."""
    bodies = world.bodies()
    world.collide()
    contacts = world.contacts()
    problem = StepProblem.from_arrays(bodies, contacts, dt=scene.dt, gravity=scene.effects.gravity,
                                      block_solve=scene.solver.block_solve, velocity_iterations=8)
    lp = local_problem(problem)
    scale = residual_scale(lp)
    s = solve(problem, contacts["normal_impulse"], contacts["tangent_impulse"],
              settings=SolveSettings(max_iterations=100_000, tolerance=1e-7))
    answer = lp.reaction(s.normal_impulse, s.tangent_impulse)
    if args.space == "ipm":
        ipm = InteriorPoint(problem, lp, 1.0)
        ipm.shift = args.shift
        lam = ipm.lam_of(lp.reaction(contacts["normal_impulse"], contacts["tangent_impulse"]))
        v, shift, rounds = ipm.velocities(ipm.r_of(lam)), np.zeros(len(lp.mu)), []
        for _ in range(args.rounds if args.shift == "fixed" else 1):
            v, lam, p = ipm.solve(v, shift, lam)
            r = ipm.r_of(lam)
            rounds.append(f"{p} passes, residual {residual(lp, r):.1e}")
            shift = lp.mu * np.abs((lp.W @ r + lp.q)[1::2])
        print(f"diagnosis, step {args.settle + 1}: the interior point method from Box2D's warm start, De Saxce's "
              f"shift {args.shift}; each round: " + "; ".join(rounds))
        return
    if args.space == "facets":
        fac = Facets(problem, lp, args.stiffness)
        lam_bar = fac.lam_of(answer)
        s = lp.mu * np.abs((lp.W @ answer + lp.q)[1::2])
        v, trail = fac.velocities(fac.r_of(lam_bar)), []
        for _ in range(8):
            v, _, _ = fac.inner_newton(v, lam_bar, s)
            trail.append(residual(lp, fac.r_of(np.maximum(lam_bar - fac.rho * fac.g(v, s), 0.0))))
        print(f"diagnosis, step {args.settle + 1}: from its own answer (PGS, residual {residual(lp, answer):.1e}), "
              f"the residual after 1-8 passes: {', '.join(f'{x:.1e}' for x in trail)}")
        return
    state = state_of(lp, answer, scale, 1e-5)
    r, m = equality_solve(lp, state, args.penalty)
    _, n = flips(lp, r, state, scale)
    dofs = 3 * int(np.count_nonzero(np.asarray(bodies["type"]) != 0))
    print(f"diagnosis, step {args.settle + 1}: {m} contact points ({2 * m} rows) on {dofs} degrees of freedom; "
          f"its answer (PGS, residual {residual(lp, answer):.1e}) has {np.count_nonzero(state == OPEN)} open, "
          f"{np.count_nonzero(state == STICK)} sticking and {np.count_nonzero(state >= PLUS)} sliding points; "
          f"one pass from that very state: residual {residual(lp, r):.2g}, {n} flips")


class Carried:
    """What a step hands the next, by contact key: each point's state (impulse space), its
    impulses (every other space's warm start) and De Saxce's shift (facets)."""

    def __init__(self):
        self.state, self.rn, self.rt, self.shift = {}, {}, {}, {}

    def impulses(self, keys):
        r = np.zeros(2 * len(keys))
        r[0::2] = [self.rn.get(key, 0.0) for key in keys]
        r[1::2] = [self.rt.get(key, 0.0) for key in keys]
        return r

    def update(self, keys, lp, r, state):
        self.state = dict(zip(keys, state.tolist()))
        self.rn, self.rt = dict(zip(keys, r[0::2].tolist())), dict(zip(keys, r[1::2].tolist()))
        self.shift = dict(zip(keys, (lp.mu * np.abs((lp.W @ r + lp.q)[1::2])).tolist()))


# Each space's passes on one step: a generator yielding each pass's impulses r; it counts the
# state changes between passes in tally["flips"] (the impulse space's, in tally["pending"] until
# the caller knows r is not the answer) and returns where a pass changes nothing.

def impulse_passes(problem, lp, keys, carried, args, tally):
    state, scale = np.array([carried.state.get(key, STICK) for key in keys]), residual_scale(lp)
    while True:
        r, _ = equality_solve(lp, state, args.penalty)
        new_state, n = flips(lp, r, state, scale)
        tally["pending"] = n   # (counted only if r is not the answer)
        yield r
        if n == 0:
            return
        state = new_state


def body_passes(problem, lp, keys, carried, args, tally):
    body = BodySpace(problem, lp, args.stiffness)
    body.exact = args.exact
    start = carried.impulses(keys)
    v, bound, pattern = body.velocities(start), lp.mu * np.maximum(start[0::2], 0.0), None
    while True:
        v, new_pattern = body.newton(v, bound)
        r, _ = body.impulses(v, bound)
        bound = lp.mu * r[0::2]   # (the friction bound of the next pass)
        r, _ = body.impulses(v, bound)
        if pattern is not None:
            tally["flips"] += int(np.count_nonzero(new_pattern != pattern))
        pattern = new_pattern
        yield r


def augmented_passes(problem, lp, keys, carried, args, tally):
    lam = carried.impulses(keys)
    active = np.zeros(len(lam), bool)
    active[0::2] = lam[0::2] > 0
    active[1::2] = (lam[0::2] > 0) & (np.abs(lam[1::2]) < 0.999 * lp.mu * lam[0::2])
    aug = Augmented(problem, lp, args.stiffness, active)
    while True:
        lam = aug.passes(lam)
        yield lam


def facets_passes(problem, lp, keys, carried, args, tally):
    fac = Facets(problem, lp, args.continuation or args.stiffness)
    stiffness = args.continuation or args.stiffness
    lam_bar = fac.lam_of(carried.impulses(keys))
    shift = np.array([carried.shift.get(key, 0.0) for key in keys])
    v, act_prev = fac.velocities(fac.r_of(lam_bar)), None
    while True:
        v, act, _ = fac.inner_newton(v, lam_bar, shift)
        if act_prev is not None:
            tally["flips"] += int(np.count_nonzero(act != act_prev))
        act_prev = act
        z = lam_bar - fac.rho * fac.g(v, shift)
        lam = np.maximum(z, 0.0)
        if args.eager or np.array_equal(z > 0, act):   # (the inner minimum: the outer update)
            lam_bar, shift = lam, fac.slide(v)
            if args.continuation and stiffness < args.stiffness:
                fac.rho *= 10.0   # (stiffer each outer round, up to --stiffness)
                stiffness *= 10.0
        yield fac.r_of(lam)


PASSES = {"impulse": impulse_passes, "body": body_passes, "augmented": augmented_passes, "facets": facets_passes}


def solve_step(problem, lp, keys, carried, args):
    """(r after the passes, passes taken or inf, state changes): the passes until the residual is
    below the tolerance, --most of them, or one that changes nothing."""
    tally = {"flips": 0}
    r = None
    for p, r in enumerate(PASSES[args.space](problem, lp, keys, carried, args, tally), start=1):
        if residual(lp, r) < args.tolerance:
            return r, p, tally["flips"]
        tally["flips"] += tally.pop("pending", 0)
        if p == args.most:
            break
    return r, np.inf, tally["flips"]


def step_world(world, scene, normal, tangent):
    """The loop's Box2D step with these impulses (Collide has run on these positions)."""
    if normal is not None:
        world.set_manifold_impulses(np.asarray(normal, np.float32), np.asarray(tangent, np.float32))
    world.inv_dt0 = 1.0 / scene.dt
    world.step(scene.dt, 0, scene.solver.position_iterations, collided=True)


def run_loop(world, scene, args):
    """Every step of the loop solved by the chosen space's passes (PGS where they do not finish):
    the gate's figures, per step."""
    carried = Carried()
    out = {k: [] for k in ("passes", "flips", "changed", "seconds", "points", "start_residual", "end_residual")}
    fallback = SolveSettings(max_iterations=100_000, tolerance=args.tolerance)
    for _ in range(args.steps):
        bodies = world.bodies()
        world.collide()
        contacts = world.contacts()
        if not len(contacts["manifold"]):
            step_world(world, scene, None, None)
            continue
        problem = StepProblem.from_arrays(bodies, contacts, dt=scene.dt, gravity=scene.effects.gravity,
                                          block_solve=scene.solver.block_solve, velocity_iterations=8)
        lp = local_problem(problem)
        keys = [contact_keys(contacts)[j] for j in lp.points]
        start = np.array([carried.state.get(key, STICK) for key in keys])
        t = time.perf_counter()
        r, passes, flipped = solve_step(problem, lp, keys, carried, args)
        out["seconds"].append(time.perf_counter() - t)
        out["start_residual"].append(residual(lp, carried.impulses(keys)))
        out["end_residual"].append(residual(lp, r))
        out["points"].append(len(lp.points))
        out["passes"].append(passes)
        out["flips"].append(flipped)
        if np.isfinite(passes):
            normal, tangent = lp.impulses(r, len(contacts["manifold"]))
        else:   # (handed to PGS, so that the trajectory goes on)
            s = solve(problem, contacts["normal_impulse"], contacts["tangent_impulse"], settings=fallback)
            normal, tangent = s.normal_impulse, s.tangent_impulse
            r = lp.reaction(normal, tangent)
        final = state_of(lp, r, residual_scale(lp), 10 * args.tolerance)
        out["changed"].append(int(np.count_nonzero(final != start)))
        carried.update(keys, lp, r, final)
        step_world(world, scene, normal, tangent)
    return {k: np.array(v) for k, v in out.items()}


def report(figures, args):
    """The gate's lines, and its verdict."""
    passes, flipped, changed = figures["passes"], figures["flips"], figures["changed"]
    within8 = float(np.mean(passes <= 8))
    print(f"the 1000-circle pile in the loop, steps {args.settle + 1}-{args.settle + args.steps}: {len(passes)} steps "
          f"with contacts, {np.median(figures['points']):.0f} contact points (median); tolerance {args.tolerance:g}")
    print(f"  passes to the tolerance: median {np.median(passes):.0f}, p90 "
          f"{np.quantile(passes, 0.9, method='inverted_cdf'):.0f}, max {passes.max():.0f}; within 8 passes: "
          f"{100 * within8:.1f}% of steps; not within {args.most}: {int(np.count_nonzero(~np.isfinite(passes)))}")
    print(f"  flips a step (the passes' state changes): median {np.median(flipped):.0f}, p90 "
          f"{np.quantile(flipped, 0.9):.0f}; states changed from the warm start to the answer: median "
          f"{np.median(changed):.0f}, p90 {np.quantile(changed, 0.9):.0f}")
    print(f"  a step's passes in scipy (Python, sparse LU each pass): median {1e3 * np.median(figures['seconds']):.1f} ms")
    print(f"  residual of the warm start (the previous answer, by contact key): median "
          f"{np.median(figures['start_residual']):.2g}; after the passes: median {np.median(figures['end_residual']):.2g}, "
          f"max {np.max(figures['end_residual']):.2g}")
    go = np.median(passes) <= 4 and np.median(flipped) <= 50 and within8 >= 0.95
    print(f"  gate (median passes <= 4, median flips <= 50, >= 95% within 8 passes): {'GO' if go else 'NO-GO'}")


def arguments():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--settle", type=int, default=300)
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--most", type=int, default=30)
    ap.add_argument("--tolerance", type=float, default=1e-4)
    ap.add_argument("--penalty", type=float, default=1e-6, help="compliance, relative to W's diagonal")
    ap.add_argument("--exact", action="store_true", help="[body] an exact line search, as MuJoCo's, not backtracking")
    ap.add_argument("--space", choices=(*PASSES, "ipm"), default="impulse",
                    help="impulse: the equalities of the local problem; body: velocities with a stiff penalty")
    ap.add_argument("--stiffness", type=float, default=1e5,
                    help="[body] the penalty, in units of each row's own effective mass (1 / W_ii)")
    ap.add_argument("--continuation", type=float, default=0.0,
                    help="[facets] start at this stiffness, x10 each outer round up to --stiffness")
    ap.add_argument("--shift", choices=("fixed", "lagged", "linearised"), default="fixed",
                    help="[ipm, with --diagnose] De Saxce's shift: fixed a solve (then updated: --rounds), from each "
                         "pass's iterate, or linearised in each pass (a nonsymmetric system)")
    ap.add_argument("--rounds", type=int, default=9, help="[ipm] solves, the shift updated after each")
    ap.add_argument("--eager", action="store_true", help="[facets] the outer update after every Newton step")
    ap.add_argument("--diagnose", action="store_true",
                    help="first, on the first step: one pass from the state of its own answer (PGS to 1e-7)")
    return ap.parse_args()


def main():
    args = arguments()
    print(protocol_line(current()) + "\n")
    scene = generate("pile", 9, dict(count=1000, box=95.0, sigma=19.0, steps=args.settle + args.steps + 1))
    world = build_world(scene)
    for _ in range(args.settle):
        world.step(scene.dt, 8, scene.solver.position_iterations)
    if args.diagnose:
        diagnose(world, scene, args)
    if args.space != "ipm":   # (ipm: a diagnosis of one step only)
        report(run_loop(world, scene, args), args)


if __name__ == "__main__":
    main()
