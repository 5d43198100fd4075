"""A long study keeps each unit of work it finishes (deepcontact/studies/units.py): stopped by the
user's signal, it publishes nothing and keeps its finished units beside its output; the same
command with --resume measures only the rest, and writes what the uninterrupted run writes
(timings apart); a changed option reuses nothing it does not decide alike."""
import csv
import math
import os
import signal
import subprocess
import time

import pytest

from conftest import dc, dc_command, one_line_error
from deepcontact.contest import fences
from deepcontact.studies import units

pytestmark = pytest.mark.skipif(not all(fences().values()), reason=f"a fence is missing here: {fences()}")

ENGINES = ["study", "engines", "--fast", "--scenes", "stack 8", "--families", "Box2D 2.4.1,pymunk,project"]
FRONTIER = ["study", "frontier", "--fast", "--scenes", "pyramid 5", "--families", "Box2D 2.4.1,PGS"]


def units_of(out):
    """{name: (inode, mtime)} of the unit files kept beside the output out."""
    folder = out.parent / f".{out.name}.units"
    return {n: (os.stat(folder / n).st_ino, os.stat(folder / n).st_mtime_ns) for n in units.units_in(folder)}


def stopped(args, out, at_least):
    """`dc ARGS -o OUT` stopped by SIGTERM once it has kept at_least units; its standard error."""
    p = subprocess.Popen([*dc_command(), *args, "-q", "-o", str(out)], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while len(units_of(out)) < at_least and p.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    p.send_signal(signal.SIGTERM)
    err = p.communicate(timeout=60)[1]
    assert p.returncode == 128 + signal.SIGTERM, f"it ended before its stop ({p.returncode}): {err}"
    return err


def measures(out, name):
    """The rows of a study's CSV without their times (a unit kept keeps the times it was measured with)."""
    with open(out / name) as f:
        return [{k: v for k, v in row.items() if k != "ms_per_step"} for row in csv.DictReader(f)]


def same_code(run):
    """run() while the code that keys the units stays as it is (other work on this tree may change
    it meanwhile: then the units are rightly measured again, and the check is made again)."""
    import dcstudies
    for _ in range(3):
        before = units.code_hash([dcstudies])
        result = run()
        if units.code_hash([dcstudies]) == before:
            return result
    pytest.skip("the code changed under every try (another edit of this working tree)")


def test_a_stopped_study_resumes_its_finished_units_to_the_uninterrupted_output(tmp_path):
    whole = tmp_path / "whole"
    r = dc(*ENGINES, "-q", "-o", whole)
    assert r.returncode == 0, r.stderr
    assert not (tmp_path / ".whole.units").exists()   # (published whole: its units have served)
    total = len(measures(whole, "engines.csv"))

    def cycle():
        part = tmp_path / "part"
        err = stopped(ENGINES, part, 3)
        kept = units_of(part)
        assert 3 <= len(kept) < total and not part.exists(), err   # (nothing published)
        assert "finished unit" in err and "--resume" in err, err
        # without --resume a run refuses to start over them, and keeps them
        one_line_error(dc(*ENGINES, "-o", part), "--resume reuses those measured with the same options")
        assert units_of(part) == kept
        r = dc(*ENGINES, "-o", part, "--resume")
        return r, kept, part
    r, kept, part = same_code(cycle)
    assert r.returncode == 0, r.stderr
    assert f"kept units: {len(kept)} units reused, {total - len(kept)} units measured now" in r.stderr, r.stderr
    assert measures(part, "engines.csv") == measures(whole, "engines.csv")
    assert sorted(p.name for p in part.iterdir()) == sorted(p.name for p in whole.iterdir())
    assert not (tmp_path / ".part.units").exists()


def test_a_changed_option_reuses_no_unit_it_changes(tmp_path):
    """frontier's --samples decides every row's one-step measures: a stop at --samples 2 resumed
    at --samples 1 measures every row again, and writes what a run at --samples 1 writes; --overwrite
    without --resume starts over, removing the kept units."""
    def cycle():
        out = tmp_path / "frontier"
        stopped([*FRONTIER, "--samples", "2"], out, 2)
        kept = len(units_of(out))
        return dc(*FRONTIER, "--samples", "1", "-o", out, "--resume"), kept, out
    r, kept, out = same_code(cycle)
    assert r.returncode == 0, r.stderr
    assert "kept units: 0 units reused" in r.stderr and f"the other {kept} kept" in r.stderr, r.stderr
    fresh = tmp_path / "fresh"
    assert dc(*FRONTIER, "--samples", "1", "-q", "-o", fresh).returncode == 0
    assert measures(out, "frontier.csv") == measures(fresh, "frontier.csv")
    again = tmp_path / "again"
    stopped(FRONTIER, again, 1)
    r = dc(*FRONTIER, "-o", again, "--overwrite")
    assert r.returncode == 0 and "reused" not in r.stderr, r.stderr
    assert not (tmp_path / ".again.units").exists()


def test_resume_needs_the_output_a_stopped_run_wrote_to():
    r = dc("study", "stability", "--fast", "--scenes", "bullet", "--resume")
    assert r.returncode == 2 and "give the output (-o)" in r.stderr, r.stderr


def test_a_stopped_stability_study_reuses_the_runs_it_finished(tmp_path, monkeypatch):
    """The stability study's units are its runs (a configuration at one count): a study stopped by
    its caller after its first row keeps that row's runs, and the resumed study reuses them and
    gives the rows of a study never stopped."""
    from dcstudies import stability as S
    case = next(c for c in S.FAST if c.label == "stack 8")
    configs = [("box2d", "builtin", 1.0, "none"), ("pgs", "builtin", 1.0, "none")]
    whole = S.study([case], configs)
    monkeypatch.setenv(units.ENV, str(tmp_path))

    def stop(row):
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt), units.keeping("study stability"):
        S.study([case], configs, log=stop)
    first = len(units.units_in(tmp_path))
    default, found = whole[0]   # (its runs: the default count, doubled up to the passing one)
    assert first == 1 + int(math.log2(found.iterations // default.iterations)) and first > 1
    with units.keeping("study stability", resume=True) as journal:
        resumed = S.study([case], configs)
    assert journal.tally()["reused"] == first and journal.tally()["measured"] > 0
    strip = [[{k: v for k, v in vars(r).items() if k != "seconds"} for r in pair] for pair in whole]
    assert [[{k: v for k, v in vars(r).items() if k != "seconds"} for r in pair] for pair in resumed] == strip


def test_a_link_where_the_units_are_kept_is_refused_before_the_study_runs(tmp_path):
    """The units folder is written by the fenced study: a link planted in its place (to a folder of
    the user's) is refused, never made writable or followed."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (tmp_path / ".out.units").symlink_to(mine)
    one_line_error(dc(*ENGINES, "-o", tmp_path / "out"), ".out.units beside it", "is not a folder")
    assert list(mine.iterdir()) == [] and not (tmp_path / "out").exists()
