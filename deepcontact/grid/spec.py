"""The grid a step is drawn on: origin, cell size d, node counts, kernel and smoothing length h.

Nodes sit at origin + (ix d, iy d), ix = 0..nx-1, spanning the scene's box (the extent of its
static bodies) or a given window: the thesis's 30 x 30 box at d = 0.5 has 61 x 61 nodes. The spec
owns the grid's contract: its span (x1, y1), which points lie outside it, and the scale from a grid
value read back at a point to an impulse (impulse_scale).
"""
import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from ..errors import InputError
from .kernels import KERNELS, weight

MAX_NODES = 4096 * 4096   # 64 MiB per float32 channel
MAX_COORDINATE = 1e7      # m: ten times the farthest a scene may place a body


class GridError(InputError):
    """A grid that cannot be: one line saying what is wrong (an InputError, so a ValueError)."""


def _grid_problem(g):
    """Why the grid g cannot be, or None."""
    for k in ("x0", "y0", "cell", "h"):
        v = getattr(g, k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return f"grid {k!r} must be a finite number, not {v!r}"
    x0, y0, cell, h = g.x0, g.y0, g.cell, g.h
    if cell <= 0 or h <= 0:
        return f"grid 'cell' and 'h' must be positive, not {cell:g} and {h:g}"
    if max(abs(x0), abs(y0)) > MAX_COORDINATE or cell < 1e-6 * max(1.0, abs(x0), abs(y0)):
        # (scenes lie within 1e6 m; float32 nodes this far out, or this close, would coincide)
        return (f"grid origin (x0, y0) = {x0:g},{y0:g} must lie within {MAX_COORDINATE:g} m, its cell "
                f"{cell:g} m above a millionth of it")
    nx, ny = g.nx, g.ny
    if not all(type(n) is int and n > 0 for n in (nx, ny)) or nx * ny > MAX_NODES:
        return f"grid 'nx' and 'ny' must be positive integers, at most {MAX_NODES:,} nodes in all"
    if max(nx, ny) * cell > 2 * MAX_COORDINATE:
        return f"the grid spans {max(nx, ny) * cell:g} m (cell times nx, ny), more than {2 * MAX_COORDINATE:g}"
    if not isinstance(g.kernel, str) or g.kernel not in KERNELS:
        return f"grid 'kernel' must be one of {', '.join(KERNELS)}, not {g.kernel!r}"
    if not isinstance(g.renormalize, bool):
        return "grid 'renormalize' must be true or false"
    return node_weight_problem(g.kernel, cell, h)


@dataclass(frozen=True)
class GridSpec:
    """The grid a step is drawn on: origin (x0, y0), cell size d, nx x ny nodes, the SPH kernel and
    smoothing length h; `over` makes one over a window, `from_dict` reads one from a file."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int
    h: float
    kernel: str = "poly6"
    renormalize: bool = True

    def __post_init__(self):
        """Every grid is checked as it is made, however it is made (from_dict, over, a library
        caller): GridError (a ValueError and an InputError) saying what is wrong."""
        problem = _grid_problem(self)
        if problem:
            raise GridError(problem)

    @property
    def shape(self):
        return (self.ny, self.nx)

    @property
    def x1(self):
        """The far corner's x: the last node's (the grid spans x0 .. x1)."""
        return self.x0 + (self.nx - 1) * self.cell

    @property
    def y1(self):
        return self.y0 + (self.ny - 1) * self.cell

    @property
    def impulse_scale(self):
        """What a grid value read back at a point is multiplied by to give an impulse (N·s): 1
        for a renormalised splat (the kernel sums to 1 over the nodes), else the cell's area (the
        value is an impulse density)."""
        return 1.0 if self.renormalize else self.cell ** 2

    def outside(self, points):
        """Which points (n, 2) lie outside the grid's span (bilinear reads them at the edge)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return (p[:, 0] < self.x0) | (p[:, 1] < self.y0) | (p[:, 0] > self.x1) | (p[:, 1] > self.y1)

    def as_dict(self):
        return asdict(self)

    @classmethod
    def from_dict(cls, d):
        """The grid a file describes (dataset metadata, a checkpoint), every field checked for its
        type and range before use; raises ValueError saying what is wrong."""
        if not isinstance(d, dict):
            raise ValueError("the grid must be a JSON object")
        names = [f.name for f in fields(cls)]
        unknown = [k for k in d if k not in names]
        missing = [k for k in names[:6] if k not in d]
        if unknown or missing:
            raise ValueError(f"bad grid description: {'unknown ' + ', '.join(map(str, unknown)) if unknown else ''}"
                             f"{'; ' if unknown and missing else ''}{'no ' + ', '.join(missing) if missing else ''}")

        def number(k):
            v = d[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"grid {k!r} must be a finite number, not {v!r}")
            return float(v)
        x0, y0, cell, h = number("x0"), number("y0"), number("cell"), number("h")
        return cls(x0=x0, y0=y0, cell=cell, nx=d["nx"], ny=d["ny"], h=h, kernel=d.get("kernel", "poly6"),
                   renormalize=d.get("renormalize", True))

    @classmethod
    def over(cls, window, cell, h, kernel="poly6", renormalize=True):
        """The grid whose nodes span window = (x0, y0, x1, y1) with spacing cell."""
        x0, y0, x1, y1 = (float(v) for v in window)
        if not all(math.isfinite(v) for v in (x0, y0, x1, y1)) or x1 <= x0 or y1 <= y0:
            raise InputError(f"the grid window {window} is empty or not finite")
        if not (math.isfinite(cell) and cell > 0):
            raise InputError(f"cell size d must be positive and finite, got {cell}")
        if not (math.isfinite(h) and h > 0):
            raise InputError(f"smoothing length h must be positive and finite, got {h}")
        if kernel not in KERNELS:
            raise InputError(f"unknown kernel {kernel!r}; choose from {', '.join(KERNELS)}")
        problem = node_weight_problem(kernel, cell, h)
        if problem:
            raise InputError(problem)
        nx = int(math.floor((x1 - x0) / cell + 1e-9)) + 1
        ny = int(math.floor((y1 - y0) / cell + 1e-9)) + 1
        if nx * ny > MAX_NODES:
            raise InputError(f"a grid of {nx} x {ny} nodes at d = {cell} exceeds the limit of "
                             f"{MAX_NODES:,} nodes (64 MiB per channel); use a larger cell or a smaller window")
        return cls(x0=x0, y0=y0, cell=float(cell), nx=nx, ny=ny, h=float(h), kernel=kernel,
                   renormalize=bool(renormalize))

    def rule_warnings(self, radius=None):
        """The thesis's rules (d <= body radius, 0.71 d <= h <= d), as warnings: they are advice."""
        out = []
        if radius is not None and self.cell > radius:
            out.append(f"d = {self.cell:g} is larger than the smallest body radius {radius:g}: two contacts "
                       f"may share a cell (thesis rule d <= r)")
        if self.h < math.sqrt(2) / 2 * self.cell:
            out.append(f"h = {self.h:g} < 0.71 d = {math.sqrt(2) / 2 * self.cell:.3g}: a point between nodes may "
                       f"reach none of them (thesis rule h >= 0.71 d)")
        if self.h > self.cell:
            out.append(f"h = {self.h:g} > d = {self.cell:g}: one contact spreads over several cells "
                       f"(thesis rule h <= d)")
        return out


def scene_box(scene):
    """(x0, y0, x1, y1) of the static bodies' shapes, or None (Scene.static_box)."""
    return scene.static_box()


def node_weight_problem(kernel, cell, h):
    """Why float32 grid images cannot carry a value at cell size d and smoothing length h, or None."""
    # A node holds about W(0) d^2 of a particle's value: it must be a float32 the grid can carry.
    try:
        node_weight = float(weight(kernel, 0.0, h)) * cell * cell
    except (ZeroDivisionError, OverflowError):   # h so small or large that the kernel's scale is not a float
        node_weight = float("inf")
    if not (math.isfinite(node_weight) and 1e-30 < node_weight < 1e30):
        return (f"h = {h:g} at d = {cell:g} puts a weight of {node_weight:.3g} on a node: float32 grid "
                f"images cannot carry that (choose h near d)")
    return None
