"""Training losses.

  masked     the thesis's eq. 5.2: squared error on the nodes whose label is non-zero only
  contacts   squared error of the prediction interpolated (bilinearly) at the contact points,
             against Box2D's impulses there: what a warm start actually uses
  mse        plain squared error over all nodes
"""
import torch


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
    scale = 1.0 if spec.renormalize else spec.cell ** 2
    total, count = pred.new_zeros(()), 0
    for k in range(pred.shape[0]):
        if len(positions[k]) == 0:
            continue
        at = bilinear_torch(pred[k], spec, positions[k]) * scale
        total = total + ((at - impulses[k][:, label_columns].T) ** 2).sum()
        count += at.numel()
    return total / max(count, 1)


LOSSES = ("masked", "contacts", "mse")
