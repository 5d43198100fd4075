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

from ..._box2d import linear_slop, polygon_radius
from ...errors import missing_module
from ...resources import check_step_work
from ..build import build_world
from ..pgs_loop import LoopStep
from . import Engine, Setting, empty_contacts

_SLEEP_TIME = 0.5        # s at rest before a body sleeps: Box2D's b2_timeToSleep
_SLEEP_SPEED = 0.01      # m/s: Box2D's b2_linearSleepTolerance


class Pymunk(Engine):
    """pymunk stepping the scene with `iterations` solver iterations (pymunk's default 10)."""
    name, label = "pymunk", "pymunk"
    sleeps = rests_in_skin = True   # (its collision slop is Box2D's linear slop: it rests as 2.4.1 does)
    SETTINGS = {"iterations": Setting(int, 1, 100_000, "solver iterations per step (pymunk's default 10)")}

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
        def step():
            if not record:
                world.space.step(world.dt)
                return LoopStep(None, None, None, 0.0, dt_ratio=1.0)
            bodies = world.bodies()
            world.space.step(world.dt)
            contacts = world.contacts()
            deepest = max(0.0, float(-contacts["separation"].min())) if len(contacts["separation"]) else 0.0
            return LoopStep(bodies, contacts, None, deepest, dt_ratio=1.0)
        return step


def _library():
    try:
        import pymunk
    except ImportError:
        raise missing_module(ImportError(name="pymunk")) from None
    return pymunk


class PymunkWorld:
    """A scene's pymunk space, and what its records need: the bodies in scene order, each
    shape's fixture index and a Box2D world's body records (mass properties, the layout)."""

    def __init__(self, scene, iterations):
        self.dt = float(scene.dt)
        self.records = build_world(scene).bodies()   # Box2D's mass properties and record layout
        self.space = self._space(scene, iterations)
        e = scene.effects
        self.linear, self.angular = e.damping if e.damping is not None else (0.0, 0.0)
        if self.linear == self.angular:   # Box2D's v / (1 + dt c) each step, as Chipmunk's v * damping^dt
            self.space.damping = (1.0 + self.dt * self.linear) ** (-1.0 / self.dt)
        self.bodies_of, self.shapes_of = [], {}
        self.index_of, self.one_shape = {}, {}   # pymunk body id -> the scene's body; its only shape's
                                                 # (fixture, friction, restitution), or None
        self._table = self._ids = None
        fixture = 0
        for i, b in enumerate(scene.bodies):
            body = self._body(i, b)
            shapes, parts = [], [body]
            for s in b.shapes:
                shape = self._shape(scene, i, s, body, fixture)
                shapes.append(shape)
                fixture += 1
                if b.type == "static" and len(b.shapes) > 1:   # (a static body of several shapes: a
                    parts.append(self._part(b, shape, i))          # body each, which names the shape)
            if len(b.shapes) == 1 or b.type != "static":
                self.one_shape[body.id] = self.shapes_of[i][0][1:] if len(b.shapes) == 1 else None
            self.space.add(*parts, *shapes)
            self.bodies_of.append((i, body, shapes))
            self.index_of.update({part.id: i for part in parts})
        self.threshold = float(e.restitution_threshold)

    @staticmethod
    def _space(scene, iterations):
        """The pymunk space with the scene's gravity, sleeping and Box2D's slop."""
        space = _library().Space()
        space.iterations = iterations
        space.collision_slop = float(linear_slop)
        if scene.effects.gravity is not None:
            space.gravity = tuple(map(float, scene.effects.gravity))
        if scene.solver.sleeping:
            space.sleep_time_threshold = _SLEEP_TIME
            space.idle_speed_threshold = _SLEEP_SPEED
        return space

    def _body(self, i, b):
        """The scene's body i, with Box2D 2.4.1's mass properties (a moving one)."""
        pymunk, r = _library(), self.records
        if b.type == "dynamic":
            moment = math.inf if b.fixed_rotation or r["inertia"][i] == 0 else float(r["inertia"][i])
            body = pymunk.Body(float(r["mass"][i]), moment)
            body.center_of_gravity = tuple(map(float, r["local_center"][i]))
            if self.linear != self.angular:
                body.velocity_func = _damped(self.linear, self.angular)
        else:
            kinds = {"static": pymunk.Body.STATIC, "kinematic": pymunk.Body.KINEMATIC}
            body = pymunk.Body(body_type=kinds[b.type])
        body.angle = b.angle   # (first: an angle set later turns the body about its centre of mass)
        body.position = (b.x, b.y)
        if b.type != "static":   # (the scene's velocities are the centre of mass's, as Box2D's)
            body.velocity, body.angular_velocity = (b.vx, b.vy), b.omega
        return body

    def _shape(self, scene, i, s, body, fixture):
        """A shape of body i, with Box2D's skin and its materials (square roots: Chipmunk multiplies
        two shapes' own, giving Box2D's sqrt(a b) mix)."""
        pymunk = _library()
        if s.kind == "circle":
            shape = pymunk.Circle(body, s.radius, (s.x, s.y))
        elif s.kind == "polygon":
            shape = pymunk.Poly(body, [tuple(v) for v in s.vertices], radius=float(polygon_radius))
        else:
            shape = pymunk.Segment(body, (s.x1, s.y1), (s.x2, s.y2), float(polygon_radius))
        shape.friction = math.sqrt(scene.friction_of(s))
        shape.elasticity = math.sqrt(scene.restitution_of(s))
        self.shapes_of.setdefault(i, []).append((shape, fixture, scene.friction_of(s), scene.restitution_of(s)))
        return shape

    def _part(self, b, shape, i):
        """A static body of its own for one of several shapes of the static body i (it names the shape)."""
        part = _library().Body(body_type=_library().Body.STATIC)
        part.angle, part.position = b.angle, (b.x, b.y)
        shape.body = part
        self.one_shape[part.id] = self.shapes_of[i][-1][1:]
        return part

    def remove_body(self, index):
        for k, (i, body, shapes) in enumerate(self.bodies_of):
            if i == index:
                self.space.remove(body, *shapes)
                del self.bodies_of[k]
                return

    def bodies(self) -> dict:
        """Every body's state now, as a step file records it (Box2D's layout and mass properties;
        pymunk's batch read of the bodies that move)."""
        import pymunk.batch as batch
        F = batch.BodyFields
        buffer = batch.Buffer()
        batch.get_space_bodies(self.space, F.BODY_ID | F.POSITION | F.ANGLE | F.VELOCITY | F.ANGULAR_VELOCITY, buffer)
        ids = np.frombuffer(buffer.int_buf(), np.int64)
        state = np.frombuffer(buffer.float_buf(), np.float64).reshape(-1, 6)   # x, y, angle, vx, vy, omega
        rows = [i for i, _, _ in self.bodies_of]
        out = {k: v[rows].copy() for k, v in self.records.items()}
        where = {i: k for k, i in enumerate(rows)}
        moving = [(where[self.index_of[body]], k) for k, body in enumerate(ids.tolist())
                  if self.index_of.get(body) in where]
        if moving:
            to, frm = np.array(moving).T
            s = state[frm]
            c, sn = np.cos(s[:, 2]), np.sin(s[:, 2])
            lc = out["local_center"][to].astype(np.float64)
            out["position"][to] = s[:, 0:2]
            out["angle"][to] = s[:, 2]
            out["velocity"][to] = s[:, 3:5]
            out["omega"][to] = s[:, 5]
            out["center"][to] = s[:, 0:2] + np.stack([c * lc[:, 0] - sn * lc[:, 1], sn * lc[:, 0] + c * lc[:, 1]], axis=1)
        return out

    def contacts(self) -> dict:
        """The contact points of the arbiters the last step solved (pymunk's batch read: every
        arbiter with contact points), as a step file records them."""
        import pymunk.batch as batch
        buffer = batch.Buffer()
        batch.get_space_arbiters(self.space, _fields(), buffer)
        ints = np.frombuffer(buffer.int_buf(), np.int64).reshape(-1, 3)        # body a, body b, points
        floats = np.frombuffer(buffer.float_buf(), np.float64).reshape(-1, 14)   # _FIELDS' floats, in order
        solved = ints[:, 2] > 0   # (an arbiter kept for persistence, no longer touching: no points)
        ints, floats = ints[solved], floats[solved]
        n_arbiters = len(ints)
        count = ints[:, 2]
        a, b = self._lookup(ints[:, 0], 0).astype(np.int64), self._lookup(ints[:, 1], 0).astype(np.int64)
        arbiter = np.repeat(np.arange(n_arbiters), count)
        point = np.arange(len(arbiter)) - np.repeat(np.cumsum(count) - count, count)
        normal = floats[arbiter, 2:4]
        # points: (point a, point b, distance) of the first, then the second, of each arbiter
        first = point == 0
        on_a = np.where(first[:, None], floats[arbiter, 4:6], floats[arbiter, 9:11])
        on_b = np.where(first[:, None], floats[arbiter, 6:8], floats[arbiter, 11:13])
        distance = np.where(first, floats[arbiter, 8], floats[arbiter, 13])
        total = floats[:, 0:2]
        tangent = np.stack([floats[:, 3], -floats[:, 2]], axis=1)   # Box2D's tangent, b2Cross(normal, 1)
        # (pymunk's total is the impulse on the first body: the second's is its opposite)
        jn = -np.sum(total * floats[:, 2:4], axis=1) / count
        jt = -np.sum(total * tangent, axis=1) / count
        fa = self._fixtures(ints[arbiter, 0], a[arbiter], on_a)
        fb = self._fixtures(ints[arbiter, 1], b[arbiter], on_b)
        out = empty_contacts(len(arbiter))
        out["manifold"][:], out["point"][:], out["point_count"][:] = arbiter, point, count[arbiter]
        out["body_a"][:], out["body_b"][:] = a[arbiter], b[arbiter]
        out["fixture_a"][:], out["fixture_b"][:] = fa[:, 0], fb[:, 0]
        out["position"][:] = 0.5 * (on_a + on_b)
        out["normal"][:] = normal
        out["separation"][:] = distance
        out["friction"][:] = np.sqrt(fa[:, 1] * fb[:, 1])
        out["restitution"][:] = np.maximum(fa[:, 2], fb[:, 2])
        out["restitution_threshold"][:] = self.threshold
        out["normal_impulse"][:] = jn[arbiter]
        out["tangent_impulse"][:] = jt[arbiter]
        return out

    def _lookup(self, ids, column):
        """A column of the table of pymunk body ids (0: the scene's body; 1-3: its only shape's
        fixture, friction, restitution, fixture -1 where it has several) for each id."""
        if self._table is None:
            known = sorted(self.index_of)
            self._ids = np.array(known, np.int64)
            self._table = np.array([(self.index_of[i], *(self.one_shape.get(i) or (-1.0, 0.0, 0.0))) for i in known],
                                   np.float64).reshape(-1, 4)
        return self._table[np.searchsorted(self._ids, ids), column]

    def _fixtures(self, ids, bodies, points):
        """(fixture, friction, restitution) of each contact point's shape: its pymunk body's only
        shape, or, on a body of several, the one nearest the point (pymunk's batch read names bodies)."""
        out = np.stack([self._lookup(ids, k) for k in (1, 2, 3)], axis=1)
        for k in np.flatnonzero(out[:, 0] < 0).tolist():
            p = tuple(points[k])
            out[k] = min(self.shapes_of[int(bodies[k])], key=lambda s: abs(s[0].point_query(p).distance))[1:]
        return out


def _damped(linear, angular):
    """A body velocity function with Box2D's two dampings (v / (1 + dt c) each step)."""
    import pymunk

    def velocity(body, gravity, damping, dt):
        pymunk.Body.update_velocity(body, gravity, 1.0, dt)
        body.velocity = body.velocity / (1.0 + dt * linear)
        body.angular_velocity = body.angular_velocity / (1.0 + dt * angular)
    return velocity


def _fields():
    """What pymunk's batch read gives of each arbiter, in its order: ints body a, body b, points;
    floats total impulse (2), normal (2), then point a (2), point b (2), distance of each point."""
    import pymunk.batch as batch
    F = batch.ArbiterFields
    return (F.BODY_A_ID | F.BODY_B_ID | F.TOTAL_IMPULSE | F.NORMAL | F.CONTACT_COUNT | F.POINT_A_1 | F.POINT_B_1
            | F.DISTANCE_1 | F.POINT_A_2 | F.POINT_B_2 | F.DISTANCE_2)
