"""A long study keeps each unit of work it finishes (deepcontact/studies/units.py): stopped by the
user's signal, it publishes nothing and keeps its finished units beside its output; the same
command with --resume measures only the rest, and writes what the uninterrupted run writes
(timings apart); a changed option reuses nothing it does not decide alike.

The stopped and resumed runs run a copy of the code made for the module (`frozen`), as an
installed copy stays: a unit's key holds a hash of the code, and this working tree may be edited
by other work while a test runs (a unit measured by other code is rightly measured again)."""
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import ROOT, dc, dc_command, one_line_error
from deepcontact.contest import fences
from deepcontact.studies import units

pytestmark = pytest.mark.skipif(not all(fences().values()), reason=f"a fence is missing here: {fences()}")

ENGINES = ["study", "engines", "--fast", "--scenes", "stack 8", "--families", "Box2D 2.4.1,pymunk,project"]
FRONTIER = ["study", "frontier", "--fast", "--scenes", "pyramid 5", "--families", "Box2D 2.4.1,PGS"]
STABILITY = ["study", "stability", "--fast", "--scenes", "arch 5"]


@pytest.fixture(scope="module")
def frozen(tmp_path_factory):
    """The environment of a dc that imports a copy of deepcontact and the studies, laid out as
    installed (the cli and schemas inside the package), made once for the module."""
    import dcstudies
    import deepcontact
    copy = tmp_path_factory.mktemp("frozen")
    skip = shutil.ignore_patterns("__pycache__", "*.o", "build")
    shutil.copytree(Path(deepcontact.__file__).parent, copy / "deepcontact", ignore=skip)
    for name in ("cli", "schemas"):
        target = copy / "deepcontact" / name
        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(ROOT / name, target, ignore=skip)
    shutil.copytree(Path(dcstudies.__file__).parent, copy / "dcstudies", ignore=skip)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(copy), *filter(None, [os.environ.get("PYTHONPATH")])]))
    found = subprocess.run([sys.executable, "-c", "import deepcontact.cli, dcstudies; print(deepcontact.cli.__file__, "
                            "dcstudies.__file__)"], env=env, capture_output=True, text=True, cwd=copy)
    assert found.stdout.startswith(str(copy)) and f" {copy}" in found.stdout, found.stdout + found.stderr
    return env


def run(env, *args):
    """`dc ARGS` in a process of its own, with env, in a folder holding no package (`python -m`,
    as the fenced study is started, puts its folder first on the path)."""
    return subprocess.run([*dc_command(), *map(str, args)], env=env, capture_output=True, text=True, timeout=900,
                          cwd=Path(env["PYTHONPATH"].split(os.pathsep)[0]).parent)


def frozen_code(env):
    """The hash of the code the frozen copy measures with (what keys its units)."""
    return subprocess.run([sys.executable, "-c", "import dcstudies; from deepcontact.studies.units import code_hash; "
                           "print(code_hash([dcstudies]))"], env=env, capture_output=True, text=True, check=True,
                          cwd=Path(env["PYTHONPATH"].split(os.pathsep)[0]).parent).stdout.strip()


def units_of(out):
    """{name: (inode, mtime)} of the unit files kept beside the output out."""
    folder = out.parent / f".{out.name}.units"
    return {n: (os.stat(folder / n).st_ino, os.stat(folder / n).st_mtime_ns) for n in units.units_in(folder)}


def stopped(env, args, out, at_least):
    """`dc ARGS -o OUT` stopped by SIGTERM once it has kept at_least units; its standard error."""
    p = subprocess.Popen([*dc_command(), *args, "-q", "-o", str(out)], env=env, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, cwd=Path(env["PYTHONPATH"].split(os.pathsep)[0]).parent)
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


def test_a_stopped_study_resumes_its_finished_units_to_the_uninterrupted_output(frozen, tmp_path):
    whole, part = tmp_path / "whole", tmp_path / "part"
    r = run(frozen, *ENGINES, "-q", "-o", whole)
    assert r.returncode == 0, r.stderr
    assert not (tmp_path / ".whole.units").exists()   # (published whole: its units have served)
    total = len(measures(whole, "engines.csv"))
    err = stopped(frozen, ENGINES, part, 3)
    kept = units_of(part)
    assert 3 <= len(kept) < total and not part.exists(), err   # (nothing published)
    unit = json.loads((tmp_path / ".part.units" / next(iter(kept))).read_text())
    assert unit["key"]["code"] == frozen_code(frozen) and unit["key"]["study"] == "study engines"
    assert "finished unit" in err and "--resume" in err, err
    # without --resume a run refuses to start over them, and keeps them
    one_line_error(run(frozen, *ENGINES, "-o", part), "--resume reuses those measured with the same options")
    assert units_of(part) == kept
    r = run(frozen, *ENGINES, "-o", part, "--resume")
    assert r.returncode == 0, r.stderr
    assert f"kept units: {len(kept)} units reused, {total - len(kept)} units measured now" in r.stderr, r.stderr
    assert measures(part, "engines.csv") == measures(whole, "engines.csv")
    assert sorted(p.name for p in part.iterdir()) == sorted(p.name for p in whole.iterdir())
    assert not (tmp_path / ".part.units").exists()


def test_a_changed_option_reuses_no_unit_it_changes(frozen, tmp_path):
    """frontier's --samples decides every row's one-step measures: a stop at --samples 2 resumed
    at --samples 1 measures every row again, and writes what a run at --samples 1 writes; --overwrite
    without --resume starts over, removing the kept units."""
    out = tmp_path / "frontier"
    stopped(frozen, [*FRONTIER, "--samples", "2"], out, 2)
    kept = len(units_of(out))
    r = run(frozen, *FRONTIER, "--samples", "1", "-o", out, "--resume")
    assert r.returncode == 0, r.stderr
    assert "kept units: 0 units reused" in r.stderr and f"the other {kept} kept" in r.stderr, r.stderr
    fresh = tmp_path / "fresh"
    assert run(frozen, *FRONTIER, "--samples", "1", "-q", "-o", fresh).returncode == 0
    assert measures(out, "frontier.csv") == measures(fresh, "frontier.csv")
    again = tmp_path / "again"
    stopped(frozen, FRONTIER, again, 1)
    r = run(frozen, *FRONTIER, "-o", again, "--overwrite")
    assert r.returncode == 0 and "reused" not in r.stderr, r.stderr
    assert not (tmp_path / ".again.units").exists()


def test_resume_needs_the_output_a_stopped_run_wrote_to():
    r = dc("study", "stability", "--fast", "--scenes", "bullet", "--resume")
    assert r.returncode == 2 and "give the output (-o)" in r.stderr, r.stderr


def test_a_stopped_stability_study_reuses_the_runs_it_finished(frozen, tmp_path):
    """The stability study's units are its runs (a configuration at one count): stopped after some,
    the resumed study reuses them and writes the table of a study never stopped."""
    def table(path):
        return [line for line in path.read_text().splitlines() if line.startswith("| arch 5 |")]
    whole, part = tmp_path / "whole.md", tmp_path / "part.md"
    assert run(frozen, *STABILITY, "-q", "-o", whole).returncode == 0
    stopped(frozen, STABILITY, part, 4)
    kept = len(units_of(part))
    r = run(frozen, *STABILITY, "-o", part, "--resume")
    assert r.returncode == 0 and f"kept units: {kept} units reused" in r.stderr, r.stderr
    assert table(part) == table(whole) and len(table(whole)) > 1


def test_a_link_where_the_units_are_kept_is_refused_before_the_study_runs(tmp_path):
    """The units folder is written by the fenced study: a link planted in its place (to a folder of
    the user's) is refused, never made writable or followed."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (tmp_path / ".out.units").symlink_to(mine)
    one_line_error(dc(*ENGINES, "-o", tmp_path / "out"), ".out.units beside it", "is not a folder")
    assert list(mine.iterdir()) == [] and not (tmp_path / "out").exists()


def test_a_unit_timed_with_other_worker_processes_is_not_reused(tmp_path, monkeypatch, caplog):
    """A unit timed at -j 2 (its solves beside another process's) is measured again at -j 1, and
    reused at -j 2: the worker count is part of every unit's key."""
    monkeypatch.setenv(units.ENV, str(tmp_path))
    calls = []

    def measure():
        calls.append(1)
        return {"ms": float(len(calls))}
    with units.keeping("study engines", conditions={"jobs": 2}):
        assert units.kept({"setting": "PGS"}, measure) == {"ms": 1.0}
    with caplog.at_level("INFO", logger="deepcontact.studies"), units.keeping("study engines", resume=True,
                                                                              conditions={"jobs": 1}):
        assert units.kept({"setting": "PGS"}, measure) == {"ms": 2.0}
    assert "another number of worker processes (-j)" in caplog.text, caplog.text
    with units.keeping("study engines", resume=True, conditions={"jobs": 2}):
        assert units.kept({"setting": "PGS"}, measure) == {"ms": 1.0}
    assert len(calls) == 2
