"""pymunk and MuJoCo as engines of the project: every scene simulates, validates and renders;
what they record is checked against physics (a resting body's weight) and MuJoCo's vectorised
force decoding against mj_contactForce, its own slow reference; commands that need Box2D 2.4.1's
contact problem refuse their runs in one line; a plug-in engine goes through the same registry."""
import inspect
import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import dc, option_error
from deepcontact.cli.main import cli
from deepcontact.scene.generators import GENERATORS, generate
from deepcontact.simulate.engines import ENGINES, Engine, engine_named
from deepcontact.simulate.stepping import steps
from deepcontact.step.reader import read_step

pymunk = pytest.importorskip("pymunk")
mujoco = pytest.importorskip("mujoco")

PEERS = ("pymunk", "mujoco")


def _run(*args):
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return result.exit_code, result.output


# (the smallest of each scene: every generator, a few steps, through dc simulate and validate)
SMALL = {"pile": ["count=12", "box=16", "sigma=3"], "stack": ["count=3"], "pyramid": ["base=3"],
         "confined": ["count=16"], "card-house": ["levels=1"], "arch": ["blocks=5"]}


@pytest.mark.parametrize("engine", PEERS)
@pytest.mark.parametrize("scene", list(GENERATORS))
def test_every_scene_simulates_validates_and_renders(tmp_path, engine, scene):
    params = [a for p in SMALL.get(scene, []) for a in ("--param", p)]
    out = tmp_path / "run"
    code, text = _run("simulate", scene, *params, "--engine", engine, "--steps", "6", "-q", "-o", str(out))
    assert code == 0, text
    code, text = _run("validate", "-q", str(out))
    assert code == 0, text
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["engine"] == engine and manifest["poses_box2d_problem"] is False
    assert manifest["engine_version"] == engine_named(engine).version()
    header, bodies, contacts = read_step(out / "seed-000000" / "step-000005.xml")
    assert header["solver"]["name"] == engine and header["engine"]["name"] == engine
    assert np.isfinite(bodies["position"]).all() and np.isfinite(contacts["normal_impulse"]).all()
    code, text = _run("render", str(out / "seed-000000" / "step-000005.xml"), "-q", "-o", str(tmp_path / "s.png"))
    assert code == 0, text


@pytest.mark.parametrize("engine", PEERS)
def test_a_resting_stack_carries_its_weight_each_step(engine):
    """Three boxes at rest: the ground carries all three weights over a step (impulse m g dt),
    the top box's contacts its own, as Box2D's would."""
    scene = generate("stack", 0, {"count": 3})
    e = engine_named(engine)
    world = e.build(scene)
    for done in steps(world, scene, e.stepper(world, scene), count=240):
        pass
    c, b = done.contacts, done.bodies
    weight = float(b["mass"][1]) * 9.81 * float(scene.dt)
    on_ground = c["normal_impulse"][(c["body_a"] == 0) | (c["body_b"] == 0)].sum()
    on_top = c["normal_impulse"][(c["body_a"] == 3) | (c["body_b"] == 3)].sum()
    assert on_ground == pytest.approx(3 * weight, rel=0.02)
    assert on_top == pytest.approx(weight, rel=0.02)
    assert (c["normal_impulse"] >= -1e-9).all()
    # (the normal runs from the first body to the second, the impulse pushing the second away)
    below = np.where(c["body_a"] < c["body_b"], 1.0, -1.0)
    assert (below * c["normal"][:, 1] > 0.99).all()


def test_mujoco_forces_match_its_own_contact_force():
    """The vectorised decoding of the solver's rows against mj_contactForce, contact by contact,
    on a pile (spheres) and a pyramid (prisms), pyramidal and elliptic cones."""
    from deepcontact.simulate.engines.mujoco import _contact_forces
    for name, params in (("pile", {"count": 30, "box": 16.0, "sigma": 4.0}), ("pyramid", {"base": 4})):
        scene = generate(name, 0, params)
        e = engine_named("mujoco")
        world = e.build(scene)
        for cone in (mujoco.mjtCone.mjCONE_PYRAMIDAL, mujoco.mjtCone.mjCONE_ELLIPTIC):
            world.model.opt.cone = cone
            for _ in steps(world, scene, e.stepper(world, scene, record=False), count=60):
                pass
            n = int(world.data.ncon)
            assert n > 0
            fast = _contact_forces(world.model, world.data, n)
            slow = np.zeros((n, 6))
            for k in range(n):
                mujoco.mj_contactForce(world.model, world.data, k, slow[k])
            np.testing.assert_allclose(fast, slow[:, :3], rtol=1e-9, atol=1e-12)


def test_mujoco_records_its_iterations_and_stop_test(tmp_path):
    out = tmp_path / "run"
    code, text = _run("simulate", "pile", "--param", "count=20", "--engine", "mujoco", "--set", "solver=cg",
                      "--set", "tolerance=1e-6", "--set", "iterations=30", "--steps", "40", "-q", "-o", str(out))
    assert code == 0, text
    header, _, _ = read_step(out / "seed-000000" / "step-000039.xml")
    assert header["engine"]["solver"] == "cg" and header["engine"]["tolerance"] == "1e-06"
    stats = header["engine_step"]
    assert 0 <= int(stats["iterations"]) <= 30 and stats["converged"] in ("true", "false")
    assert float(stats["improvement"]) >= 0 and float(stats["gradient"]) >= 0


def test_a_mujoco_arena_too_small_for_the_contacts_stops_the_run_in_one_line(tmp_path, monkeypatch):
    # (MuJoCo itself would drop the constraints that do not fit, warn and step on, and append the
    # warning to MUJOCO_LOG.TXT in the working folder)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "run"
    code, text = _run("simulate", "pile", "--param", "count=300", "--param", "box=60", "--param", "sigma=15",
                      "--engine", "mujoco", "--set", "memory=1", "--steps", "300", "-q", "-o", str(out))
    assert code == 1 and "--set memory" in text and "Traceback" not in text, text
    assert len(text.strip().splitlines()) == 1, text
    assert sorted(p.name for p in tmp_path.iterdir()) == []   # (no MUJOCO_LOG.TXT, no partial run)


def test_mujoco_orders_bodies_row_by_row_and_keeps_the_records_in_scene_order():
    scene = generate("pile", 3, {"count": 25, "box": 16.0, "sigma": 4.0})
    rows, listed = engine_named("mujoco"), engine_named("mujoco", {"order": "scene"})
    a, b = rows.build(scene), listed.build(scene)
    assert list(a.dynamic) != list(b.dynamic) and sorted(a.dynamic) == sorted(b.dynamic)
    ra, rb = a.bodies(), b.bodies()
    np.testing.assert_array_equal(ra["index"], rb["index"])
    np.testing.assert_allclose(ra["position"], rb["position"], atol=1e-6)


def test_mujoco_impedance_makes_its_contacts_stiffer():
    # (a penalty of d / (1 - d) effective masses: a resting stack sinks less into its contacts)
    scene = generate("stack", 1, {"count": 3})

    def rest_depth(settings):
        engine = engine_named("mujoco", settings)
        world = engine.build(scene)
        for _ in steps(world, scene, engine.stepper(world, scene, record=False), count=120):
            pass
        return world, -float(world.data.contact.dist[:world.data.ncon].min())
    default, soft = rest_depth({})
    stiff, stiff_depth = rest_depth({"impedance": 0.999})
    assert default.model.geom_solimp[0, :2].tolist() == pytest.approx([0.9, 0.95])   # (MuJoCo's own)
    assert stiff.model.geom_solimp[0, :2].tolist() == pytest.approx([0.999, 0.999])
    assert 0 < stiff_depth < 0.5 * soft, (stiff_depth, soft)


@pytest.mark.parametrize("command", [("evaluate", "--starts", "zero"), ("export",), ("validate", "--replay")])
def test_commands_that_need_box2d_s_problem_refuse_a_peer_run_in_one_line(tmp_path, command):
    out = tmp_path / "run"
    assert _run("simulate", "pile", "--param", "count=8", "--engine", "pymunk", "--steps", "5", "-q", "-o",
                str(out))[0] == 0
    target = ["-o", str(tmp_path / "x")] if command[0] in ("evaluate", "export") else []
    code, text = _run(command[0], str(out), *command[1:], *target)
    assert code == 1 and "pymunk" in text and "Traceback" not in text
    assert len(text.strip().splitlines()) == 1, text


def test_settings_are_checked_naming_the_option(tmp_path):
    code, text = _run("simulate", "pile", "--engine", "mujoco", "--set", "solver=lbfgs", "-o", str(tmp_path / "r"))
    assert code == 2 and "--set" in text and "newton" in text
    code, text = _run("simulate", "pile", "--engine", "pymunk", "--set", "substeps=4", "-o", str(tmp_path / "r"))
    assert code == 2 and "no setting 'substeps'" in text
    code, text = _run("simulate", "pile", "--engine", "pymunk", "--set", "iterations=0", "-o", str(tmp_path / "r"))
    assert code == 2 and "from 1 to 100000" in text
    assert not (tmp_path / "r").exists()


class StillWorld:
    """A world where nothing moves (the smallest engine a plug-in can bring)."""

    def __init__(self, scene):
        from deepcontact.simulate.build import build_world
        self.records = build_world(scene).bodies()

    def bodies(self):
        return {k: v.copy() for k, v in self.records.items()}

    def remove_body(self, index):
        keep = self.records["index"] != index
        self.records = {k: v[keep] for k, v in self.records.items()}


class Still(Engine):
    """An engine of one's own: registered by its module:Class, stepping nothing."""
    name, label = "still", "still"

    @classmethod
    def version(cls):
        return "1.0"

    def build(self, scene, source=None):
        return StillWorld(scene)

    def stepper(self, world, scene, record=True):
        from deepcontact.simulate.engines import empty_contacts
        from deepcontact.simulate.pgs_loop import LoopStep
        return lambda: LoopStep(world.bodies(), empty_contacts(0), None, 0.0, dt_ratio=1.0)


def test_a_plugin_engine_runs_through_the_same_registry(tmp_path):
    out = tmp_path / "run"
    code, text = _run("simulate", "stack", "--param", "count=2", "--engine", "test_peer_engines:Still", "--steps",
                      "3", "-q", "-o", str(out))
    assert code == 0, text
    assert _run("validate", "-q", str(out))[0] == 0
    header, bodies, _ = read_step(out / "seed-000000" / "step-000002.xml")
    assert header["solver"]["name"] == "still" and header["engine"] == {"name": "still", "version": "1.0"}
    assert "mujoco" in ENGINES.builtin() and "pymunk" in ENGINES.builtin()


class Contacts999(Still):
    """Reports one contact naming body 999 of a 7-body scene."""

    def stepper(self, world, scene, record=True):
        from deepcontact.simulate.engines import empty_contacts
        from deepcontact.simulate.pgs_loop import LoopStep

        def step():
            contacts = empty_contacts(1)
            contacts["body_b"][:] = 999
            return LoopStep(world.bodies(), contacts, None, 0.0, dt_ratio=1.0)
        return step


class Ragged(Still):
    """Reports contacts whose arrays are of different lengths."""

    def stepper(self, world, scene, record=True):
        from deepcontact.simulate.engines import empty_contacts
        from deepcontact.simulate.pgs_loop import LoopStep

        def step():
            contacts = empty_contacts(2)
            contacts["friction"] = contacts["friction"][:1]
            return LoopStep(world.bodies(), contacts, None, 0.0, dt_ratio=1.0)
        return step


class OddStats(Still):
    """Gives an account of its step under keys XML cannot hold."""
    stats = {"iterations done": 3}

    def stepper(self, world, scene, record=True):
        from deepcontact.simulate.engines import empty_contacts
        from deepcontact.simulate.pgs_loop import LoopStep
        return lambda: LoopStep(world.bodies(), empty_contacts(0), None, 0.0, dt_ratio=1.0,
                                engine_stats=dict(type(self).stats))


class ControlStats(OddStats):
    stats = {"note": "bell\x07"}


class NaNStats(OddStats):
    stats = {"residual": float("nan")}


@pytest.mark.parametrize("engine, needles", [
    ("Contacts999", ["naming body 999", "the step has"]), ("Ragged", ["different lengths", "friction 1"]),
    ("OddStats", ["'iterations done'", "XML attribute"]), ("ControlStats", ["character XML cannot"]),
    ("NaNStats", ["residual", "not finite"]),
])
def test_what_an_engine_returns_is_checked_before_it_is_written(tmp_path, engine, needles):
    """A plug-in engine's arrays and account of its step, held to a step file before any is
    written (contacts naming body 999 of a 7-body scene were written and validated; a stats key
    with a space made 150 of 151 files invalid XML): one line naming the engine, no output."""
    code, text = _run("simulate", "stack", "--param", "count=2", "--engine", f"test_peer_engines:{engine}",
                      "--steps", "3", "-q", "-o", str(tmp_path / "run"))
    assert code == 1 and all(n in text for n in needles), text
    assert len(text.strip().splitlines()) == 1 and not (tmp_path / "run").exists()


def test_validate_finds_a_contact_naming_a_body_its_step_has_not(run, tmp_path):
    import shutil
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    step = next(f for f in sorted((copy / "seed-000000").glob("step-*.xml")) if 'master="' in f.read_text())
    text = step.read_text()
    import re
    step.write_text(re.sub(r'master="\d+"', 'master="999"', text, count=1))
    r = dc("validate", copy)
    assert r.returncode == 1 and f"{step.name}:0:0: contact 0 names body 999 (master)" in r.stdout, r.stdout


@pytest.mark.parametrize("args, needles", [
    (["--set", "iterations"], ["dc simulate: error:", "'--set'", "takes KEY=VALUE"]),
    (["--engine", "pymunk", "--set", "iterations=5", "--set", "iterations=50"], ["iterations is given twice"]),
    (["--engine", "mujoco", "--set", "memory=1000000000"], ["memory must be from 0 to 65536"]),
    (["--engine", "mujoco", "--set", "iterations=1e9"], ["iterations must be a whole number"]),
    (["--engine", "mujoco", "--set", "iterations=100000000"], ["iterations must be from 1 to 100000"]),
    (["--engine", "box2d3", "--set", "contact_hertz=1e300"], ["contact_hertz must be from 0 to 1e+06"]),
    (["--param", "count=5", "--param", "count=6"], ["'--param'", "count is given twice"]),
])
def test_every_engine_setting_is_bounded_and_given_once(tmp_path, args, needles):
    """Each --set key has a range (a value past what the engine can hold is one line, not its
    crash: MuJoCo's arena of 10^9 MB was "Could not allocate memory"), and a key given twice is
    refused (it silently took the last); the errors are dc's one line, exit 2."""
    r = dc("simulate", "pile", "--steps", "3", *args, "-o", tmp_path / "o")
    option_error(r, *needles)
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


# Misbehaving engines, each a module:Class run only in its sandbox: Still (above) with a hook that
# each misdeed overrides, run before every step.
BAD_ENGINES = """
import os, signal, sys, time
from deepcontact.simulate.engines import Engine
""" + inspect.getsource(StillWorld) + inspect.getsource(Still) + """
class Base(Still):
    name, label = "bad", "bad"
    def act(self):
        pass
    def stepper(self, world, scene, record=True):
        still = super().stepper(world, scene, record)
        def step():
            self.act()
            return still()
        return step

class RaisesInInit(Base):
    def __init__(self, **settings):
        raise ValueError("no init")

class RaisesInVersion(Base):
    @classmethod
    def version(cls):
        raise ValueError("no version")

class RaisesInBuild(Base):
    def build(self, scene, source=None):
        raise ValueError("no build")

class RaisesInStep(Base):
    def act(self):
        raise ValueError("no step")

class NoneStep(Base):
    def stepper(self, world, scene, record=True):
        return lambda: None

class NotAnEngine:
    pass

class ExitsInBuild(Base):
    def build(self, scene, source=None):
        os._exit(0)

class ExitsInStep(Base):
    def act(self):
        os._exit(0)

class SysExitInStep(Base):
    def act(self):
        sys.exit(3)

class MovesAway(Base):
    def act(self):
        os.chdir("/")
        os.umask(0o777)
"""


@pytest.mark.parametrize("engine, needle", [
    ("RaisesInInit", "no init"), ("RaisesInVersion", "no version"), ("RaisesInBuild", "no build"),
    ("RaisesInStep", "no step"), ("NoneStep", "returned no bodies and contacts"),
    ("NotAnEngine", "is not a deepcontact Engine"), ("ExitsInBuild", "os._exit(0)"), ("ExitsInStep", "os._exit(0)"),
    ("SysExitInStep", "sys.exit(3)"),
])
def test_a_plugin_engine_that_misbehaves_is_one_line_naming_it(tmp_path, monkeypatch, engine, needle):
    """A plug-in engine runs only in its sandbox (contest/engine.py): whatever leaves its code (an
    exception, sys.exit, os._exit: once exit 0 with the lock and partial output left) is one line
    naming it, exit 1, nothing left."""
    import sys
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "bad_engines.py").write_text(BAD_ENGINES)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    monkeypatch.chdir(tmp_path)
    try:
        r = dc("simulate", "stack", "--param", "count=2", "--engine", f"bad_engines:{engine}", "--steps", "3",
               "-o", "run")
    finally:
        sys.modules.pop("bad_engines", None)
        ENGINES._loaded = {k: v for k, v in ENGINES._loaded.items() if not k.startswith("bad_engines")}
    assert r.returncode == 1 and f"bad_engines:{engine}" in r.stderr and needle in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mods"]


def test_what_a_plugin_engine_changes_in_its_process_reaches_nothing_of_dcs(tmp_path, monkeypatch):
    import sys
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "bad_engines.py").write_text(BAD_ENGINES)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    monkeypatch.chdir(tmp_path)
    try:
        r = dc("simulate", "stack", "--param", "count=2", "--engine", "bad_engines:MovesAway", "--steps", "3", "-q",
               "-o", "run")
    finally:
        sys.modules.pop("bad_engines", None)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "run" / "manifest.json").exists() and dc("validate", tmp_path / "run").returncode == 0


HANGS = BAD_ENGINES + """
class Hangs(Base):
    def act(self):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        print(CUE, file=sys.stderr, flush=True)
        while True:
            time.sleep(0.01)
"""


def test_a_plugin_engine_that_ignores_every_stop_cannot_keep_dc_alive(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time
    from conftest import wait_for
    from test_plugin_guests import CUE, Watch
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "bad_engines.py").write_text(f"CUE = {CUE!r}\n" + HANGS)
    proc = subprocess.Popen([sys.executable, "-m", "deepcontact.cli.main", "simulate", "stack", "--param", "count=2",
                             "--engine", "bad_engines:Hangs", "--steps", "3", "-o", "run"], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "mods"), *sys.path])})
    watch = Watch(proc)
    try:
        wait_for(watch.cued)
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        err = watch.finish()
        took = time.monotonic() - sent
    finally:
        proc.kill()
    assert proc.returncode == 143 and took < 3, (proc.returncode, took, err)
    assert "interrupted" in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mods"]


class FailsOnItsSecondStep(Still):
    def stepper(self, world, scene, record=True):
        step, calls = super().stepper(world, scene, record), []

        def once():
            calls.append(1)
            if len(calls) == 2:
                raise ValueError("the engine broke")
            return step()
        return once


def test_a_world_whose_step_failed_says_so_on_every_later_step():
    """After one failed step a World was dead with a bare StopIteration; now each later step is
    one line saying where and why it stopped."""
    from deepcontact.errors import InputError
    from deepcontact.simulate.world import World
    world = World(generate("stack", 0, {"count": 2}), FailsOnItsSecondStep())
    world.step()
    with pytest.raises(ValueError, match="the engine broke"):
        world.step()
    for _ in range(2):
        with pytest.raises(InputError, match="stopped at step 1, where its step raised ValueError: the engine broke"):
            world.step()
