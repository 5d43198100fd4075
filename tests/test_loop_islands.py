"""The loop's native step (deepcontact/native/world_loop.cpp: the islands found once, then stepped as
b2Island::Solve steps them with no velocity iterations) against the same step in pieces through
Python, which runs Box2D's own Solve: the same trajectory, recorded step, solution and penetration,
bit for bit (signed zeros too), on every kind of scene a scene file can declare."""
import signal
from pathlib import Path

import numpy as np
import pytest

from deepcontact._box2d import PGSStepSettings, StepSettings, pgs_step
from deepcontact.scene.generators import generate
from deepcontact.scene.model import Body, Circle, Edge, Effects, Polygon, Scene, Solver, f32
from deepcontact.scene.xml import read_scene
from deepcontact.simulate.build import build_world
from deepcontact.simulate.pgs_loop import PGSStepper, unit_dt_ratio_inv
from deepcontact.solver.settings import SolveSettings

SCENES = Path(__file__).parent.parent / "datasets" / "scenes"
SETTINGS = SolveSettings(mode="float64", max_iterations=200, tolerance=1e-4)


def _box(hx, hy, cx=0.0, cy=0.0, density=1.0):
    return Polygon(((cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)), density=density)


def _ground(half_width=20.0):
    return Body(type="static", shapes=[Edge(-half_width, 0.0, half_width, 0.0)])


def _scene(bodies, gravity=(0.0, -9.81), friction=0.5, restitution=None, damping=None, **solver):
    return Scene(name="loop-islands", dt=f32(1 / 60), steps=50, solver=Solver(**solver), bodies=bodies,
                 effects=Effects(gravity=gravity, friction=friction, restitution=restitution, damping=damping))


def _stacked(**kw):
    return _scene([_ground(), Body(x=0, y=0.5, shapes=[_box(0.5, 0.5)]), Body(x=0.2, y=1.5, shapes=[_box(0.5, 0.5)])], **kw)


# Each a few bodies, 50 steps: what Box2D's island solve reads, one feature at a time.
KINDS = {
    "kinematic": lambda: _scene([_ground(), Body(type="kinematic", x=0, y=1, vx=1.0, omega=0.3, shapes=[_box(3, 0.2)]),
                                 Body(x=0, y=1.7, shapes=[_box(0.5, 0.5)]),
                                 Body(x=1.2, y=1.7, shapes=[Circle(0.5, density=1)])]),
    "fixed rotation, damping": lambda: _scene(
        [_ground(), Body(x=0, y=0.5, vx=3, fixed_rotation=True, shapes=[_box(0.5, 0.5)]),
         Body(x=0.3, y=1.6, angle=0.4, omega=4, shapes=[_box(0.5, 0.5)])], damping=(0.5, 0.8)),
    "restitution": lambda: _scene([_ground(), Body(x=0, y=3, vy=-5, shapes=[Circle(0.5, density=1)]),
                                   Body(x=2, y=2, vy=-8, angle=0.2, shapes=[_box(0.5, 0.3)])], restitution=0.8),
    "frictionless, no gravity": lambda: _scene([Body(x=0, y=0, vx=2, shapes=[_box(0.5, 0.5)]),
                                                Body(x=2, y=0.1, vx=-1, omega=1, shapes=[_box(0.5, 0.5)]),
                                                Body(x=5, y=5, shapes=[Circle(0.3, density=1)])],
                                               gravity=None, friction=None),
    # b2_maxTranslation and b2_maxRotation clamp these
    "clamped": lambda: _scene([_ground(200), Body(x=0, y=0.5, vx=200, omega=300, shapes=[_box(0.5, 0.5)]),
                               Body(x=5, y=0.5, vy=-300, shapes=[Circle(0.5, density=1)])]),
    "warm starting off": lambda: _stacked(warm_starting=False),
    "no position iterations": lambda: _stacked(position_iterations=0),
    # thin cards: two-point manifolds the block solver cuts to one point (and keeps, without it)
    "card house": lambda: generate("card-house", 0, dict(levels=2)),
    "card house, no block solver": lambda: _without_block_solve(generate("card-house", 0, dict(levels=2))),
    "polygons and edges": lambda: read_scene(SCENES / "boxes-and-circles.xml"),
    # one static body in several islands, static and dynamic bodies mixed in the body list
    "static between islands": lambda: _scene(
        [Body(x=-2, y=0.5, shapes=[_box(0.5, 0.5)]), _ground(), Body(x=2, y=0.5, shapes=[Circle(0.5, density=1)]),
         Body(type="static", x=6, y=0.5, shapes=[_box(0.5, 0.5)]), Body(x=6, y=1.5, shapes=[Circle(0.5, density=1)]),
         Body(x=5.5, y=2.5, shapes=[_box(0.4, 0.4)])]),
    "removals": lambda: read_scene(SCENES / "removals.xml"),
    "no contacts": lambda: _scene([Body(x=0, y=10, vx=1, shapes=[Circle(0.5, density=1)])]),
    "empty": lambda: _scene([]),
    "static only": lambda: _scene([_ground(), Body(type="static", x=0, y=0.4, shapes=[_box(1, 0.5)])]),
}


def _without_block_solve(scene):
    scene.solver.block_solve = False
    return scene


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return False
    if a.dtype.kind != "f":
        return np.array_equal(a, b)
    return np.array_equal(a, b, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(b))


def _twins(scene, settings=SETTINGS):
    native, pieces = (PGSStepper(build_world(scene), scene, settings, "builtin", native=n) for n in (True, False))
    assert native.native and not pieces.native
    return native, pieces


def _differences(a, b, native, pieces):
    """What differs between two LoopSteps and the worlds after them."""
    out = [] if (a.solution is None) == (b.solution is None) else ["solution"]
    if a.solution is not None and b.solution is not None:
        out += [f"solution.{k}" for k in ("normal_impulse", "tangent_impulse")
                if not _same(getattr(a.solution, k), getattr(b.solution, k))]
        out += [] if a.solution.iterations == b.solution.iterations else ["solution.iterations"]
    out += [] if _same(a.deepest, b.deepest) else [f"deepest {a.deepest!r} != {b.deepest!r}"]
    for what, got, want in (("bodies", a.bodies, b.bodies), ("contacts", a.contacts, b.contacts),
                            ("world", native.world.bodies(), pieces.world.bodies())):
        assert got.keys() == want.keys()
        out += [f"{what}.{k}" for k in want if not _same(got[k], want[k])]
    return out


def _step_both(native, pieces, steps, between=None):
    removals = native.scene.removals()
    for k in range(steps):
        for body in removals.get(k, ()):
            native.world.remove_body(body)
            pieces.world.remove_body(body)
        if between is not None:
            between(k, native.world)
            between(k, pieces.world)
        a, b = native.step(), pieces.step()
        differ = _differences(a, b, native, pieces)
        assert differ == [], f"step {k}: {differ}"


@pytest.mark.parametrize("kind", list(KINDS))
def test_the_native_step_is_the_step_in_pieces_on_every_kind_of_scene(kind):
    scene = KINDS[kind]()
    _step_both(*_twins(scene), min(scene.steps, 50))


def test_a_body_placed_off_its_centre_reports_the_penetration_contacts_measures():
    # A body placed directly (created, or set_body_state) keeps the position given, which the one
    # Box2D's solver rebuilds from its centre differs from in the last bits where the centre is off
    # the body's origin: the native step reported the penetration from the rebuilt transform, the
    # step in pieces (and the native step before islands were its own) from the body's.
    box = _box(0.5, 0.5, cx=0.7, cy=0.2)
    scene = _scene([_ground(), Body(x=f32(0.05), y=f32(0.16438965499401093), angle=f32(0.5), shapes=[box]),
                    Body(x=f32(3.1), y=f32(0.23), angle=f32(0.7), shapes=[Circle(0.5, x=0.3, y=0.3, density=1)])])

    def placed(k, world):
        if k in (10, 25):
            b = world.bodies()
            dynamic = b["type"] == 2
            position = b["position"].reshape(-1, 2)[dynamic] - np.float32([0, 0.01])
            world.set_body_state(b["index"][dynamic], position, b["angle"][dynamic] + np.float32(0.1),
                                 b["velocity"].reshape(-1, 2)[dynamic], b["omega"][dynamic])
    _step_both(*_twins(scene), 40, placed)


def test_a_static_body_with_a_velocity_moves_as_box2d_moves_it():
    # A scene may give a static body a velocity; Box2D keeps it and moves the body once in every
    # island it is in, posing a later island's contacts where an earlier one left it. The native
    # step posed them all where it was before the step.
    ground = Body(type="static", vx=0.5, omega=0.2, shapes=[Polygon(((-4, -0.5), (4, -0.5), (4, 0), (-4, 0)))])
    scene = _scene([ground, Body(x=-2, y=0.5, shapes=[_box(0.5, 0.5)]), Body(x=2, y=0.5, shapes=[_box(0.5, 0.5)])])
    native, pieces = _twins(scene)
    _step_both(native, pieces, 30)
    assert native.world.bodies()["position"][0, 0] > 30 * scene.dt * 0.5   # (moved by both islands)


@pytest.mark.parametrize("setting", ["sleeping", "continuous"])
def test_pgs_step_with_sleeping_or_continuous_on_is_the_step_in_pieces(setting):
    # The loop refuses such scenes, but pgs_step may be called on any world: with sleeping on it
    # takes Box2D's own Solve, with continuous collision its time-of-impact sub-steps after the
    # islands; the step in pieces does the same.
    def switched_on(k, world):
        if k == 0:
            setattr(world, setting, True)
    _step_both(*_twins(read_scene(SCENES / "boxes-and-circles.xml")), 150, switched_on)


def test_pgs_step_with_sleeping_on_wakes_no_body_box2d_would_not():
    # One body of a sleeping stack woken alone (set_body_state gives it a speed): finding the
    # islands for the solve woke the bodies asleep on it, so Box2D's own Solve, which steps a
    # world with sleeping on, started its search from the first of them in the body list
    # instead: another island order, other contacts recorded, another trajectory.
    scene = _scene([_ground()] + [Body(x=0, y=0.5 + k, shapes=[_box(0.5, 0.5)]) for k in range(3)])
    native, pieces = _twins(scene)

    def woken(k, world):
        if k == 0:
            world.sleeping = True
        if k == 40:   # (asleep from step 29 on)
            assert not world.bodies()["velocity"].any()
            b = world.bodies()
            world.set_body_state(b["index"][1:2], b["position"].reshape(-1, 2)[1:2], b["angle"][1:2],
                                 np.float32([[0.3, 0.0]]), b["omega"][1:2])
    _step_both(native, pieces, 60, woken)


class _Stopped(Exception):
    pass


def _stop(signum, frame):
    raise _Stopped


def test_a_step_after_an_interrupted_pgs_step_uses_the_block_solver_setting_of_the_step():
    # pgs_step finds and poses the islands, then a signal may stop its solve (Ctrl-C in a
    # notebook). A Step of the same collided world that follows, with the block solver switched
    # off in between, must apply the warm start to both points of each pair pgs_step's posing cut
    # for the block solver (the thin cards' pairs, stepped by Box2D without the block solver so
    # far: both points hold an impulse).
    scene = _without_block_solve(generate("card-house", 0, dict(levels=2)))
    native, pieces = worlds = [build_world(scene) for _ in range(2)]
    for world in worlds:
        for _ in range(10):
            world.step(scene.dt, 8, scene.solver.position_iterations)
    native.block_solve = True
    endless = SolveSettings(mode="float64", max_iterations=2 ** 31 - 1, tolerance=0.0)
    settings = PGSStepSettings(step=StepSettings(dt=scene.dt, gravity=scene.effects.gravity, block_solve=True),
                               solve=endless.native(dt=scene.dt), start="builtin", warm_scale=1.0,
                               inv_dt0=unit_dt_ratio_inv(scene.dt), position_iterations=3, record=False)
    previous = signal.signal(signal.SIGALRM, _stop)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.2)
        with pytest.raises(_Stopped):
            pgs_step(native, settings)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    pieces.collide()
    for world in worlds:
        world.block_solve = False
        world.step(scene.dt, 0, scene.solver.position_iterations, collided=True)
    for key in ("velocity", "omega", "position", "angle"):
        assert _same(native.bodies()[key], pieces.bodies()[key]), key
