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
    assert r.returncode == 1 and f'step-000010.xml:1:0: the step file\'s <solve {attribute}="{value}">' in r.stdout, r.stdout


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
