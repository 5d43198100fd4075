"""Checks a scene before Box2D sees it: Box2D 2.4.1 asserts (aborting the process) or quietly
substitutes shapes on bad geometry, so everything it would trip on is caught here first."""
import math

import numpy as np

from .._box2d import linear_slop, max_polygon_vertices, polygon_radius
from ..errors import InputError
from .model import BODY_TYPES


def _finite(*values):
    return all(math.isfinite(v) for v in values)


def polygon_problem(vertices):
    """Why Box2D would not take these vertices as they are, or None."""
    n = len(vertices)
    if not 3 <= n <= max_polygon_vertices:
        return f"a polygon needs 3 to {max_polygon_vertices} vertices, got {n}"
    p = np.asarray(vertices, dtype=np.float64)
    if not np.all(np.isfinite(p)):
        return "polygon vertex is not a finite number"
    # Box2D welds vertices closer than half the linear slop.
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    if np.any(d[np.triu_indices(n, 1)] < 0.5 * linear_slop):
        return "polygon has vertices closer than half the linear slop"
    # Strictly convex in the given order (either winding), non-degenerate.
    e = np.roll(p, -1, axis=0) - p
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    if not (np.all(cross > 0) or np.all(cross < 0)):
        return "polygon is not strictly convex (or its vertices are not in order around it)"
    area = 0.5 * abs(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
    if area < 1e-6:
        return "polygon has (almost) no area"
    return None


def check_scene(scene, path=None):
    """Raises InputError naming the file, line and problem."""
    def fail(msg, line=None):
        raise InputError(msg, path, line)

    if not (_finite(scene.dt) and scene.dt > 0):
        fail(f"dt must be positive, got {scene.dt}")
    if scene.steps < 1:
        fail(f"steps must be at least 1, got {scene.steps}")
    if scene.solver.velocity_iterations < 0 or scene.solver.position_iterations < 0:
        fail("iteration counts must be >= 0")
    e = scene.effects
    if e.gravity is not None and not _finite(*e.gravity):
        fail("gravity is not finite")
    for name in ("friction", "restitution"):
        v = getattr(e, name)
        if v is not None and not (_finite(v) and v >= 0):
            fail(f"{name} coefficient must be a finite number >= 0")
    if e.damping is not None and not (_finite(*e.damping) and min(e.damping) >= 0):
        fail("damping must be finite and >= 0")

    for i, b in enumerate(scene.bodies):
        where = f"body {i}"
        if b.type not in BODY_TYPES:
            fail(f"{where}: unknown type {b.type!r}", b.line)
        if not _finite(b.x, b.y, b.angle, b.vx, b.vy, b.omega):
            fail(f"{where}: position, angle or velocity is not a finite number", b.line)
        if b.bullet and not e.continuous:
            fail(f"{where} is a bullet, which needs the continuous effect declared", b.line)
        mass = 0.0
        for s in b.shapes:
            line = s.line or b.line
            if s.friction is not None and e.friction is None:
                fail(f"{where}: a {s.kind} gives friction but the scene does not declare the "
                     f"friction effect", line)
            if s.restitution is not None and e.restitution is None:
                fail(f"{where}: a {s.kind} gives restitution but the scene does not declare the "
                     f"restitution effect", line)
            for name in ("friction", "restitution", "density"):
                v = getattr(s, name)
                if v is not None and not (_finite(v) and v >= 0):
                    fail(f"{where}: {s.kind} {name} must be a finite number >= 0", line)
            if s.kind == "circle":
                if not (_finite(s.radius, s.x, s.y) and s.radius > 0):
                    fail(f"{where}: circle radius must be positive and finite", line)
                mass += s.density * s.radius ** 2
            elif s.kind == "polygon":
                problem = polygon_problem(s.vertices)
                if problem:
                    fail(f"{where}: {problem}", line)
                mass += s.density
            else:
                if not _finite(s.x1, s.y1, s.x2, s.y2):
                    fail(f"{where}: edge end is not a finite number", line)
                if math.hypot(s.x2 - s.x1, s.y2 - s.y1) < linear_slop:
                    fail(f"{where}: edge shorter than the linear slop ({linear_slop:g} m)", line)
        if b.type == "dynamic" and mass <= 0:
            fail(f"{where} is dynamic but has no mass: give a circle or polygon a density > 0", b.line)

    for ev in scene.events:
        if ev.body >= len(scene.bodies):
            fail(f"event removes body {ev.body}, but the scene has {len(scene.bodies)} bodies", ev.line)
        if ev.step >= scene.steps:
            fail(f"event at step {ev.step} is after the last step ({scene.steps - 1})", ev.line)
    removed = [ev.body for ev in scene.events]
    if len(set(removed)) != len(removed):
        fail("a body is removed twice")


def overlap_tolerance(kind_a, kind_b):
    """How far two shapes may overlap at rest in Box2D: their skins plus the linear slop."""
    skin = {"circle": 0.0, "polygon": polygon_radius, "edge": polygon_radius}
    return skin[kind_a] + skin[kind_b] + linear_slop
