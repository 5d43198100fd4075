"""deepcontact._box2d against real Box2D 2.4.1."""
import numpy as np
import pytest

from deepcontact import _box2d
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world


def box(hx, hy):
    return np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]], dtype=np.float32)


def test_version_is_the_debian_package():
    assert _box2d.box2d_version == "2.4.1"


def test_hello_world_box_comes_to_rest_on_the_ground():
    # Box2D's own hello-world: a 2 x 2 box dropped from y = 4 onto a ground box.
    world = _box2d.World(0.0, -10.0)
    ground = world.add_body(0, 0.0, -10.0)
    world.add_polygon(ground, box(50.0, 10.0))
    body = world.add_body(2, 0.0, 4.0)
    world.add_polygon(body, box(1.0, 1.0), density=1.0, friction=0.3)
    for _ in range(150):
        world.step(1.0 / 60.0, 6, 2)
    y = world.bodies()["position"][1, 1]
    assert y == pytest.approx(1.01, abs=0.01)


def test_recorded_step_has_every_field_with_matching_lengths():
    world = build_world(generate("pile", 0, dict(count=30, box=16.0, sigma=4.0)))
    for _ in range(150):
        bodies, contacts = world.step(0.01, 8, 3, record=True)
    n = len(contacts["manifold"])
    assert n > 20
    for key, value in contacts.items():
        assert value.shape[0] == n, key
    assert contacts["position"].dtype == np.float32
    assert np.allclose(np.linalg.norm(contacts["normal"], axis=1), 1.0, atol=1e-6)
    assert np.all(contacts["normal_impulse"] >= 0)
    # (|lt| <= mu ln does not hold exactly for what Box2D returns: each sweep clamps the tangent
    # impulse with the normal impulse from before that sweep's normal rows.)
    assert len(bodies["index"]) == 31


def keyed(c, field):
    keys = zip(c["fixture_a"], c["child_a"], c["fixture_b"], c["child_b"], c["id_key"])
    return {k: v for k, v in zip(keys, c[field])}


def test_start_impulse_is_the_previous_steps_impulse_matched_by_feature_id():
    world = build_world(generate("pile", 0, dict(count=30, box=16.0, sigma=4.0)))
    _, first = world.step(0.01, 8, 3, record=True)
    assert world.last_dt_ratio == 0.0           # no warm start on the first step
    assert not np.any(first["start_normal_impulse"])
    previous = None
    matched = 0
    for _ in range(150):
        _, c = world.step(0.01, 8, 3, record=True)
        assert world.last_dt_ratio == 1.0       # exactly 1 at constant dt
        if previous is not None:
            before_n, before_t = keyed(previous, "normal_impulse"), keyed(previous, "tangent_impulse")
            now_n, now_t = keyed(c, "start_normal_impulse"), keyed(c, "start_tangent_impulse")
            for key, start in now_n.items():
                if key in before_n:
                    assert start == before_n[key] and now_t[key] == before_t[key]
                    matched += 1
                else:
                    assert start == 0.0 and now_t[key] == 0.0
        previous = c
    assert matched > 500


def test_no_warm_start_means_zero_start():
    world = build_world(generate("pile", 0, dict(count=30, box=16.0, sigma=4.0)))
    world.warm_starting = False
    for _ in range(150):
        _, c = world.step(0.01, 8, 3, record=True)
    assert len(c["manifold"]) and not np.any(c["start_normal_impulse"])
    assert np.any(c["normal_impulse"])


def test_manifold_impulses_written_after_collide_are_the_next_start():
    world = build_world(generate("pile", 0, dict(count=30, box=16.0, sigma=4.0)))
    for _ in range(120):
        world.step(0.01, 8, 3)
    world.collide()
    c = world.contacts()
    n = len(c["manifold"])
    normal = np.linspace(0.1, 1.0, n).astype(np.float32)
    tangent = np.linspace(-0.05, 0.05, n).astype(np.float32)
    world.set_manifold_impulses(normal, tangent)
    _, rec = world.step(0.01, 0, 3, record=True)   # zero velocity iterations: applied as given
    assert np.array_equal(rec["start_normal_impulse"], normal)
    assert np.array_equal(rec["normal_impulse"], normal)
    assert np.array_equal(rec["start_tangent_impulse"], tangent)


def test_stale_contacts_and_bad_arrays_are_refused():
    world = build_world(generate("pile", 0, dict(count=30, box=16.0, sigma=4.0)))
    for _ in range(120):
        world.step(0.01, 8, 3)
    c = world.contacts()
    n = len(c["manifold"])
    with pytest.raises(ValueError):
        world.set_manifold_impulses(np.zeros(n + 1, np.float32), np.zeros(n + 1, np.float32))
    world.step(0.01, 8, 3)
    with pytest.raises(RuntimeError, match="changed"):
        world.set_manifold_impulses(np.zeros(n, np.float32), np.zeros(n, np.float32))
    with pytest.raises(ValueError):
        world.add_polygon(0, np.zeros((2, 2), np.float32), density=1.0)
    with pytest.raises(ValueError, match="convex"):
        world.add_polygon(0, np.array([[0, 0], [1, 0], [0.5, 0.1], [1, 1], [0, 1]], np.float32))


def test_contacts_are_in_island_order_and_each_manifold_once():
    world = build_world(generate("pile", 0, dict(count=30, box=16.0, sigma=4.0)))
    for _ in range(150):
        _, c = world.step(0.01, 8, 3, record=True)
    m = c["manifold"]
    assert np.all(np.diff(m) >= 0) and np.all(np.diff(c["island"]) >= 0)
    keys = set(zip(c["fixture_a"], c["child_a"], c["fixture_b"], c["child_b"], c["point"]))
    assert len(keys) == len(m)
    # contacts of one island share no body (other than static ones) with another island
    dynamic = set(np.nonzero(world.bodies()["type"] == 2)[0])
    owner = {}
    for a, b, island in zip(c["body_a"], c["body_b"], c["island"]):
        for body in (a, b):
            if body in dynamic:
                assert owner.setdefault(body, island) == island


def test_switches():
    world = _box2d.World()
    assert world.block_solve and world.warm_starting
    world.block_solve = False
    world.continuous = False
    world.sleeping = False
    assert not (world.block_solve or world.continuous or world.sleeping)
    world.inv_dt0 = 100.0
    assert world.inv_dt0 == 100.0
    for bad in (float("nan"), float("inf"), -1.0):   # (the next warm start's scale, dt * inv_dt0)
        with pytest.raises(ValueError, match="inv_dt0 must be finite and at least 0"):
            world.inv_dt0 = bad
    assert world.inv_dt0 == 100.0


def test_step_releases_the_gil():
    # Two threads stepping two worlds must both make progress (and not corrupt each other).
    import threading
    scenes = [generate("pile", s, dict(count=30, box=16.0, sigma=4.0)) for s in (0, 1)]
    results = {}

    def work(i):
        w = build_world(scenes[i])
        for _ in range(100):
            w.step(0.01, 8, 3)
        results[i] = w.bodies()["position"].copy()

    threads = [threading.Thread(target=work, args=(i,)) for i in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i in (0, 1):
        w = build_world(scenes[i])
        for _ in range(100):
            w.step(0.01, 8, 3)
        assert np.array_equal(results[i], w.bodies()["position"])
