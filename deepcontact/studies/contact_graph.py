"""A learned correction to Box2D's warm start on the contact graph.

Nodes are the contact points and the bodies; a point talks to its two bodies and they to their
other points. The network sees each point in velocity units (impulse times effective inverse
mass, divided by the step's free-velocity scale, so one model serves any mass and any speed):
its warm start, the contact velocity that start leaves, the free velocity, bias, friction, the
normal. It outputs a change of the start in the same units. Its last layer starts at zero, so an
untrained model is Box2D's warm start exactly.

It is trained on what the solver needs, not on impulses (which are not unique on redundant
contacts): the loss is the LCP's min-map residual after `sweeps` differentiable Gauss-Seidel
sweeps from the corrected start. The sweeps visit the manifolds colour by colour (no two
manifolds of one colour share a dynamic body, so a colour updates at once) - a Gauss-Seidel
order different from Box2D's, without the 2x2 block solver: a surrogate of the real solver,
which measures the result.
"""
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .._box2d import contact_rows

FEATURES = 11
OUTPUT_SCALE = 0.01


@dataclass
class Graph:
    """One step's or a batch of steps' contact graph, as float64 tensors."""
    a: torch.Tensor            # body rows of each point (global across the batch)
    b: torch.Tensor
    normal: torch.Tensor       # (points, 2)
    r_a: torch.Tensor
    r_b: torch.Tensor
    k_normal: torch.Tensor
    k_tangent: torch.Tensor
    bias: torch.Tensor
    friction: torch.Tensor     # mu, 0 where the manifold has no friction row
    active: torch.Tensor       # points the solver updates (Box2D drops one of a redundant pair)
    inv_mass: torch.Tensor     # per body
    inv_inertia: torch.Tensor
    velocity: torch.Tensor     # per body, before any impulse: (bodies, 2)
    omega: torch.Tensor
    scale: torch.Tensor        # per point: its step's free-velocity scale
    step: torch.Tensor         # per point: which step of the batch it belongs to
    steps: int
    groups: list               # per colour, the active rows of its manifolds' point 0 and point 1
    start_normal: torch.Tensor
    start_tangent: torch.Tensor


def _colours(manifold, row_a, row_b, dynamic):
    """Greedy colouring of the manifolds: no two of a colour share a dynamic body."""
    first = np.flatnonzero(np.r_[True, manifold[1:] != manifold[:-1]])
    colour_of_body = {}
    colours = np.zeros(len(first), np.int64)
    for i, k in enumerate(first):
        used = set()
        for body in (row_a[k], row_b[k]):
            if dynamic[body]:
                used |= colour_of_body.setdefault(body, set())
        c = 0
        while c in used:
            c += 1
        colours[i] = c
        for body in (row_a[k], row_b[k]):
            if dynamic[body]:
                colour_of_body[body].add(c)
    return first, colours


def graph_of(problems, start_normal=None, start_tangent=None):
    """A batch Graph from StepProblems (starts default to each problem's own, Box2D's warm start)."""
    parts, offset, base = [], 0, 0     # bodies and points of the steps before this one
    groups = {}
    for s, p in enumerate(problems):
        rows = contact_rows(p.bodies, p.contacts, p.settings())
        inv_mass = p.bodies["inv_mass"].astype(np.float64)
        inv_inertia = p.bodies["inv_inertia"].astype(np.float64)
        dynamic = (inv_mass > 0) | (inv_inertia > 0)
        first, colours = _colours(rows["manifold"], rows["row_a"], rows["row_b"], dynamic)
        counts = p.contacts["point_count"][first]
        for f, c, n in zip(first, colours, counts):
            for j in range(n):
                groups.setdefault((int(c), j), []).append(base + f + j)
        # the start as the solver takes it: no negative normal, tangent inside the cone
        sn = np.maximum(np.asarray(p.start_normal if start_normal is None else start_normal[s], np.float64), 0.0)
        st = np.asarray(p.start_tangent if start_tangent is None else start_tangent[s], np.float64)
        bound = rows["friction"] * sn
        st = np.clip(st, -bound, bound)
        parts.append(dict(rows, a=rows["row_a"] + offset, b=rows["row_b"] + offset, inv_mass=inv_mass,
                          inv_inertia=inv_inertia, scale_p=np.full(len(rows["k_normal"]), rows["scale"]),
                          step=np.full(len(rows["k_normal"]), s), sn=sn,
                          st=np.where(rows["friction_row"], st, 0.0)))
        offset += len(inv_mass)
        base += len(rows["k_normal"])

    def cat(key):
        return torch.from_numpy(np.concatenate([q[key] for q in parts]))
    friction = cat("friction") * cat("friction_row").double()
    active = cat("active")
    colours = []
    for c in sorted({c for c, _ in groups}):
        rows = [torch.tensor(groups[(c, j)]) for j in (0, 1) if (c, j) in groups]
        colours.append([r[active[r]] for r in rows if active[r].any()])
    return Graph(a=cat("a").long(), b=cat("b").long(), normal=cat("normal"), r_a=cat("r_a"), r_b=cat("r_b"),
                 k_normal=cat("k_normal"), k_tangent=cat("k_tangent"), bias=cat("bias"), friction=friction,
                 active=active, inv_mass=cat("inv_mass"), inv_inertia=cat("inv_inertia"),
                 velocity=cat("velocity"), omega=cat("omega"), scale=cat("scale_p"), step=cat("step").long(),
                 steps=len(problems), groups=colours,
                 start_normal=cat("sn"), start_tangent=cat("st"))


def _cross_sv(s, r):      # s x r for a scalar s and vectors r: (-s r_y, s r_x)
    return torch.stack((-s * r[:, 1], s * r[:, 0]), 1)


def _cross_vv(r, p):
    return r[:, 0] * p[:, 1] - r[:, 1] * p[:, 0]


class _Velocities:
    """Body velocities with impulses applied out of place (autograd keeps every version)."""

    def __init__(self, g):
        self.g, self.v, self.w = g, g.velocity, g.omega

    def contact(self, rows):
        g = self.g
        a, b = g.a[rows], g.b[rows]
        return (self.v[b] + _cross_sv(self.w[b], g.r_b[rows])) - (self.v[a] + _cross_sv(self.w[a], g.r_a[rows]))

    def apply(self, rows, impulse):
        g = self.g
        a, b = g.a[rows], g.b[rows]
        self.v = self.v.index_add(0, a, -g.inv_mass[a, None] * impulse).index_add(0, b, g.inv_mass[b, None] * impulse)
        self.w = self.w.index_add(0, a, -g.inv_inertia[a] * _cross_vv(g.r_a[rows], impulse)) \
                       .index_add(0, b, g.inv_inertia[b] * _cross_vv(g.r_b[rows], impulse))


def _tangent(normal):
    return torch.stack((normal[:, 1], -normal[:, 0]), 1)


def sweep(g, normal_impulse, tangent_impulse, sweeps):
    """Warm start, then `sweeps` coloured Gauss-Seidel sweeps; returns (normal, tangent, velocities)."""
    vel = _Velocities(g)
    active = torch.nonzero(g.active).squeeze(1)
    tangent = _tangent(g.normal)
    vel.apply(active, normal_impulse[active, None] * g.normal[active] + tangent_impulse[active, None] * tangent[active])
    n, t = normal_impulse, tangent_impulse
    for _ in range(sweeps):
        for colour in g.groups:
            # as Box2D per manifold: friction rows first, then normal rows; within a colour
            # no two manifolds share a dynamic body, so each point j updates at once
            for rows in colour:
                vt = (vel.contact(rows) * tangent[rows]).sum(1)
                hi = g.friction[rows] * n[rows]
                new = torch.minimum(torch.maximum(t[rows] - vt / g.k_tangent[rows], -hi), hi)
                vel.apply(rows, (new - t[rows])[:, None] * tangent[rows])
                t = t.index_copy(0, rows, new)
            for rows in colour:
                vn = (vel.contact(rows) * g.normal[rows]).sum(1)
                new = torch.clamp(n[rows] - (vn - g.bias[rows]) / g.k_normal[rows], min=0.0)
                vel.apply(rows, (new - n[rows])[:, None] * g.normal[rows])
                n = n.index_copy(0, rows, new)
    return n, t, vel


def residual(g, n, t, vel):
    """Per active point, the squared min-map residual (normal and friction rows) over the step's
    scale squared (squared: its square root has no gradient at 0)."""
    rows = torch.nonzero(g.active).squeeze(1)
    dv = vel.contact(rows)
    vn = (dv * g.normal[rows]).sum(1) - g.bias[rows]
    vt = (dv * _tangent(g.normal)[rows]).sum(1)
    kn, kt = g.k_normal[rows], g.k_tangent[rows]
    rn = torch.minimum(kn * n[rows], vn)
    x = kt * t[rows]
    hi = g.friction[rows] * n[rows] * kt
    rt = x - torch.minimum(torch.maximum(x - vt, -hi), hi)
    return rows, (rn ** 2 + rt ** 2) / g.scale[rows] ** 2


def features(g):
    """FEATURES numbers per point, in velocity units over the step's scale."""
    V = g.scale
    tangent = _tangent(g.normal)
    _, _, vel = sweep(g, g.start_normal, g.start_tangent, 0)
    after = vel.contact(torch.arange(len(V)))
    free = _Velocities(g).contact(torch.arange(len(V)))
    static_pair = ((g.inv_mass[g.a] == 0) | (g.inv_mass[g.b] == 0)).double()
    return torch.stack((g.k_normal * g.start_normal / V, g.k_tangent * g.start_tangent / V,
                        ((after * g.normal).sum(1) - g.bias) / V, (after * tangent).sum(1) / V,
                        ((free * g.normal).sum(1) - g.bias) / V, (free * tangent).sum(1) / V,
                        g.bias / V, g.friction, g.normal[:, 0], g.normal[:, 1], static_pair), 1)


def _mlp(sizes):
    layers = []
    for i, (p, q) in enumerate(zip(sizes, sizes[1:])):
        layers.append(nn.Linear(p, q))
        if i < len(sizes) - 2:
            layers.append(nn.Tanh())
    return nn.Sequential(*layers)


class CorrectionNet(nn.Module):
    """Points -> their bodies -> points, `rounds` times; out: (d normal, d tangent) in velocity units."""

    def __init__(self, width=32, rounds=2):
        super().__init__()
        self.encode = _mlp([FEATURES, width, width])
        self.to_a = nn.ModuleList(nn.Linear(width, width) for _ in range(rounds))
        self.to_b = nn.ModuleList(nn.Linear(width, width) for _ in range(rounds))
        self.update = nn.ModuleList(_mlp([3 * width, width, width]) for _ in range(rounds))
        self.out = nn.Linear(width, 2)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x, a, b, bodies):
        h = self.encode(x)
        for to_a, to_b, update in zip(self.to_a, self.to_b, self.update):
            body = torch.zeros(bodies, h.shape[1], dtype=h.dtype)
            body = body.index_add(0, a, torch.tanh(to_a(h))).index_add(0, b, torch.tanh(to_b(h)))
            h = h + update(torch.cat((h, body[a], body[b]), 1))
        return self.out(h)


def corrected_start(model, g):
    """The model's start: Box2D's warm start plus the predicted change, kept feasible."""
    x = features(g).float()
    # (a small output step: the warm start is already close, a change of 1 is the whole scale)
    d = OUTPUT_SCALE * model(x, g.a, g.b, len(g.inv_mass)).double()
    n = torch.clamp(g.start_normal + d[:, 0] * g.scale / g.k_normal, min=0.0)
    hi = g.friction * n
    t = torch.minimum(torch.maximum(g.start_tangent + d[:, 1] * g.scale / g.k_tangent, -hi), hi)
    return n, t


def loss(model, g, sweeps):
    """Mean over the batch's steps of log(mean squared residual after `sweeps` sweeps)."""
    n, t = corrected_start(model, g) if model is not None else (g.start_normal, g.start_tangent)
    n, t, vel = sweep(g, n, t, sweeps)
    rows, r = residual(g, n, t, vel)
    per_step = torch.zeros(g.steps, dtype=r.dtype).index_add(0, g.step[rows], r)
    count = torch.zeros(g.steps, dtype=r.dtype).index_add(0, g.step[rows], torch.ones_like(r))
    return torch.log(per_step / count.clamp(min=1) + 1e-16).mean()
