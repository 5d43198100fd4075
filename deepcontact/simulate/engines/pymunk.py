"""pymunk (Chipmunk2D), what Python users pick for 2D: `--engine pymunk`.

The scene's bodies with Box2D 2.4.1's own mass properties (its world is built once to read them),
so both engines move the same bodies; polygons and edges keep Box2D's skin radius. Materials:
Chipmunk multiplies two shapes' friction, so each shape gets the square root of its friction (the
product is Box2D's mix, sqrt(a b), exactly); restitution likewise (Box2D takes the larger of two:
equal only where they are equal). Chipmunk has no restitution threshold, no continuous collision
and a single damping for both motions (a body's own velocity function where the scene's two
differ). Its collision slop, a length, is Box2D's linear slop (pymunk's default is for pixels).

A step file of pymunk holds, per contact point, an equal share of its arbiter's total impulse:
pymunk reports an arbiter's total only (the header's <engine impulses="per_arbiter">)."""
import math

import numpy as np

from ...resources import check_step_work
from ..pgs_loop import LoopStep
from . import Engine, Setting, empty_contacts

_SLEEP_TIME = 0.5        # s at rest before a body sleeps: Box2D's b2_timeToSleep
_SLEEP_SPEED = 0.01      # m/s: Box2D's b2_linearSleepTolerance


class Pymunk(Engine):
    """pymunk stepping the scene with `iterations` solver iterations (pymunk's default 10)."""
    name, label = "pymunk", "pymunk"
    sleeps = rests_in_skin = True   # (its collision slop is Box2D's linear slop: it rests as 2.4.1 does)
    DEFAULT_COUNT = 10
    SETTINGS = {"iterations": Setting(int, 1, None, "solver iterations per step (pymunk's default 10)",
                                      sweep=(1, 2, 4, 8, 10, 16, 32, 64, 128, 256), fast=(1, 10))}

    def __init__(self, iterations=10):
        super().__init__(iterations=iterations)

    @classmethod
    def version(cls) -> str:
        import pymunk
        return pymunk.version

    def settings(self) -> dict:
        return {**self._settings, "impulses": "per_arbiter"}

    def check(self, scene, source=None):
        _library()
        check_step_work(len(scene.bodies), self._settings["iterations"],
                        f"{self._settings['iterations']:,} iterations a step")

    def build(self, scene, source=None):
        return PymunkWorld(scene, self._settings["iterations"])

    def stepper(self, world, scene, record=True):
        world.record(record)

        def step():
            if not record:
                world.space.step(world.dt)
                return LoopStep(None, None, None, 0.0, dt_ratio=1.0)
            bodies = world.bodies()
            world.arbiters.clear()
            world.space.step(world.dt)
            contacts = world.contacts()
            deepest = max(0.0, float(-contacts["separation"].min())) if len(contacts["separation"]) else 0.0
            return LoopStep(bodies, contacts, None, deepest, dt_ratio=1.0)
        return step


def _library():
    from ...errors import InputError
    try:
        import pymunk
    except ImportError:
        raise InputError("pymunk is not installed: make setup installs it (pymunk==7.3.1)") from None
    return pymunk


class PymunkWorld:
    """A scene's pymunk space, and what its records need: the bodies in scene order, each
    shape's fixture index and a Box2D world's body records (mass properties, the layout)."""

    def __init__(self, scene, iterations):
        pymunk = _library()
        from ..build import build_world
        from ..._box2d import linear_slop, polygon_radius
        e = scene.effects
        self.dt = float(scene.dt)
        self.records = build_world(scene).bodies()   # Box2D's mass properties and record layout
        space = self.space = pymunk.Space()
        space.iterations = iterations
        space.collision_slop = float(linear_slop)
        if e.gravity is not None:
            space.gravity = tuple(map(float, e.gravity))
        if scene.solver.sleeping:
            space.sleep_time_threshold = _SLEEP_TIME
            space.idle_speed_threshold = _SLEEP_SPEED
        linear, angular = e.damping if e.damping is not None else (0.0, 0.0)
        if linear == angular:   # Box2D's v / (1 + dt c) each step, as Chipmunk's v * damping^dt
            space.damping = (1.0 + self.dt * linear) ** (-1.0 / self.dt)
        kinds = {"static": pymunk.Body.STATIC, "kinematic": pymunk.Body.KINEMATIC, "dynamic": pymunk.Body.DYNAMIC}
        r = self.records
        self.bodies_of, self.fixture_of = [], {}
        fixture = 0
        for i, b in enumerate(scene.bodies):
            if b.type == "dynamic":
                moment = math.inf if b.fixed_rotation or r["inertia"][i] == 0 else float(r["inertia"][i])
                body = pymunk.Body(float(r["mass"][i]), moment)
                body.center_of_gravity = tuple(map(float, r["local_center"][i]))
                if linear != angular:
                    body.velocity_func = _damped(linear, angular)
            else:
                body = pymunk.Body(body_type=kinds[b.type])
            body.position, body.angle = (b.x, b.y), b.angle
            if b.type != "static":   # (the scene's velocities are the centre of mass's, as Box2D's)
                body.velocity, body.angular_velocity = (b.vx, b.vy), b.omega
            shapes = []
            for s in b.shapes:
                if s.kind == "circle":
                    shape = pymunk.Circle(body, s.radius, (s.x, s.y))
                elif s.kind == "polygon":
                    shape = pymunk.Poly(body, [tuple(v) for v in s.vertices], radius=float(polygon_radius))
                else:
                    shape = pymunk.Segment(body, (s.x1, s.y1), (s.x2, s.y2), float(polygon_radius))
                shape.friction = math.sqrt(scene.friction_of(s))
                shape.elasticity = math.sqrt(scene.restitution_of(s))
                self.fixture_of[shape] = (fixture, i, scene.friction_of(s), scene.restitution_of(s))
                shapes.append(shape)
                fixture += 1
            space.add(body, *shapes)
            self.bodies_of.append((i, body, shapes))
        self.threshold = float(e.restitution_threshold)
        self.arbiters = []

    def record(self, on):
        """Collect each solved arbiter after the step (a Python call per arbiter: only when recording)."""
        self.space.on_collision(post_solve=self._solved if on else None)

    def _solved(self, arbiter, space, data):
        self.arbiters.append((arbiter.shapes, arbiter.contact_point_set, arbiter.total_impulse))

    def remove_body(self, index):
        for k, (i, body, shapes) in enumerate(self.bodies_of):
            if i == index:
                self.space.remove(body, *shapes)
                del self.bodies_of[k]
                return

    def bodies(self) -> dict:
        """Every body's state now, as a step file records it (Box2D's layout and mass properties)."""
        rows = [i for i, _, _ in self.bodies_of]
        out = {k: v[rows].copy() for k, v in self.records.items()}
        state = np.array([(*b.position, b.angle, *b.velocity, b.angular_velocity, *b.local_to_world(b.center_of_gravity))
                          for _, b, _ in self.bodies_of], dtype=np.float64).reshape(-1, 8)
        out["position"] = state[:, 0:2].astype(np.float32)
        out["angle"] = state[:, 2].astype(np.float32)
        out["velocity"] = state[:, 3:5].astype(np.float32)
        out["omega"] = state[:, 5].astype(np.float32)
        out["center"] = state[:, 6:8].astype(np.float32)
        return out

    def contacts(self) -> dict:
        """The contact points of the arbiters the last step solved, as a step file records them."""
        rows = []
        for m, (shapes, points, total) in enumerate(self.arbiters):
            (fa, ba, mu_a, e_a), (fb, bb, mu_b, e_b) = self.fixture_of[shapes[0]], self.fixture_of[shapes[1]]
            n = points.normal
            t = (n.y, -n.x)   # Box2D's tangent, b2Cross(normal, 1)
            jn, jt = -total.dot(n), -total.dot(t)   # (pymunk reports the impulse on the first body)
            k = len(points.points)
            for p, cp in enumerate(points.points):
                x = 0.5 * (cp.point_a + cp.point_b)
                rows.append((m, p, k, ba, bb, fa, fb, x.x, x.y, n.x, n.y, cp.distance,
                             math.sqrt(mu_a * mu_b), max(e_a, e_b), jn / k, jt / k))
        return _contact_columns(rows, self.threshold)


def _damped(linear, angular):
    """A body velocity function with Box2D's two dampings (v / (1 + dt c) each step)."""
    import pymunk

    def velocity(body, gravity, damping, dt):
        pymunk.Body.update_velocity(body, gravity, 1.0, dt)
        body.velocity = body.velocity / (1.0 + dt * linear)
        body.angular_velocity = body.angular_velocity / (1.0 + dt * angular)
    return velocity


_INT = ("manifold", "point", "point_count", "body_a", "body_b", "fixture_a", "fixture_b")


def _contact_columns(rows, threshold) -> dict:
    """Contact rows (tuples in `contacts`' order) as a step file's contact columns; the fields an
    engine other than Box2D does not have are 0 (island, feature id, children, radii)."""
    a = np.array(rows, dtype=np.float64).reshape(-1, 16)
    out = empty_contacts(len(a))
    for k, name in enumerate(_INT):
        out[name][:] = a[:, k]
    out["position"][:] = a[:, 7:9]
    out["normal"][:] = a[:, 9:11]
    out["separation"][:] = a[:, 11]
    out["friction"][:] = a[:, 12]
    out["restitution"][:] = a[:, 13]
    out["restitution_threshold"][:] = threshold
    out["normal_impulse"][:] = a[:, 14]
    out["tangent_impulse"][:] = a[:, 15]
    return out
