"""Box2D v3 (3.1, the pyb2d3 wheel's library) in the same module as 2.4.1: a scene builds into a v3 world with the same calls, steps with the soft step, and hands
its bodies back as 2.4.1's world does. Checked against physics, not against 2.4.1's numbers (the
engines solve differently)."""
import numpy as np
import pytest

from deepcontact import _box2d
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world, build_world3

pytestmark = pytest.mark.skipif(not hasattr(_box2d, "World3"),
                                reason="built without Box2D v3 (make setup installs pyb2d3)")


def test_both_engines_live_in_one_module():
    assert _box2d.box2d3_version == "3.1.1" and _box2d.box2d_version.startswith("2.4")


def test_a_resting_circle_carries_its_weight_each_step():
    world = _box2d.World3(0.0, -10.0, substeps=4)
    ground = world.add_body(0, 0.0, 0.0)
    world.add_polygon(ground, np.array([[-10, -0.5], [10, -0.5], [10, 0.5], [-10, 0.5]], np.float32), friction=0.6)
    ball = world.add_body(2, 0.0, 2.0)
    world.add_circle(ball, 0.5, density=1.0, friction=0.6)
    dt = 1 / 60
    for _ in range(240):
        world.step(dt)
    b = world.bodies()
    assert b["position"][ball, 1] == pytest.approx(1.0, abs=0.01)        # on the ground's top at y = 0.5
    assert abs(b["velocity"][ball]).max() < 1e-3
    c = world.contacts()
    points, last_substep, total = len(c["separation"]), float(c["normal_impulse"].sum()), \
        float(c["total_normal_impulse"].sum())
    mass = float(b["mass"][ball])
    assert mass == pytest.approx(np.pi * 0.25, rel=1e-5) and points == 1
    # the weight over a step, as an impulse: each of the 4 substeps carries a quarter of it; v3's
    # total counts the substeps' solves and their relax passes, twice the weight
    assert 4 * last_substep == pytest.approx(mass * 10.0 * dt, rel=1e-3)
    assert total == pytest.approx(2 * mass * 10.0 * dt, rel=1e-3)


def test_a_generated_scene_builds_and_settles_under_both_engines():
    scene = generate("pile", 0, {"count": 30, "box": 16, "sigma": 4})
    w2, w3 = build_world(scene), build_world3(scene)
    b2, b3 = w2.bodies(), w3.bodies()
    for key in ("index", "type", "mass", "inertia", "inv_mass", "local_center"):   # the same bodies
        np.testing.assert_allclose(b2[key], b3[key], rtol=1e-5, atol=1e-6, err_msg=key)
    for _ in range(400):
        w3.step(scene.dt)
    b = w3.bodies()
    dynamic = b["type"] == 2
    assert np.isfinite(b["position"]).all() and np.isfinite(b["velocity"]).all()
    assert np.abs(b["velocity"][dynamic]).max() < 0.5                       # settled
    x0, y0, x1, y1 = 0.0, 0.0, 16.0, 16.0
    inside = (b["position"][dynamic] > [x0 - 0.5, y0 - 0.5]) & (b["position"][dynamic] < [x1 + 0.5, y1 + 0.5])
    assert inside.all()                                                  # nothing tunnelled out of the box
    assert len(w3.contacts()["separation"]) > 20


def test_an_unbuildable_polygon_is_one_error():
    world = _box2d.World3(0.0, -10.0)
    body = world.add_body(2, 0.0, 0.0)
    with pytest.raises(ValueError, match="cannot hull"):
        world.add_polygon(body, np.array([[0, 0], [1, 0], [2, 0]], np.float32), density=1.0)


def test_the_stability_criteria_judge_a_v3_run():
    """A hard scene run under v3 through the stability study's own measure (studies/stability.py):
    the pyramid stands; the 8-box stack's top drifts more than 1 cm at any substep count (v3's
    soft step is weaker on tall stacks than 2.4.1's block solver, as its author says)."""
    from deepcontact.studies import stability as S
    cases = {c.label: c for c in S.FAST}
    pyramid = S.run_case(cases["pyramid 6"], "box2d3", "builtin", 4)
    assert pyramid.finite and pyramid.passed and pyramid.solver == "box2d3"
    for substeps in (4, 32):
        stack = S.run_case(cases["stack 8"], "box2d3", "builtin", substeps)
        assert stack.finite and stack.top_drift > S.TOP_DRIFT_LIMIT and not stack.passed
    removal = S.run_case(cases["warm-start energy"], "box2d3", "builtin", 4)   # (a body removed mid-run)
    assert removal.finite
