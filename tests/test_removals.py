"""Scenes whose events remove bodies that are not the last, in any order, two in one step, a
static one among them (datasets/scenes/removals.xml): simulated in every engine and by the
project's solver, validated (replay and residuals too), drawn, rasterized, and driven by every
start in the closed loop. Contacts name bodies by their index in the scene, which a removal
makes differ from their row in the step (a run of this scene was refused as "naming body 6,
but the step has 6 bodies")."""
import importlib.util
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from conftest import dc
from deepcontact.errors import InputError
from deepcontact.scene.xml import read_scene
from deepcontact.simulate.engines import engine_named
from deepcontact.simulate.run import checked_step
from deepcontact.simulate.stepping import steps
from deepcontact.step.reader import read_step

SCENE = Path(__file__).parent.parent / "datasets" / "scenes" / "removals.xml"
# The bodies each step has: body 4 removed before step 3, the ledge 1 and the circle 3 before step 6.
ALL = [0, 1, 2, 3, 4, 5, 6]
BODIES = {**{k: ALL for k in range(3)}, **{k: [0, 1, 2, 3, 5, 6] for k in range(3, 6)},
          **{k: [0, 2, 5, 6] for k in range(6, 10)}}
# (the engines' own modules; one is skipped only where its wheel is missing)
WHEELS = {"box2d": None, "box2d3": None, "pymunk": "pymunk", "mujoco": "mujoco"}


def _needs(engine):
    if WHEELS[engine] and importlib.util.find_spec(WHEELS[engine]) is None:
        pytest.skip(f"{WHEELS[engine]} is not installed")


def _simulated(out, *args):
    r = dc("simulate", SCENE, *args, "-q", "-o", out)
    assert r.returncode == 0, r.stderr
    return out


def _steps(run):
    return [read_step(f) for f in sorted(Path(run).glob("seed-000000/step-*.xml"))]


def _holds_the_removals(run):
    """Each step has the bodies the events leave, its contacts name only those, and some contact
    names a body whose index is past its row (what the scene is for)."""
    recorded = _steps(run)
    assert [h["index"] for h, _, _ in recorded] == list(range(10))
    past_its_row = False
    for header, bodies, contacts in recorded:
        index = bodies["index"].tolist()
        assert index == BODIES[header["index"]], (header["index"], index)
        named = set(contacts["body_a"].tolist()) | set(contacts["body_b"].tolist())
        assert named <= set(index), (header["index"], named)
        past_its_row |= any(index.index(b) != b for b in named)
    assert past_its_row
    # the circle that lay on the removed ledge falls; the ones on the ground stay on it
    last = recorded[-1][1]
    assert last["velocity"][1, 1] < -0.3 and np.all(np.abs(last["position"][2:, 1] - 0.5) < 0.02)
    return recorded


def test_the_scene_removes_bodies_that_are_not_the_last_two_in_a_step():
    scene = read_scene(SCENE)
    assert scene.removals() == {6: [3, 1], 3: [4]}
    assert scene.bodies[1].type == "static" and len(scene.bodies) == 7


@pytest.mark.parametrize("engine", sorted(WHEELS))
def test_every_engine_simulates_and_validates_removals_of_any_body(tmp_path, engine):
    _needs(engine)
    run = _simulated(tmp_path / "run", "--engine", engine)
    assert json.loads((run / "manifest.json").read_text())["engine"] == engine
    _holds_the_removals(run)
    r = dc("validate", run)
    assert r.returncode == 0 and "0 invalid" in r.stdout + r.stderr, r.stdout + r.stderr
    r = dc("render", run / "seed-000000" / "step-000007.xml", "-q", "-o", tmp_path / "s.png")
    assert r.returncode == 0 and (tmp_path / "s.png").stat().st_size > 0, r.stderr


@pytest.mark.parametrize("engine", sorted(WHEELS))
def test_every_engine_steps_the_removals_through_the_one_loop(engine):
    """The library's way (no step file between): the bodies each engine steps are the scene's
    less those removed, and every contact passes the writer's check."""
    _needs(engine)
    scene, e = read_scene(SCENE), engine_named(engine)
    world = e.build(scene)
    for done in steps(world, scene, e.stepper(world, scene)):
        assert done.bodies["index"].tolist() == BODIES[done.index]
        checked_step(done.index, done.bodies, done.contacts, e)


def test_the_projects_solver_replay_and_the_closed_loop_take_removals(tmp_path):
    """--solver pgs follows Box2D's own trajectory through the removals; the Box2D run replays
    exactly, re-solves from every start, and drives the closed loop."""
    box2d = _simulated(tmp_path / "box2d")
    pgs = _simulated(tmp_path / "pgs", "--solver", "pgs", "--tolerance", "1e-6")
    for (_, ours, _), (_, theirs, _) in zip(_holds_the_removals(pgs), _steps(box2d)):
        assert np.array_equal(ours["index"], theirs["index"])
        assert np.abs(ours["position"] - theirs["position"]).max() < 1e-3
    r = dc("validate", "--residuals", pgs)
    assert r.returncode == 0 and "0 invalid" in r.stdout + r.stderr, r.stdout + r.stderr
    r = dc("validate", "--replay", box2d)
    assert r.returncode == 0 and "largest difference 0: exact" in r.stdout + r.stderr, r.stdout + r.stderr
    r = dc("evaluate", box2d, "--starts", "zero,builtin,prev", "--no-plots", "--no-budgets", "-q", "-o",
           tmp_path / "replay")
    assert r.returncode == 0, r.stderr
    starts = json.loads((tmp_path / "replay" / "summary.json").read_text())["starts"]
    assert {name: row["steps"] for name, row in starts.items()} == {"zero": 10, "builtin": 10, "prev": 10}
    r = dc("evaluate", box2d, "--closed-loop", "--starts", "zero,builtin,prev", "--no-plots", "--no-budgets", "-q",
           "-o", tmp_path / "loop")
    assert r.returncode == 0, r.stderr
    loop = json.loads((tmp_path / "loop" / "closed-loop.json").read_text())["results"]
    assert sorted(row["start"] for row in loop) == ["builtin", "prev", "zero"]
    for row in loop:   # every start through all ten steps, on the reference trajectory (the float64 solve)
        assert row["steps"] == 10 and row["finite"] and max(row["drift"]) < 1e-3, row
    r = dc("rasterize", box2d, "-q", "-o", tmp_path / "data")
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "data" / "metadata.json").read_text())["samples"] == 10


def test_a_contact_naming_a_removed_body_is_refused(tmp_path):
    """dc validate checks a contact against the bodies its step has, by index: a contact moved to
    the removed body 3 (4 bodies, so 3 passed as a row) is found, one naming body 6 (past the
    count, as a row) is not."""
    run = _simulated(tmp_path / "run")
    step = run / "seed-000000" / "step-000007.xml"
    text = step.read_text()
    assert 'slave="6"' in text
    broken = tmp_path / "broken"
    shutil.copytree(run, broken)
    (broken / step.relative_to(run)).write_text(re.sub(r'slave="6"', 'slave="3"', text, count=1))
    r = dc("validate", broken)
    assert r.returncode == 1 and "names body 3 (slave), but the step has no body 3" in r.stdout, r.stdout
    # (and a body recorded twice, which the schema cannot see either)
    (broken / step.relative_to(run)).write_text(text.replace('<body index="2"', '<body index="5"', 1))
    r = dc("validate", broken)
    assert r.returncode == 1 and f'{step.name}:0:0: body 5 is recorded twice' in r.stdout, r.stdout


@pytest.mark.parametrize("index, contacts, needle", [
    ([0, 2, 5, 6], [3], "naming body 3, but the step has no body 3"),
    ([0, 2, 5, 6], [-1], "naming body -1"),
    ([0, 2, 2, 6], [2], "not the scene's bodies (each once"),
    ([0, 2, -5, 6], [2], "not the scene's bodies (each once"),
    ([0, 2, 5, 7], [7], "from 0 to 6"),
])
def test_what_an_engine_returns_names_the_scenes_bodies(index, contacts, needle):
    bodies = {"index": np.array(index, np.int32), "mass": np.ones(len(index), np.float32)}
    named = {"body_a": np.zeros(len(contacts), np.int32), "body_b": np.array(contacts, np.int32)}
    engine = engine_named("box2d")
    with pytest.raises(InputError, match=re.escape(needle)):
        checked_step(4, bodies, named, engine, 7)
    for fine in ([0, 2, 5, 6], [6, 0, 5, 2]):   # (the scene's order is not a step file's rule)
        checked_step(4, bodies | {"index": np.array(fine, np.int32)},
                     {"body_a": np.zeros(2, np.int32), "body_b": np.array([5, 6], np.int32)}, engine, 7)
