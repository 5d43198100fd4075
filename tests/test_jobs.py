"""Long work shows its progress per step, and -j changes how fast, never what: the same bytes
(pictures, exports, tables) and the same rows with any -j."""
import dataclasses
import filecmp

import pytest

from conftest import dc, one_line_error
from test_mutations import invoke


def test_replay_reports_progress_per_step_with_any_jobs(run):
    from deepcontact.evaluate.replay import evaluate
    from deepcontact.step.run_folder import read_run
    from deepcontact.warmstart import make_starts
    evaluated = sum(-(-len(s.files) // 40) for s in read_run(run).simulations)   # (each 40th step: the evaluated)
    for jobs in (1, 2):
        calls = []
        evaluate([run], make_starts(["builtin"]), every=40, progress=calls.append, jobs=jobs)
        assert sum(calls) == evaluated and len(calls) == evaluated, (jobs, len(calls))


def test_the_closed_loop_reports_progress_per_step(run):
    from deepcontact.evaluate.closed_loop import every_simulation, steps_stepped
    from deepcontact.evaluate.replay import box2d_run
    from deepcontact.scene.xml import read_scene
    from deepcontact.warmstart import make_starts
    scenes = [read_scene(s.scene_file()) for s in box2d_run(run).simulations]
    calls = []
    every_simulation(scenes, make_starts(["builtin", "zero"]), steps=12, progress=calls.append, jobs=2)
    assert sum(calls) == steps_stepped(scenes, 2, False, 12) == len(calls)


def same_tree(a, b, leave_out=()):
    compared = filecmp.dircmp(a, b, ignore=[".dc-output.json", *leave_out])
    assert not compared.left_only and not compared.right_only and not compared.diff_files, compared.report()
    for sub in compared.common_dirs:
        same_tree(a / sub, b / sub, leave_out)


@pytest.mark.parametrize("fmt", ["fclib", "csv"])
def test_an_export_is_the_same_bytes_with_any_jobs(run, tmp_path, fmt):
    for jobs in ("1", "2"):
        r = invoke("export", run, "--format", fmt, "--every", "15", "-j", jobs, "-q", "-o", tmp_path / jobs)
        assert r.exit_code == 0, r.stderr
    same_tree(tmp_path / "1", tmp_path / "2")


def test_study_figures_are_the_same_pictures_with_any_jobs(run, tmp_path):
    for jobs in ("1", "2"):
        r = invoke("study", "figures", run, "--every", "40", "-j", jobs, "-q", "-o", tmp_path / jobs)
        assert r.exit_code == 0, r.stderr
    out = tmp_path / "1"
    assert {p.name for p in out.iterdir()} == {"figures.md", ".dc-output.json"} | {
        f"fig-5.{k}.{e}" for k in (4, 5, 6, 7) for e in ("png", "svg")}
    assert "## fig-5.7" in (out / "figures.md").read_text()
    same_tree(out, tmp_path / "2", leave_out=["figures.md"])   # (its times are each run's own)
    tables = [[line.split("|")[1:4] for line in (tmp_path / j / "figures.md").read_text().splitlines()
               if line.startswith("| ") and "start" not in line] for j in "12"]
    assert tables[0] == tables[1]   # the starts and their sweeps
    (out / "mine.txt").write_text("mine")
    one_line_error(dc("study", "figures", str(run), "-o", str(out), "--overwrite"), out / "mine.txt",
                   "not written by dc study figures")


def test_a_movie_is_the_same_bytes_with_any_jobs(pile_run, tmp_path):
    for jobs in ("1", "2"):
        r = invoke("render", pile_run, "--every", "10", "--size", "200", "-j", jobs, "-q", "-o", tmp_path / f"{jobs}.gif")
        assert r.exit_code == 0, r.stderr
    assert (tmp_path / "1.gif").read_bytes() == (tmp_path / "2.gif").read_bytes()
    r = invoke("render", pile_run, "-j", "2", "-o", tmp_path / "v.html")
    assert r.exit_code == 2 and "-j" in r.stderr


def test_the_stability_study_is_the_same_rows_with_any_jobs_and_says_what_it_judged():
    from deepcontact.protocol import protocol, protocol_line
    from dcstudies import stability as S
    cases = [c for c in S.FAST if c.label in ("stack 8", "bullet")]
    configs = S.CONFIGS[:3]
    rows = {jobs: S.study(cases, configs, jobs=jobs) for jobs in (1, 2)}

    def judged(rs):
        return [tuple(dataclasses.replace(r, seconds=0.0) for r in pair) for pair in rs]
    assert repr(judged(rows[1])) == repr(judged(rows[2])) and len(rows[1]) == 4   # (bullet: Box2D only; nan != nan)
    text = S.markdown(rows[2], True, protocol_line(protocol(jobs=2)))
    lines = text.splitlines()
    assert lines[0] == "# Stability of the hard scenes: fast (the test suite's small variants)"
    assert "3 linear slops" in text and "recomputed" in text and "Measured with" in text and "deepcontact" in text
    assert sum(line.startswith("| stack 8 |") for line in lines) == 3
