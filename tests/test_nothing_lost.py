"""Nothing lost, ever: tried as a hostile user would, through the real `dc`.

--overwrite replaces only what the command wrote; two commands never write one output; signals,
full disks and dying parents leave no partial output and no live worker; runaway sizes are
refused before anything is written; tampered or inconsistent input is one line naming the file,
and bad option values exit 2. (The property-based sweep over mutated files is
tests/test_mutations.py.)
"""
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from conftest import dc, dc_process, one_line_error, option_error, snapshot, wait_for
from deepcontact import output

PILE = ["pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5"]
TINY_TRAIN = ["--epochs", "1", "--width", "4", "--depth", "2", "--no-plots", "-q"]


def leftovers(parent):
    """What our commands leave beside their outputs when something goes wrong."""
    return sorted(p.name for p in Path(parent).iterdir() if p.name.startswith(".") and
                  (".partial-" in p.name or ".old-" in p.name or p.name.endswith(".lock")))


def copy(src, dst):
    shutil.copytree(src, dst)
    return dst


# --- --overwrite replaces only what the command wrote -------------------------------------------

def test_overwrite_refuses_a_dataset_folder_holding_user_files(run, dataset, tmp_path):
    mine = copy(dataset, tmp_path / "data")
    (mine / "src").mkdir()
    (mine / "src" / "main.py").write_text("print('mine')")
    (mine / "README").write_text("notes")
    before = snapshot(mine)
    r = dc("rasterize", str(run), "-o", str(mine), "--overwrite", "--cell", "1", "--smoothing", "1")
    one_line_error(r, mine / "README", "not written by dc rasterize")
    (mine / "README").unlink()
    r = dc("rasterize", str(run), "-o", str(mine), "--overwrite", "--cell", "1", "--smoothing", "1")
    one_line_error(r, mine / "src", "not written by dc rasterize")
    assert snapshot(mine) == {k: v for k, v in before.items() if k != "README"}
    assert leftovers(tmp_path) == []


def test_overwrite_refuses_report_and_training_folders_with_foreign_files(run, dataset, model, tmp_path):
    report = tmp_path / "report"
    assert dc("evaluate", "--no-plots", str(run), "--starts", "builtin", "--every", "40", "--no-budgets", "-q",
              "-o", str(report)).returncode == 0
    (report / "analysis.ipynb").write_text("{}")
    r = dc("evaluate", "--no-plots", str(run), "--starts", "builtin", "--every", "40", "--overwrite", "-q", "-o",
           str(report))
    one_line_error(r, report / "analysis.ipynb", "not written by dc evaluate")
    assert (report / "analysis.ipynb").exists() and (report / "report.md").exists()
    trained = copy(model, tmp_path / "model")
    (trained / "notes.txt").write_text("mine")
    r = dc("train", str(dataset), "-o", str(trained), "--overwrite", *TINY_TRAIN)
    one_line_error(r, trained / "notes.txt", "not written by dc train")
    assert (trained / "notes.txt").read_text() == "mine"
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("foreign", [".git/HEAD", "seed-000001/inputs.npy", "seed-000002/todo.txt"])
def test_simulate_overwrite_looks_at_hidden_files_and_inside_seed_folders(run, tmp_path, foreign):
    out = copy(run, tmp_path / "run")
    (out / foreign).parent.mkdir(exist_ok=True)
    (out / foreign).write_text("mine")
    before = snapshot(out)
    r = dc("simulate", *PILE, "--steps", "10", "--overwrite", "-q", "-o", str(out))
    # the first entry the run's record does not list: a new folder itself, else the file
    first = out / foreign if (out / foreign).parent.name == "seed-000001" else out / foreign.split("/")[0]
    one_line_error(r, "not written by dc simulate", first)
    assert snapshot(out) == before and leftovers(tmp_path) == []


def test_overwrite_replaces_a_folder_of_the_commands_own_files(run, tmp_path):
    out = copy(run, tmp_path / "run")
    r = dc("simulate", *PILE, "--steps", "10", "--overwrite", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "manifest.json").read_text())["simulations"][0]["steps"] == 10
    assert not (out / "seed-000001").exists() and leftovers(tmp_path) == []


@pytest.mark.parametrize("name", [".field-notes.tmp", "seed-000001/.labels-checked.tmp",
                                  "seed-000000/.step-000005.xml.999.tmp", ".dc-partial"])
def test_a_users_file_named_like_ours_is_never_taken_for_ours(run, tmp_path, name):
    out = copy(run, tmp_path / "run")
    (out / name).write_text("the user's own")
    r = dc("simulate", *PILE, "--steps", "10", "--overwrite", "-q", "-o", str(out))
    one_line_error(r, "not written by dc simulate", out / name)
    assert (out / name).read_text() == "the user's own"

def test_a_symlinked_output_is_refused_and_nothing_is_left_beside_it(run, dataset, tmp_path):
    real = copy(dataset, tmp_path / "real")
    link = tmp_path / "link"
    link.symlink_to(real)
    before = snapshot(real)
    r = dc("rasterize", str(run), "-o", str(link), "--overwrite", "--cell", "1", "--smoothing", "1")
    one_line_error(r, link, "symbolic link")
    r = dc("simulate", *PILE, "--steps", "5", "--overwrite", "-o", str(link))
    one_line_error(r, link, "symbolic link")
    assert link.is_symlink() and snapshot(real) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]


def test_leftovers_of_a_killed_run_are_cleared_by_the_next(run, tmp_path):
    out = tmp_path / "run"
    stale = tmp_path / ".run.partial-99999999-abc"    # a partial folder of ours: it holds our record
    (stale / "seed-000000").mkdir(parents=True)
    (stale / "seed-000000" / "step-000000.xml").write_text("<step/>")
    output.record.write_record(stale, "simulate", "partial")
    users = tmp_path / ".run.partial-12345"           # named like ours, but no record: the user's
    users.mkdir()
    (users / "notes.txt").write_text("mine")
    r = dc("simulate", *PILE, "--steps", "5", "-q", "-o", str(out))
    assert r.returncode == 0 and sorted(p.name for p in tmp_path.iterdir()) == [".run.partial-12345", "run"]
    assert (users / "notes.txt").read_text() == "mine"


def identity(folder):
    """A folder's [device, inode], as a journal dc wrote names it."""
    st = os.lstat(folder)
    return [st.st_dev, st.st_ino]


def test_a_replacement_killed_between_its_renames_is_undone_or_finished(run, tmp_path):
    # killed after the earlier output was moved aside, before the new one was in place: the next
    # command restores the earlier output (it is the only copy) and says so
    out = copy(run, tmp_path / "run")
    before = snapshot(out)
    old = tmp_path / ".run.old-4242-xyz"
    new = copy(run, tmp_path / ".run.partial-4242-abc")   # complete, but never swapped in
    os.replace(out, old)
    (tmp_path / ".run.swap").write_text(json.dumps({"old": old.name, "new": new.name, "old_id": identity(old),
                                                    "new_id": identity(new)}))
    r = dc("simulate", *PILE, "--steps", "5", "-o", str(out))
    assert r.returncode == 1 and "restored" in r.stderr and "not empty" in r.stderr, r.stderr
    assert snapshot(out) == before and leftovers(tmp_path) == [] and not (tmp_path / ".run.swap").exists()
    # killed after the new output was in place, while the old one was being removed: finished
    stale = copy(run, tmp_path / ".run.old-4343-xyz")
    (tmp_path / ".run.swap").write_text(json.dumps({"old": stale.name, "new": ".run.partial-4343-gone",
                                                    "old_id": identity(stale), "new_id": None}))
    r = dc("simulate", *PILE, "--steps", "5", "-o", str(out))
    assert r.returncode == 1 and not stale.exists() and snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_signal_during_the_swap_waits_for_it(run, tmp_path, monkeypatch):
    """SIGTERM delivered between the two renames of a replacement is raised only once the new
    output is in place: never a moment with neither."""
    from deepcontact import interrupts
    out = copy(run, tmp_path / "run")
    real_replace = os.replace

    def replace(src, dst, **kw):
        if Path(dst).name.startswith(".run.old-"):
            os.kill(os.getpid(), signal.SIGTERM)   # the handler runs now: the swap must hold it
            time.sleep(0.05)
        return real_replace(src, dst, **kw)
    saved = {s: signal.getsignal(s) for s in interrupts.STOP_SIGNALS}
    interrupts.install()
    monkeypatch.setattr(os, "replace", replace)
    try:
        with pytest.raises(interrupts.Terminated):
            with output.output_folder(out, output.Owned("run"), overwrite=True, command="simulate") as work:
                (work / "new.txt").write_text("new")
    finally:
        for s, h in saved.items():
            signal.signal(s, h)
    assert sorted(p.name for p in out.iterdir()) == [".dc-output.json", "new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"] and output.completed[-1] == out


def test_long_output_names_and_the_current_folder(run, tmp_path):
    name = "r" * 250    # legal, but .NAME.partial-PID would not be
    r = dc("simulate", *PILE, "--steps", "5", "-q", "-o", str(tmp_path / name))
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
    r = subprocess.run([sys.executable, "-m", "deepcontact.cli.main", "simulate", *PILE, "--steps", "5", "-o", "."],
                       cwd=tmp_path / name, capture_output=True, text=True)
    one_line_error(r, "the current folder")


def test_a_lock_file_that_is_a_symlink_is_not_followed(tmp_path):
    target = tmp_path / "elsewhere"
    (tmp_path / ".run.lock").symlink_to(target)
    r = dc("simulate", *PILE, "--steps", "5", "-o", str(tmp_path / "run"))
    one_line_error(r, "symbolic link")
    assert not target.exists() and not (tmp_path / "run").exists()


# --- one writer per output ---------------------------------------------------------------------

@contextmanager
def held(path):
    with output.locked(path):
        yield


def test_a_second_command_on_a_locked_output_refuses(run, dataset, tmp_path):
    for args, out in ((["rasterize", str(run), "--cell", "1", "--smoothing", "1"], tmp_path / "data"),
                      (["train", str(dataset), *TINY_TRAIN], tmp_path / "model"),
                      (["simulate", *PILE, "--steps", "5"], tmp_path / "run"),
                      (["evaluate", "--no-plots", str(run), "--starts", "builtin", "--every", "40"],
                       tmp_path / "report")):
        with held(out):
            r = dc(*args, "-o", str(out))
        one_line_error(r, out, "another dc command is writing this output")
        assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_two_trainings_into_one_folder_at_once(dataset, tmp_path):
    out = tmp_path / "m"
    first = start(["train", str(dataset), "-o", str(out), "--epochs", "100000", "--width", "4", "--depth", "2", "-q"],
                  tmp_path)
    wait_for(lambda: (out / "last.pt").exists())
    second = dc("train", str(dataset), "-o", str(out), "--epochs", "3", "--width", "4", "--depth", "2", "-q")
    one_line_error(second, out, "another dc command")
    first.send_signal(signal.SIGINT)
    assert first.wait(timeout=60) == 130
    # only the first training's files, whole: it can be resumed
    assert {p.name for p in out.iterdir()} <= {"last.pt", "best.pt", "metrics.csv", "metrics.json", output.RECORD}
    assert len(json.loads((out / "metrics.json").read_text())) >= 1
    assert leftovers(tmp_path) == []


# --- full disks ----------------------------------------------------------------------------------

@contextmanager
def small_disk(tmp_path, **options):
    """A tmpfs of the given size / inode count (root only: mount)."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small file system needs root")
    where = tmp_path / "disk"
    where.mkdir()
    opts = ",".join(f"{k}={v}" for k, v in options.items())
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(where)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


def test_a_disk_too_small_for_the_estimate_is_refused_before_writing(run, tmp_path):
    with small_disk(tmp_path, size="2m") as disk:
        r = dc("rasterize", str(run), "-o", str(disk / "data"), "--cell", "0.2", "--smoothing", "0.2")
        one_line_error(r, disk / "data", "on disk", "free there")
        r = dc("simulate", "pile", "--seeds", "0..3", "-o", str(disk / "run"))
        one_line_error(r, disk / "run", "on disk", "free there")
        r = dc("simulate", *PILE, "--steps", "10", "--max-disk", "0.0001", "-o", str(disk / "run"))
        one_line_error(r, "--max-disk")
        assert list(disk.iterdir()) == []


@pytest.mark.parametrize("inodes", [6, 8, 10])
def test_a_full_disk_while_writing_is_one_line_naming_the_file(run, tmp_path, inodes):
    # A file system out of inodes runs out of room after the estimate passed: the write fails.
    with small_disk(tmp_path, size="100m", nr_inodes=inodes) as disk:
        r = dc("rasterize", str(run), "-o", str(disk / "data"), "--cell", "1", "--smoothing", "1", "-q")
        line = one_line_error(r, "No space left on device")
        assert f"{disk / 'data'}/" in line and ".partial-" not in line
        r = dc("evaluate", str(run), "--starts", "builtin", "--every", "40", "-q", "-o", str(disk / "report"))
        line = one_line_error(r, "No space left on device")
        assert f"{disk / 'report'}" in line and ".partial-" not in line
        assert list(disk.iterdir()) == []


# --- signals and workers -------------------------------------------------------------------------

def start(args, cwd):
    return subprocess.Popen([sys.executable, "-m", "deepcontact.cli.main", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def children(pid):
    try:
        return [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def alive(pid):
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_leaves_the_earlier_output_and_no_partial_folder(run, dataset, model, tmp_path, sig):
    outputs = {"run": copy(run, tmp_path / "run"), "data": copy(dataset, tmp_path / "data"),
               "model": copy(model, tmp_path / "model")}
    commands = {"run": ["simulate", "pile", "--seeds", "0..40", "--overwrite", "-q", "-o", "run"],
                "data": ["rasterize", str(run), "--cell", "0.05", "--smoothing", "0.05", "--overwrite", "-q",
                         "-o", "data", "--max-memory", "20"],
                "model": ["train", "--no-plots", str(dataset), "--epochs", "500", "--width", "4", "--depth", "2",
                          "--overwrite", "-q", "-o", "model"]}
    for name, args in commands.items():
        before = snapshot(outputs[name])
        proc = start(args, tmp_path)
        wait_for(lambda: any(tmp_path.glob(f".{name}.partial-*/*")))
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 128 + sig, err
        assert "interrupted" in err and "Traceback" not in err
        assert snapshot(outputs[name]) == before, name
        assert leftovers(tmp_path) == [], name


@contextmanager
def stop_signals_handled():
    """dc's stop-signal handlers installed in this (test) process, and the test's own back after."""
    from deepcontact import interrupts
    saved = {s: signal.getsignal(s) for s in interrupts.STOP_SIGNALS}
    try:
        interrupts.install()
        yield interrupts
    finally:
        interrupts.uninstall()
        for s, handler in saved.items():
            signal.signal(s, handler)


def test_a_signal_inside_a_held_block_is_raised_as_it_is_left():
    """The mechanism behind the writer threads of dc simulate: a stop signal never unwinds the
    main thread out of a block that waits on locks shared with other threads."""
    with stop_signals_handled() as interrupts:
        finished = False
        with pytest.raises(interrupts.Terminated) as raised:
            with interrupts.held():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)          # the handler has run by now; nothing was raised here
                with interrupts.held():   # nested blocks: raised when the outermost is left
                    pass
                finished = True
        assert finished and raised.value.signum == signal.SIGTERM
        # the clean-up is not cut short: a second signal raises nothing (outside a plug-in's code)
        assert signal.getsignal(signal.SIGTERM) == interrupts._on_repeat
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
        interrupts.install()
        with pytest.raises(interrupts.Terminated):   # outside a held block: at once
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.05)
            raise AssertionError("not interrupted")


@pytest.mark.parametrize("in_place,owner,name", [(False, output.record, "write_record"), (True, output.InPlace, "__init__")])
def test_a_signal_while_the_output_folder_is_being_made_leaves_nothing(tmp_path, monkeypatch, in_place, owner, name):
    """The window between making the partial (or in-place) folder and owning it: a stop signal
    that lands while its record is written is raised, and the folder goes with it."""
    real = getattr(owner, name)

    def signalled(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)                  # the handler has run: the stop is pending, not raised
        return real(*args, **kwargs)
    monkeypatch.setattr(owner, name, signalled)
    with stop_signals_handled() as interrupts:
        with pytest.raises(interrupts.Terminated):
            with output.output_folder(tmp_path / "out", output.Owned("test output", [r"x"]), command="test",
                                      in_place=in_place):
                raise AssertionError("the block ran: the signal was lost")
    assert leftovers(tmp_path) == [] and not (tmp_path / "out").exists()


def test_a_signal_to_a_fresh_run_leaves_nothing(dataset, tmp_path):
    proc = start(["simulate", "pile", "--seeds", "0..40", "-q", "-o", "run"], tmp_path)
    wait_for(lambda: any(tmp_path.glob(".run.partial-*/seed-*/step-*.xml")))
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 143
    assert list(tmp_path.iterdir()) == []
    proc = start(["train", str(dataset), "--epochs", "500", "--width", "4", "--depth", "2", "-q", "-o", "m"],
                 tmp_path)
    wait_for(lambda: (tmp_path / ".m.lock").exists())
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 143
    # a training folder is written in place (so it can resume): only whole checkpoints, or nothing
    assert not (tmp_path / "m").exists() or {p.name for p in (tmp_path / "m").iterdir()} <= \
        {"last.pt", "best.pt", "metrics.csv", "metrics.json"}
    assert not [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")] and leftovers(tmp_path) == []


@pytest.mark.parametrize("command", ["simulate", "rasterize"])
def test_no_worker_outlives_the_command(run, tmp_path, command):
    args = {"simulate": ["simulate", "pile", "--seeds", "0..200", "-j", "2", "-q", "-o", "out"],
            "rasterize": ["rasterize", str(run), "--cell", "0.03", "--smoothing", "0.03", "-j", "2", "-q",
                          "-o", "out", "--max-memory", "20"]}[command]
    proc = start(args, tmp_path)
    wait_for(lambda: len(children(proc.pid)) >= 2)
    workers = children(proc.pid)
    proc.send_signal(signal.SIGTERM)   # (at once: on a quiet machine the small run's rasterizing ended within 0.5 s)
    assert proc.wait(timeout=60) == 143
    wait_for(lambda: not any(alive(w) for w in workers), seconds=10)
    time.sleep(0.5)
    assert list(tmp_path.iterdir()) == []   # and nothing written after the command exited


def test_the_reaper_kills_only_what_dc_started(tmp_path):
    """A job of the user's that dc inherits across exec (`sh -c 'job & exec dc ...'`) is the
    user's: dc neither kills it nor blames it on a plug-in at exit."""
    from conftest import dc_command
    command = " ".join(f"'{a}'" for a in [*map(str, dc_command()), "simulate", "pile", "--steps", "5", "-q", "-o",
                                          str(tmp_path / "out")])
    r = subprocess.run(["sh", "-c", f"sleep 300 >/dev/null 2>&1 & echo $! > {tmp_path / 'job'}; exec {command}"],
                       capture_output=True, text=True, timeout=120)
    job = int((tmp_path / "job").read_text())
    try:
        assert r.returncode == 0 and r.stderr == "", r.stderr
        assert alive(job)
    finally:
        os.kill(job, signal.SIGKILL)


# --- input that blocks or lies -------------------------------------------------------------------

def test_a_fifo_named_like_a_step_file_is_refused(run, tmp_path):
    bad = copy(run, tmp_path / "run")
    fifo = bad / "seed-000000" / "step-000999.xml"
    os.mkfifo(fifo)
    for args in (["validate", str(bad)], ["validate", str(fifo)], ["validate", "--replay", str(bad)],
                 ["rasterize", str(bad), "-o", str(tmp_path / "d")],
                 ["evaluate", "--no-plots", str(bad), "--starts", "builtin", "-o", str(tmp_path / "r")]):
        r = dc_process(*args, timeout=60)
        one_line_error(r, fifo, "not a regular file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_fifo_in_place_of_a_scene_or_checkpoint_is_refused(run, tmp_path):
    bad = copy(run, tmp_path / "run")
    scene = bad / "seed-000000" / "scene.xml"
    scene.unlink()
    os.mkfifo(scene)
    checkpoint = tmp_path / "model.pt"
    os.mkfifo(checkpoint)
    for args, fifo in ((["validate", str(scene)], scene), (["rasterize", str(bad), "-o", str(tmp_path / "d")], scene),
                       (["evaluate", "--no-plots", str(bad), "--closed-loop", "--starts", "builtin", "-o",
                         str(tmp_path / "r")], scene),
                       (["evaluate", "--no-plots", str(run), "--starts", "cnn", "--checkpoint", str(checkpoint), "-o",
                         str(tmp_path / "r")],
                        checkpoint)):
        one_line_error(dc_process(*args, timeout=60), fifo, "not a regular file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt", "run"]


def test_a_checkpoint_that_cannot_be_one_is_refused_by_the_settings_check(run, tmp_path):
    """EvaluateSettings.checked() refuses the path before anything imports torch to read it."""
    from deepcontact.errors import InputError
    from deepcontact.evaluate.command import EvaluateSettings
    fifo, text, folder = tmp_path / "fifo.pt", tmp_path / "text.pt", tmp_path / "folder.pt"
    os.mkfifo(fifo)
    text.write_text("not torch's")
    folder.mkdir()
    for path, needle in ((fifo, "not a regular file"), (text, "not a file torch.save writes"),
                         (folder, "a folder"), (tmp_path / "gone.pt", "no such checkpoint")):
        with pytest.raises(InputError, match=needle):
            EvaluateSettings(runs=[str(run)], starts=["cnn"], checkpoint=str(path)).checked()


def test_a_wrong_contacts_count_names_the_step_file(run, tmp_path):
    for count, needle in (("999", "but it holds"), ("0", 'count="0"> but it holds')):
        bad = copy(run, tmp_path / f"run{count}")
        step = sorted(bad.glob("seed-000000/step-*.xml"))[-1]
        text = step.read_text()
        start_ = text.index('<contacts count="')
        end = text.index('"', start_ + 17)
        step.write_text(text[:start_] + f'<contacts count="{count}' + text[end:])
        for args in (["rasterize", str(bad), "-o", str(tmp_path / "d")],
                     ["evaluate", "--no-plots", str(bad), "--starts", "builtin", "--every", "200", "-o",
                      str(tmp_path / "r")],
                     ["validate", "--replay", str(bad)]):
            one_line_error(dc(*args), step, needle)
    assert not (tmp_path / "d").exists() and not (tmp_path / "r").exists()


@pytest.mark.parametrize("pattern,value,needle", [
    (r'(<step [^>]*\bindex=")\d+', "abc", "<step index> must be a whole number"),
    (r'(<step [^>]*\bseed=")\d+', "x", "<step seed> must be a whole number"),
    (r'(<step [^>]*\bindex=")\d+', "99999999999", "must be between 0 and 2147483647"),
    (r'(<contact [^>]*\bmaster=")\d+', "99999999999", "out of range"),
])
def test_step_file_integers_are_checked_alike_by_the_schema_and_the_readers(run, tmp_path, pattern, value, needle):
    bad = copy(run, tmp_path / "run")
    step = sorted(bad.glob("seed-000000/step-*.xml"))[-1]
    text, n = re.subn(pattern, lambda m: m.group(1) + value, step.read_text(), count=1)
    assert n == 1
    step.write_text(text)
    r = dc("validate", str(step))
    assert r.returncode == 1 and "not a valid value of the atomic type 'count'" in r.stdout, r.stdout
    readers = [["evaluate", "--no-plots", str(bad), "--starts", "builtin", "--every", "200", "-o", str(tmp_path / "r")],
               ["validate", "--replay", str(bad)]]
    if "master" not in pattern:    # rasterizing reads no body numbers of contacts
        readers.append(["rasterize", str(bad), "-o", str(tmp_path / "d")])
    for args in readers:   # (read through the schema's table: the XSD's words, or the reader's own)
        line = one_line_error(dc(*args), step)
        assert needle in line or "is not a valid value of the atomic type 'count'" in line, line


def test_a_step_file_copied_from_another_simulation_is_refused(run, tmp_path):
    other = tmp_path / "other"
    assert dc("simulate", *PILE, "--steps", "120", "--seed", "7", "-q", "-o", str(other)).returncode == 0
    bad = copy(run, tmp_path / "run")
    step = sorted(bad.glob("seed-000000/step-*.xml"))[-1]
    shutil.copy(other / "seed-000007" / step.name, step)
    r = dc("validate", "-q", str(bad))
    assert r.returncode == 1 and "seed 7, but lies in a simulation of scene 'pile' seed 0" in r.stdout
    for args in (["rasterize", str(bad), "-o", str(tmp_path / "d")],
                 ["evaluate", "--no-plots", str(bad), "--starts", "builtin", "--every", "200", "-o",
                  str(tmp_path / "r")],
                 ["validate", "--replay", str(bad)]):
        one_line_error(dc(*args), step, "copied from another run")


def test_one_simulation_twice_is_refused(run, tmp_path):
    bad = copy(run, tmp_path / "run")
    manifest = json.loads((bad / "manifest.json").read_text())
    manifest["simulations"].append(dict(manifest["simulations"][0]))
    (bad / "manifest.json").write_text(json.dumps(manifest))
    one_line_error(dc("rasterize", str(bad), "-o", str(tmp_path / "d")), bad / "manifest.json", "same dir")
    one_line_error(dc("rasterize", str(run), str(run), "-o", str(tmp_path / "d")), run, "given twice")
    one_line_error(dc("evaluate", "--no-plots", str(run), str(run), "--starts", "builtin", "-o", str(tmp_path / "r")),
                   run, "given twice")
    assert not (tmp_path / "r").exists()
    assert not (tmp_path / "d").exists()


def test_a_grid_that_cannot_carry_a_value_is_refused(run, tmp_path):
    option_error(dc("rasterize", str(run), "--smoothing", "1e30", "-o", str(tmp_path / "d")), "float32 grid")
    assert not (tmp_path / "d").exists()


def test_a_dataset_names_its_runs_relative_to_itself(run, tmp_path):
    moved = tmp_path / "project"
    copy(run, moved / "runs" / "pile")
    r = subprocess.run([sys.executable, "-m", "deepcontact.cli.main", "rasterize", "runs/pile", "-o", "data/pile",
                        "--cell", "1", "--smoothing", "1", "--validation", "0.5", "-q"], cwd=moved,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    meta = json.loads((moved / "data" / "pile" / "metadata.json").read_text())
    assert meta["sources"][0]["run"] == "../../runs/pile" and meta["simulations"][0]["run"] == "../../runs/pile"
    shutil.move(moved, tmp_path / "elsewhere")   # the two move together
    r = dc("train", str(tmp_path / "elsewhere" / "data" / "pile"), "-o", str(tmp_path / "m"), "--loss", "solver",
           *TINY_TRAIN)
    assert r.returncode == 0, r.stderr


def test_a_scene_without_a_static_box_gets_a_window_around_its_bodies(tmp_path):
    run = tmp_path / "pyramid"
    assert dc("simulate", "pyramid", "--param", "base=4", "--steps", "30", "-q", "-o", str(run)).returncode == 0
    extent = json.loads((run / "manifest.json").read_text())["simulations"][0]["extent"]
    assert extent[0] == -40.0 and extent[2] == 40.0 and -0.5 < extent[1] < 0 and 3 < extent[3] < 5
    r = dc("rasterize", str(run), "-o", str(tmp_path / "d"))
    assert r.returncode == 0, r.stderr
    assert "where the bodies went over the runs" in r.stderr
    grid = json.loads((tmp_path / "d" / "metadata.json").read_text())["grid"]
    assert grid["x0"] < -40 and grid["y0"] < extent[1] and grid["y0"] + (grid["ny"] - 1) * grid["cell"] >= extent[3]
    from deepcontact.grid.dataset import GridDataset
    assert GridDataset(tmp_path / "d").arrays["inputs"][-1, 0].max() > 0    # the boxes' mass is on the grid


# --- runaway sizes --------------------------------------------------------------------------------

def test_runaway_sizes_are_refused_before_anything_is_written(dataset, tmp_path):
    out = tmp_path / "o"
    option_error(dc("simulate", *PILE, "--steps", "99999999999999999999", "-o", str(out)), "--steps")
    one_line_error(dc("simulate", *PILE, "--steps", "2000000000", "-o", str(out)), "GB on disk")
    one_line_error(dc_process("simulate", *PILE, "--seeds", "0..999999999", "-o", str(out), timeout=30), "GB on disk")
    for option in ("--iterations", "--max-iterations"):
        option_error(dc("simulate", *PILE, "--solver", "pgs", option, str(2 ** 31), "-o", str(out)), option)
    option_error(dc("train", "--no-plots", str(dataset), "--solver-sweeps", str(2 ** 31), "-o", str(out)),
                 "--solver-sweeps")
    option_error(dc("train", "--no-plots", str(dataset), "--width", "100000", "-o", str(out)), "--width")
    one_line_error(dc("train", "--no-plots", str(dataset), "--width", "4000", "--depth", "8", "-o", str(out)),
                   "GB of memory", "--max-memory")
    one_line_error(dc("train", "--no-plots", str(dataset), "--width", "64", "--max-memory", "0.01", "-o", str(out)),
                   "GB of memory")
    assert list(tmp_path.iterdir()) == []


def test_scene_files_are_held_to_the_generators_limits(tmp_path):
    scene = tmp_path / "s.xml"
    assert dc("simulate", *PILE, "--write-scene", str(scene)).returncode == 0
    text = scene.read_text()
    for pattern, value, needle in ((r'(<friction coefficient=")[^"]*', "1e20", "from 0 to 1e+09"),
                                   (r'(<friction coefficient=")[^"]*', "1e9", None),
                                   (r'(velocity_iterations=")\d+', str(2 ** 31), "not a valid value of the atomic type"),
                                   (r'(\bsteps=")\d+', "99999999999", "not a valid value of the atomic type")):
        changed, n = re.subn(pattern, lambda m: m.group(1) + value, text, count=1)
        assert n == 1
        (tmp_path / "bad.xml").write_text(changed)
        r = dc("simulate", str(tmp_path / "bad.xml"), "--steps", "2", "-q", "-o", str(tmp_path / "o"))
        if needle is None:   # the limit itself is allowed
            assert r.returncode == 0, r.stderr
            shutil.rmtree(tmp_path / "o")
            continue
        one_line_error(r, tmp_path / "bad.xml", needle)
    assert not (tmp_path / "o").exists()


# --- tampered datasets and checkpoints -------------------------------------------------------------

def tamper_array(dataset, tmp_path, name, change):
    bad = copy(dataset, tmp_path / "data")
    np.save(bad / f"{name}.npy", change(np.load(dataset / f"{name}.npy")))
    return bad


def tamper_metadata(dataset, tmp_path, change):
    bad = copy(dataset, tmp_path / "data")
    meta = json.loads((bad / "metadata.json").read_text())
    change(meta)
    (bad / "metadata.json").write_text(json.dumps(meta))
    return bad


@pytest.mark.parametrize("name,change,needle", [
    ("inputs", lambda a: a.astype(np.float64), "holds float64"),
    ("inputs", lambda a: a.astype(np.float16), "holds float16"),
    ("inputs", lambda a: a.astype(np.int16), "holds int16"),
    ("inputs", lambda a: a[:, :3], "the metadata implies"),
    ("contact_offsets", lambda a: a[:-3], "the metadata implies"),
    ("simulation", lambda a: a + 5, "names simulations outside"),
])
def test_a_dataset_array_that_does_not_fit_its_metadata_is_refused(dataset, tmp_path, name, change, needle):
    bad = tamper_array(dataset, tmp_path, name, change)
    one_line_error(dc("train", "--no-plots", str(bad), "-o", str(tmp_path / "m"), *TINY_TRAIN), bad / f"{name}.npy",
                   needle)
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize("change,needle", [
    (lambda m: m.__setitem__("split", "all"), "'split' must be a JSON object"),
    (lambda m: m["split"].__setitem__("train", ["0"]), "split 'train' must be a list"),
    (lambda m: m["split"].__setitem__("validation", [99]), "split 'validation' must be a list"),
    (lambda m: m.__setitem__("labels", "normal_impulse"), "'labels' must be a JSON list"),
    (lambda m: m.__setitem__("labels", [1, 2]), "list of channel names"),
])
def test_metadata_of_the_wrong_type_is_refused(dataset, tmp_path, change, needle):
    bad = tamper_metadata(dataset, tmp_path, change)
    one_line_error(dc("train", "--no-plots", str(bad), "-o", str(tmp_path / "m"), *TINY_TRAIN), bad / "metadata.json",
                   needle)


def test_a_nan_in_a_dataset_names_the_array_and_what_was_kept(dataset, tmp_path):
    def poison(a):
        a = a.copy()
        a[3, 0, 2, 2] = np.nan
        return a
    bad = tamper_array(dataset, tmp_path, "labels", poison)
    r = dc("train", "--no-plots", str(bad), "-o", str(tmp_path / "m"), *TINY_TRAIN)
    one_line_error(r, bad / "labels.npy", "sample 3", "no checkpoint was written")
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize("change,needle", [
    (lambda ck: ck["model"].__setitem__(next(iter(ck["model"])), __import__("torch").zeros(3, 3)), "has shape"),
    (lambda ck: ck["network"].__setitem__("model", "thesis"), "do not belong to this network"),
    (lambda ck: ck["network"].__setitem__("fcn_width", 10 ** 6), "fcn_width must be"),
    (lambda ck: ck["network"].__setitem__("in_channels", "6"), "in_channels must be"),
    (lambda ck: ck["train_config"].__setitem__("evil", 1), "training config"),
])
def test_a_tampered_checkpoint_is_refused_before_a_network_is_built(run, dataset, model, tmp_path, change, needle):
    import torch
    bad = copy(model, tmp_path / "model")
    ck = torch.load(bad / "last.pt", weights_only=True)
    change(ck)
    torch.save(ck, bad / "last.pt")
    before = snapshot(bad)
    one_line_error(dc("train", str(dataset), "-o", str(bad), "--resume"), bad / "last.pt")
    if "training config" not in needle:
        one_line_error(dc("evaluate", "--no-plots", str(run), "--starts", "cnn", "--checkpoint", str(bad / "last.pt"),
                          "-o", str(tmp_path / "r")), bad / "last.pt", "refused", needle)
    assert snapshot(bad) == before and not (tmp_path / "r").exists()


# --- option values, closed loop, messages ---------------------------------------------------------

@pytest.mark.parametrize("args,option", [
    (["train", "{data}", "--lr", "-1", "--optimizer", "adam"], "--lr"),
    (["train", "{data}", "--weight-decay", "-1"], "--weight-decay"),
    (["train", "{data}", "--device", "meta"], "--device"),
    (["train", "{data}", "--device", "nonsense"], "--device"),
    (["rasterize", "{run}", "--validation", "1"], "--validation"),
    (["rasterize", "{run}", "--window", "nan,0,1,1"], "--window"),
    (["rasterize", "{run}", "--window", "1,1,0,0"], "--window"),
    (["rasterize", "{run}", "--inputs", "mass,mass"], "listed twice"),
    (["simulate", "pile", "--iterations", "-1"], "--iterations"),
    (["simulate", "pile", "--seeds", "3..1"], "--seeds"),
    (["simulate", "pile", "--shard", "2/2"], "--shard"),
    (["simulate", "pile", "--param", "count"], "--param"),
    (["simulate", "pile", "--solver", "pgs", "--relaxation", "2.5"], "--relaxation"),
    (["simulate", "pile", "--tolerance", "1e-3"], "only applies with --solver pgs"),
    (["evaluate", "{run}", "--relaxation", "2.5"], "--relaxation"),
    (["evaluate", "{run}", "--accelerate", "foo"], "--accelerate"),
    (["evaluate", "{run}", "--starts", "zero,lucky"], "--starts"),
])
def test_bad_option_values_exit_2_in_every_command(run, dataset, tmp_path, args, option):
    args = [a.format(run=run, data=dataset) for a in args]
    option_error(dc(*args, "-o", str(tmp_path / "o")), option)
    assert not (tmp_path / "o").exists()


def test_the_closed_loop_follows_removals_and_empty_scenes(tmp_path):
    from deepcontact.evaluate.closed_loop import closed_loop, reference_trajectory
    from deepcontact.warmstart.starts import make_starts
    from deepcontact.scene.generators import generate
    from deepcontact.scene.model import RemoveEvent
    scene = generate("stack", 0, {"count": 5})
    scene.steps = 40
    scene.events = [RemoveEvent(step=20, body=5), RemoveEvent(step=20, body=4)]   # two in one step
    ref = reference_trajectory(scene, 40)
    assert len(ref.positions[19]) == 6 and len(ref.positions[20]) == 4          # ground + 3 boxes left
    [result] = closed_loop(scene, make_starts(["builtin"]), steps=40, reference=ref)
    assert result.finite and result.steps == 40 and np.all(np.isfinite(result.drift))
    run = tmp_path / "wse"
    assert dc("simulate", "warm-start-energy", "--steps", "160", "-q", "-o", str(run)).returncode == 0
    r = dc("evaluate", "--no-plots", str(run), "--closed-loop", "--starts", "builtin", "--no-budgets", "-q", "-o",
           str(tmp_path / "r"))
    assert r.returncode == 0, r.stderr
    empty = tmp_path / "empty.xml"
    empty.write_text('<scene name="empty" format="1"><world dt="0.01" steps="20"/><effects/><bodies/></scene>')
    assert dc("simulate", str(empty), "-q", "-o", str(tmp_path / "e")).returncode == 0
    r = dc("evaluate", "--no-plots", str(tmp_path / "e"), "--closed-loop", "--starts", "builtin", "-q", "-o",
           str(tmp_path / "re"))
    assert r.returncode == 0, r.stderr


def test_messages_stay_on_one_line(run, tmp_path):
    weird = tmp_path / "two\nlines"
    copy(run, weird)
    line = one_line_error(dc("rasterize", str(weird), str(weird), "-o", str(tmp_path / "d")), "given twice")
    assert repr(str(weird)) in line
    bad = copy(run, tmp_path / "huge")
    step = sorted(bad.glob("seed-000000/step-*.xml"))[-1]
    step.write_text(step.read_text().replace("<step ", '<step junk="' + "x" * 20_000_000 + '" ', 1))
    line = one_line_error(dc("rasterize", str(bad), "-o", str(tmp_path / "d")), step)
    assert len(line) <= 600
    r = dc("validate", str(step))
    assert r.returncode == 1 and len(r.stdout.strip().splitlines()) >= 1
    assert all(len(x) <= 600 for x in r.stdout.strip().splitlines())


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o077])
def test_outputs_honour_the_umask(run, dataset, tmp_path, mask):
    """Colleagues on a cluster read each other's runs: an output folder and its files get the modes
    the user's umask gives (mkdtemp's 0700 is for secrets)."""
    saved = os.umask(mask)
    try:
        assert dc("simulate", *PILE, "--steps", "3", "-q", "-o", str(tmp_path / "run")).returncode == 0
        assert dc("render", str(next(Path(run).glob("seed-*/step-000100.xml"))), "-q",
                  "-o", str(tmp_path / "pic.png")).returncode == 0
        assert dc("rasterize", str(run), "--cell", "1", "--smoothing", "1", "-q",
                  "-o", str(tmp_path / "data")).returncode == 0
    finally:
        os.umask(saved)
    for p in [tmp_path / "run", *(tmp_path / "run").rglob("*"), tmp_path / "pic.png", tmp_path / "data",
              *(tmp_path / "data").rglob("*")]:
        expected = (0o777 if p.is_dir() else 0o666) & ~mask
        assert stat.S_IMODE(os.stat(p).st_mode) == expected, (p, oct(os.stat(p).st_mode), oct(expected))


def test_render_makes_the_folder_its_picture_goes_in(run, tmp_path):
    step = next(Path(run).glob("seed-*/step-000100.xml"))
    r = dc("render", str(step), "-q", "-o", str(tmp_path / "figures" / "new" / "x.png"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "figures" / "new" / "x.png").stat().st_size > 0


@pytest.mark.parametrize("args", [["--engine", "box2d3", "--substeps", "2147483647"],
                                  ["--solver", "pgs", "--max-iterations", "2147483647"],
                                  ["--iterations", "2147483647"]])
def test_iteration_counts_that_would_run_for_hours_are_refused_before_work(tmp_path, args):
    r = dc("simulate", *PILE, "--steps", "3", "-q", "-o", str(tmp_path / "run"), *args)
    one_line_error(r, "2,147,483,647", "body-iterations a step")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args", [
    # a fixed count of ten million sweeps a step: hours for the run, every step in the native sweeps
    ["simulate", *PILE, "--steps", "300", "--solver", "pgs", "--max-iterations", "10000000", "-q", "-o", "out"],
])
def test_a_native_solve_stops_within_a_second_of_a_signal(run, tmp_path, args):
    """The sweeps run with the GIL released; they poll for signals (native/interrupt.hpp)."""
    proc = start([str(run) if a == "RUN" else a for a in args], tmp_path)
    time.sleep(3)   # (in the sweeps by now: the cap and the tolerance keep it there for hours)
    assert proc.poll() is None
    sent = time.time()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert time.time() - sent < 1.5 and proc.returncode == 128 + signal.SIGTERM, err
    assert "interrupted" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_command_run_in_the_callers_process_gives_its_signal_handlers_back():
    """A notebook or a test that runs a dc command in its own process keeps its Ctrl-C, even after
    the command was stopped (dc's handler then ignores a repeat while it cleans up)."""
    import click
    from click.testing import CliRunner
    from deepcontact.cli import options

    @click.command()
    @options.verbosity
    @options.command("probe")
    def probe(verbose, quiet):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    result = CliRunner().invoke(probe, [])
    assert result.exit_code == 128 + signal.SIGTERM
    assert {s: signal.getsignal(s) for s in before} == before


def test_a_native_solve_called_from_python_takes_ctrl_c(run):
    """The library alone (no dc handlers): Python's own SIGINT handler stops a native solve."""
    import threading
    import deepcontact as dcl
    from deepcontact.solver.problem import StepProblem
    problem = StepProblem.from_step_file(next(Path(run).glob("seed-*/step-000100.xml")))
    saved = signal.signal(signal.SIGINT, signal.default_int_handler)   # (Python's own, whatever ran before)
    try:
        timer = threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT))
        timer.start()
        began = time.time()
        with pytest.raises(KeyboardInterrupt):
            dcl.solve(problem, tolerance=1e-300, max_iterations=2 ** 31 - 1, stop_on="none")
        assert time.time() - began < 1.5
    finally:
        signal.signal(signal.SIGINT, saved)


def test_a_signal_that_lands_in_a_weakref_callback_is_raised_in_the_commands_code(capfd):
    """Python cannot raise an exception out of a weakref callback (an import lock's, say): it
    prints "Exception ignored in ..." with a traceback and goes on. A stop signal that lands there
    is sent again and raised where the command is, with nothing printed."""
    import weakref

    class Thing:
        pass

    def callback(_):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)   # the handler runs in here, and its exception cannot leave

    with stop_signals_handled() as interrupts:
        with pytest.raises(interrupts.Terminated) as raised:
            thing = Thing()
            ref = weakref.ref(thing, callback)
            del thing
            for _ in range(100):   # (the signal is sent again: raised at the next bytecode here)
                time.sleep(0.01)
            raise AssertionError(f"not raised ({ref})")
    assert raised.value.signum == signal.SIGTERM
    assert "Exception ignored" not in capfd.readouterr().err


@pytest.mark.parametrize("command", ["simulate", "render"])
def test_an_output_path_through_a_missing_folder_and_up_makes_no_folder(run, tmp_path, monkeypatch, command):
    """`-o x/../y` went into a folder x that was not there, made it, and went up out of it: x stayed
    behind. A folder before '..' must be there; through one that is, the output is written."""
    monkeypatch.chdir(tmp_path)
    args = {"simulate": ["simulate", *PILE, "--steps", "3", "-q"],
            "render": ["render", run / "seed-000000" / "step-000010.xml", "-q"]}[command]
    suffix = "" if command == "simulate" else ".png"
    one_line_error(dc(*args, "-o", f"x/../y{suffix}"), "before '..'")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    (tmp_path / "x").mkdir()
    assert dc(*args, "-o", f"x/../y{suffix}").returncode == 0
    assert (tmp_path / f"y{suffix}").exists() and list((tmp_path / "x").iterdir()) == []


def test_the_users_empty_output_folder_keeps_its_mode_group_and_attributes(tmp_path):
    """An empty folder the user made for the output is replaced by the finished output: its mode
    (a setgid bit too), group and extended attributes are carried over, not reset to the umask's."""
    import stat
    out = tmp_path / "out"
    out.mkdir()
    os.chmod(out, 0o2750)
    os.chown(out, -1, 4242)
    os.chmod(out, 0o2750)
    try:
        os.setxattr(out, "user.project", b"contact")
        xattr = True
    except OSError:   # (a file system without user attributes)
        xattr = False
    assert dc("simulate", *PILE, "--steps", "3", "-q", "-o", out).returncode == 0
    st = os.lstat(out)
    assert (out / "manifest.json").exists()
    assert stat.S_IMODE(st.st_mode) == 0o2750 and st.st_gid == 4242
    assert not xattr or os.getxattr(out, "user.project") == b"contact"


def test_a_mount_point_as_output_is_refused_before_the_work(tmp_path):
    """A mount point cannot be renamed aside, so its swap failed after the whole run, leaving a
    journal behind. It is refused first; a folder inside it is written."""
    out = tmp_path / "mnt"
    out.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "none", str(out)], capture_output=True).returncode != 0:
        pytest.skip("no tmpfs can be mounted here (not root, or no mount permission)")
    try:
        one_line_error(dc("simulate", *PILE, "--steps", "3", "-q", "-o", out), "mount point")
        assert sorted(p.name for p in tmp_path.iterdir()) == ["mnt"] and list(out.iterdir()) == []
        assert dc("simulate", *PILE, "--steps", "3", "-q", "-o", out / "run").returncode == 0
    finally:
        subprocess.run(["umount", str(out)], capture_output=True)


# --- Links: dc never writes through a name it did not make in this run ----------------------------

THESIS = "\\documentclass{article} the only copy\n"


def a_users_file(tmp_path):
    thesis = tmp_path / "thesis.tex"
    thesis.write_text(THESIS)
    return thesis


@pytest.mark.parametrize("writer", ["write_bytes", "open_for_write", "record"])
def test_a_hard_link_planted_at_a_temporary_name_is_never_opened(tmp_path, writer):
    """Every name dc would take for a temporary file is a hard link to the user's file: dc takes
    another, and the user's file keeps its bytes."""
    thesis = a_users_file(tmp_path)
    out = tmp_path / ("out" if writer == "record" else "figure.png")
    name = output.RECORD if writer == "record" else out.name
    where = tmp_path / ".out.partial" if writer == "record" else tmp_path
    planted = [f".{name}.{os.getpid()}.tmp"] + [f".{name}.{os.getpid()}_{k}.tmp" for k in range(1, 4)]
    if writer == "record":   # (inside the folder being built: planted once it is there)
        with output.output_folder(out, output.Owned("report"), command="evaluate") as work:
            for p in planted:
                os.link(thesis, work / p)
            output.write_text(work / "report.md", "report")
            for p in planted:
                (work / p).unlink()
    elif writer == "write_bytes":
        for p in planted:
            os.link(thesis, where / p)
        output.write_bytes(out, b"\x89PNG")
    else:
        for p in planted:
            os.link(thesis, where / p)
        with output.open_for_write(out) as f:
            f.write(b"\x89PNG")
    assert thesis.read_text() == THESIS and os.stat(thesis).st_nlink == (1 if writer == "record" else 5)
    assert (out / "report.md").read_text() == "report" if writer == "record" else out.read_bytes() == b"\x89PNG"


def test_a_lock_that_is_a_hard_link_to_a_users_file_is_refused(run, tmp_path):
    thesis = a_users_file(tmp_path)
    os.link(thesis, tmp_path / ".r.lock")
    r = dc("evaluate", "--no-plots", run, "--starts", "builtin", "--every", "40", "--no-budgets", "-q", "-o",
           tmp_path / "r")
    assert "is a hard link to another file" in one_line_error(r, "r")
    assert thesis.read_text() == THESIS and not (tmp_path / "r").exists()


@pytest.mark.parametrize("what", ["the output being built", "a folder inside it", "an output written in place"])
def test_a_folder_swapped_for_a_link_during_the_run_is_never_written_through(tmp_path, what):
    """The folder dc writes in is moved away and a link to the user's folder put in its place,
    between two writes: nothing lands in the user's folder, and nothing is swapped in."""
    users = tmp_path / "users"
    users.mkdir()
    (users / "notes.txt").write_text("mine")
    out = tmp_path / "out"
    in_place = what == "an output written in place"
    with pytest.raises((OSError, atomic_error())):
        with output.output_folder(out, output.Owned("report"), command="train", in_place=in_place) as work:
            output.make_dir(work / "sub")
            output.write_text(work / "sub" / "first.txt", "first")
            target = work / "sub" if what == "a folder inside it" else work
            os.rename(target, tmp_path / "moved")
            os.symlink(users, target)
            output.write_text(work / "report.md", "report")
            output.write_text(work / "sub" / "second.txt", "second")
            if in_place:   # (written where the folder went, never through the link: then refused below)
                raise OSError("end of the run")
    assert sorted(p.name for p in users.iterdir()) == ["notes.txt"]
    if what == "the output being built":
        assert os.path.islink(tmp_path / next(p for p in os.listdir(tmp_path) if ".partial-" in p)) \
            and not out.exists()


def atomic_error():
    from deepcontact.errors import InputError
    return InputError


@pytest.mark.parametrize("at", ["journal", "record", "moving aside", "moving in"])
@pytest.mark.parametrize("error", ["ENOSPC", "EROFS"])
def test_a_full_or_read_only_disk_in_the_swap_leaves_the_output_as_it_was_and_nothing_beside(tmp_path, monkeypatch,
                                                                                          at, error):
    import errno
    out = tmp_path / "out"
    with output.output_folder(out, output.Owned("report"), command="evaluate") as work:
        output.write_text(work / "report.md", "old")
    real_write, real_replace = output.write_text, os.replace

    def failing():
        return OSError(getattr(errno, error), os.strerror(getattr(errno, error)))

    def write_text(path, text):
        if (at == "journal" and str(path).endswith(".swap")) or (at == "record" and '"done"' in text):
            raise failing()
        return real_write(path, text)

    def replace(src, dst, **kw):
        if ((at == "moving aside" and ".old-" in str(dst)) or (at == "moving in" and str(dst) == str(out))) \
                and not failed:   # (once: the undo's rename back then works, as when space is freed)
            failed.append(dst)
            raise failing()
        return real_replace(src, dst, **kw)
    failed = []
    monkeypatch.setattr(output.files, "write_text", write_text)
    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(OSError):
        with output.output_folder(out, output.Owned("report"), overwrite=True, command="evaluate") as work:
            output.write_text(work / "report.md", "new")
    monkeypatch.undo()
    assert (out / "report.md").read_text() == "old" and sorted(os.listdir(tmp_path)) == ["out"]
    with output.output_folder(out, output.Owned("report"), overwrite=True, command="evaluate") as work:
        output.write_text(work / "report.md", "newer")
    assert (out / "report.md").read_text() == "newer" and sorted(os.listdir(tmp_path)) == ["out"]


def test_a_tree_of_any_depth_is_removed_and_no_link_in_it_followed(tmp_path):
    """shutil.rmtree recursed (RecursionError past about 1,000 levels) and walked by path (past
    PATH_MAX it cannot name the entries): what a job left could not be removed."""
    from deepcontact.output import remove_tree
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "keep").write_text("mine")
    top = tmp_path / "left"
    top.mkdir()
    fd = os.open(top, os.O_RDONLY)
    for k in range(1500):
        os.mkdir("d" * 40, dir_fd=fd)
        os.symlink(outside, f"link-{k}", dir_fd=fd)
        child = os.open("d" * 40, os.O_RDONLY, dir_fd=fd)
        os.close(fd)
        fd = child
    os.fchmod(fd, 0)   # (a folder of mode 000 at the bottom)
    os.close(fd)
    remove_tree(top)
    assert not top.exists() and (outside / "keep").read_text() == "mine"


def test_a_private_folder_being_made_is_never_swept_by_a_concurrent_run(tmp_path, monkeypatch):
    # (another run's sweep at the moment between the lock file's creation and its lock: it found
    # the file unlocked, took the folder for a dead run's and removed it under the live one)
    import fcntl
    import tempfile

    from deepcontact.output import trees
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    real, swept = fcntl.flock, []

    def flock(fd, operation):
        if not swept:
            swept.append(True)
            trees.sweep(str(tmp_path), "race")
        return real(fd, operation)
    monkeypatch.setattr(fcntl, "flock", flock)
    with trees.private_folder("race") as folder:
        assert swept and os.path.isdir(folder)
        monkeypatch.setattr(fcntl, "flock", real)
        trees.sweep(str(tmp_path), "race")   # (a sweep while it lives leaves it)
        assert os.path.isdir(folder)
    assert not os.listdir(tmp_path)


def test_a_signal_while_the_lock_is_taken_leaves_no_lock_file(tmp_path, monkeypatch):
    """The window between making the lock file beside an output and owning it (a signal sent as
    soon as the lock file shows, as a user's script may): the stop is raised, and the lock goes."""
    from deepcontact.output import lock as locks
    real = locks._open_lock

    def signalled(*args):
        fd = real(*args)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)   # (the handler has run: the stop is pending, not raised)
        return fd
    monkeypatch.setattr(locks, "_open_lock", signalled)
    with stop_signals_handled() as interrupts:
        with pytest.raises(interrupts.Terminated):
            with locks.locked(tmp_path / "out"):
                raise AssertionError("the block ran: the signal was lost")
    assert leftovers(tmp_path) == [] and not locks._locks


def stop_at(n):
    """A profile function that sends SIGTERM at the n-th place where Python raises a stop signal's
    exception (a function's start, a generator's resumption, a C function's return), and its count."""
    count = [0]

    def profile(frame, event, arg):
        if event in ("call", "c_return"):
            count[0] += 1
            if count[0] == n:
                sys.setprofile(None)
                os.kill(os.getpid(), signal.SIGTERM)   # (its handler runs here: raised at that place)
    return profile, count


def test_a_signal_anywhere_as_a_lock_is_taken_used_or_let_go_leaves_nothing(tmp_path):
    """A stop signal at every place one can land, in turn, from taking an output's lock (whose last
    holder was killed with a temporary file noted) to letting it go after writing the output: the
    lock and the temporary files are gone, or (a stop before the lock was taken) untouched."""
    from deepcontact.output import files, lock as locks
    planted = {".out.lock": json.dumps([".out.7.tmp"]), ".out.7.tmp": "a killed run's"}
    n, count = 0, [1]
    while count[0] >= n:
        n += 1
        for name, text in planted.items():
            (tmp_path / name).write_text(text)
        profile, count = stop_at(n)
        with stop_signals_handled() as interrupts:
            try:
                sys.setprofile(profile)
                with locks.locked(tmp_path / "out"):
                    files.write_text(tmp_path / "out", "whole")
            except interrupts.Terminated:
                pass
            finally:
                sys.setprofile(None)
        left = {p.name: p.read_text() for p in tmp_path.iterdir() if p.name != "out"}
        assert left in ({}, planted) and not locks._locks and not files.lock_notes, (n, left)
        if (tmp_path / "out").exists():
            assert (tmp_path / "out").read_text() == "whole"
    assert n > 100   # (every place was tried: the count ran out)


def test_a_lock_is_let_go_after_a_stop_its_block_swallowed(tmp_path):
    """A stop that a library's bare except swallowed inside the block: the lock still goes as the
    block ends (the clean-up does not raise the swallowed stop before it has run)."""
    from deepcontact.output import lock as locks
    with stop_signals_handled() as interrupts:
        raised = False
        try:
            with locks.locked(tmp_path / "out"):
                try:
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(0.05)
                except interrupts.Terminated:
                    pass
        except interrupts.Terminated:   # (a KeyboardInterrupt: it would end pytest's session)
            raised = True
        with pytest.raises(interrupts.Terminated):   # (still raised where the command checks)
            interrupts.check()
    assert leftovers(tmp_path) == [] and not locks._locks and not raised
