"""Reports that answer at a glance: a verdict line naming the fastest fair start and its ratio to
Box2D's warm start, 'vs builtin' columns, no column of zeros, oracles marked; the closed loop's
summary.csv and its caveat on chaotic drift."""
import csv
import json

from test_mutations import invoke


def test_the_replay_report_opens_with_a_verdict_and_compares_with_builtin(run, tmp_path):
    r = invoke("evaluate", run, "--starts", "zero,builtin,prev,copy", "--every", "20", "--no-budgets", "-q",
               "-o", tmp_path / "r")
    assert r.exit_code == 0, r.stderr
    text = (tmp_path / "r" / "report.md").read_text()
    lines = text.splitlines()
    assert lines[2].startswith("**Verdict**: the fastest start to the tolerance") and "copy" not in lines[2], lines[2]
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())["starts"]
    fair = {k: v for k, v in summary.items() if k != "copy"}
    best = min(fair, key=lambda k: (fair[k]["at_cap"], fair[k]["total_ms_median"]))
    assert f"**{best}**" in lines[2]
    header = next(line for line in lines if line.startswith("| start |"))
    assert "sweeps vs builtin" in header and "time vs builtin" in header
    assert "factorizations" not in header and "w fell back" not in header   # all zero here: not shown
    row = next(line for line in lines if line.startswith("| builtin |"))
    assert "| 1.00x | 1.00x |" in row
    assert "| copy (oracle) |" in text


def test_columns_appear_when_they_carry_something(run, tmp_path):
    r = invoke("evaluate", run, "--starts", "builtin", "--accelerate", "none,newton", "--every", "20",
               "--no-budgets", "-q", "-o", tmp_path / "r")
    assert r.exit_code == 0, r.stderr
    header = next(line for line in (tmp_path / "r" / "report.md").read_text().splitlines()
                  if line.startswith("| start |"))
    assert "factorizations" in header


def test_the_closed_loop_writes_a_summary_table_and_says_drift_is_chaotic(run, tmp_path):
    r = invoke("evaluate", run, "--closed-loop", "--starts", "builtin,prev", "--steps", "20", "--no-budgets", "-q",
               "-o", tmp_path / "loop")
    assert r.exit_code == 0, r.stderr
    with open(tmp_path / "loop" / "summary.csv") as f:
        rows = list(csv.DictReader(f))
    assert [row["start"] for row in rows][:2] == ["builtin", "prev"] or len(rows) == 6
    assert all(float(row["ms_per_step_median"]) > 0 for row in rows)
    assert "A pile is chaotic" in (tmp_path / "loop" / "closed-loop.md").read_text()


def test_training_shows_the_predict_zero_bar_and_warns_of_an_empty_split(run, dataset, tmp_path):
    r = invoke("train", dataset, "--epochs", "2", "--width", "4", "--depth", "2", "-o", tmp_path / "m")
    assert r.exit_code == 0, r.stderr
    assert "(0 scores " in r.stderr, r.stderr
    rows = json.loads((tmp_path / "m" / "metrics.json").read_text())
    assert rows[0]["val_zero_rmse_normal"] == rows[1]["val_zero_rmse_normal"] > 0
    alone = tmp_path / "alone"
    assert invoke("rasterize", run, "--cell", "1", "--smoothing", "1", "--validation", "0", "-q",
                  "-o", alone).exit_code == 0
    r = invoke("train", alone, "--epochs", "1", "--width", "4", "--depth", "2", "-o", tmp_path / "m2")
    assert r.exit_code == 0 and "no validation samples" in r.stderr, r.stderr
