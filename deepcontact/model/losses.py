"""Training losses.

  masked     the thesis's eq. 5.2: squared error on the nodes whose label is non-zero only
  contacts   squared error of the prediction interpolated (bilinearly) at the contact points,
             against Box2D's impulses there: what a warm start actually uses
  mse        plain squared error over all nodes
  solver     the residual of the step's contact problem at the predicted start (SolverLoss)
"""
import numpy as np
import torch

from ..solver.local import local_problem, residual_scale
from ..solver.problem import StepProblem
from . import choices


def masked_mse(pred, target):
    mask = (target != 0).to(pred.dtype)
    return (mask * (pred - target) ** 2).sum() / mask.sum().clamp(min=1.0)


def mse(pred, target):
    return torch.mean((pred - target) ** 2)


def bilinear_torch(grid, spec, points):
    """grid (C, H, W) at points (n, 2) → (C, n), differentiable in grid."""
    fx = ((points[:, 0] - spec.x0) / spec.cell).clamp(0, spec.nx - 1)
    fy = ((points[:, 1] - spec.y0) / spec.cell).clamp(0, spec.ny - 1)
    ix = fx.floor().long().clamp(max=max(spec.nx - 2, 0))
    iy = fy.floor().long().clamp(max=max(spec.ny - 2, 0))
    tx, ty = fx - ix, fy - iy
    ix1 = (ix + 1).clamp(max=spec.nx - 1)
    iy1 = (iy + 1).clamp(max=spec.ny - 1)
    return (grid[:, iy, ix] * (1 - tx) * (1 - ty) + grid[:, iy, ix1] * tx * (1 - ty)
            + grid[:, iy1, ix] * (1 - tx) * ty + grid[:, iy1, ix1] * tx * ty)


def contact_mse(pred, positions, impulses, spec, label_columns):
    """Mean squared error at the contact points. positions/impulses: lists of tensors per sample;
    label_columns: for each output channel, its column in impulses (0 normal, 1 tangent)."""
    scale = spec.impulse_scale
    total, count = pred.new_zeros(()), 0
    for k in range(pred.shape[0]):
        if len(positions[k]) == 0:
            continue
        at = bilinear_torch(pred[k], spec, positions[k]) * scale
        total = total + ((at - impulses[k][:, label_columns].T) ** 2).sum()
        count += at.numel()
    return total / max(count, 1)


LOSSES = choices.LOSSES   # (the names live where the command line can read them without torch)


class SolverLoss:
    """Solver-aware loss: how far the predicted start is from solving the step's contact problem.

    For each sample the step's local problem (W, q, friction bounds; deepcontact.solver.local) is
    assembled once from its step file and cached, dense. The prediction, interpolated at the contact points
    and projected onto the feasible set (ln >= 0, |lt| <= mu ln), is relaxed by k damped
    projected-Jacobi sweeps, and the loss is the squared min-map residual of the LCP there
    (docs/solver.md: in velocity units, normalised by the step's largest free velocity).

    Why Jacobi and not Gauss-Seidel: a Gauss-Seidel sweep is a chain of one-row updates, hundreds of
    tiny autograd operations per sample; a Jacobi sweep is one matrix product, differentiable and
    fast. Both relax towards the same LCP solution and both are 0 exactly there; with k = 0 (the
    default) the loss is the residual of the start itself, which is what PGS starts from.
    """

    def __init__(self, dataset, sweeps=0, damping=0.5):
        self.ds, self.sweeps, self.damping = dataset, sweeps, damping
        self.cache = {}
        dataset.check_step_sources()

    @staticmethod
    def memory(dataset, batch_size, sweeps):
        """Bytes the loss holds: each sample's dense LCP matrix, cached (two rows a contact point,
        float64), and for one batch the autograd graph of its sweeps: about 72 row vectors a sweep,
        measured (dc train --loss solver on a 12-circle pile's dataset peaked 0.65 GB above the
        process's own at 500 sweeps and 2.4 GB at 2,000; 80 is counted, to be refused early)."""
        points = np.diff(np.asarray(dataset.arrays["contact_offsets"], np.int64))
        rows = 2 * points
        cached = int(np.sum(rows.astype(np.float64) ** 2)) * 8
        biggest = int(np.sort(rows)[-batch_size:].sum()) if len(rows) else 0
        return cached + biggest * 8 * 80 * (sweeps + 1)

    def problem(self, i):
        """Sample i's contact problem as dense torch rows: the step's local problem (the one native
        assembly, solver/local.py), a tangent row only where there is friction."""
        if i not in self.cache:
            lp = local_problem(StepProblem.from_step_file(self.ds.step_file(i)))
            m = len(lp.points)
            kind = np.tile([0, 1], m)
            keep = np.nonzero((kind == 0) | (np.repeat(lp.mu, 2) > 0))[0]   # (rows: per point normal, tangent)
            renumber = np.full(2 * m, -1)
            renumber[keep] = np.arange(len(keep))
            t = {"A": lp.W[keep][:, keep].toarray(), "b": lp.q[keep], "kind": kind[keep],
                 "point": np.repeat(lp.points, 2)[keep], "friction": np.repeat(lp.mu, 2)[keep],
                 "normal_row": np.where(kind[keep] == 1, renumber[np.maximum(keep - 1, 0)], -1)}
            t = {name: torch.as_tensor(value) for name, value in t.items()}
            t["scale"] = residual_scale(lp) if m else 1.0
            self.cache[i] = t
        return self.cache[i]

    def residual(self, normal, tangent, p):
        """Normalised min-map residual vector of the LCP at per-point impulses (normal, tangent)."""
        kind, point = p["kind"], p["point"]
        lam = torch.where(kind == 0, normal[point], tangent[point])
        k = torch.diagonal(p["A"])
        nrm = kind == 0
        for _ in range(self.sweeps):
            w = p["A"] @ lam + p["b"]
            x = lam - self.damping * w / k.clamp(min=1e-12)
            bound = p["friction"] * torch.relu(x[p["normal_row"].clamp(min=0)])
            lam = torch.where(nrm, torch.relu(x), torch.maximum(torch.minimum(x, bound), -bound))
        w = p["A"] @ lam + p["b"]
        hi = p["friction"] * lam[p["normal_row"].clamp(min=0)] * k
        r = torch.where(nrm, torch.minimum(k * lam, w),
                        k * lam - torch.maximum(torch.minimum(k * lam - w, hi), -hi))
        return r / p["scale"]

    def __call__(self, pred, indices, spec, label_columns):
        scale = spec.impulse_scale
        total, count = pred.new_zeros(()), 0
        for k, i in enumerate(indices):
            p = self.problem(int(i))
            if len(p["b"]) == 0:
                continue
            pos, _ = self.ds.contacts(int(i))
            at = bilinear_torch(pred[k], spec, torch.as_tensor(np.array(pos), dtype=pred.dtype)) * scale
            zero = torch.zeros(at.shape[1], dtype=torch.float64)
            normal = at[label_columns.index(0)].double() if 0 in label_columns else zero
            tangent = at[label_columns.index(1)].double() if 1 in label_columns else zero
            normal = torch.relu(normal)
            mu = p["friction"][p["kind"] == 0]     # per point, in normal-row order
            order = p["point"][p["kind"] == 0]
            mu_point = torch.zeros_like(normal)
            mu_point[order] = mu
            bound = mu_point * normal
            tangent = torch.maximum(torch.minimum(tangent, bound), -bound)
            r = self.residual(normal, tangent, p)
            total = total + (r ** 2).sum()
            count += len(r)
        return (total / max(count, 1)).to(pred.dtype)
