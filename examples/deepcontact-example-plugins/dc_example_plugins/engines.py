"""An engine as a plug-in: moving circles (dynamic, or kinematic: moved at their velocity) against
each other and the circles and edges of static bodies, stepped by a solver of its own: sequential
impulses from the last step's impulses, as Box2D's velocity solver.

The contract (docs/engines.md, "An engine of your own"): a subclass of `deepcontact.Engine` with
a name, a version and the settings it takes; `build(scene)` makes its world (which can remove a
body and report its bodies), `stepper(world, scene, record)` a function stepping that world once
and returning a `deepcontact.LoopStep`: the bodies before the step and the contact points it
solved, as arrays in a step file's layout (`deepcontact.empty_bodies`, `deepcontact.empty_contacts`:
every field in its dtype and width; SI units: m, kg, s, rad, N s). `dc simulate --engine
dc_example_plugins.engines:Circles` (or `--engine circles`, installed) runs it in a sandbox of its
own and writes its steps, which `dc validate` and `dc render` read as any engine's.

What it leaves out, to stay short: shapes other than circles on moving bodies (polygons, the
boxes of `stack` and `pyramid`: refused in one line), a broad phase (every pair is tested: fine
for tens of circles, not thousands) and a position solver: an overlap is pushed out through the
velocities (Baumgarte's correction, where Box2D 2.4.1 corrects the positions themselves), so a
heavy body resting on a light one bounces at 10 sweeps (`warm-start-energy`'s 100:1 stack) and
rests at 100 (`--set iterations=100`).
"""
import math

import numpy as np

import deepcontact as dc

VERSION = "0.1.0"   # this engine's own: what its step files' <engine version> records
SLOP = 0.005        # m: overlap left uncorrected, so that resting contacts keep touching (Box2D's linear slop)
BAUMGARTE = 0.2     # the share of an overlap beyond the slop pushed out in one step
MARGIN = 0.02       # m: a pair closer than this is a contact, which may close its gap but no more (speculative)
SKIN = 0.01         # m: an edge's radius (Box2D's polygon skin: what step files record as an edge's radius)


class Circles(dc.Engine):
    """Moving bodies of circles (dynamic or kinematic) and static bodies of circles and edges,
    `iterations` sweeps of sequential impulses a step at most, stopping early once a sweep
    changes no impulse by more than `tolerance` (N s; 0: every sweep)."""
    name, label = "circles", "circles (example)"
    rests_in_skin = True   # (resting contacts sit about one slop into each other, as Box2D 2.4.1's)
    SETTINGS = {"iterations": dc.EngineSetting(int, 1, 10_000, "sweeps over the contacts a step, at most"),
                "tolerance": dc.EngineSetting(float, 0.0, 1.0, "stop once a sweep changes no impulse more (N s)")}

    def __init__(self, iterations=10, tolerance=0.0):
        super().__init__(iterations=iterations, tolerance=tolerance)

    @classmethod
    def version(cls) -> str:
        return VERSION

    def check(self, scene, source=None):
        for i, body in enumerate(scene.bodies):
            held = {"circle", "edge"} if body.type == "static" else {"circle"}
            other = sorted({s.kind for s in body.shapes} - held)
            if other:
                raise dc.InputError(f"body {i} ({body.type}) has a {other[0]}: the circles engine moves circles "
                                    f"and holds still circles and edges only", source)

    def build(self, scene, source=None):
        return CircleWorld(scene, **self.settings())

    def stepper(self, world, scene, record=True):
        def step():
            before = world.bodies() if record else None
            contacts, sweeps, change = world.step()
            if not record:
                return dc.LoopStep(None, None, dt_ratio=1.0)
            deepest = max(0.0, -float(contacts["separation"].min(initial=0.0)))
            # (<engine_step sweeps last_change>: how this step's solve ended)
            return dc.LoopStep(before, contacts, deepest=deepest, dt_ratio=1.0,
                               engine_stats={"sweeps": sweeps, "last_change": change})
        return step


class CircleWorld:
    """A scene's bodies (one row each, in scene order, kept when removed: `live` says which are
    there), their circles and the edges of the static bodies."""

    def __init__(self, scene, iterations, tolerance):
        self.dt, self.iterations, self.tolerance = float(scene.dt), iterations, tolerance
        self.gravity = np.array(scene.effects.gravity or (0.0, 0.0), float)
        self.threshold = float(scene.effects.restitution_threshold)
        self.records = dc.scene_bodies(scene)   # Box2D 2.4.1's mass properties, in a step file's layout
        r = self.records
        self.center, self.angle = r["center"].astype(float), r["angle"].astype(float)
        self.velocity, self.omega = r["velocity"].astype(float), r["omega"].astype(float)
        self.live = np.ones(len(scene.bodies), bool)
        self.warm = scene.solver.warm_starting   # (the scene's <solver warm_starting>, which the step files record)
        self.carried = {}   # (fixture a, fixture b) -> the pair's impulses (normal, tangent) of the last step
        self.circles, self.edges = [], []   # (body, fixture, geometry in the body's frame, friction, restitution)
        for fixture, (i, s) in enumerate(scene.fixtures()):
            material = (scene.friction_of(s), scene.restitution_of(s))
            if s.kind == "circle":
                self.circles.append((i, fixture, (s.x, s.y, s.radius), *material))
            else:
                self.edges.append((i, fixture, (s.x1, s.y1, s.x2, s.y2), *material))

    def remove_body(self, index):
        self.live[index] = False

    def bodies(self) -> dict:
        """The live bodies now, as a step file records them."""
        out = {k: v[self.live].copy() for k, v in self.records.items()}
        out["center"][:], out["angle"][:] = self.center[self.live], self.angle[self.live]
        out["velocity"][:], out["omega"][:] = self.velocity[self.live], self.omega[self.live]
        out["position"][:] = self.center[self.live] - _turned(out["local_center"], self.angle[self.live])
        return out

    def step(self):
        """One step: contacts found where the bodies are, velocities moved by gravity and damping,
        the contacts solved, positions moved. Returns (the contacts, sweeps done, the last sweep's
        largest change of an impulse)."""
        found = self._contacts()
        self._accelerate()
        v, w = self.velocity.tolist(), self.omega.tolist()   # (Python floats: the solve is scalar work)
        rows = [Row(self, c, v, w) for c in found]
        for row in rows:   # (the warm start: each pair's impulses of the step before, applied first)
            row.pn, row.pt = self.carried.get(row.key, (0.0, 0.0)) if self.warm else (0.0, 0.0)
            row.push(row.n, row.pn, v, w)
            row.push(row.t, row.pt, v, w)
        sweeps, change = self._solve(rows, v, w)
        self.velocity[:], self.omega[:] = v, w
        self.carried = {row.key: (row.pn, row.pt) for row in rows}
        moving = self.live & (self.records["type"] != 0)
        self.center[moving] += self.dt * self.velocity[moving]
        self.angle[moving] += self.dt * self.omega[moving]
        return _recorded(self, found, rows), sweeps, change

    def _accelerate(self):
        """Gravity (dynamic bodies) and damping (Box2D's v / (1 + dt c)), before the contacts are solved."""
        r, dt = self.records, self.dt
        dynamic = self.live & (r["type"] == 2)
        self.velocity[dynamic] += dt * self.gravity * r["gravity_scale"][dynamic, None]
        self.velocity[dynamic] /= (1.0 + dt * r["linear_damping"][dynamic, None])
        self.omega[dynamic] /= (1.0 + dt * r["angular_damping"][dynamic])

    def _world_shapes(self, shapes, points):
        """Each shape's body and its points (`points`: columns pairs of its geometry) in world axes."""
        body = np.array([s[0] for s in shapes], int)
        origin = self.center[body] - _turned(self.records["local_center"][body], self.angle[body])
        return body, [origin + _turned(np.array([s[2][k:k + 2] for s in shapes], float), self.angle[body])
                      for k in points]

    def _contacts(self):
        """(shape a, shape b, point, normal from a to b, separation) of every pair closer than
        MARGIN with a dynamic body in it: circles with circles, then edges with circles."""
        circles = [c for c in self.circles if self.live[c[0]]]
        if not circles:
            return []
        body, (centre,) = self._world_shapes(circles, (0,))
        radius = np.array([c[2][2] for c in circles])
        dynamic = self.records["type"][body] == 2
        found = []
        for k in range(len(circles)):
            for m in range(k + 1, len(circles)):
                if body[k] != body[m] and (dynamic[k] or dynamic[m]):
                    found += _touching(circles[k], circles[m], centre[k], radius[k], centre[m], radius[m])
        edges = [e for e in self.edges if self.live[e[0]]]
        if edges:
            _, (p1, p2) = self._world_shapes(edges, (0, 2))
            for e in range(len(edges)):
                for m in np.flatnonzero(dynamic):
                    q = _nearest_on_segment(p1[e], p2[e], centre[m])
                    found += _touching(edges[e], circles[m], q, SKIN, centre[m], radius[m])
        return found

    def _solve(self, rows, v, w):
        """Sequential impulses over `rows` (the contacts' Rows) on the velocities v and spins w,
        friction then normal, as Box2D's velocity solver; returns (sweeps done, the last sweep's
        largest change of an impulse)."""
        sweeps, change = 0, 0.0
        while sweeps < self.iterations:
            sweeps, change = sweeps + 1, 0.0
            for row in rows:
                change = max(change, row.relax_tangent(v, w), row.relax_normal(v, w))
            if change <= self.tolerance:
                break
        return sweeps, change


def _turned(xy, angle):
    """Points `xy` (n, 2) in a body's frame, turned by its angle (n,) into world axes."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]], axis=1)


def _nearest_on_segment(p1, p2, x):
    d = p2 - p1
    length2 = float(d @ d)
    t = 0.0 if length2 == 0.0 else min(1.0, max(0.0, float((x - p1) @ d) / length2))
    return p1 + t * d


def _touching(a, b, ca, ra, cb, rb):
    """[(a, b, point, normal, separation)] where the round shapes at ca and cb (radii ra, rb) are
    closer than MARGIN, else []. The point lies halfway between the two surfaces."""
    d = cb - ca
    distance = math.hypot(d[0], d[1])
    separation = float(distance - ra - rb)
    if separation >= MARGIN:
        return []
    normal = d / distance if distance > 0 else np.array([0.0, 1.0])
    point = ca + normal * (ra + 0.5 * separation)
    return [(a, b, point, normal, separation)]


class Row:
    """A contact's constants for the solver (its bodies, lever arms, effective masses, the normal
    velocity it aims at: the gap it may close, the overlap it pushes out, its bounce) and its
    impulses so far (N s)."""
    __slots__ = ("a", "b", "key", "ra", "rb", "n", "t", "inv", "normal_mass", "tangent_mass", "bias", "mu", "pn", "pt")

    def __init__(self, world, contact, v, w):
        shape_a, shape_b, point, n, separation = contact
        self.a, self.b = a, b = shape_a[0], shape_b[0]
        self.key = (shape_a[1], shape_b[1])   # (the pair's fixtures: what carries its impulses to the next step)
        r = world.records
        self.ra, self.rb = tuple((point - world.center[a]).tolist()), tuple((point - world.center[b]).tolist())
        self.n = nx, ny = tuple(n.tolist())
        self.t = (ny, -nx)   # (Box2D's tangent: the normal crossed with 1)
        self.inv = (float(r["inv_mass"][a]), float(r["inv_inertia"][a]), float(r["inv_mass"][b]),
                    float(r["inv_inertia"][b]))
        self.normal_mass, self.tangent_mass = self._mass(self.n), self._mass(self.t)
        self.mu = math.sqrt(shape_a[3] * shape_b[3])   # (Box2D's mix of two frictions)
        self.bias = -separation / world.dt if separation > 0 else BAUMGARTE / world.dt * max(0.0, -separation - SLOP)
        approach = self._along(self.n, v, w)
        if approach < -world.threshold:   # (Box2D's restitution: the approach reversed, scaled)
            self.bias = max(self.bias, -max(shape_a[4], shape_b[4]) * approach)
        self.pn = self.pt = 0.0

    def _mass(self, d):
        inv_ma, inv_ia, inv_mb, inv_ib = self.inv
        k = inv_ma + inv_mb + inv_ia * _cross(self.ra, d) ** 2 + inv_ib * _cross(self.rb, d) ** 2
        return 1.0 / k if k > 0 else 0.0

    def _along(self, d, v, w):
        """The velocity of the contact point on b relative to a's, along d."""
        (va, wa), (vb, wb) = (v[self.a], w[self.a]), (v[self.b], w[self.b])
        (rax, ray), (rbx, rby) = self.ra, self.rb
        return ((vb[0] - wb * rby - va[0] + wa * ray) * d[0] + (vb[1] + wb * rbx - va[1] - wa * rax) * d[1])

    def push(self, d, amount, v, w):
        """An impulse `amount` along d on b, and its opposite on a, at the contact point."""
        inv_ma, inv_ia, inv_mb, inv_ib = self.inv
        px, py = amount * d[0], amount * d[1]
        va, vb = v[self.a], v[self.b]
        va[0] -= inv_ma * px
        va[1] -= inv_ma * py
        vb[0] += inv_mb * px
        vb[1] += inv_mb * py
        w[self.a] -= inv_ia * _cross(self.ra, (px, py))
        w[self.b] += inv_ib * _cross(self.rb, (px, py))

    def relax_tangent(self, v, w):
        """Friction: the sliding stopped, within the cone of the normal impulse; returns the change."""
        bound = self.mu * self.pn
        new = min(bound, max(-bound, self.pt - self.tangent_mass * self._along(self.t, v, w)))
        change, self.pt = new - self.pt, new
        self.push(self.t, change, v, w)
        return abs(change)

    def relax_normal(self, v, w):
        """The normal velocity brought to its target, never pulling; returns the change."""
        new = max(0.0, self.pn - self.normal_mass * (self._along(self.n, v, w) - self.bias))
        change, self.pn = new - self.pn, new
        self.push(self.n, change, v, w)
        return abs(change)


def _cross(r, d):
    return r[0] * d[1] - r[1] * d[0]


def _recorded(world, found, rows):
    """The step's contact points in a step file's layout: one manifold of one point per pair."""
    out = dc.empty_contacts(len(found))
    if not found:
        return out
    index = world.records["index"]
    a, b, point, normal, separation = zip(*found)
    out["manifold"][:] = np.arange(len(found))
    out["point_count"][:] = 1
    out["body_a"][:], out["body_b"][:] = index[[s[0] for s in a]], index[[s[0] for s in b]]
    out["fixture_a"][:], out["fixture_b"][:] = [s[1] for s in a], [s[1] for s in b]
    out["position"][:], out["normal"][:], out["separation"][:] = point, normal, separation
    out["radius_a"][:] = [s[2][2] if len(s[2]) == 3 else SKIN for s in a]
    out["radius_b"][:] = [s[2][2] for s in b]
    out["friction"][:] = [row.mu for row in rows]
    out["restitution"][:] = [max(s[4], t[4]) for s, t in zip(a, b)]
    out["restitution_threshold"][:] = world.threshold
    out["normal_impulse"][:] = [row.pn for row in rows]
    out["tangent_impulse"][:] = [row.pt for row in rows]
    return out
