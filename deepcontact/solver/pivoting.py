"""Lemke's complementary pivoting on a step's 2D friction LCP: the fallback of the reference
where Newton stalls near, not at, an exact solution (a pivot between active sets is what it
lacks; docs/solver.md).

The step's local problem (solver/local.py: u = W r + q per point normal, tangent) becomes an LCP
in z = (ln, l+, l-, beta), lt = l+ - l-, exact in 2D (the friction cone has two edges):

    w_n    =  A_nn ln + A_nt (l+ - l-) + q_n          >= 0  _|_ ln
    w_+    =  A_tn ln + A_tt (l+ - l-) + q_t + beta   >= 0  _|_ l+
    w_-    = -A_tn ln - A_tt (l+ - l-) - q_t + beta   >= 0  _|_ l-
    w_beta =  mu ln - l+ - l-                         >= 0  _|_ beta   (beta: the sliding speed)

Lemke's method with covering vector e (natively in revised form, lemke(); the numpy tableau,
lemke_tableau(), is its readable reference): O(N^2) per pivot for N = 4 x points, even revised
(the basis inverse is dense), so it is kept for the steps that need it, and is first run on a
neighbourhood (StepPivots.local): where Newton stalls, its residual sits on a few contacts, and an
exact answer of their LCP, the other contacts' impulses held, lets Newton go on to an exact
answer of the step.
"""
import numpy as np

from .._box2d import contact_rows, lemke as native_lemke
from .local import LocalProblem, local_problem, point_residuals

PIVOTS_PER_ROW = 10


def friction_lcp(lp):
    """(M, q) of the LCP above from an FCLIB LocalProblem."""
    W = lp.W.toarray()
    Ann, Ant, Atn, Att = W[0::2, 0::2], W[0::2, 1::2], W[1::2, 0::2], W[1::2, 1::2]
    qn, qt = lp.q[0::2], lp.q[1::2]
    m = len(qn)
    I, Z = np.eye(m), np.zeros((m, m))
    M = np.block([[Ann, Ant, -Ant, Z], [Atn, Att, -Att, I], [-Atn, -Att, Att, I], [np.diag(lp.mu), -I, -I, Z]])
    return M, np.concatenate([qn, qt, -qt, np.zeros(m)])


def lemke(M, q, max_pivots=None):
    """z >= 0 with w = M z + q >= 0 and z.w = 0, or None (ray termination or too many pivots):
    the native revised form (native/lemke.hpp), the same pivot rule as lemke_tableau."""
    z, _ = native_lemke(np.ascontiguousarray(M, dtype=np.float64), np.asarray(q, dtype=np.float64),
                        max_pivots or PIVOTS_PER_ROW * len(q))
    return z


def lemke_tableau(M, q, max_pivots=None):
    """Lemke's method on a dense tableau in numpy: the slow, readable reference of lemke()."""
    n = len(q)
    if n == 0 or q.min() >= 0:
        return np.zeros(n)
    # tableau rows: w - M z - e z0 = q; columns w (0..n-1), z (n..2n-1), z0 (2n), right side
    T = np.hstack([np.eye(n), -M, -np.ones((n, 1)), q[:, None]])
    basis = np.arange(n)
    z0 = 2 * n
    scale = max(1.0, np.abs(q).max())

    def pivot(r, c):
        T[r] /= T[r, c]
        column = T[:, c].copy()
        column[r] = 0.0
        T[:] -= np.outer(column, T[r])

    r = int(np.argmin(q))
    pivot(r, z0)
    leaving, basis[r] = basis[r], z0
    for _ in range(max_pivots or PIVOTS_PER_ROW * n):
        entering = leaving + n if leaving < n else leaving - n   # the complement
        column = T[:, entering]
        rows = np.nonzero(column > 1e-12 * np.abs(column).max(initial=1.0))[0]
        if len(rows) == 0:
            return None
        ratios = T[rows, -1] / column[rows]
        best = ratios.min()
        ties = rows[ratios <= best + 1e-12 * scale]
        r = int(ties[np.nonzero(basis[ties] == z0)[0][0]]) if np.any(basis[ties] == z0) else int(ties[0])
        pivot(r, entering)
        leaving, basis[r] = basis[r], entering
        if leaving == z0:
            z = np.zeros(n)
            inside = (basis >= n) & (basis < 2 * n)
            z[basis[inside] - n] = np.maximum(T[inside, -1], 0.0)
            return z
    return None


def _from_z(z, m):
    """FCLIB's r (per contact: normal, tangent) from the LCP's z = (ln, l+, l-, beta)."""
    r = np.empty(2 * m)
    r[0::2], r[1::2] = z[:m], z[m:2 * m] - z[2 * m:3 * m]
    return r


class StepPivots:
    """One step made ready for pivoting once, however many pivots are tried on it: its local
    problem (W in CSR), each contact's two bodies and, when first asked for, its friction LCP."""

    def __init__(self, problem):
        self.problem = problem
        self.lp = local_problem(problem)
        self.W = self.lp.W.tocsr()
        rows = contact_rows(problem.bodies, problem.contacts, problem.settings(prune=False))
        self.body_a, self.body_b = rows["row_a"][self.lp.points], rows["row_b"][self.lp.points]
        self.dynamic = problem.bodies["type"] == 2
        self._lcp = None

    def whole(self, method=None, perturb=0.0):
        """Per-point (normal, tangent) impulses of the step by Lemke's method (default the native
        lemke; lemke_tableau is the other), or None. perturb: q raised by up to this fraction of
        its largest entry, pseudo-randomly (the same every time): on a degenerate step the ties
        that end Lemke on a ray or a wrong basis are broken, and Newton finishes from there."""
        if self._lcp is None:
            self._lcp = friction_lcp(self.lp)
        M, q = self._lcp
        if perturb:
            q = q + perturb * np.abs(q).max(initial=0.0) * np.random.default_rng(0).random(len(q))
        z = (method or lemke)(M, q)
        if z is None:
            return None
        return self.lp.impulses(_from_z(z, len(self.lp.mu)), self.problem.points)

    def neighbourhood(self, r, rings=1, share=1e-2):
        """The contacts (indices into lp) whose residual at r is at least `share` of the
        largest, grown by `rings` rings of contacts on the same dynamic bodies."""
        a, b = self.body_a, self.body_b
        f = point_residuals(self.lp, r)
        chosen = f >= share * f.max(initial=0.0)
        for _ in range(rings):
            touched = np.zeros(len(self.dynamic), bool)
            touched[a[chosen]] = True
            touched[b[chosen]] = True
            touched &= self.dynamic     # the ground touches everything: it joins nothing
            chosen |= touched[a] | touched[b]
        return np.nonzero(chosen)[0]

    def local(self, normal, tangent, rings=1, share=1e-2, most=120):
        """Per-point (normal, tangent) impulses: the given ones, with the neighbourhood of the
        contacts carrying the residual replaced by Lemke's exact answer of their LCP (the other
        contacts' impulses held); None if Lemke fails there or the neighbourhood has more than
        `most` contacts (a pivot costs (4 x contacts)^2)."""
        r = self.lp.reaction(normal, tangent)
        chosen = self.neighbourhood(r, rings, share)
        if len(chosen) > most:
            return None
        rows = np.ravel(np.column_stack([2 * chosen, 2 * chosen + 1]))
        held = np.ones(len(r), bool)
        held[rows] = False
        W = self.W[rows]
        sub = LocalProblem(W=W[:, rows].tocsc(), q=self.lp.q[rows] + W[:, held] @ r[held],
                           mu=self.lp.mu[chosen], points=np.arange(len(chosen)))
        z = lemke(*friction_lcp(sub))
        if z is None:
            return None
        r[rows] = _from_z(z, len(chosen))
        return self.lp.impulses(r, self.problem.points)
