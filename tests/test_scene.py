"""Scenes: generators, the scene file format, and refusing bad scenes with file and line."""
import numpy as np
import pytest

from deepcontact.errors import InputError
from deepcontact.scene.generators import GENERATORS, generate, parameters
from deepcontact.scene.xml import read_scene, to_xml
from deepcontact.simulate.build import build_world, check_overlaps

# Small sizes of every generator, for the fast suite.
SMALL = {"pile": dict(count=20, box=14.0, sigma=3.5), "stack": dict(count=5), "pyramid": dict(base=5),
         "mass-ratio": {}, "card-house": dict(levels=2), "arch": dict(blocks=5),
         "confined": dict(count=49), "warm-start-energy": {}, "bullet": dict(stack=4)}


def test_every_generator_is_covered():
    assert set(SMALL) == set(GENERATORS)


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_generator_round_trips_through_a_scene_file(name, tmp_path):
    scene = generate(name, 3, SMALL[name])
    data = to_xml(scene)
    path = tmp_path / "scene.xml"
    path.write_bytes(data)
    again = read_scene(path)
    assert to_xml(again) == data
    assert again.generator == name and again.seed == 3


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_generator_scene_builds_runs_and_stays_finite(name):
    scene = generate(name, 0, SMALL[name])
    check_overlaps(scene)
    world = build_world(scene)
    removals = {e.step: e.body for e in scene.events}
    for k in range(min(scene.steps, 200)):
        if k in removals:
            world.remove_body(removals[k])
        bodies, contacts = world.step(scene.dt, 8, 3, record=True)
        for arrays in (bodies, contacts):
            for key, value in arrays.items():
                if value.dtype.kind == "f":
                    assert np.all(np.isfinite(value)), (name, k, key)


def test_default_sizes_match_notes():
    assert parameters("pile")["count"] == 100 and parameters("pile")["box"] == 30.0
    assert len(generate("pyramid", 0).bodies) == 1 + 210
    assert len(generate("confined", 0).bodies) == 1 + 625
    stack = generate("stack", 0)
    assert len(stack.bodies) == 21


def test_pile_is_deterministic_and_seed_dependent():
    a, b, c = (to_xml(generate("pile", s)) for s in (5, 5, 6))
    assert a == b and a != c


def test_pile_has_no_overlap_and_stays_in_the_box():
    scene = generate("pile", 1)
    p = np.array([(b.x, b.y) for b in scene.bodies[1:]])
    assert p.min() >= 1.0 and p.max() <= 29.0
    d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(len(p)) * 10
    assert d.min() >= 2.0


def test_only_declared_effects():
    scene = generate("confined", 0, dict(count=16))
    assert scene.effects.gravity is None and scene.effects.friction is None
    world = build_world(scene)
    for _ in range(200):
        _, c = world.step(scene.dt, 8, 3, record=True)
    assert len(c["friction"]) and not np.any(c["friction"]) and not np.any(c["tangent_impulse"])
    assert not np.any(c["restitution"])
    # no gravity: total momentum of the closed box is only changed by the walls
    pile = generate("pile", 0, dict(gravity=0.0, count=10))
    assert pile.effects.gravity is None and "gravity" not in pile.effects.names()
    w = build_world(pile)
    w.step(pile.dt, 8, 3)
    assert not np.any(w.bodies()["velocity"])


SCENE = """<?xml version="1.0" encoding="UTF-8"?>
<scene name="t" format="1">
  <world dt="{dt}" steps="10"/>
  <effects>
    <gravity x="0" y="-9.8"/>
    {friction}
  </effects>
  <bodies>
    <body type="static">
      <edge x1="-10" y1="0" x2="10" y2="0"/>
    </body>
    <body type="dynamic" x="0" y="{y}">
      {shape}
    </body>
    <body type="dynamic" x="0" y="3">
      <circle radius="0.5" density="1"/>
    </body>
  </bodies>
</scene>
"""


def scene_file(tmp_path, dt="0.01", friction="", y="1", shape='<circle radius="0.5" density="1"/>'):
    path = tmp_path / "scene.xml"
    path.write_text(SCENE.format(dt=dt, friction=friction, y=y, shape=shape))
    return path


def test_a_good_scene_file_reads(tmp_path):
    scene = read_scene(scene_file(tmp_path))
    assert scene.effects.names() == ["gravity"]
    assert len(scene.bodies) == 3


@pytest.mark.parametrize("kwargs, message, line", [
    (dict(dt="0"), "dt", 3),
    (dict(dt="-0.01"), "dt", 3),
    (dict(dt="NaN"), "dt", 3),
    (dict(y="nan"), "'y'", 12),
    (dict(shape='<circle radius="0.5" density="1" friction="0.3"/>'), "friction effect", 13),
    (dict(shape='<polygon density="1"><vertex x="0" y="0"/><vertex x="1" y="0"/>'
                '<vertex x="0.5" y="0.1"/><vertex x="1" y="1"/><vertex x="0" y="1"/></polygon>'),
     "convex", 13),
    (dict(shape='<circle radius="0.5"/>'), "no mass", 12),
    (dict(shape='<sphere radius="1"/>'), "sphere", 13),
])
def test_bad_scene_files_name_the_line(tmp_path, kwargs, message, line):
    path = scene_file(tmp_path, **kwargs)
    with pytest.raises(InputError) as err:
        read_scene(path)
    assert message in str(err.value)
    assert err.value.path == str(path) and err.value.line == line
    assert "\n" not in str(err.value)


def test_malformed_xml_names_the_line(tmp_path):
    path = scene_file(tmp_path)
    path.write_text(path.read_text().replace("</bodies>", "</bodys>"))
    with pytest.raises(InputError) as err:
        read_scene(path)
    assert err.value.line == 18


def test_overlapping_bodies_are_refused(tmp_path):
    scene = read_scene(scene_file(tmp_path, y="2.7"))
    with pytest.raises(InputError, match="bodies 1 and 2 overlap"):
        check_overlaps(scene, "scene.xml")


def test_unknown_generator_and_parameter():
    with pytest.raises(InputError, match="unknown scene generator"):
        generate("piles")
    with pytest.raises(InputError, match="no parameter 'cout'"):
        generate("pile", 0, {"cout": "3"})
    with pytest.raises(InputError, match="not a whole number"):
        generate("pile", 0, {"count": "many"})
    with pytest.raises(InputError, match="dt must be positive"):
        generate("stack", 0, {"dt": "-1"})
    with pytest.raises(InputError, match="cannot be placed"):
        generate("pile", 0, {"count": "500"})


def test_shipped_example_scenes_are_valid_and_run():
    from pathlib import Path
    scenes = sorted((Path(__file__).parent.parent / "datasets" / "scenes").glob("*.xml"))
    assert len(scenes) >= 2
    for path in scenes:
        scene = read_scene(path)
        check_overlaps(scene, path)
        world = build_world(scene)
        for _ in range(scene.steps):
            _, c = world.step(scene.dt, 8, 3, record=True)
        assert len(c["manifold"]) > 0


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_full_size_scene_runs_its_steps_finite(name):
    scene = generate(name, 0)
    check_overlaps(scene)
    world = build_world(scene)
    removals = {e.step: e.body for e in scene.events}
    for k in range(scene.steps):
        if k in removals:
            world.remove_body(removals[k])
        world.step(scene.dt, 8, 3)
        if k % 50 == 0 or k == scene.steps - 1:
            b = world.bodies()
            assert np.all(np.isfinite(b["position"])) and np.all(np.isfinite(b["velocity"]))
