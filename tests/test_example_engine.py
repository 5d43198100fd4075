"""An engine of one's own from the docs alone: the example (examples/deepcontact-example-plugins,
dc_example_plugins.engines:Circles) uses public names only, runs through dc simulate (by module
path, in its sandbox; by entry point, installed), dc validate and dc render, writes in its sandbox
what it steps in a caller's process byte for byte, and holds a pile at rest; docs/engines.md lists
every field of a step's arrays as they are; an engine returning another layout is one line."""
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import deepcontact as dc
from deepcontact.simulate.engines import ENGINES, step_layout
from test_mutations import invoke

ROOT = Path(__file__).parent.parent
EXAMPLE = ROOT / "examples" / "deepcontact-example-plugins"
CIRCLES = "dc_example_plugins.engines:Circles"
# (a small pile: six circles falling into an 8 m box, touching from step 30)
PILE = ["pile", "--param", "count=6", "--param", "box=8", "--param", "sigma=2"]
PILE_PARAMS = {"count": "6", "box": "8", "sigma": "2"}


@pytest.fixture
def example_on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    yield
    for name in [m for m in sys.modules if m.startswith(("dc_example_plugins", "broken_engines"))]:
        del sys.modules[name]
    ENGINES._loaded = {k: v for k, v in ENGINES._loaded.items() if not k.startswith(("dc_example", "broken_"))}


def test_every_name_an_engine_needs_is_public():
    names = ("Engine", "EngineSetting", "LoopStep", "empty_bodies", "empty_contacts", "scene_bodies", "InputError",
             "Scene", "Body", "Circle", "Polygon", "Edge", "Effects", "SceneSolver")
    assert set(names) <= set(dc.__all__)
    # the example reaches nothing below deepcontact's public names
    source = (EXAMPLE / "dc_example_plugins" / "engines.py").read_text()
    assert re.findall(r"^(?:from|import) deepcontact\S*", source, flags=re.M) == ["import deepcontact"]
    assert set(re.findall(r"\bdc\.(\w+)", source)) <= set(dc.__all__)
    step = dc.LoopStep(dc.empty_bodies(2), dc.empty_contacts(0))   # (solution and deepest have defaults)
    assert step.solution is None and step.deepest == 0.0 and step.dt_ratio is None


def _documented(table):
    """docs/engines.md's table of `table` fields: field -> (dtype, shape of a row)."""
    text = (ROOT / "docs" / "engines.md").read_text()
    rows = re.findall(rf"^\| `(\w+)` \| (\w+) \| \(n,(?: (\d))?\) \|.*\|$",
                      text.split(f"| {table} field |")[1].split("\n\n")[0], flags=re.M)
    return {name: (np.dtype(dtype), (int(width),) if width else ()) for name, dtype, width in rows}


@pytest.mark.parametrize("table", ["body", "contact"])
def test_docs_list_every_field_of_a_step_with_its_dtype_and_shape(table):
    assert _documented(table) == step_layout()[f"{table.replace('body', 'bodie')}s"]


def test_the_example_engine_simulates_validates_and_renders(tmp_path, example_on_path):
    """Through dc simulate in its sandbox (data back, checked, written), byte for byte what it
    steps in this process; then dc validate and dc render (a step to .png), as any engine's run."""
    from dc_example_plugins.engines import Circles
    run = tmp_path / "run"
    r = invoke("simulate", *PILE, "--steps", "40", "--engine", CIRCLES, "--set", "iterations=20", "-q", "-o", run)
    assert r.exit_code == 0, r.stderr
    here = tmp_path / "here"
    dc.simulate_run(dc.SceneSource("pile", PILE_PARAMS, steps=40), [0], here, engine=Circles(iterations=20))
    files = sorted(p.name for p in (run / "seed-000000").iterdir())
    assert len(files) == 41 and files == sorted(p.name for p in (here / "seed-000000").iterdir())
    assert all((run / "seed-000000" / f).read_bytes() == (here / "seed-000000" / f).read_bytes() for f in files)
    header, bodies, contacts = dc.read_step(run / "seed-000000" / "step-000039.xml")
    assert header["solver"]["name"] == "circles" and header["engine"]["version"] == "0.1.0"
    assert len(contacts["manifold"]) > 0 and (contacts["normal_impulse"] > 0).any()
    assert 'engine_step sweeps="' in (run / "seed-000000" / "step-000039.xml").read_text()
    r = invoke("validate", "-q", run)
    assert r.exit_code == 0, r.stdout + r.stderr
    r = invoke("render", run / "seed-000000" / "step-000039.xml", "-o", tmp_path / "last.png")
    assert r.exit_code == 0, r.stderr
    assert (tmp_path / "last.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_example_engine_removes_bodies_in_its_sandbox(tmp_path, example_on_path):
    run = tmp_path / "run"
    r = invoke("simulate", "warm-start-energy", "--param", "remove_step=3", "--steps", "5", "--engine", CIRCLES,
               "-q", "-o", run)
    assert r.exit_code == 0, r.stderr
    counts = [len(dc.read_step(run / "seed-000000" / f"step-{k:06d}.xml")[1]["index"]) for k in (2, 3)]
    assert counts == [4, 3]


def test_the_example_engine_holds_a_pile_at_rest(example_on_path):
    """At rest the walls carry the pile's weight: their impulses' vertical sum is the weight times dt."""
    from dc_example_plugins.engines import SLOP, Circles
    scene = dc.generate("pile", 0, {"count": 6, "box": 8, "sigma": 2})
    world = dc.World(scene, Circles())
    for _ in range(300):
        done = world.step()
    c, b = done.contacts, done.bodies
    walls = c["body_a"] == 0
    n, jn, jt = c["normal"][walls].astype(float), c["normal_impulse"][walls], c["tangent_impulse"][walls]
    up = float(np.sum(jn * n[:, 1] - jt * n[:, 0]))   # (the tangent is (n_y, -n_x))
    weight = float(b["mass"][b["type"] == 2].sum()) * 9.81 * float(scene.dt)
    assert up == pytest.approx(weight, rel=1e-3)
    assert np.abs(b["velocity"]).max() < 1e-3 and done.deepest < 2 * SLOP


def test_the_example_honours_the_scenes_warm_starting(tmp_path, example_on_path):
    """Off (`scene.solver.warm_starting`, what <solver warm_starting> records), each step's solve
    starts from zero impulses: at 10 sweeps a pile sinks deeper than one warm started."""
    import dataclasses
    from dc_example_plugins.engines import Circles
    scene = dc.generate("pile", 0, {"count": 6, "box": 8, "sigma": 2})
    cold = dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, warm_starting=False))
    deepest = []
    for s in (scene, cold):
        world = dc.World(s, Circles())
        deepest.append([world.step().deepest for _ in range(300)][-1])
    assert deepest[1] > 2 * deepest[0] > 0, deepest
    from deepcontact.scene.xml import to_xml
    (tmp_path / "cold.xml").write_bytes(to_xml(cold))   # (a scene file's <solver warm_starting="false">)
    dc.simulate_run(dc.SceneSource(str(tmp_path / "cold.xml"), steps=2), [0], tmp_path / "run", engine=Circles())
    header = dc.read_step(tmp_path / "run" / "seed-000000" / "step-000001.xml")[0]
    assert header["solver"]["name"] == "circles" and header["solver"]["warm_starting"] == "false", header["solver"]


def test_what_the_example_says_of_a_heavy_body_on_a_light_one(example_on_path):
    """Its docstring (and docs/engines.md): warm-start-energy's 100:1 stack bounces at 10 sweeps
    and rests at 100."""
    from dc_example_plugins.engines import Circles
    scene = dc.generate("warm-start-energy", 0, {"remove_step": 200, "steps": 201})
    spans = []
    for sweeps in (10, 100):
        world = dc.World(scene, Circles(iterations=sweeps))
        top = [world.step().bodies["center"][3, 1] for _ in range(200)][100:]
        spans.append(max(top) - min(top))
    assert spans[0] > 0.1 and spans[1] < 1e-3, spans


def test_a_scene_the_example_cannot_step_is_one_line(tmp_path, example_on_path):
    r = invoke("simulate", "stack", "--param", "count=2", "--steps", "3", "--engine", CIRCLES, "-o", tmp_path / "r")
    assert r.exit_code == 1 and "has a polygon" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "r").exists()


BROKEN = textwrap.dedent('''
    import numpy as np
    import deepcontact as dc
    from dc_example_plugins.engines import Circles

    class Broken(Circles):
        def stepper(self, world, scene, record=True):
            step = super().stepper(world, scene, record)
            def broken():
                done = step()
                self.breaks(done.contacts)
                return done
            return broken

    class WithoutFriction(Broken):
        def breaks(self, contacts):
            del contacts["friction"]

    class DoubleFriction(Broken):
        def breaks(self, contacts):
            contacts["friction"] = contacts["friction"].astype(np.float64)

    class FlatNormal(Broken):
        def breaks(self, contacts):
            contacts["normal"] = contacts["normal"][:, 0].copy()

    class NoRatio(Circles):
        def stepper(self, world, scene, record=True):
            step = super().stepper(world, scene, record)
            def unscaled():
                done = step()
                done.dt_ratio = None
                return done
            return unscaled
    ''')


def test_a_step_that_names_no_dt_ratio_is_written_alike_in_its_sandbox_and_here(tmp_path, monkeypatch,
                                                                                 example_on_path):
    """LoopStep's dt_ratio left None is the loop's own (0 on the first step, 1 after) in the
    sandbox as in a caller's process (the sandbox made it 1 on every step)."""
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "broken_engines.py").write_text(BROKEN)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    from broken_engines import NoRatio
    r = invoke("simulate", *PILE, "--steps", "2", "--engine", "broken_engines:NoRatio", "-q", "-o", tmp_path / "run")
    assert r.exit_code == 0, r.stderr
    dc.simulate_run(dc.SceneSource("pile", PILE_PARAMS, steps=2), [0], tmp_path / "here", engine=NoRatio())
    for k, ratio in ((0, "0"), (1, "1")):
        name = f"seed-000000/step-{k:06d}.xml"
        assert (tmp_path / "run" / name).read_bytes() == (tmp_path / "here" / name).read_bytes()
        assert dc.read_step(tmp_path / "run" / name)[0]["dt_ratio"] == float(ratio)


@pytest.mark.parametrize("engine, needle", [
    ("WithoutFriction", "returned contacts without 'friction'"),
    ("DoubleFriction", "returned contacts.friction as float64 of shape (0,); a step file's is float32 of shape (n,)"),
    ("FlatNormal", "contacts.normal as float32 of shape (0,); a step file's is float32 of shape (n, 2)"),
])
def test_a_plugin_engine_returning_another_layout_is_one_line(tmp_path, monkeypatch, example_on_path, engine, needle):
    """A field missing or of another dtype or width is one line naming the engine and the field
    (it was the writer's KeyError or TypeError, "not a message of ours")."""
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "broken_engines.py").write_text(BROKEN)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    r = invoke("simulate", *PILE, "--steps", "2", "--engine", f"broken_engines:{engine}", "-o", tmp_path / "r")
    assert r.exit_code == 1 and f"broken_engines:{engine}" in r.stderr and needle in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "r").exists()


@pytest.mark.pipeline
def test_the_installed_example_engine_is_found_by_its_entry_point(tmp_path):
    target = tmp_path / "site"
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                          "--target", str(target), str(EXAMPLE)], capture_output=True, text=True)
    assert pip.returncode == 0, pip.stderr
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-m", "deepcontact", "simulate", *PILE, "--steps", "5", "--engine",
                        "circles", "--set", "tolerance=1e-6", "-q", "-o", str(tmp_path / "run")],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    header = dc.read_step(tmp_path / "run" / "seed-000000" / "step-000004.xml")[0]
    assert header["solver"]["name"] == "circles" and header["engine"]["tolerance"] == "1e-06"
