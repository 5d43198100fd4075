"""A run's records are checked, not trusted: every field of the manifest's record of the project's
solver and of its counts, and every step file's <solve>, for type, range and agreement with the
run (deepcontact/step/records.py). Each bad record is one line naming its file, exit 1."""
import json
import math
import shutil

import pytest

from conftest import dc, one_line_error

SMALL = ["--param", "count=12", "--param", "box=12", "--param", "sigma=2.5"]


@pytest.fixture(scope="module")
def pgs_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("records") / "run"
    r = dc("simulate", "pile", *SMALL, "--steps", "30", "--solver", "pgs", "--tolerance", "1e-4", "-q", "-o", out)
    assert r.returncode == 0, r.stderr
    return out


def edited(run, tmp_path, change):
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    change(manifest)
    (copy / "manifest.json").write_text(json.dumps(manifest))
    return copy


@pytest.mark.parametrize("key, value", [("tolerance", -1), ("tolerance", math.nan), ("tolerance", "1e-4"),
                                        ("tolerance", True), ("tolerance", 1e308), ("max_iterations", 0),
                                        ("max_iterations", 2.5), ("mode", "float16"), ("stop_on", "never"),
                                        ("relaxation", 2.0), ("accelerate", None)])
def test_a_manifest_pgs_record_out_of_range_is_refused(pgs_run, tmp_path, key, value):
    run = edited(pgs_run, tmp_path, lambda m: m["pgs"].__setitem__(key, value))
    r = dc("validate", "--residuals", run)
    assert r.returncode == 1 and "manifest.json" in r.stdout, (r.stdout, r.stderr)
    one_line_error(dc("rasterize", run, "-q", "-o", tmp_path / "g"), "manifest.json")


def test_a_builtin_run_names_no_method_that_is_not_built_in(pgs_run, tmp_path):
    run = edited(pgs_run, tmp_path, lambda m: m["pgs"].__setitem__("accelerate", "lagegd"))
    r = dc("validate", run)
    assert r.returncode == 1 and "no built-in method has that name" in r.stdout, r.stdout


@pytest.mark.parametrize("value", [-5, "many", 1e300, True])
def test_a_count_of_steps_above_the_tolerance_is_a_count(pgs_run, tmp_path, value):
    run = edited(pgs_run, tmp_path, lambda m: m["simulations"][0].__setitem__("above_tolerance", value))
    one_line_error(dc("rasterize", run, "-q", "-o", tmp_path / "g"), "manifest.json", "above_tolerance")
    assert not (tmp_path / "g").exists()


@pytest.mark.parametrize("attribute, value", [("accelerate", "lagegd"), ("origin", "plug-in"), ("mode", "float32"),
                                              ("tolerance", "1"), ("max_iterations", "7"), ("start", "zero")])
def test_a_step_files_solve_record_agrees_with_its_run(pgs_run, tmp_path, attribute, value):
    run = edited(pgs_run, tmp_path, lambda m: None)
    step = run / "seed-000000" / "step-000010.xml"
    text = step.read_text()
    import re
    changed = re.sub(rf'(<solve [^>]*\b{attribute}=")[^"]*"', rf'\g<1>{value}"', text, count=1)
    assert changed != text
    step.write_text(changed)
    r = dc("validate", run)
    line = solve_line_of(step)   # (the line of the <solve> that disagrees)
    assert r.returncode == 1 and f'step-000010.xml:{line}:0: the step file\'s <solve {attribute}="{value}">' in r.stdout, r.stdout


def solve_line_of(step):
    return next(n for n, text in enumerate(step.read_text().splitlines(), 1) if "<solve " in text)


def test_a_box2d_run_holds_no_solve_record(run, pgs_run, tmp_path):
    copy = tmp_path / "box2d"
    shutil.copytree(run, copy)
    donor = (pgs_run / "seed-000000" / "step-000010.xml").read_text()
    import re
    solve = re.search(r"<solve [^>]*/>", donor).group(0)
    step = sorted((copy / "seed-000000").glob("step-*.xml"))[10]
    text = step.read_text()
    assert "</header>" in text
    step.write_text(text.replace("</header>", f"{solve}</header>", 1))
    r = dc("validate", copy)
    assert r.returncode == 1 and "was not stepped by it" in r.stdout, r.stdout


def set_solve(step, attribute, value):
    """The step file with its <solve>'s `attribute` set to `value` (added where it has none, removed
    where value is None; kept where it is value already)."""
    import re
    text = step.read_text()
    if re.search(rf'<solve [^>]*\b{attribute}="', text):
        replacement = r"\g<1>" if value is None else rf'\g<1> {attribute}="{value}"'
        changed = re.sub(rf'(<solve [^>]*?)\s+{attribute}="[^"]*"', replacement, text, count=1)
    else:
        changed = text.replace("<solve ", f'<solve {attribute}="{value}" ', 1)
    step.write_text(changed)
    assert solve_of(step).get(attribute) == value


def solve_of(step):
    import re
    return dict(re.findall(r'(\w+)="([^"]*)"', re.search(r"<solve [^>]*/>", step.read_text()).group(0)))


@pytest.mark.parametrize("manifest_w, step_w, refused", [
    (1.0, "1.5", "<solve relaxation=\"1.5\"> disagrees with its run's manifest (1.0)"),
    (1.0, None, "<solve relaxation> disagrees with its run's manifest (1.0)"),
    ("auto", "2.5", "<solve> relaxation=\"2.5\" is not a w in (0, 2)"),
    (None, "1", "<solve relaxation=\"1\"> disagrees with its run's manifest (null: the method takes no w)"),
    ("auto", "1.3", None)])   # (a w tuned as the run went: any w in (0, 2))
def test_a_step_files_w_is_its_runs(pgs_run, tmp_path, manifest_w, step_w, refused):
    """The relaxation a step records was never held to its run's: a step swept with w = 1.5 in a
    run of w = 1 was valid."""
    run = edited(pgs_run, tmp_path, lambda m: m["pgs"].__setitem__("relaxation", manifest_w))
    step = run / "seed-000000" / "step-000010.xml"
    set_solve(step, "relaxation", step_w)
    for extra in ([], ["--residuals"]):
        r = dc("validate", *extra, run)
        if refused is None:
            assert r.returncode == 0 and ", 0 invalid" in r.stderr, (r.stdout, r.stderr)
            continue
        lines = r.stdout.strip().splitlines()   # (a manifest of no w: every step file disagrees)
        assert r.returncode == 1 and len(lines) == (1 if manifest_w is not None else 30), (r.stdout, r.stderr)
        mine = [line for line in lines if line.startswith(f"{step}:")]
        assert mine == [f"{step}:{solve_line_of(step)}:0: the step file's {refused}"], lines


@pytest.mark.parametrize("attribute, value, refused", [
    ("iterations", "past the cap", "is past its own cap, max_iterations="),
    ("max_iterations", "0", 'max_iterations="0" is not a whole number from 1 to'),
    ("relaxation", "3", 'relaxation="3" is not a w in (0, 2)'),
    ("mode", "float16", 'mode="float16" is not one of exact, float32, float64'),
    ("residual", "0.5", "sweeps with residual=\"0.5\", above its tolerance=\"1e-04\"")])
def test_a_step_files_solve_record_agrees_with_itself(pgs_run, tmp_path, attribute, value, refused):
    """What a <solve> says of itself holds, in its run and alone: at most its cap in sweeps (a step
    recording more was valid, and counted as stopped at the cap), a w in (0, 2), a mode the
    solver has, and a built-in method that stopped before its cap at its tolerance."""
    run = edited(pgs_run, tmp_path, lambda m: None)
    step = next(f for f in sorted(run.glob("seed-*/step-*.xml"))   # (one that stopped before its cap)
                if int(solve_of(f)["iterations"]) < int(solve_of(f)["max_iterations"]))
    if value == "past the cap":
        value = str(int(solve_of(step)["max_iterations"]) + 1)
    set_solve(step, attribute, value)
    for where in (run, step):   # (in its run and alone: the same line)
        r = dc("validate", where)
        lines = r.stdout.strip().splitlines()
        assert r.returncode == 1 and len(lines) == 1, (where, r.stdout, r.stderr)
        assert lines[0].startswith(f"{step}:{solve_line_of(step)}:0: the step file's <solve> ") and refused in lines[0], lines


@pytest.mark.parametrize("method", ["none", "nncg", "newton", "subspace", "bodyspace", "lagged"])
def test_a_builtin_method_at_its_default_tolerance_is_valid(tmp_path, method):
    """With no --tolerance (0) a global method stops at its own (1e-12), the sweeps at their cap:
    a run of each built-in method is valid, its residuals too (tolerance 0 was held to be 0, and
    every early stop of newton, subspace, bodyspace and lagged refused)."""
    out = tmp_path / "run"
    r = dc("simulate", "pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4", "--steps", "40",
           "--solver", "pgs", "--accelerate", method, "-q", "-o", out)   # (the global methods stop early)
    assert r.returncode == 0, r.stderr
    for flags in ([], ["--residuals"]):
        r = dc("validate", *flags, out)
        assert r.returncode == 0, (flags, r.stdout, r.stderr)
