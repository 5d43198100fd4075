"""Grid back to points: bilinear interpolation (thesis eq. 3.17), vectorised."""
import numpy as np


def bilinear(grid, spec, points):
    """Values of grid (C, H, W) or (H, W) at points (n, 2): ((C, n) or (n,), outside count).

    Points outside the grid are clamped to its edge and counted."""
    g = np.asarray(grid)
    single = g.ndim == 2
    if single:
        g = g[None]
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    fx = (p[:, 0] - spec.x0) / spec.cell
    fy = (p[:, 1] - spec.y0) / spec.cell
    outside = int(np.count_nonzero(spec.outside(p)))
    fx = np.clip(fx, 0.0, spec.nx - 1)
    fy = np.clip(fy, 0.0, spec.ny - 1)
    ix = np.minimum(np.floor(fx).astype(np.int64), max(spec.nx - 2, 0))
    iy = np.minimum(np.floor(fy).astype(np.int64), max(spec.ny - 2, 0))
    tx = fx - ix
    ty = fy - iy
    ix1 = np.minimum(ix + 1, spec.nx - 1)
    iy1 = np.minimum(iy + 1, spec.ny - 1)
    out = (g[:, iy, ix] * (1 - tx) * (1 - ty) + g[:, iy, ix1] * tx * (1 - ty)
           + g[:, iy1, ix] * (1 - tx) * ty + g[:, iy1, ix1] * tx * ty)
    return (out[0] if single else out), outside
