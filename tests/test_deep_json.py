"""JSON dc reads back, however it is nested or typed: a manifest, a dataset's metadata, a
replacement journal, an output's record or a lock's notes nested 100,000 levels deep was
Python's RecursionError, which no reader caught (the catch-all's "the input is nested too deeply
to read", naming no file); a manifest field of another type than dc writes (a list as the solver's
name) was the catch-all's TypeError. Each is now one line naming the file and what is wrong, or,
for a control file that is only a claim, the claim not taken."""
import json
import shutil

import pytest

from conftest import dc, one_line_error

pytestmark = pytest.mark.audit

DEEP = "[" * 100_000 + "]" * 100_000   # (deeper than Python's parser recurses)
SHALLOW_BUT_DEEP = "[" * 100 + "]" * 100   # (the parser reads it; deeper than anything dc writes)


def copied_run(run, tmp_path, edit):
    """A copy of the shared run whose manifest is edit(its text)."""
    mine = tmp_path / "run"
    shutil.copytree(run, mine)
    path = mine / "manifest.json"
    path.write_text(edit(path.read_text()))
    return mine


@pytest.mark.parametrize("nested", [DEEP, '{"simulations": [], "params": ' + SHALLOW_BUT_DEEP + "}"],
                         ids=["100000-levels", "100-levels-in-a-field"])
def test_a_deeply_nested_manifest_is_one_line_naming_it(run, tmp_path, nested):
    mine = copied_run(run, tmp_path, lambda text: nested)
    for args in (["validate", mine], ["rasterize", mine, "-q", "-o", tmp_path / "data"],
                 ["evaluate", mine, "--starts", "builtin", "--no-plots", "-o", tmp_path / "report"]):
        r = dc(*args)
        said = r.stdout + r.stderr   # (dc validate says each file's verdict on stdout)
        assert "not a message of ours" not in one_line_error(r)
        assert "manifest.json" in said and "nested deeper than 64 levels" in said, (args[0], said[-400:])
    assert not (tmp_path / "data").exists() and not (tmp_path / "report").exists()


@pytest.mark.parametrize("field, value", [("solver", {}), ("scene", ["pile"]), ("engine", 5), ("dt", "0.01"),
                                          ("poses_box2d_problem", "yes"), ("params", []), ("compression", None)])
def test_a_manifest_field_of_another_type_is_one_line_naming_it(run, tmp_path, field, value):
    mine = copied_run(run, tmp_path, lambda text: json.dumps({**json.loads(text), field: value}))
    for args in (["validate", mine], ["evaluate", mine, "--starts", "builtin", "--no-plots", "-o", tmp_path / "r"]):
        r = dc(*args)
        said = r.stdout + r.stderr
        assert r.returncode == 1 and f"manifest's {field!r} must be" in said, (args[0], said[-400:])
        assert "not a message of ours" not in said


def test_a_deeply_nested_dataset_metadata_is_one_line_naming_it(dataset, tmp_path):
    mine = tmp_path / "data"
    shutil.copytree(dataset, mine)
    (mine / "metadata.json").write_text('{"grid": ' + DEEP + "}")
    r = dc("train", mine, "--epochs", "1", "-o", tmp_path / "model")
    assert r.returncode == 1 and "metadata.json" in one_line_error(r) and "nested deeper" in r.stderr, r.stderr[-400:]


def test_deeply_nested_control_files_are_claims_not_taken(tmp_path):
    """A journal nested deeply is refused naming it (nothing done); a record nested deeply is no
    record of ours (the folder is the user's, --overwrite refuses it); a lock's notes nested
    deeply are no notes (the run goes on)."""
    pile = ["pile", "--param", "count=5", "--param", "box=12", "--steps", "3", "-q"]
    (tmp_path / ".out.swap").write_text(DEEP)
    r = dc("simulate", *pile, "-o", tmp_path / "out")
    assert r.returncode == 1 and ".out.swap" in one_line_error(r) and "not one dc wrote" in r.stderr, r.stderr[-400:]
    (tmp_path / ".out.swap").unlink()
    (tmp_path / ".out.lock").write_text(DEEP)
    assert dc("simulate", *pile, "-o", tmp_path / "out").returncode == 0
    (tmp_path / "out" / ".dc-output.json").write_text(DEEP)
    r = dc("simulate", *pile, "--overwrite", "-o", tmp_path / "out")
    assert r.returncode == 1 and "not a message of ours" not in r.stderr and "out" in one_line_error(r), \
        r.stderr[-400:]
    assert (tmp_path / "out" / "manifest.json").exists()   # (the folder is left as it was)
