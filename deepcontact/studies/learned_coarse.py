"""Does a learned coarse space help PGS? A coarse space whose aggregation weights are trained
through the solve, on the residual it leaves.

The two-level correction: the step's contact points are grouped into square cells of --cell
metres (the aggregates); each aggregate has one normal and one tangent mode, a pattern of impulse
changes over its points, P's columns. Between sweeps, the impulses move by P c, c minimising the
step's energy 1/2 x'Ax + x'(q) along those modes (the Galerkin solve (P'AP) c = -P'w, w the rows'
velocities), restricted to the touching rows; the result is projected back onto the cone.

Unlearned, every point of an aggregate weighs 1 (piecewise constant: the correction tried and
not kept in docs/results.md). Learned, the weights are exp() of the output of the contact-graph
network (studies/contact_graph.py, CorrectionNet, zero-initialised output: untrained, it is
the unlearned space exactly) from each point's state at the iterate, trained (Adam, fixed seed) on
the log mean squared residual after --sweeps differentiable coloured Gauss-Seidel sweeps, the
correction, and --sweeps more (the surrogate of contact_graph.py).

Data: the 100-circle pile driven by our PGS in the loop (builtin start, residual < 1e-4, cap
1000), training seeds --train, held-out seed 1000 (every second step), as in
`dc study learned-correction`.

Reported on the held-out steps, each solved by the real solver (float64 PGS, Box2D's order and
block solver) to a residual of 1e-4 (cap 1000): builtin alone; and --sweeps sweeps, the
correction (always, or kept only if the residual falls right after it; its time counted:
operators, network, Galerkin solve, the check), then sweeps to the tolerance, unlearned and
learned: median sweeps, median time, how often the correction was kept, each against builtin in
the same run.

    dc study learned-coarse [--cell 4] [--sweeps 8] [--epochs 4] [--train 0,1] [--steps 600]
"""
import time

import numpy as np
import torch

from .._box2d import contact_rows
from ..solver.pgs import solve
from ..solver.settings import CAP, TOLERANCE
from . import contact_graph as cg
from .learned_correction import datasets
from .text import StudyText, progress



class Coarse:
    """One step's dense operators for the coarse correction: rows are (normal of every point,
    tangent of every point); A = J M^-1 J' in those rows; the aggregate of each point."""

    def __init__(self, problem, cell):
        self.g = g = cg.graph_of([problem])
        rows = contact_rows(problem.bodies, problem.contacts, problem.settings())
        points = len(g.k_normal)
        where = problem.bodies["center"][rows["row_a"]] + rows["r_a"]
        _, self.aggregate = np.unique(np.floor(where / cell).astype(np.int64), axis=0, return_inverse=True)
        self.aggregate = torch.from_numpy(self.aggregate.ravel())
        self.count = int(self.aggregate.max()) + 1 if points else 0
        tangent = cg._tangent(g.normal)
        bodies = len(g.inv_mass)
        J = torch.zeros(2 * points, 3 * bodies, dtype=torch.float64)
        for block, d in ((0, g.normal), (points, tangent)):
            r = torch.arange(points) + block
            for body, arm, sign in ((g.a, g.r_a, -1.0), (g.b, g.r_b, 1.0)):
                J.index_put_((r, 3 * body), sign * d[:, 0], accumulate=True)
                J.index_put_((r, 3 * body + 1), sign * d[:, 1], accumulate=True)
                J.index_put_((r, 3 * body + 2), sign * cg._cross_vv(arm, d), accumulate=True)
        inv_m = torch.stack((g.inv_mass, g.inv_mass, g.inv_inertia), 1).reshape(-1)
        self.J = J
        self.A = (J * inv_m) @ J.T
        self.bias = torch.cat((g.bias, torch.zeros(points, dtype=torch.float64)))
        self.points = points

    def velocities(self, vel):
        v = torch.cat((vel.v, vel.w[:, None]), 1).reshape(-1)
        return self.J @ v - self.bias

    def features(self, n, t, w):
        g, V = self.g, self.g.scale
        p = self.points
        free = cg._Velocities(g).contact(torch.arange(p))
        static_pair = ((g.inv_mass[g.a] == 0) | (g.inv_mass[g.b] == 0)).double()
        return torch.stack((g.k_normal * n / V, g.k_tangent * t / V, w[:p] / V, w[p:] / V,
                            (free * g.normal).sum(1) / V, (free * cg._tangent(g.normal)).sum(1) / V,
                            g.bias / V, g.friction, g.normal[:, 0], g.normal[:, 1], static_pair), 1)

    def correct(self, model, n, t, vel):
        """Impulses after one coarse correction from (n, t) whose velocities are vel."""
        g, p, K = self.g, self.points, self.count
        w = self.velocities(vel)
        if model is None:
            weight = torch.ones(p, 2, dtype=torch.float64)
        else:
            weight = torch.exp(model(self.features(n, t, w).float(), g.a, g.b, len(g.inv_mass)).double())
        touching = g.active & ((n > 0) | (w[:p] < 0))
        frictional = touching & (g.friction > 0)   # their tangent rows
        P = torch.zeros(2 * p, 2 * K, dtype=torch.float64)
        r = torch.arange(p)
        P = P.index_put((r, self.aggregate), weight[:, 0] * touching) \
             .index_put((r + p, K + self.aggregate), weight[:, 1] * frictional)
        # a mode with no touching row has an empty column: a small ridge keeps G regular (and
        # its derivative defined), and leaves such a mode at zero
        G = P.T @ self.A @ P
        G = G + 1e-9 * G.diagonal().max().clamp(min=1e-30) * torch.eye(2 * K, dtype=torch.float64)
        c = -torch.linalg.solve(G, P.T @ w)
        x = torch.cat((n, t)) + P @ c
        n2 = torch.clamp(x[:p], min=0.0)
        hi = g.friction * n2
        return n2, torch.minimum(torch.maximum(x[p:], -hi), hi)


def surrogate_loss(model, coarse, sweeps):
    g = coarse.g
    n, t, vel = cg.sweep(g, g.start_normal, g.start_tangent, sweeps)
    if model != "none":
        n, t = coarse.correct(model, n, t, vel)
    n, t, vel = cg.sweep(g, n, t, sweeps)
    _, r = cg.residual(g, n, t, vel)
    return torch.log(r.mean() + 1e-16)


def train(steps, epochs, sweeps, cell, lr, seed, batch=8):
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = cg.CorrectionNet(width=32, rounds=2)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    ops = [Coarse(p, cell) for p in steps]
    with torch.no_grad():
        plain = np.mean([surrogate_loss("none", c, sweeps).item() for c in ops])
        unlearned = np.mean([surrogate_loss(None, c, sweeps).item() for c in ops])
    progress(f"surrogate loss on the training steps: sweeps alone {plain:.3f}, unlearned coarse {unlearned:.3f}")
    for epoch in range(epochs):
        t0, total = time.perf_counter(), 0.0
        order = rng.permutation(len(ops))
        for i in range(0, len(order), batch):
            opt.zero_grad()
            value = sum(surrogate_loss(model, ops[j], sweeps) for j in order[i:i + batch]) / len(order[i:i + batch])
            value.backward()
            opt.step()
            total += value.item() * len(order[i:i + batch])
        progress(f"epoch {epoch + 1}: learned {total / len(ops):.3f}, {time.perf_counter() - t0:.0f} s")
    return model


def solved(problem, n, t, cap):
    t0 = time.perf_counter()
    s = solve(problem, n, t, mode="float64", max_iterations=cap, tolerance=TOLERANCE, stop_on="residual")
    return s, time.perf_counter() - t0


def two_level(problem, model, sweeps, cell, always):
    """Sweeps, the correction, sweeps to the tolerance: (sweeps, seconds, kept). always=False keeps
    the correction only if the residual falls right after it (its check counted in the time)."""
    first, t1 = solved(problem, problem.start_normal, problem.start_tangent, sweeps)
    if first.residual < TOLERANCE:
        return first.iterations, t1, False
    t0 = time.perf_counter()
    with torch.no_grad():
        coarse = Coarse(problem, cell)
        n = torch.from_numpy(np.asarray(first.normal_impulse, np.float64))
        t = torch.from_numpy(np.asarray(first.tangent_impulse, np.float64))
        _, _, vel = cg.sweep(coarse.g, n, t, 0)
        n, t = coarse.correct(model, n, t, vel)
    n, t = n.numpy(), t.numpy()
    kept = True
    if not always:
        check = solve(problem, n, t, mode="float64", max_iterations=0, tolerance=TOLERANCE, stop_on="residual")
        kept = check.residual < first.residual
        if not kept:
            n, t = first.normal_impulse, first.tangent_impulse
    t_correct = time.perf_counter() - t0
    rest, t2 = solved(problem, n, t, CAP - first.iterations)
    return first.iterations + rest.iterations, t1 + t_correct + t2, kept


VARIANTS = {"unlearned, always": (False, True), "unlearned, if the residual falls": (False, False),
            "learned, always": (True, True), "learned, if the residual falls": (True, False)}


def evaluate(model, steps, sweeps, cell, out):
    rows = {"builtin": []} | {label: [] for label in VARIANTS}
    surrogate = {"sweeps alone": [], "unlearned": [], "learned": []}
    for p in steps:
        with torch.no_grad():
            coarse = Coarse(p, cell)
            for label, m in zip(surrogate, ("none", None, model)):
                surrogate[label].append(surrogate_loss(m, coarse, sweeps).item())
        s, dt = solved(p, p.start_normal, p.start_tangent, CAP)
        rows["builtin"].append((s.iterations, dt, False))
        for label, (learned, always) in VARIANTS.items():
            rows[label].append(two_level(p, model if learned else None, sweeps, cell, always))
    base_it = np.median([r[0] for r in rows["builtin"]])
    base_s = np.median([r[1] for r in rows["builtin"]])
    out(f"\nheld-out: {len(steps)} loop steps of seed 1000, residual < {TOLERANCE:g}, cap {CAP}; "
          f"cells of {cell:g} m, correction after {sweeps} sweeps")
    out("surrogate loss on them: " + ", ".join(f"{k} {np.mean(v):.3f}" for k, v in surrogate.items()))
    out("| start | median sweeps | vs builtin | median ms (correction included) | vs builtin | correction kept |")
    out("| --- | ---: | ---: | ---: | ---: | ---: |")
    for label, r in rows.items():
        it, ms = np.median([x[0] for x in r]), np.median([x[1] for x in r])
        kept = f"{sum(x[2] for x in r)} of {len(r)}" if label != "builtin" else ""
        out(f"| {label} | {it:.0f} | {it / base_it:.2f}x | {ms * 1e3:.3f} | {ms / base_s:.2f}x | {kept} |")


MIN_CELL = 1e-3   # metres: a coarse cell finer than a millimetre groups nothing (and 1e-300 divides by zero)


def run(cell=4.0, sweeps=8, epochs=4, lr=1e-4, train_seeds=(0, 1), steps=600, out=None) -> StudyText:
    """The study's tables (a StudyText; `out` one to add to), on held-out seed 1000."""
    from ..errors import OptionError
    if not MIN_CELL <= cell < float("inf"):
        raise OptionError(f"a coarse cell must be at least {MIN_CELL:g} m, got {cell:g}", "--cell")

    train_set, test_set = datasets(train_seeds, steps)
    out = StudyText() if out is None else out
    model = train(train_set, epochs, sweeps, cell, lr, seed=0)
    evaluate(model, test_set, sweeps, cell, out)
    return out
