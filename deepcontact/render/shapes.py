"""The shapes of a simulation's bodies, in each body's own frame, read once from a step file
(they do not change over a run; the native reader moves only the per-step state)."""
from dataclasses import dataclass, field

import numpy as np

from .. import schema
from ..errors import InputError


@dataclass
class Placed:
    """A step's shapes in the world: each with the row of its body in the step's arrays."""
    circle_rows: np.ndarray      # (k,)
    centres: np.ndarray          # (k, 2)
    radii: np.ndarray            # (k,)
    polygon_rows: np.ndarray     # (p,)
    polygons: list               # p arrays of (m, 2) vertices
    edges: np.ndarray            # (e, 2, 2): both ends


@dataclass
class Shapes:
    circles: np.ndarray          # (k, 4): body index, radius, x, y
    polygons: list = field(default_factory=list)   # (body index, (m, 2) vertices)
    edges: np.ndarray = None     # (k, 5): body index, x1, y1, x2, y2

    def placed(self, bodies) -> Placed:
        """The shapes of the bodies a step holds, where the step puts them."""
        row = _rows(bodies["index"])
        pos = bodies["position"].astype(np.float64)
        angle = bodies["angle"].astype(np.float64)
        c = self.circles[_present(row, self.circles[:, 0])]
        cr = row[c[:, 0].astype(int)]
        e = self.edges[_present(row, self.edges[:, 0])]
        er = row[e[:, 0].astype(int)]
        polys = [(row[b], v) for b, v in self.polygons if 0 <= b < len(row) and row[b] >= 0]
        return Placed(circle_rows=cr, centres=place(pos[cr], angle[cr], c[:, 2:4]), radii=c[:, 1],
                      polygon_rows=np.array([k for k, _ in polys], np.int64),
                      polygons=[place(np.repeat(pos[k:k + 1], len(v), 0), np.repeat(angle[k], len(v)), v)
                                for k, v in polys],
                      edges=np.stack([place(pos[er], angle[er], e[:, 1:3]), place(pos[er], angle[er], e[:, 3:5])], 1))

    def bounds(self, bodies):
        """(x0, y0, x1, y1) around every shape of the step's bodies, or None."""
        p = self.placed(bodies)
        r = p.radii[:, None]
        parts = [q for q in (p.centres - r, p.centres + r, p.edges.reshape(-1, 2), *p.polygons) if len(q)]
        if not parts:
            return None
        points = np.concatenate(parts)
        return float(points[:, 0].min()), float(points[:, 1].min()), float(points[:, 0].max()), float(points[:, 1].max())


def _rows(indices):
    """body index -> row of the step's arrays (-1: not in this step)."""
    indices = np.asarray(indices, dtype=np.int64)
    row = np.full(int(indices.max()) + 1 if len(indices) else 1, -1, np.int64)
    row[indices] = np.arange(len(indices))
    return row


def _present(row, bodies):
    b = bodies.astype(np.int64)
    ok = (b >= 0) & (b < len(row))
    ok[ok] = row[b[ok]] >= 0
    return ok


def place(positions, angles, local):
    """Points given in body frames, moved to the world: p + R(angle) local."""
    c, s = np.cos(angles), np.sin(angles)
    x, y = local[:, 0], local[:, 1]
    return np.stack([positions[:, 0] + c * x - s * y, positions[:, 1] + s * x + c * y], axis=1)


def read_shapes(path) -> Shapes:
    """Every body's shapes as a step file records them."""
    from lxml import etree
    try:
        root = schema.parse(path).getroot()
    except etree.XMLSyntaxError as e:
        raise InputError(f"not a well-formed step file: {e.msg}", path, e.lineno) from None
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror or e}", path) from None
    circles, polygons, edges = [], [], []
    try:
        for body in root.iterfind("bodies/body"):
            index = int(body.get("index"))
            for s in body.iterfind("shape/*"):
                if s.tag == "circle":
                    circles.append((index, float(s.get("radius")), float(s.get("x", 0)), float(s.get("y", 0))))
                elif s.tag == "polygon":
                    polygons.append((index, np.array([(float(v.get("x")), float(v.get("y")))
                                                      for v in s.iterfind("vertex")], np.float64)))
                elif s.tag == "edge":
                    edges.append((index, *(float(s.get(k)) for k in ("x1", "y1", "x2", "y2"))))
    except (TypeError, ValueError):
        raise InputError("a body's shape has a missing or unreadable value", path) from None
    return Shapes(circles=np.array(circles, np.float64).reshape(-1, 4), polygons=polygons,
                  edges=np.array(edges, np.float64).reshape(-1, 5))
