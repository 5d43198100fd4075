"""An empty folder the user made for an output (`mkdir out; dc simulate ... -o out`) is the
user's: it was replaced by the finished output (a new folder renamed over it: another inode, and
the owner of whoever ran dc, a colleague's folder becoming the runner's). It is now kept, filled
entry by entry, its record last; a run killed while filling it leaves it empty again for the next
command, which says so."""
import json
import os
import signal
import subprocess
import sys

import pytest

from conftest import dc
from deepcontact import output

PILE = ["pile", "--param", "count=5", "--param", "box=12", "--steps", "3", "-q"]


def test_the_users_empty_folder_is_kept_with_its_owner_mode_and_inode(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    os.chmod(out, 0o2751)
    owner = 4321 if os.geteuid() == 0 else os.geteuid()   # (a colleague's folder, where root can make one)
    os.chown(out, owner, 2345 if os.geteuid() == 0 else -1)
    os.chmod(out, 0o2751)
    before = os.lstat(out)
    r = dc("simulate", *PILE, "-o", out)
    assert r.returncode == 0, r.stderr
    after = os.lstat(out)
    assert (after.st_ino, after.st_uid, after.st_gid, after.st_mode) == \
        (before.st_ino, before.st_uid, before.st_gid, before.st_mode)
    assert (out / "manifest.json").is_file() and output.read_record(out)["state"] == "done"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert dc("validate", out).returncode == 0


def test_a_run_killed_while_filling_the_users_folder_is_undone_by_the_next(tmp_path):
    """SIGKILL after the first entry moved into the user's folder (no record there yet): the next
    command moves it back, removes the partial folder, says so, and fills the folder itself."""
    out = tmp_path / "out"
    out.mkdir()
    inode = os.lstat(out).st_ino
    script = f"""
import os, signal, sys
real = os.rename
def rename(src, dst, *a, **k):
    real(src, dst, *a, **k)
    if ".partial-" in str(src) and os.path.dirname(str(dst)) == {str(out)!r}:
        os.kill(os.getpid(), signal.SIGKILL)
os.rename = rename
from deepcontact.cli.main import cli
sys.argv = ["dc", "simulate", *{PILE!r}, "-o", {str(out)!r}]
cli()
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert r.returncode == -signal.SIGKILL, r.stderr[-2000:]
    journal = json.loads((tmp_path / ".out.swap").read_text())
    assert journal.get("fill") is True and len(os.listdir(out)) == 1   # (one entry moved, no record)
    r = dc("simulate", *PILE, "-o", out)
    assert r.returncode == 0 and "undid the filling" in r.stderr, r.stderr
    assert os.lstat(out).st_ino == inode and sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert dc("validate", out).returncode == 0


def test_a_planted_fill_journal_moves_nothing_out_of_a_folder_it_does_not_name(tmp_path):
    """A journal is a claim: one saying a fill of `out` was cut, where `out` is another folder
    than the one it names (by identity), moves none of the user's files."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "thesis.tex").write_text("the only copy")
    new = tmp_path / ".out.partial-4242-abc"
    new.mkdir()
    output.record.write_record(new, "simulate", "done", ["thesis.tex"])
    (tmp_path / ".out.swap").write_text(json.dumps({"old": ".out.old-4242-abc", "new": new.name, "fill": True,
                                                    "old_id": [0, 0], "new_id": [0, 0]}))
    r = dc("simulate", *PILE, "-o", out)
    assert r.returncode == 1 and (out / "thesis.tex").read_text() == "the only copy", r.stderr


@pytest.mark.skipif(os.geteuid() != 0, reason="setting another owner needs root")
def test_a_replaced_output_keeps_the_owner_of_the_folder_it_replaces(tmp_path):
    out = tmp_path / "out"
    assert dc("simulate", *PILE, "-o", out).returncode == 0
    os.chown(out, 4321, 2345)
    assert dc("simulate", *PILE, "--overwrite", "-o", out).returncode == 0
    st = os.lstat(out)
    assert (st.st_uid, st.st_gid) == (4321, 2345)
