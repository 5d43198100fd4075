"""Checks a scene before Box2D sees it: Box2D 2.4.1 asserts (aborting the process) or quietly
substitutes shapes on bad geometry, so everything it would trip on is caught here first."""
import math

import numpy as np

from .._box2d import linear_slop, max_polygon_vertices, polygon_radius
from ..errors import InputError
from .model import BODY_TYPES


def _finite(*values):
    return all(math.isfinite(v) for v in values)


# Box2D computes in float32 and asserts (aborting the process) on what overflows there, such as
# a circle of radius 1e20 whose mass is infinite. These bounds keep every quantity it forms from
# the scene (areas, masses, inertias, their inverses, impulses) well inside float32's range.
MAX_LENGTH = 1e6      # m: positions, radii, vertices (float32 still resolves 6 cm there)
MAX_SPEED = 1e6       # m/s, and rad/s for spin
MAX_GRAVITY = 1e6     # m/s^2
MAX_DAMPING = 1e6     # 1/s
MASS_RANGE = (1e-20, 1e20)   # kg (and kg m^2 for the rotational inertia of a body)
MAX_COEFFICIENT = 1e9   # friction and restitution: the generators' limit (1e20 overflows float32 impulses)
MAX_COUNT = 2 ** 31 - 1   # steps and iterations: Box2D's int32


def _f32(bound):
    """A bound as a scene holds a value (float32): a value written as the bound itself is within it."""
    return float(np.float32(bound))


def _within(limit, *values):
    return all(math.isfinite(v) and abs(v) <= limit for v in values)


def shape_mass(s):
    """(mass, first moment (2,), polar moment about the body origin) of one shape, in float64."""
    if s.kind == "circle":
        m = s.density * math.pi * s.radius ** 2
        return m, m * np.array([s.x, s.y]), m * (0.5 * s.radius ** 2 + s.x ** 2 + s.y ** 2)
    if s.kind == "polygon":
        p = np.asarray(s.vertices, dtype=np.float64)
        q = np.roll(p, -1, axis=0)
        cross = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
        sign = 1.0 if cross.sum() >= 0 else -1.0
        area = 0.5 * sign * cross.sum()
        first = sign * s.density * np.array([np.sum(cross * (p[:, 0] + q[:, 0])),
                                             np.sum(cross * (p[:, 1] + q[:, 1]))]) / 6.0
        polar = sign * s.density * np.sum(cross * (p[:, 0] ** 2 + p[:, 0] * q[:, 0] + q[:, 0] ** 2
                                                   + p[:, 1] ** 2 + p[:, 1] * q[:, 1] + q[:, 1] ** 2)) / 12.0
        return s.density * area, first, polar
    return 0.0, np.zeros(2), 0.0


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
    """Raises InputError naming the file, line and problem: the first the scene has of the rules
    in SCENE_RULES, in their order (the world, its effects, each body and its shapes, the events)."""
    for rule in SCENE_RULES:
        for message, line in rule(scene):
            raise InputError(message, path, line)


def _world(scene):
    at = scene.lines.get
    if not (_finite(scene.dt) and _f32(1e-6) <= scene.dt <= 10):
        yield f"dt must be between 1e-6 and 10 s, got {scene.dt}", at("world")
    if not 1 <= scene.steps <= MAX_COUNT:
        yield f"steps must be between 1 and {MAX_COUNT}, got {scene.steps}", at("world")
    if not all(0 <= n <= MAX_COUNT for n in (scene.solver.velocity_iterations, scene.solver.position_iterations)):
        yield f"iteration counts must be between 0 and {MAX_COUNT}", at("solver")


def _effects(scene):
    at, e = scene.lines.get, scene.effects
    if e.gravity is not None and not _within(MAX_GRAVITY, *e.gravity):
        yield (f"gravity must be finite and at most {MAX_GRAVITY:g} m/s^2 in each component, got {e.gravity}",
               at("gravity"))
    for name in ("friction", "restitution"):
        v = getattr(e, name)
        if v is not None and not (_finite(v) and 0 <= v <= MAX_COEFFICIENT):
            yield f"{name} coefficient must be a finite number from 0 to {MAX_COEFFICIENT:g}", at(name)
    if e.restitution is not None and not (_finite(e.restitution_threshold) and
                                          0 <= e.restitution_threshold <= MAX_SPEED):
        yield (f"the restitution threshold must be a speed from 0 to {MAX_SPEED:g} m/s, got "
               f"{e.restitution_threshold}", at("restitution"))
    if e.damping is not None and not (_within(MAX_DAMPING, *e.damping) and min(e.damping) >= 0):
        yield f"damping must be between 0 and {MAX_DAMPING:g}", at("damping")


def _bodies(scene):
    for i, b in enumerate(scene.bodies):
        where = f"body {i}"
        yield from _body(where, b, scene.effects)
        for s in b.shapes:
            yield from ((f"{where}: {message}", s.line or b.line) for message in _shape(s, scene.effects))
        yield from _mass(where, b)


def _body(where, b, effects):
    """What is wrong with a body itself (its type, pose, velocity, bullet flag)."""
    if b.type not in BODY_TYPES:
        yield f"{where}: unknown type {b.type!r}", b.line
    if not _within(MAX_LENGTH, b.x, b.y, b.angle):
        yield f"{where}: position and angle must be finite and at most {MAX_LENGTH:g} in size", b.line
    if not _within(MAX_SPEED, b.vx, b.vy, b.omega):
        yield f"{where}: velocity and spin must be finite and at most {MAX_SPEED:g} in size", b.line
    if b.bullet and not effects.continuous:
        yield f"{where} is a bullet, which needs the continuous effect declared", b.line


def _shape(s, effects):
    """What is wrong with one shape: its materials against the scene's effects, then its geometry."""
    for name in ("friction", "restitution"):
        if getattr(s, name) is not None and getattr(effects, name) is None:
            yield f"a {s.kind} gives {name} but the scene does not declare the {name} effect"
    for name in ("friction", "restitution", "density"):
        v = getattr(s, name)
        if v is not None and not (_finite(v) and v >= 0):
            yield f"{s.kind} {name} must be a finite number >= 0"
        if name != "density" and v is not None and v > MAX_COEFFICIENT:
            yield f"{s.kind} {name} must be at most {MAX_COEFFICIENT:g}"
    if s.density is not None and s.density > _f32(1e20):
        yield f"{s.kind} density must be at most 1e20 kg/m^2"
    yield from _GEOMETRY[s.kind](s)


def _circle(s):
    if not (_within(MAX_LENGTH, s.radius, s.x, s.y) and s.radius > 0):
        yield (f"circle radius must be positive and at most {MAX_LENGTH:g} m, and its centre finite and within "
               f"{MAX_LENGTH:g} m")


def _polygon(s):
    if not _within(MAX_LENGTH, *np.ravel(np.asarray(s.vertices, dtype=np.float64))):
        yield f"polygon vertices must be finite and within {MAX_LENGTH:g} m"
    problem = polygon_problem(s.vertices)
    if problem:
        yield problem


def _edge(s):
    if not _within(MAX_LENGTH, s.x1, s.y1, s.x2, s.y2):
        yield f"edge ends must be finite and within {MAX_LENGTH:g} m"
    if math.hypot(s.x2 - s.x1, s.y2 - s.y1) < linear_slop:
        yield f"edge shorter than the linear slop ({linear_slop:g} m)"


_GEOMETRY = {"circle": _circle, "polygon": _polygon, "edge": _edge}


def _mass(where, b):
    """A dynamic body's mass and rotational inertia, within what float32 holds safely."""
    if b.type != "dynamic":
        return
    mass, first, polar = 0.0, np.zeros(2), 0.0
    for s in b.shapes:
        m, f, j = shape_mass(s)
        mass, first, polar = mass + m, first + f, polar + j
    lo, hi = MASS_RANGE
    if mass <= 0:
        yield f"{where} is dynamic but has no mass: give a circle or polygon a density > 0", b.line
    if not lo <= mass <= hi:
        # (its digits to the one that tells it from the bound: never "1e+20 is outside [..., 1e+20]")
        bound = lo if mass < lo else hi
        shown = next(f"{mass:.{p}g}" for p in range(3, 18) if float(f"{mass:.{p}g}") != bound)
        yield (f"{where}: its mass {shown} kg is outside [{lo:g}, {hi:g}] (float32 could not hold it, "
               f"or its inverse, safely)", b.line)
    if not b.fixed_rotation:
        # Box2D shifts the inertia to the centre of mass in float32 and asserts it stays > 0:
        # shapes tiny beside their distance from the body origin cancel it out.
        inertia = polar - float(first @ first) / mass
        if not (inertia <= hi and inertia > 1e-5 * polar and inertia >= lo):
            yield (f"{where}: its rotational inertia about the centre of mass ({inertia:.3g} kg m^2) is "
                   f"outside [{lo:g}, {hi:g}] or lost to rounding (shapes small beside their distance "
                   f"from the body's origin)", b.line)


def _events(scene):
    for ev in scene.events:
        if ev.body >= len(scene.bodies):
            yield f"event removes body {ev.body}, but the scene has {len(scene.bodies)} bodies", ev.line
        if ev.step >= scene.steps:
            yield f"event at step {ev.step} is after the last step ({scene.steps - 1})", ev.line
    removed = [ev.body for ev in scene.events]
    if len(set(removed)) != len(removed):
        yield "a body is removed twice", None


# The scene's rules, in the order they are checked: the first problem found is the one reported.
SCENE_RULES = (_world, _effects, _bodies, _events)


def overlap_tolerance(kind_a, kind_b):
    """How far two shapes may overlap at rest in Box2D: their skins plus the linear slop."""
    skin = {"circle": 0.0, "polygon": polygon_radius, "edge": polygon_radius}
    return skin[kind_a] + skin[kind_b] + linear_slop
