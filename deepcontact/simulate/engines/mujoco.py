"""MuJoCo, the converged solve to beat: `--engine mujoco`.

The scene as a planar model: each dynamic body slides in x and z and turns about y (Box2D's y is
MuJoCo's z; the hinge's axis is -y, so its angle is Box2D's, counter-clockwise), with Box2D 2.4.1's
own mass properties (its world is built once to read them). Circles are spheres, polygons convex
prisms, edges capsules of Box2D's skin radius; static bodies are the world's, kinematic ones mocap
bodies moved at their velocity. MuJoCo's sparse factor does not reorder: the dynamic bodies are
listed column by column (by x, then up each column), so bodies in contact sit near each other in
the factor (`order=rows` lists them row by row, `order=scene` in the scene's order, to see what
each costs).

MuJoCo poses its own soft contact problem (solimp's impedance d from `impedance`, solref's from
`timeconst` and `dampratio`, MuJoCo's defaults unless given: a row's regulariser is (1 - d) / d
times its diagonal of J M^-1 J^T, a penalty of d / (1 - d), 9 to 19, times its effective mass,
where the project's problem is rigid) and solves it to its
tolerance; friction pairs take the larger coefficient (Box2D's mix, sqrt(a b), where they are
equal); it has no restitution, sleeping or continuous collision. Each step file holds the contact
forces of the step times dt (impulses, Box2D's signs: on the second body, along the normal from
the first) and, in <engine_step>, the solver's iterations and its last improvement and gradient
(its stop test: either below the tolerance)."""
import logging

import numpy as np

from ..._box2d import polygon_radius
from ...errors import Failure, missing_module
from ...resources import check_step_work
from ..build import build_world
from ..pgs_loop import LoopStep
from . import Engine, Setting, empty_contacts

_HALF_DEPTH = 0.5   # half the thickness (m, along y) of a polygon's prism: any will do in a plane
# MuJoCo's own arena default grows faster than the model (532 MB for the
# 1000-circle pile, which used at most 5.9 MB; the 10,000-circle pile's could not be allocated).
# The most measured per dynamic body: 60 KB (pyramid 40 under PGS, 7.7 contacts a box).
_ARENA_BASE = 16 << 20
_ARENA_PER_BODY = 128 << 10


class MuJoCo(Engine):
    """MuJoCo stepping the scene's planar model with `solver` (newton, cg or pgs) to `tolerance`,
    at most `iterations` iterations a step (MuJoCo's defaults: newton, 1e-8, 100)."""
    name, label = "mujoco", "MuJoCo"
    SETTINGS = {"solver": Setting(("newton", "cg", "pgs"), help="MuJoCo's constraint solver"),
                "tolerance": Setting(float, 0, 1, "the solver's tolerance (its stop test)"),
                "iterations": Setting(int, 1, 100_000, "the most solver iterations a step"),
                "order": Setting(("columns", "rows", "scene"), help="the bodies' order in the model (for its sparse "
                                                                   "factor, which does not reorder)"),
                "timeconst": Setting(float, 0, 10, "the soft contacts' time constant (s; solref's first; "
                                                     "MuJoCo's default 0.02): smaller is stiffer, down to 2 dt"),
                "dampratio": Setting(float, 0, 100, "the soft contacts' damping ratio (solref's second; 1)"),
                "impedance": Setting(float, 0, 0.9999, "the soft contacts' impedance d (solimp's dmin and dmax): a "
                                                       "penalty of d / (1 - d) times a row's effective mass; 0: "
                                                       "MuJoCo's default, 0.9 rising to 0.95 over 1 mm"),
                "memory": Setting(int, 0, 65_536, "MuJoCo's arena for contacts and solver (MB; 0: sized from the scene, "
                                                f"{_ARENA_BASE >> 20} MB and {_ARENA_PER_BODY >> 10} KB per dynamic body)")}

    def __init__(self, solver="newton", tolerance=1e-8, iterations=100, order="columns", timeconst=0.02,
                 dampratio=1.0, impedance=0.0, memory=0):
        super().__init__(solver=solver, tolerance=tolerance, iterations=iterations, order=order, timeconst=timeconst,
                         dampratio=dampratio, impedance=impedance, memory=memory)

    @classmethod
    def version(cls) -> str:
        return _library().__version__

    def check(self, scene, source=None):
        _library()
        check_step_work(len(scene.bodies), self._settings["iterations"],
                        f"{self._settings['iterations']:,} iterations a step")

    def build(self, scene, source=None):
        return MuJoCoWorld(scene, **self._settings)

    def stepper(self, world, scene, record=True):
        def step():
            world.move_kinematic()
            if not record:   # (its own account of the solve kept: whether it met its tolerance, a few us)
                world.step()
                return LoopStep(None, None, None, 0.0, dt_ratio=1.0, engine_stats=world.solve_stats())
            bodies = world.bodies()
            world.step()
            contacts = world.contacts()
            deepest = max(0.0, float(-contacts["separation"].min())) if len(contacts["separation"]) else 0.0
            return LoopStep(bodies, contacts, None, deepest, dt_ratio=1.0, engine_stats=world.solve_stats())
        return step


def _library():
    try:
        import mujoco
    except ImportError:
        raise missing_module(ImportError(name="mujoco")) from None
    if mujoco.get_mju_user_warning() is not _warn:
        # MuJoCo's own handler prints and appends to MUJOCO_LOG.TXT in the working folder: a file
        # of the user's we did not ask to write. Its warnings go to the log (stderr) instead.
        mujoco.set_mju_user_warning(_warn)
    return mujoco


def _warn(message):
    # (a full arena is reported by MuJoCoWorld.step as the run's error; the rest are warnings)
    logging.getLogger(__name__).log(logging.DEBUG if "arena" in message else logging.WARNING, "MuJoCo: %s", message)


def _banded(scene, dynamic, order):
    """The dynamic bodies in bands one typical body wide: columns (by x, then up each column) or
    rows (by height, then along x). Bodies in contact then sit near each other in MuJoCo's factor,
    which does not reorder: its fill grows with the band's length, so columns suit a structure
    wider than it is tall (a settled pile: 4.3x faster steps than rows on the 1000-circle pile)."""
    if not dynamic:
        return []
    width = 2.0 * float(np.median([scene.bodies[i].reach() for i in dynamic])) or 1.0
    across, along = ("x", "y") if order == "columns" else ("y", "x")
    return sorted(dynamic, key=lambda i: (int(np.floor(getattr(scene.bodies[i], across) / width)),
                                          getattr(scene.bodies[i], along), i))


class MuJoCoWorld:
    """A scene's planar MuJoCo model and data, and what its records need (which geom is which
    fixture, which joints are which body's, Box2D's body records)."""

    def __init__(self, scene, solver, tolerance, iterations, order, timeconst, dampratio, impedance=0.0, memory=0):
        mujoco = _library()
        self.records = build_world(scene).bodies()
        self.scene = scene
        dynamic = [i for i, b in enumerate(scene.bodies) if b.type == "dynamic"]
        listed = dynamic if order == "scene" else _banded(scene, dynamic, order)
        arena = memory << 20 if memory else _ARENA_BASE + _ARENA_PER_BODY * len(dynamic)
        xml, geoms = _model_xml(scene, self.records, listed, solver, tolerance, iterations, (timeconst, dampratio),
                                impedance, arena)
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self._mj_step = mujoco.mj_step
        # the warnings MuJoCo gives when the arena cannot hold a step's contacts or rows
        self._full = [self.data.warning[w] for w in (mujoco.mjtWarning.mjWARN_CONTACTFULL,
                                                     mujoco.mjtWarning.mjWARN_CNSTRFULL)]
        m, d = self.model, self.data
        # geom id -> (fixture, body, friction, restitution), as arrays for the contacts
        self.geom_fixture = np.array([g[0] for g in geoms], np.int32)
        self.geom_body = np.array([g[1] for g in geoms], np.int32)
        self.geom_friction = np.array([g[2] for g in geoms], np.float64)
        self.geom_restitution = np.array([g[3] for g in geoms], np.float64)
        # each dynamic body's three joints, in qpos/qvel order (x, z, angle; no angle: fixed rotation)
        self.dynamic = np.array(listed, np.int64)
        self.qpos = np.array([m.jnt_qposadr[m.body_jntadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"b{i}")]]
                              for i in listed], np.int64)
        self.turns = np.array([not scene.bodies[i].fixed_rotation for i in listed], bool)
        lc = self.records["local_center"][listed].astype(np.float64)
        self.local_center = lc
        for k, i in enumerate(listed):   # the scene's start: origin, angle, the origin's velocity
            b, a = scene.bodies[i], self.qpos[k]
            d.qpos[a:a + 2] = (b.x, b.y)
            rx, ry = _rotate(lc[k], b.angle)
            d.qvel[a:a + 2] = (b.vx + b.omega * ry, b.vy - b.omega * rx)
            if self.turns[k]:
                d.qpos[a + 2], d.qvel[a + 2] = b.angle, b.omega
        self.kinematic = [(i, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"b{i}"))
                          for i, b in enumerate(scene.bodies) if b.type == "kinematic"]
        self.kinematic_state = {i: [b.x, b.y, b.angle, b.vx, b.vy, b.omega]
                                for i, b in ((i, scene.bodies[i]) for i, _ in self.kinematic)}
        self.removed = set()
        self.dt = float(scene.dt)
        mujoco.mj_forward(m, d)

    def step(self):
        """One mj_step; a Failure where the arena was too small for the step's contacts (MuJoCo
        then drops constraints with a warning and steps on: a wrong step, not a slow one)."""
        before = [w.number for w in self._full]
        self._mj_step(self.model, self.data)
        if [w.number for w in self._full] != before:
            raise Failure(f"MuJoCo's arena ({self.model.narena >> 20} MB) is too small for this scene's "
                          f"contacts at t = {self.data.time:g} s: ask for more with --set memory=MB")

    def move_kinematic(self):
        """Kinematic bodies (mocap) moved on at their velocity, as Box2D moves them."""
        for i, body in self.kinematic:
            s = self.kinematic_state[i]
            s[0], s[1], s[2] = s[0] + self.dt * s[3], s[1] + self.dt * s[4], s[2] + self.dt * s[5]
            mocap = self.model.body_mocapid[body]
            self.data.mocap_pos[mocap] = (s[0], 0.0, s[1])
            self.data.mocap_quat[mocap] = (np.cos(s[2] / 2), 0.0, -np.sin(s[2] / 2), 0.0)

    def remove_body(self, index):
        """The body's shapes collide no more and it leaves the records (MuJoCo keeps its joints)."""
        self.removed.add(index)
        gone = self.geom_body == index
        self.model.geom_contype[gone] = 0
        self.model.geom_conaffinity[gone] = 0

    def bodies(self) -> dict:
        """Every body's state now, as a step file records it (Box2D's layout and mass properties)."""
        r = {k: v.copy() for k, v in self.records.items()}
        q, v, a = self.data.qpos, self.data.qvel, self.qpos
        if len(a):
            origin = np.stack([q[a], q[a + 1]], axis=1)
            angle = np.where(self.turns, q[np.minimum(a + 2, len(q) - 1)], 0.0)
            omega = np.where(self.turns, v[np.minimum(a + 2, len(v) - 1)], 0.0)
            arm = _rotate(self.local_center.T, angle).T
            r["position"][self.dynamic] = origin
            r["angle"][self.dynamic] = angle
            r["center"][self.dynamic] = origin + arm
            # Box2D's velocity is the centre of mass's: the origin's plus omega x arm
            r["velocity"][self.dynamic] = np.stack([v[a] - omega * arm[:, 1], v[a + 1] + omega * arm[:, 0]], axis=1)
            r["omega"][self.dynamic] = omega
        for i, _ in self.kinematic:
            s = self.kinematic_state[i]
            r["position"][i], r["center"][i], r["angle"][i] = s[0:2], s[0:2], s[2]
            r["velocity"][i], r["omega"][i] = s[3:5], s[5]
        if self.removed:
            keep = np.array([i not in self.removed for i in range(len(r["index"]))])
            r = {k: x[keep] for k, x in r.items()}
        return r

    def contacts(self) -> dict:
        """The contacts of the last step, with its forces times dt (impulses), as a step file
        records them; each contact is a manifold of one point."""
        d = self.data
        n = int(d.ncon)
        out = empty_contacts(n)
        if n == 0:
            return out
        c = d.contact
        geom = c.geom[:n]
        frame = c.frame[:n]
        normal = frame[:, [0, 2]]
        force = _contact_forces(self.model, d, n)
        tangent = np.stack([normal[:, 1], -normal[:, 0]], axis=1)   # Box2D's, b2Cross(normal, 1)
        # the tangential force in the plane: t1, t2 (3-D) projected on Box2D's tangent
        along = force[:, 1:2] * frame[:, 3:6] + force[:, 2:3] * frame[:, 6:9]
        out["manifold"][:] = np.arange(n)
        out["point_count"][:] = 1
        out["body_a"][:], out["body_b"][:] = self.geom_body[geom[:, 0]], self.geom_body[geom[:, 1]]
        out["fixture_a"][:], out["fixture_b"][:] = self.geom_fixture[geom[:, 0]], self.geom_fixture[geom[:, 1]]
        out["position"][:] = c.pos[:n][:, [0, 2]]
        out["normal"][:] = normal
        out["separation"][:] = c.dist[:n]
        out["friction"][:] = np.sqrt(self.geom_friction[geom[:, 0]] * self.geom_friction[geom[:, 1]])
        out["restitution"][:] = np.maximum(self.geom_restitution[geom[:, 0]], self.geom_restitution[geom[:, 1]])
        out["restitution_threshold"][:] = self.scene.effects.restitution_threshold
        out["normal_impulse"][:] = force[:, 0] * self.dt
        out["tangent_impulse"][:] = (along[:, 0] * tangent[:, 0] + along[:, 2] * tangent[:, 1]) * self.dt
        return out

    def solve_stats(self) -> dict:
        """The last step's solve: its iterations (the most over MuJoCo's islands), whether it met the
        tolerance before the cap, and the last iteration's improvement and gradient."""
        mujoco = _library()
        d, m = self.data, self.model
        islands = max(int(getattr(d, "nisland", 0)), 1)
        niter = np.asarray(d.solver_niter[:islands])
        k = int(np.argmax(niter))
        last = max(int(niter[k]) - 1, 0)
        stats = np.asarray(d.solver.improvement).reshape(-1, mujoco.mjNSOLVER), \
            np.asarray(d.solver.gradient).reshape(-1, mujoco.mjNSOLVER)
        return {"iterations": int(niter[k]), "converged": bool(niter.max() < m.opt.iterations),
                "improvement": float(stats[0][k, last]), "gradient": float(stats[1][k, last])}


def _rotate(xy, angle):
    """Points (2, ...) turned by angle (radians, counter-clockwise)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * xy[0] - s * xy[1], s * xy[0] + c * xy[1]])


def _contact_forces(model, data, n) -> np.ndarray:
    """Each contact's force in its own frame (normal, t1, t2), decoded from the solver's rows as
    mj_contactForce does (a pyramid's edges, or an elliptic cone's rows), for all at once."""
    mujoco = _library()
    c = data.contact
    adr = c.efc_address[:n]
    f = data.efc_force
    out = np.zeros((n, 3))
    if model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL:
        mu = c.friction[:n, :2]
        edges = np.stack([f[adr + k] for k in range(4)], axis=1)   # condim 3: two edges per direction
        out[:, 0] = edges.sum(axis=1)
        out[:, 1] = (edges[:, 0] - edges[:, 1]) * mu[:, 0]
        out[:, 2] = (edges[:, 2] - edges[:, 3]) * mu[:, 1]
    else:
        out[:] = np.stack([f[adr + k] for k in range(3)], axis=1)
    out[adr < 0] = 0.0   # (a contact the solver did not take: excluded, or beyond the margin)
    return out


def _inflated(vertices, skin):
    """A convex polygon grown by `skin` on every side (Box2D's polygon radius: its collision shape
    is the polygon and that skin; each corner mitred, a little beyond Box2D's rounded one)."""
    v = np.asarray(vertices, np.float64)
    edges = np.roll(v, -1, axis=0) - v
    area = float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
    outward = np.stack([edges[:, 1], -edges[:, 0]], axis=1) * (1.0 if area > 0 else -1.0)
    outward /= np.linalg.norm(outward, axis=1, keepdims=True)
    before, after = np.roll(outward, 1, axis=0), outward   # the normals of the edges meeting at each vertex
    return v + skin * (before + after) / (1.0 + np.sum(before * after, axis=1, keepdims=True))


def _fmt(*values):
    return " ".join(f"{float(v):.9g}" for v in values)


def _defaults_xml(solref, impedance):
    """The geoms' defaults: solref, and solimp where an impedance is given (a constant one:
    MuJoCo's width, midpoint and power then do nothing)."""
    solimp = f' solimp="{_fmt(impedance, impedance, 0.001, 0.5, 2)}"' if impedance else ""
    return f'<default><geom solref="{_fmt(*solref)}"{solimp}/></default>'


def _model_xml(scene, records, listed, solver, tolerance, iterations, solref, impedance, arena):
    """The scene's planar MJCF, and one (fixture, body, friction, restitution) per geom in the
    model's geom order (MuJoCo numbers geoms as the file lists them, the world's first).
    impedance: solimp's dmin = dmax (0: MuJoCo's own solimp)."""
    e = scene.effects
    g = e.gravity if e.gravity is not None else (0.0, 0.0)
    linear, angular = e.damping if e.damping is not None else (0.0, 0.0)
    first = np.concatenate([[0], np.cumsum([len(b.shapes) for b in scene.bodies])]).astype(int)   # body -> fixture
    assets, geoms = [], []

    def shapes_xml(i, b):
        return "".join(shape_xml(i, int(first[i]) + j, s) for j, s in enumerate(b.shapes))

    def shape_xml(i, fixture, s):
        mu = scene.friction_of(s)
        geoms.append((fixture, i, mu, scene.restitution_of(s)))
        common = f'friction="{_fmt(mu)} 0 0" condim="3"'
        if s.kind == "circle":
            return f'<geom type="sphere" size="{_fmt(s.radius)}" pos="{_fmt(s.x, 0, s.y)}" {common}/>'
        if s.kind == "edge":
            return (f'<geom type="capsule" size="{_fmt(polygon_radius)}" '
                    f'fromto="{_fmt(s.x1, 0, s.y1, s.x2, 0, s.y2)}" {common}/>')
        name = f"p{fixture}"
        vertex = " ".join(_fmt(x, y, z) for x, z in _inflated(s.vertices, polygon_radius)
                          for y in (-_HALF_DEPTH, _HALF_DEPTH))
        assets.append(f'<mesh name="{name}" vertex="{vertex}"/>')
        return f'<geom type="mesh" mesh="{name}" {common}/>'

    def frame(b):   # a static or kinematic body's own frame: its place and angle
        return f'pos="{_fmt(b.x, 0, b.y)}" axisangle="0 -1 0 {_fmt(b.angle)}"'

    parts = []
    for i, b in enumerate(scene.bodies):   # the world's and the mocap bodies first (geom order: as listed)
        if b.type == "static":
            parts.append(f'<body name="b{i}" {frame(b)}>' + shapes_xml(i, b) + "</body>")
        elif b.type == "kinematic":
            parts.append(f'<body name="b{i}" mocap="true" {frame(b)}>'
                         + shapes_xml(i, b) + "</body>")
    for i in listed:
        b = scene.bodies[i]
        mass, inertia = float(records["mass"][i]), float(records["inertia"][i])
        lc = records["local_center"][i]
        joints = (f'<joint type="slide" axis="1 0 0" damping="{_fmt(linear * mass)}"/>'
                  f'<joint type="slide" axis="0 0 1" damping="{_fmt(linear * mass)}"/>')
        if not b.fixed_rotation:
            joints += f'<joint type="hinge" axis="0 -1 0" damping="{_fmt(angular * inertia)}"/>'
        inertial = (f'<inertial pos="{_fmt(lc[0], 0, lc[1])}" mass="{_fmt(mass)}" '
                    f'diaginertia="{_fmt(*(max(inertia, 1e-12),) * 3)}"/>')
        parts.append(f'<body name="b{i}">{joints}{inertial}' + shapes_xml(i, b)
                     + "</body>")
    warm = "enable" if scene.solver.warm_starting else "disable"
    xml = (f'<mujoco model="{scene.name}"><compiler angle="radian"/><size memory="{arena >> 10}K"/>'
           f'<option timestep="{_fmt(scene.dt)}" gravity="{_fmt(g[0], 0, g[1])}" solver="{solver.upper() if solver != "newton" else "Newton"}" '
           f'tolerance="{_fmt(tolerance)}" iterations="{iterations}"><flag warmstart="{warm}"/></option>'
           f'{_defaults_xml(solref, impedance)}'
           f'<asset>{"".join(assets)}</asset><worldbody>{"".join(parts)}</worldbody></mujoco>')
    # (MuJoCo numbers geoms in the order of the bodies it lists: the world's children as written)
    return xml, geoms
