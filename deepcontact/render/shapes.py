"""The shapes of a simulation's bodies, in each body's own frame, read once from a step file
(they do not change over a run; the native reader moves only the per-step state)."""
from dataclasses import dataclass, field

import numpy as np

from .. import schema
from ..errors import InputError


@dataclass
class Shapes:
    circles: np.ndarray          # (k, 4): body index, radius, x, y
    polygons: list = field(default_factory=list)   # (body index, (m, 2) vertices)
    edges: np.ndarray = None     # (k, 5): body index, x1, y1, x2, y2
    types: dict = field(default_factory=dict)      # body index -> "static", "kinematic", "dynamic"

    def bounds(self, positions, angles, indices):
        """(x0, y0, x1, y1) around every shape of the given bodies, placed as given."""
        pts = [p for p in self.world_points(positions, angles, indices) if len(p)]
        if not pts:
            return None
        allp = np.concatenate(pts)
        return float(allp[:, 0].min()), float(allp[:, 1].min()), float(allp[:, 0].max()), float(allp[:, 1].max())

    def world_points(self, positions, angles, indices):
        """Points that outline each shape in the world: circle extremes, vertices, edge ends."""
        row = _rows(indices)
        out = []
        if len(self.circles):
            keep = _present(row, self.circles[:, 0])
            c = self.circles[keep]
            r = row[c[:, 0].astype(int)]
            centre = place(positions[r], angles[r], c[:, 2:4])
            rad = c[:, 1:2]
            out += [centre - rad, centre + rad]
        for body, verts in self.polygons:
            if 0 <= body < len(row) and row[body] >= 0:
                k = row[body]
                out.append(place(np.repeat(positions[k:k + 1], len(verts), 0), np.repeat(angles[k], len(verts)), verts))
        if self.edges is not None and len(self.edges):
            keep = _present(row, self.edges[:, 0])
            e = self.edges[keep]
            r = row[e[:, 0].astype(int)]
            out += [place(positions[r], angles[r], e[:, 1:3]), place(positions[r], angles[r], e[:, 3:5])]
        return out


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
    circles, polygons, edges, types = [], [], [], {}
    try:
        for body in root.iterfind("bodies/body"):
            index = int(body.get("index"))
            types[index] = body.get("type")
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
                  edges=np.array(edges, np.float64).reshape(-1, 5), types=types)
