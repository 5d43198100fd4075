"""Outputs that can never be written as asked are refused before the work, not after it: a bind
mount of a folder or file of the same file system is a mount point os.path.ismount does not see
(the swap's rename then failed with EBUSY or EXDEV once the whole run was done, naming the partial
folder), and an empty folder this user cannot write in cannot take the output's entries."""
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from conftest import dc, one_line_error

PILE = ["pile", "--param", "count=5", "--param", "box=12", "--steps", "3", "-q"]


@pytest.fixture
def bind(tmp_path):
    """bind(source, target): source bind-mounted on target, unmounted at the end (skips where this
    process may not mount)."""
    mounted = []

    def mount(source, target):
        if subprocess.run(["mount", "--bind", str(source), str(target)], capture_output=True).returncode != 0:
            pytest.skip("no bind mount can be made here (not root, or no mount permission)")
        mounted.append(target)
    yield mount
    for target in reversed(mounted):
        subprocess.run(["umount", str(target)], capture_output=True)


def test_a_bind_mounted_output_folder_is_refused_before_the_work(run, tmp_path, bind):
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "out").mkdir()
    bind(tmp_path / "elsewhere", tmp_path / "out")
    assert not os.path.ismount(tmp_path / "out")   # (what the check used to ask)
    for args in (["simulate", *PILE], ["study", "figures", run, "--every", "60"]):
        t0 = time.perf_counter()
        one_line_error(dc(*args, "-o", tmp_path / "out"), "is a mount point")
        assert time.perf_counter() - t0 < 10, args[0]   # (the study's work took 30 s before it failed)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "out"] and not any((tmp_path / "out").iterdir())
    assert dc("simulate", *PILE, "-o", tmp_path / "out" / "run").returncode == 0   # (a folder inside it is fine)


def test_a_bind_mounted_output_file_is_refused_before_the_work(run, tmp_path, bind):
    (tmp_path / "elsewhere.png").write_bytes(b"the user's picture")
    (tmp_path / "fig.png").write_bytes(b"")
    bind(tmp_path / "elsewhere.png", tmp_path / "fig.png")
    step = run / "seed-000000" / "step-000100.xml"
    t0 = time.perf_counter()
    one_line_error(dc("render", step, "--overwrite", "-o", tmp_path / "fig.png"), "is a mount point")
    assert time.perf_counter() - t0 < 5 and (tmp_path / "elsewhere.png").read_bytes() == b"the user's picture"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere.png", "fig.png"]


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another user")
def test_an_empty_folder_this_user_cannot_write_in_is_refused_before_the_work():
    """As another user (uid 65534), an empty output folder of root's (0755): its entries could not
    be renamed into it at the end; refused when it is checked, in one line naming it."""
    root = Path(tempfile.mkdtemp(dir="/tmp"))
    try:
        os.chmod(root, 0o777)
        (root / "out").mkdir(mode=0o755)
        code = ("import os, sys\n"
                "from deepcontact.errors import InputError\n"
                "from deepcontact.output import check_folder\n"
                "os.setgid(65534); os.setuid(65534)\n"
                "try:\n"
                f"    check_folder({str(root / 'out')!r})\n"
                "except InputError as e:\n"
                "    print(e); sys.exit(1)\n")
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
        assert r.returncode == 1 and "cannot write in" in r.stdout, (r.stdout, r.stderr)
    finally:
        shutil.rmtree(root)
