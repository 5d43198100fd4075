"""What a scene declares: the world, its bodies and shapes, and which effects are on.

Numbers are stored as float32 values (Python floats holding a float32 exactly), because that is
what Box2D simulates: a scene written to XML and read back is the same scene, bit for bit.
Only declared effects are simulated: no gravity unless given, friction and restitution 0 unless
their effect is declared, no damping unless declared, no continuous collision unless declared.
"""
import math
import struct
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

BODY_TYPES = ("static", "kinematic", "dynamic")


_FLOAT32 = struct.Struct("f")


def f32(value) -> float:
    """The float32 nearest to value, as a Python float (inf beyond float32's range: the scene
    check refuses it with the line it came from)."""
    try:   # C's double -> float cast, as numpy's, without numpy's per-call overhead
        return _FLOAT32.unpack(_FLOAT32.pack(value))[0]
    except (OverflowError, struct.error, TypeError):   # beyond float32 (inf), or not a float
        with np.errstate(over="ignore"):
            return float(np.float32(value))


@dataclass
class Circle:
    """A circle of `radius` (m) centred at (x, y) in its body's frame (m), `density` in kg/m²."""
    radius: float
    x: float = 0.0
    y: float = 0.0
    density: float = 0.0
    friction: Optional[float] = None      # None: the friction effect's coefficient (or 0)
    restitution: Optional[float] = None   # None: the restitution effect's coefficient (or 0)
    line: Optional[int] = None            # where it was read from, for error messages

    kind = "circle"


@dataclass
class Polygon:
    """A convex polygon: its vertices (m) in its body's frame, in order; `density` in kg/m²."""
    vertices: tuple   # ((x, y), ...) in the body frame, convex, 3 to 8 of them
    density: float = 0.0
    friction: Optional[float] = None
    restitution: Optional[float] = None
    line: Optional[int] = None

    kind = "polygon"


@dataclass
class Edge:
    """A line segment from (x1, y1) to (x2, y2), m, in its body's frame; it has no mass."""
    x1: float
    y1: float
    x2: float
    y2: float
    friction: Optional[float] = None
    restitution: Optional[float] = None
    line: Optional[int] = None

    kind = "edge"
    density = 0.0


@dataclass
class Body:
    """A body: its `type` (static, kinematic, dynamic), its origin (x, y) (m) and `angle` (rad) in
    the world, its velocity (vx, vy) (m/s) and spin `omega` (rad/s) at the start, and its `shapes`."""
    type: str = "dynamic"
    x: float = 0.0
    y: float = 0.0
    angle: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    omega: float = 0.0
    fixed_rotation: bool = False
    bullet: bool = False
    shapes: list = field(default_factory=list)
    line: Optional[int] = None

    def reach(self):
        """The largest distance of any point of the body's shapes from its origin."""
        reach = 0.0
        for sh in self.shapes:
            if sh.kind == "circle":
                reach = max(reach, math.hypot(sh.x, sh.y) + sh.radius)
            elif sh.kind == "polygon":
                reach = max(reach, max(math.hypot(x, y) for x, y in sh.vertices))
            else:
                reach = max(reach, math.hypot(sh.x1, sh.y1), math.hypot(sh.x2, sh.y2))
        return reach


@dataclass
class Effects:
    """What the scene simulates besides contact (each None or False: off)."""
    gravity: Optional[tuple] = None            # (gx, gy) or None: no gravity
    friction: Optional[float] = None           # default coefficient, or None: frictionless
    restitution: Optional[float] = None        # default coefficient, or None: perfectly inelastic
    restitution_threshold: float = 1.0         # m/s; slower approaches do not bounce (Box2D's default)
    damping: Optional[tuple] = None            # (linear, angular) for every dynamic body, or None
    continuous: bool = False                   # Box2D's continuous collision (time of impact)

    def names(self):
        """The effects that are on, in a fixed order."""
        on = [("gravity", self.gravity is not None), ("friction", self.friction is not None),
              ("restitution", self.restitution is not None), ("damping", self.damping is not None),
              ("continuous", self.continuous)]
        return [name for name, is_on in on if is_on]


@dataclass
class RemoveEvent:
    """Remove a body before the given step (the warm-start energy case: a heavy top removed
    mid-run must not launch the bodies below it with its stale impulses)."""
    step: int
    body: int
    line: Optional[int] = None


@dataclass
class Solver:
    """What the scene asks of the solver: Box2D 2.4.1's iterations and switches (`warm_starting`:
    each contact starts from its impulses of the step before)."""
    velocity_iterations: int = 8
    position_iterations: int = 3
    warm_starting: bool = True
    block_solve: bool = True
    sleeping: bool = False     # off: sleeping islands are skipped by the solver, hiding its work


@dataclass
class Scene:
    """A scene: its world (`dt` s, `steps`), `solver`, `effects`, `bodies` (a body's index is its
    place here) and removal `events`; what `read_scene` and `generate` return."""
    name: str
    dt: float = f32(0.01)
    steps: int = 600
    solver: Solver = field(default_factory=Solver)
    effects: Effects = field(default_factory=Effects)
    bodies: list = field(default_factory=list)
    events: list = field(default_factory=list)
    generator: Optional[str] = None            # provenance: which generator made it
    seed: Optional[int] = None
    params: dict = field(default_factory=dict)
    lines: dict = field(default_factory=dict, compare=False)   # element -> line, for a file's errors

    def static_box(self):
        """(x0, y0, x1, y1) of the static bodies' shapes, or None if there are none or they enclose
        no area (a ground line: the pyramid, the stack): the box a grid is drawn over."""
        box = self.static_extent()
        return box if box is not None and box[2] > box[0] and box[3] > box[1] else None

    def static_extent(self):
        """(x0, y0, x1, y1) of the static bodies' shapes in the world, or None if there are none."""
        pts = []
        for b in self.bodies:
            if b.type != "static":
                continue
            c, s = math.cos(b.angle), math.sin(b.angle)

            def world(x, y):
                return (b.x + c * x - s * y, b.y + s * x + c * y)
            for sh in b.shapes:
                if sh.kind == "edge":
                    pts += [world(sh.x1, sh.y1), world(sh.x2, sh.y2)]
                elif sh.kind == "polygon":
                    pts += [world(x, y) for x, y in sh.vertices]
                else:
                    cx, cy = world(sh.x, sh.y)
                    pts += [(cx - sh.radius, cy - sh.radius), (cx + sh.radius, cy + sh.radius)]
        if not pts:
            return None
        xs, ys = zip(*pts)
        return (float(min(xs)), float(min(ys)), float(max(xs)), float(max(ys)))

    def removals(self):
        """{step: [body, ...]}: every removal event, several in one step included."""
        out = {}
        for ev in self.events:
            out.setdefault(ev.step, []).append(ev.body)
        return out

    def fixtures(self):
        """(body index, shape) for every shape, in fixture index order."""
        return [(i, s) for i, b in enumerate(self.bodies) for s in b.shapes]

    def friction_of(self, shape) -> float:
        """The shape's friction coefficient: its own, else the friction effect's, 0 with no friction effect."""
        if self.effects.friction is None:
            return 0.0
        return self.effects.friction if shape.friction is None else shape.friction

    def restitution_of(self, shape) -> float:
        """The shape's restitution: its own, else the restitution effect's, 0 with no restitution effect."""
        if self.effects.restitution is None:
            return 0.0
        return self.effects.restitution if shape.restitution is None else shape.restitution
