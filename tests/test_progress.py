"""Every long run says how long, off a terminal (a log file, Make, CI): a first line on a clock,
whether or not a unit of work has finished, then what is done of a total that the count never
passes, the rate and the time left (cli/terminal.py's LineBar)."""
import re
import time

import pytest

from conftest import dc

from deepcontact.cli import terminal

LINE = re.compile(r"^dc (?P<desc>[^:]+): (?P<n>[\d,]+)/(?P<total>[\d,]+) (?P<unit>\w+)s \((?P<share>\d+)%\) ")


def counts(stderr, desc):
    """(done, total, share) of each progress line of `desc`, in order."""
    out = []
    for line in stderr.splitlines():
        m = LINE.match(line)
        if m and m["desc"] == desc:
            out.append((int(m["n"].replace(",", "")), int(m["total"].replace(",", "")), int(m["share"])))
    return out


def test_a_line_comes_on_the_clock_while_the_first_unit_is_still_running(capsys, monkeypatch):
    """The line came at the first update a period after the last: a first unit that took four
    minutes (dc study stability's) left the log silent for four minutes."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0.05")
    bar = terminal.LineBar(3, "setting", "study x")
    try:
        time.sleep(0.4)   # the first setting still running: no update
        first = capsys.readouterr().err.splitlines()
        assert first and first[0].startswith("dc study x: 0/3 settings (0%) so far in "), first
        assert first[0].endswith(", the first setting still running"), first
        bar.update(1)
        bar.update(1)
        time.sleep(0.3)
        later = capsys.readouterr().err.splitlines()
        assert later and later[-1].startswith("dc study x: 2/3 settings (66%) so far in ") and " left" in later[-1]
    finally:
        bar.close()
    assert capsys.readouterr().err.startswith("dc study x: 2/3 settings (66%) when it ended in ")
    time.sleep(0.2)
    assert capsys.readouterr().err == ""   # (the clock stops with the bar)


def test_the_count_and_its_share_never_pass_the_total(capsys, monkeypatch):
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")   # (a line at every update)
    bar = terminal.LineBar(2, "setting", "study x")
    for _ in range(5):
        bar.update(1)
    bar.close()
    lines = counts(capsys.readouterr().err, "study x")
    assert lines and all(n <= total == 2 and share <= 100 for n, total, share in lines), lines


def test_the_time_left_follows_the_work_where_units_differ(monkeypatch):
    """A setting of a 10,000-circle pile is not one of 40 boxes: weighed, two light units done in
    10 s say the other 98 parts of the work take about 8m10s, not another 10 s; one unit, or less
    than 1% of the work, gives no estimate (a study's first setting on a scene carries the scene's
    set-up: its reference solves)."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "1e9")
    bar = terminal.LineBar(4, "setting", "study x", work=100)
    bar.update(1, work=1)
    assert terminal.progress_line(bar, 10.0, done=False).endswith("(25%) so far in 10s, 10s a setting")
    bar.update(1, work=1)
    bar.close()
    assert terminal.progress_line(bar, 10.0, done=False).endswith("(50%) so far in 10s, 5s a setting, "
                                                                  "about 8m10s left")


def test_the_engines_study_counts_its_settings_and_nothing_else(tmp_path, monkeypatch):
    """It counted every step of its reference trajectories as well: "4,049/520 settings (779%)"
    after "about 14 s left". Each setting once, up to the total."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")
    r = dc("study", "engines", "--fast", "--scenes", "stack 8", "--families", "Box2D 2.4.1", "-o", tmp_path / "e")
    assert r.returncode == 0, r.stderr
    lines = counts(r.stderr, "study engines")
    total = lines[0][1]
    assert [n for n, _, _ in lines] == [*range(1, total + 1), total], r.stderr   # (the last: "done")


def test_the_stability_study_says_where_it_is(tmp_path, monkeypatch):
    """It said nothing until its first configuration had passed (4 minutes on the full scenes)."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")
    r = dc("study", "stability", "--fast", "--scenes", "stack 8", "-o", tmp_path / "s.md")
    assert r.returncode == 0, r.stderr
    lines = counts(r.stderr, "study stability")
    assert lines and lines[-1][0] == lines[-1][1] == len(lines) - 1, r.stderr


def test_validate_gives_its_total(run, monkeypatch):
    """Its lines had no total: "1,200 files so far"."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")
    r = dc("validate", run)
    assert r.returncode == 0, r.stderr
    files = len(list(run.rglob("*.xml")))
    lines = counts(r.stderr, "validate")
    assert lines and lines[-1][:2] == (files, files), r.stderr


def test_a_text_study_says_where_it_is(monkeypatch):
    """dc study scale, exact and peer said nothing until a table's row was measured (a settled
    10,000-circle pile: minutes)."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")
    r = dc("study", "scale", "--quick", "--sizes", "100", "--samples", "1", "--methods", "PGS")
    assert r.returncode == 0, r.stderr
    assert [n for n, _, _ in counts(r.stderr, "study scale")] == [1, 2, 2], r.stderr   # (from zero, warm; done)


def test_a_resumed_studys_kept_units_count_but_give_no_rate(tmp_path, monkeypatch, capsys):
    """A resumed study reads its kept units back in an instant: counted in its rate, 300 of 348
    settings "done" in a second would say the rest takes seconds. They are done before the run."""
    from dcstudies import stability as S
    from deepcontact.studies import units
    case = next(c for c in S.FAST if c.label == "stack 8")
    configs = [("box2d", "builtin", 1.0, "none"), ("pgs", "builtin", 1.0, "none")]
    monkeypatch.setenv(units.ENV, str(tmp_path))

    def stop(row):
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt), units.keeping("study stability"):
        S.study([case], configs, log=stop)   # (stopped after its first configuration)
    calls = []
    with units.keeping("study stability", resume=True):
        S.study([case], configs, progress=lambda *told: calls.append(told))
    assert calls == [(1, None, True), (1,)]   # (the first read back, the second measured)
    monkeypatch.setenv("DC_PROGRESS_EVERY", "1e9")
    bar = terminal.LineBar(100, "setting", "study x", work=100)
    bar.update(50, work=50, kept=True)
    bar.update(1, work=1)
    bar.update(1, work=1)
    bar.close()
    assert terminal.progress_line(bar, 10.0, done=False).endswith("(52%) so far in 10s, 5s a setting, "
                                                                  "about 4m00s left")


def test_a_bad_period_is_one_warning_naming_it_and_the_default(tmp_path, monkeypatch, caplog):
    """DC_PROGRESS_EVERY=abc, -1 or nan was silently the default: one warning line each (not one a
    bar) naming the variable and the period used."""
    monkeypatch.setattr(terminal, "_WARNED", set())
    for bad in ("abc", "-1", "nan"):
        monkeypatch.setenv("DC_PROGRESS_EVERY", bad)
        caplog.clear()
        assert terminal.progress_every() == terminal.PROGRESS_EVERY
        assert terminal.progress_every() == terminal.PROGRESS_EVERY
        said = [r.getMessage() for r in caplog.records if "DC_PROGRESS_EVERY" in r.getMessage()]
        assert said == [f"DC_PROGRESS_EVERY={bad} is not a number of seconds >= 0: a progress line every 30s "
                        "(the default) instead"], said
    monkeypatch.setenv("DC_PROGRESS_EVERY", "abc")
    monkeypatch.setattr(terminal, "_WARNED", set())   # (a command is its own process: said once in it)
    r = dc("simulate", "pile", "--param", "count=12", "--steps", "5", "-o", tmp_path / "run")
    assert r.returncode == 0, r.stderr
    assert [x for x in r.stderr.splitlines() if "DC_PROGRESS_EVERY" in x] == [
        "WARNING: DC_PROGRESS_EVERY=abc is not a number of seconds >= 0: a progress line every 30s (the default) "
        "instead"], r.stderr


def test_evaluate_counts_the_steps_it_evaluates(run, tmp_path, monkeypatch):
    """With --every 3 it counted every step file of the run (600) though a third were evaluated:
    the total is the every-th steps, each counted once."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")
    r = dc("evaluate", "--no-plots", run, "--starts", "zero", "--every", "7", "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    evaluated = sum(-(-len(list(sim.glob("*.xml"))) // 7) for sim in run.iterdir() if sim.is_dir())
    lines = counts(r.stderr, "evaluate")
    assert lines and {total for _, total, _ in lines} == {evaluated}, r.stderr
    assert [n for n, _, _ in lines] == [*range(1, evaluated + 1), evaluated], r.stderr   # (the last: "done")


def row(epoch, epochs):
    return {"epoch": epoch, "epochs": epochs, "train_loss": 1.0, "samples_per_second": 10.0}


def test_an_epochs_bar_says_no_more_once_the_epoch_ended(capsys, monkeypatch):
    """After "epoch 1 of 2: loss ..." came "epoch 1 of 2: 348/348 samples (100%) so far" on the
    clock while epoch 2 ran: the bar is closed with its epoch."""
    from deepcontact.cli.train import EpochLines
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0.05")
    lines = EpochLines(False, 2)
    try:
        lines.within(0, 0, 10)
        lines.within(0, 10, 10)
        lines.epoch(row(0, 2))
        capsys.readouterr()
        time.sleep(0.3)   # (epoch 2's first batch still running)
        assert capsys.readouterr().err == ""
    finally:
        lines.close()


def test_the_runs_time_left_counts_validation(monkeypatch):
    """"the run: at most 0s left" came before each epoch's validation: the time left leaves it out
    until one is timed ("plus validation"), then counts it in this epoch and every later one."""
    from deepcontact.cli.train import EpochLines
    monkeypatch.setenv("DC_PROGRESS_EVERY", "1e9")
    lines = EpochLines(False, 3)
    try:
        lines.within(0, 0, 10)
        assert lines.run_left(0, 5.0) == "; the run: about 15s left plus validation"   # (5 s a pass, 3 passes)
        lines.within(0, 10, 10)
        time.sleep(1.2)   # (the validation)
        lines.epoch(row(0, 3))
        assert lines.validation >= 1.2
        lines.within(1, 0, 10)
        lines.within(1, 5, 10)
        said = lines.run_left(1, 0.0)   # (the pass's end: its validation and a whole epoch left)
    finally:
        lines.close()
    m = re.fullmatch(r"; the run: about (\d+)s left, validation included", said)
    assert m and int(m[1]) >= 2, said


def test_training_says_its_first_line_before_its_first_batch_ends(dataset, tmp_path, monkeypatch):
    """With one batch an epoch nothing came until epoch 1's line (32 s): the bar was made after
    the first batch. Now each epoch's bar begins with its pass, so its clock runs from there."""
    monkeypatch.setenv("DC_PROGRESS_EVERY", "0")   # (a line at every heartbeat)
    r = dc("train", dataset, "-o", tmp_path / "m", "--epochs", "2", "--width", "4", "--depth", "2",
           "--batch-size", "4096", "--no-plots")
    assert r.returncode == 0, r.stderr
    for epoch in (1, 2):
        said = [x for x in r.stderr.splitlines() if x.startswith(f"dc train, epoch {epoch} of 2: ")]
        assert said and re.match(rf"dc train, epoch {epoch} of 2: 0/\d+ samples \(0%\) so far in \d+s, "
                                 r"the first sample still running", said[0]), r.stderr
