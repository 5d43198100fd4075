"""Box2D v3 (3.1, the pyb2d3 wheel's library) in the same module as 2.4.1: a scene builds into a v3 world with the same calls, steps with the soft step, and hands
its bodies back as 2.4.1's world does. Checked against physics, not against 2.4.1's numbers (the
engines solve differently)."""
import numpy as np
import pytest

from deepcontact import _box2d
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world, build_world3
from deepcontact.simulate.engines import SoftStep

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
    assert b["position"][ball, 1] == pytest.approx(1.01, abs=1e-3)   # on the ground's top at y = 0.5, and its 1 cm skin
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
    w2, w3 = build_world(scene), build_world3(scene, SoftStep())
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
    from dcstudies import stability as S
    cases = {c.label: c for c in S.FAST}
    pyramid = S.run_case(cases["pyramid 6"], "box2d3", "builtin", 4)
    assert pyramid.finite and pyramid.passed and pyramid.solver == "box2d3"
    for substeps in (4, 32):
        stack = S.run_case(cases["stack 8"], "box2d3", "builtin", substeps)
        assert stack.finite and stack.top_drift > S.TOP_DRIFT_LIMIT and not stack.passed
    removal = S.run_case(cases["warm-start energy"], "box2d3", "builtin", 4)   # (a body removed mid-run)
    assert removal.finite


# --- dc simulate --engine box2d3 and the rest of the pipeline ---------------------------------

import re  # noqa: E402
from pathlib import Path  # noqa: E402

from conftest import dc, one_line_error, option_error, simulated, written  # noqa: E402

from deepcontact.scene.generators import GENERATORS  # noqa: E402
from deepcontact.step import reader_lxml  # noqa: E402
from deepcontact.step.reader import read_step  # noqa: E402

SCENE_FILES = sorted((Path(__file__).parent.parent / "datasets" / "scenes").glob("*.xml"))
V3_PILE = ["pile", "--engine", "box2d3", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5",
           "--steps", "120"]


@pytest.fixture(scope="module")
def v3_run(tmp_path_factory):
    return simulated(tmp_path_factory, "v3", *V3_PILE)


@pytest.mark.parametrize("scene", [*GENERATORS, *(str(p) for p in SCENE_FILES)],
                         ids=[*GENERATORS, *(p.stem for p in SCENE_FILES)])
def test_every_scene_simulates_under_v3_and_its_steps_validate(tmp_path, scene):
    out = written(tmp_path / "run", "simulate", scene, "--engine", "box2d3", "--steps", "4")
    r = dc("validate", out)
    assert r.returncode == 0, r.stdout + r.stderr
    header = read_step(next(out.glob("seed-*/step-000003.xml")))[0]
    assert header["solver"]["name"] == "box2d3" and header["versions"]["box2d"] == _box2d.box2d3_version
    assert header["soft_step"]["substeps"] == "4" and header["velocity_iterations"] is None


def test_a_v3_step_reads_the_same_through_both_readers_and_holds_v3_fields(v3_run):
    path = sorted(v3_run.glob("seed-*/step-*.xml"))[-1]
    native, reference = read_step(path), reader_lxml.read_step(path)
    for a, b in zip(native[1:], reference[1:]):
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert native[0]["soft_step"] == reference[0]["soft_step"]
    c = native[2]
    assert len(c["manifold"]) > 10
    # v3's fields are written; 2.4.1's are not (read back as 0)
    assert (c["total_normal_impulse"] > 0).any() and (c["anchor_b"] != 0).any()
    assert not c["start_normal_impulse"].any() and not c["local_normal"].any()
    text = path.read_text()
    assert "<total n=" in text and "<anchors " in text and "<start " not in text and "<manifold " not in text
    # the contact points are where the bodies were before the step: anchor_a from body a's origin
    bodies = native[1]
    rows = {int(i): k for k, i in enumerate(bodies["index"])}
    a = np.array([rows[i] for i in c["body_a"]])
    np.testing.assert_allclose(bodies["position"][a] + c["anchor_a"], c["position"], atol=1e-4)


def test_a_step_missing_its_engines_fields_is_refused(v3_run, pile_run, tmp_path):
    from deepcontact.errors import InputError
    v3 = sorted(v3_run.glob("seed-*/step-*.xml"))[-1].read_text()
    cut = tmp_path / "step-000001.xml"
    cut.write_text(v3.replace("<total n=", "<totl n=", 1))
    with pytest.raises(InputError, match="has no <total n=...>"):
        read_step(cut, validate=False)
    old = sorted(pile_run.glob("seed-*/step-*.xml"))[-1].read_text()
    cut.write_text(old.replace("<iterations ", "<soft_step ", 1))
    with pytest.raises(InputError, match="<header> has no <iterations>"):
        read_step(cut, validate=False)


def test_options_of_one_engine_are_refused_with_the_other(tmp_path):
    out = str(tmp_path / "x")
    for option in (["--substeps", "8"], ["--contact-hertz", "60"], ["--damping-ratio", "1"], ["--push-speed", "1"]):
        option_error(dc("simulate", "pile", *option, "-o", out), option[0], "--engine box2d3")
    option_error(dc("simulate", "pile", "--engine", "box2d3", "--iterations", "20", "-o", out), "--iterations")
    option_error(dc("simulate", "pile", "--engine", "box2d3", "--solver", "pgs", "-o", out), "--solver")
    option_error(dc("simulate", "pile", "--engine", "box2d3", "--substeps", "0", "-o", out), "--substeps")
    assert not Path(out).exists()


def test_substeps_and_tuning_reach_the_engine(tmp_path):
    out = written(tmp_path / "run", "simulate", *V3_PILE[:-1], "20", "--substeps", "2", "--contact-hertz", "60",
                  "--push-speed", "1.5")
    header = read_step(next(out.glob("seed-*/step-000010.xml")))[0]
    assert header["soft_step"]["substeps"] == "2" and header["soft_step"]["contact_hertz"] == "60"
    assert header["soft_step"]["push_speed"] == "1.5"
    import json
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["engine"] == "box2d3" and manifest["soft_step"]["substeps"] == 2
    # the same seed and settings, the same bytes
    again = written(tmp_path / "again", "simulate", *V3_PILE[:-1], "20", "--substeps", "2", "--contact-hertz", "60",
                    "--push-speed", "1.5")
    for f in sorted(out.glob("seed-*/step-*.xml")):
        assert f.read_bytes() == (again / f.relative_to(out)).read_bytes()


def test_replay_and_evaluate_refuse_a_v3_run_in_one_line(v3_run, tmp_path):
    one_line_error(dc("validate", "--replay", v3_run), "Box2D v3", "2.4.1's contact problem")
    one_line_error(dc("evaluate", "--no-plots", v3_run, "-o", tmp_path / "e"), "Box2D v3", "2.4.1's contact problem")
    from deepcontact.errors import InputError
    from deepcontact.solver.problem import StepProblem
    with pytest.raises(InputError, match="soft step"):
        StepProblem.from_step_file(sorted(v3_run.glob("seed-*/step-*.xml"))[-1])


def test_a_v3_runs_table_holds_v3s_columns_not_2_4_1s(v3_run, pile_run, tmp_path):
    from deepcontact import run_tables
    _, v3 = run_tables(v3_run)
    _, old = run_tables(pile_run)
    assert {"total_normal_impulse", "anchor_a_x", "anchor_b_y"} <= set(v3) and "start_normal_impulse" not in v3
    assert "manifold_type" not in v3 and "local_normal_x" not in v3
    assert {"start_normal_impulse", "manifold_type"} <= set(old) and "total_normal_impulse" not in old
    one_line_error(dc("export", v3_run, "-o", tmp_path / "fclib"), "Box2D v3")   # (FCLIB: a 2.4.1 problem)


def test_a_v3_run_rasterizes_trains_and_renders(v3_run, tmp_path):
    data = written(tmp_path / "data", "rasterize", v3_run, "--cell", "1")
    assert dc("train", data, "--epochs", "1", "--batch-size", "8", "--no-plots", "-q", "-o", tmp_path / "m").returncode == 0
    for picture in ("step.png", "run.gif"):
        source = sorted(v3_run.glob("seed-*/step-*.xml"))[-1] if picture == "step.png" else v3_run
        r = dc("render", source, "--every", "20", "-o", tmp_path / picture) if picture == "run.gif" else \
            dc("render", source, "-o", tmp_path / picture)
        assert r.returncode == 0 and (tmp_path / picture).stat().st_size > 1000, r.stderr


def test_a_thin_card_builds_in_v3_as_a_box():
    """v3's hull welds vertices closer than 5 mm: a 4 mm card is made as a box instead (with the
    polygon skin both engines give it), weighs what 2.4.1 says and lies on the ground where the
    skins touch."""
    world = _box2d.World3(0.0, -10.0)
    ground = world.add_body(0, 0.0, 0.0)
    world.add_edge(ground, -5.0, 0.0, 5.0, 0.0, friction=0.7)
    skin = _box2d.polygon_radius
    card = world.add_body(2, 0.0, 0.002 + 2 * skin)
    world.add_polygon(card, np.array([[-0.5, -0.002], [0.5, -0.002], [0.5, 0.002], [-0.5, 0.002]], np.float32),
                      density=1.0, friction=0.7)
    w2 = _box2d.World(0.0, -10.0)
    w2.add_body(2, 0.0, 0.0)
    w2.add_polygon(0, np.array([[-0.5, -0.002], [0.5, -0.002], [0.5, 0.002], [-0.5, 0.002]], np.float32), density=1.0)
    for key in ("mass", "inertia"):
        assert world.bodies()[key][card] == pytest.approx(w2.bodies()[key][0], rel=1e-5)   # the skin weighs nothing
    for _ in range(60):
        world.step(1 / 60)
    assert world.bodies()["position"][card, 1] == pytest.approx(0.002 + 2 * skin, abs=1e-3)


# --- dc study engines ----------------------------------------------------------------------------

def test_the_engines_study_writes_its_tables_and_plots(tmp_path):
    from dcstudies import engines as E
    out = tmp_path / "engines"
    families = ("Box2D 2.4.1", "Box2D v3", "pymunk", "MuJoCo Newton", "project", "lagged")
    r = dc("study", "engines", "--fast", "--scenes", "stack 8,bullet", "--families", ",".join(families), "-q", "-o", out)
    assert r.returncode == 0, r.stderr
    written_files = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))   # (and its record)
    assert written_files == ["engines.csv", "engines.md", "pareto-bullet.png", "pareto-stack-8.png"]
    import csv
    rows = list(csv.DictReader((out / "engines.csv").open()))
    stack = [row for row in rows if row["scene"] == "stack 8"]
    assert {row["family"] for row in stack} == set(families)
    assert len(stack) == len(E.settings(families, fast=True))
    bullet = [row for row in rows if row["scene"] == "bullet"]
    # (ours cannot drive a bullet; every engine steps it)
    assert {row["family"] for row in bullet} == {"Box2D 2.4.1", "Box2D v3", "pymunk", "MuJoCo Newton"}
    assert all(row["drift"] == "nan" for row in bullet)                       # (no reference either)
    for row in stack:
        assert float(row["ms_per_step"]) > 0 and row["finite"] == "True"
    # the reference's own family converges onto it; 2.4.1 gets closer with iterations
    project = {row["setting"]: float(row["drift"]) for row in stack if row["family"] == "project"}
    assert project["residual 1e-08"] < project["residual 0.01"] < 0.01
    box2d = [float(row["drift"]) for row in stack if row["family"] == "Box2D 2.4.1"]
    assert box2d[-1] < box2d[0] / 100
    text = (out / "engines.md").read_text()
    # (which passing setting is cheapest is a matter of measured time: not asserted here)
    verdict = (r"\| stack 8 \| 64 iterations: [0-9.e-]+ ms \| none up to 4 substeps \| "
               r"none up to 10 iterations \| none up to tolerance 1e-08 \| residual ")
    assert re.search(verdict, text) and re.search(verdict, r.stdout), text
    assert "![stack 8](pareto-stack-8.png)" in text and "Measured with" in text


def test_the_cheapest_passing_setting_of_each_family():
    from dcstudies import engines as E

    def row(family, setting, passed, ms, variant=False):
        return E.Row("s", family, setting, passed, True, ms, 0.1, 0.0, 0.0, 0.0, 1.0, float("nan"), 0.0, 0,
                     variant)
    rows = [row("Box2D 2.4.1", "1 iterations", False, 0.1), row("Box2D 2.4.1", "2 iterations", True, 0.3),
            row("Box2D 2.4.1", "4 iterations", True, 0.2),   # (cheaper though more effort: it wins)
            row("Box2D 2.4.1", "8 iterations", True, 0.199),  # (within 5%: a tie, to the least effort)
            row("Box2D v3", "1 substeps", False, 0.1), row("Box2D v3", "16 substeps", False, 0.9),
            row("Box2D v3", "4 substeps, no warm start", True, 0.05, variant=True)]
    best = E.cheapest(rows)
    assert best["Box2D 2.4.1"].setting == "4 iterations"
    assert best["Box2D v3"] is None and "project" not in best       # an ablation is no candidate
    table = E.verdict_table(rows)   # a column per family run
    assert table.startswith("| scene | Box2D 2.4.1 | Box2D v3 |\n")
    assert "| s | 4 iterations: 0.2 ms | none up to 16 substeps |\n" in table
    other = [E.Row("t", "project", "residual 0.01", True, True, 0.5, 0.1, 0.0, 0.0, 0.0, 1.0, float("nan"), 0.0, 0)]
    table = E.verdict_table(rows + other)   # a family that does not apply to a scene: n/a
    assert "| s | 4 iterations: 0.2 ms | none up to 16 substeps | n/a |" in table
    assert "| t | n/a | n/a | residual 0.01: 0.5 ms |" in table


def test_the_engines_study_refuses_an_unknown_scene(tmp_path):
    option_error(dc("study", "engines", "--fast", "--scenes", "stack 99", "-o", tmp_path / "x"), "--scenes",
                 "stack 8")
    assert not (tmp_path / "x").exists()


def test_resting_contacts_start_where_each_engine_rests_them():
    """2.4.1 rests skins one linear slop into each other (the generators' default); v3 pushes any
    overlap out and rests them touching (overlap 0), so the studies start v3 there."""
    from dcstudies import stability as S
    skin, slop = _box2d.polygon_radius, _box2d.linear_slop
    for overlap, gap in ((None, 2 * skin - slop), (0.0, 2 * skin)):
        scene = generate("stack", 0, {"count": 3} if overlap is None else {"count": 3, "overlap": overlap})
        ys = [b.y for b in scene.bodies[1:]]
        assert ys[0] == pytest.approx(gap + 0.5, abs=1e-6) and np.diff(ys) == pytest.approx([1 + gap] * 2, abs=1e-6)
    case = S.Case("stack 3", "stack", {"count": 3, "steps": 120}, stack_top=True)
    assert S.own_rest(case, "box2d3") == {"count": 3, "steps": 120, "overlap": 0.0}
    assert S.own_rest(case, "box2d") == case.params and S.own_rest(S.Case("p", "pile", {}), "box2d3") == {}
    own = S.run_case(case, "box2d3", "builtin", 4)
    lifted = S.run_case(case, "box2d3", "builtin", 4, params=case.params)   # from 2.4.1's rest
    assert own.energy_rise < 0.01 < lifted.energy_rise


def test_the_soft_steps_defaults_are_v3s_own_and_the_help_prints_them():
    """SoftStep's defaults come from Box2D v3's library (b2DefaultWorldDef), not a copy: 3.1's are
    30 Hz, a damping ratio of 10 and 3 m/s, at the 4 substeps its samples step; `dc simulate
    --help` prints what the library says."""
    from deepcontact.simulate.engines import soft_step_defaults
    native = _box2d.soft_step_defaults()
    assert native == {"substeps": 4, "contact_hertz": 30.0, "damping_ratio": 10.0, "push_speed": 3.0}
    assert SoftStep() == SoftStep(**native) == SoftStep(**soft_step_defaults())
    assert SoftStep(substeps=8).contact_hertz == native["contact_hertz"]
    text = " ".join(dc("simulate", "--help").stdout.split()).split("Options:", 1)[1]
    for flag, name in (("--substeps", "substeps"), ("--contact-hertz", "contact_hertz"),
                       ("--damping-ratio", "damping_ratio"), ("--push-speed", "push_speed")):
        assert f"(default {native[name]:g}: Box2D v3's own)" in text.split(flag, 1)[1].split(" --", 1)[0], flag
