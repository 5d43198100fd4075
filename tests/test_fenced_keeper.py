"""What a fenced training hands back is opened once, safely (cli/fenced_training.py's keeper,
deepcontact/contest/returned.py): dc's own process, which has no fence, copied whatever appeared in
the training's staging folder into the user's run, checking by path and then opening by path: a
link swapped in after the check was followed, a FIFO blocked dc for ever, a 64 GiB sparse file was
read into its memory, and a crashing network's garbage checkpoint replaced the user's on --resume.
Each hostile network here is a plug-in on the path (as tests/test_study_fence.py installs them)."""
import json
import os
import shutil
import sys
import textwrap

import pytest
import torch

from conftest import dc, dc_process, one_line_error, snapshot
from deepcontact.contest import fences, returned

fenced = pytest.mark.skipif(not all(fences().values()), reason=f"a fence is missing here: {fences()}")

HANDS = textwrap.dedent("""
    import ctypes, os, select, signal, struct, time
    import torch
    from torch import nn

    IN_OPEN = 0x20

    def _put(path, make):
        '''path replaced whole by what make(a new name) makes (made beside the run, renamed in).'''
        tmp = os.path.join(os.environ["TMPDIR"], "handed")
        make(tmp)
        os.replace(tmp, path)

    def _write(data):
        def make(tmp):
            with open(tmp, "wb") as f:
                f.write(data)
        return make

    def _sparse(tmp):
        with open(tmp, "wb") as f:
            f.truncate(64 << 30)

    def _opened(fd, names, seconds=30):
        '''The name of the first of `names` someone opens (inotify), or None.'''
        end = time.monotonic() + seconds
        while select.select([fd], [], [], max(0, end - time.monotonic()))[0]:
            data = os.read(fd, 65536)
            while data:
                _, mask, _, size = struct.unpack_from("iIII", data)
                name = data[16:16 + size].rstrip(b"\\0").decode()
                data = data[16 + size:]
                if mask & IN_OPEN and name in names:
                    return name
        return None

    def _swap_when_read(run, make):
        '''The run's files touched, so that dc reads them again, and the moment dc opens one of
        them, every other swapped for what make makes: between dc's check of a file and its read.'''
        names = [n for n in os.listdir(run) if n.endswith((".pt", ".json", ".csv"))]
        libc = ctypes.CDLL(None, use_errno=True)
        fd = libc.inotify_init1(os.O_CLOEXEC)
        libc.inotify_add_watch(fd, run.encode(), IN_OPEN)
        for n in names:
            os.utime(os.path.join(run, n))
        first = _opened(fd, names)
        for n in names:
            if n != first:
                _put(os.path.join(run, n), make)
        time.sleep(1.5)   # (dc reads on)

    ACTS = {
        "link": lambda run: _swap_when_read(run, lambda tmp: os.symlink(os.environ["DC_TEST_SECRET"], tmp)),
        "fifo": lambda run: _swap_when_read(run, os.mkfifo),
        "sparse": lambda run: _put(os.path.join(run, "last.pt"), _sparse),
        "garbage": lambda run: (_put(os.path.join(run, "last.pt"), _write(b"")),
                                _put(os.path.join(run, "best.pt"), _write(b"PK\\x03\\x04" + b"\\x00" * 60))),
    }

    class Hands(nn.Sequential):
        '''Trains as a plain convolution; with DC_TEST_HANDS, as it is built it hands back that
        (ACTS) for the run it resumes, and crashes.'''
        def __init__(self, in_channels, out_channels, height, width):
            super().__init__(nn.Conv2d(in_channels, out_channels, 1))
            # (16 MB in each checkpoint: what reads a file takes long enough for a swap meanwhile)
            self.register_buffer("ballast", torch.ones(4 << 20))
            how = os.environ.get("DC_TEST_HANDS")
            if how and str(next(self.parameters()).device) != "meta":
                ACTS[how](os.path.join(os.environ["TMPDIR"], "run"))
                os.kill(os.getpid(), signal.SIGKILL)
""")
ARCH = "dc_hands_net:Hands"


@pytest.fixture(scope="module")
def hands(tmp_path_factory):
    """The hostile network's folder, on the path."""
    lib = tmp_path_factory.mktemp("handslib")
    (lib / "dc_hands_net.py").write_text(HANDS)
    sys.path.insert(0, str(lib))
    yield lib
    sys.path.remove(str(lib))
    sys.modules.pop("dc_hands_net", None)


@pytest.fixture(scope="module")
def hands_run(hands, dataset, tmp_path_factory):
    """A run of one epoch the hostile network trained in order (read-only: copy before changing)."""
    out = tmp_path_factory.mktemp("hands") / "m"
    r = dc("train", dataset, "-o", out, "--arch", ARCH, "--epochs", "1", "--batch-size", "4", "--no-plots", "-q")
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture
def users(hands_run, tmp_path, monkeypatch):
    """(the user's copy of the run, what its files hold, a file of theirs the training is not to
    hand back through a link)."""
    out = tmp_path / "m"
    shutil.copytree(hands_run, out)
    secret = tmp_path / "secret.txt"
    secret.write_text("the user's secret")
    secret.chmod(0o600)
    monkeypatch.setenv("DC_TEST_SECRET", str(secret))
    return out, _model_files(out), secret


def _model_files(out):
    return {k: v for k, v in snapshot(out).items() if k != ".dc-output.json"}   # (its record: dc's own)


def _resume(dataset, out, how, monkeypatch):
    monkeypatch.setenv("DC_TEST_HANDS", how)
    return dc("train", dataset, "-o", out, "--arch", ARCH, "--resume", "--epochs", "2", "-q")


@fenced
def test_a_link_swapped_in_for_a_checkpoint_is_never_followed(dataset, users, monkeypatch):
    out, before, secret = users
    r = _resume(dataset, out, "link", monkeypatch)
    assert _model_files(out) == before   # (the old keeper, winning the race, copied the secret in)
    one_line_error(r, ARCH, "as a symbolic link", "not kept")


@fenced
def test_a_fifo_named_like_a_checkpoint_never_blocks_dc(dataset, users, hands):
    out, before, secret = users
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(hands), *sys.path]), DC_TEST_HANDS="fifo",
               DC_TEST_SECRET=str(secret))
    r = dc_process("train", str(dataset), "-o", str(out), "--arch", ARCH, "--resume", "--epochs", "2", "-q",
                   env=env, timeout=120)   # (the old keeper waited on the FIFO for ever)
    assert _model_files(out) == before
    one_line_error(r, ARCH, "as a FIFO, not a regular file", "not kept")


@fenced
def test_a_sparse_checkpoint_is_stopped_at_the_jobs_file_size_limit(dataset, users, monkeypatch):
    # (a job's fence limits a file to 256 MiB: the 64 GiB file is refused as it is made; the
    # keeper's own refusal of a sparse file is held below, one file at a time)
    out, before, _ = users
    r = _resume(dataset, out, "sparse", monkeypatch)
    assert _model_files(out) == before
    one_line_error(r, ARCH, "File too large")


@fenced
def test_a_crash_that_leaves_a_garbage_checkpoint_keeps_the_users(dataset, users, monkeypatch):
    out, before, _ = users
    r = _resume(dataset, out, "garbage", monkeypatch)
    assert _model_files(out) == before   # (the old keeper copied both in after the crash)
    one_line_error(r, ARCH, "best.pt that does not load as a checkpoint", "the run's own is as it was")


# --- The keeper's rules, one file at a time (no training) --------------------------------------------

def test_what_is_handed_back_is_read_from_the_opened_file_alone(tmp_path):
    stage = tmp_path / "run"
    stage.mkdir()
    (stage / "plain").write_bytes(b"x" * 100)
    os.symlink(tmp_path / "elsewhere", stage / "link")
    (tmp_path / "elsewhere").write_bytes(b"secret")
    os.mkfifo(stage / "fifo")
    (stage / "folder").mkdir()
    os.link(tmp_path / "elsewhere", stage / "linked")
    with open(stage / "holes", "wb") as f:
        f.truncate(32 << 20)
    with returned.Staging(stage) as staging:
        stage.rename(tmp_path / "moved")   # (the folder moved, a link in its place: read where it was opened)
        os.symlink(tmp_path, stage)
        assert staging.read("plain", 100)[0] == b"x" * 100
        refused = {}
        for name, limit in (("link", 100), ("fifo", 100), ("folder", 100), ("linked", 100), ("holes", 64 << 20),
                            ("plain", 99)):
            with pytest.raises(returned.Refused) as e:
                staging.read(name, limit)
            refused[name] = str(e.value)
        with pytest.raises(FileNotFoundError):
            staging.read("gone", 100)
    assert refused == {"link": "a symbolic link (never followed)", "fifo": "a FIFO, not a regular file",
                       "folder": "a folder, not a regular file",
                       "linked": "a file with 2 names (a hard link to a file elsewhere)",
                       "holes": "a sparse file (33,554,432 bytes long, 0 of them on disk)",
                       "plain": "a file of 100 bytes, more than such a file may hold (99)"}


@pytest.fixture
def keeper(model, tmp_path):
    """(a keeper of the user's copy of a one-epoch run, the staging folder it reads, the user's
    checkpoint) for the network 'fcn'."""
    from deepcontact.cli.fenced_training import _Keeper
    work, stage = tmp_path / "m", tmp_path / "run"
    shutil.copytree(model, work)
    stage.mkdir()
    with returned.Staging(stage) as staging:
        yield _Keeper(staging, work, work, "fcn", 1 << 30), stage, torch.load(work / "last.pt", weights_only=True)


def _epochs(ck, n):
    """ck as of its n-th epoch: its history a row an epoch."""
    return {**ck, "epoch": n - 1, "history": [{**ck["history"][0], "epoch": k} for k in range(n)]}


def _handed(stage, name, ck):
    torch.save(ck, stage / f".{name}.tmp")
    os.replace(stage / f".{name}.tmp", stage / name)


@pytest.mark.parametrize("name, ck, needle", [
    ("last.pt", b"", "does not load as a checkpoint (not a checkpoint: not a file torch.save writes"),
    ("best.pt", b"PK\x03\x04" + bytes(60), "does not load as a checkpoint (not a readable checkpoint"),
    ("last.pt", "behind", "before the run's own (epoch 2)"),
    ("last.pt", "history", "its history is not a row for each of its 3 epochs"),
    ("mid-epoch.pt", "whole", "no position within its epoch"),
    ("last.pt", "dataset", "it is of another run"),
])
def test_a_checkpoint_takes_the_users_place_only_where_it_continues_the_run(keeper, name, ck, needle):
    from deepcontact.plugins import PluginError
    keep, stage, users = keeper
    torch.save(_epochs(users, 2), keep.work / "last.pt")   # (the user's run is at its second epoch)
    before = _model_files(keep.work)
    made = {"behind": users, "history": {**_epochs(users, 2), "epoch": 2}, "whole": _epochs(users, 3),
            "dataset": {**_epochs(users, 3), "dataset": {**users["dataset"], "samples": 7}}}
    if isinstance(ck, bytes):
        (stage / name).write_bytes(ck)
    else:
        _handed(stage, name, made[ck])
    with pytest.raises(PluginError) as e:
        keep()
    there = "nothing of it was kept" if name == "mid-epoch.pt" else "the run's own is as it was"
    assert needle in e.value.message and there in e.value.message, e.value.message
    assert e.value.path == str(keep.work / name) and _model_files(keep.work) == before


def test_a_checkpoint_of_another_network_is_refused(keeper):
    from deepcontact.cli.fenced_training import _Keeper
    from deepcontact.plugins import PluginError
    keep, stage, users = keeper
    other = _Keeper(keep.staging, keep.work, keep.work, "dc_elsewhere:Net", 1 << 30)
    _handed(stage, "best.pt", _epochs(users, 2))
    with pytest.raises(PluginError, match="it is of another network \\('fcn'\\)"):
        other()


def test_the_next_epochs_are_kept_and_mid_epoch_removed_once_whole(keeper):
    keep, stage, users = keeper
    within = {**_epochs(users, 1), "epoch": 1, "position": {"order": torch.arange(4), "next": 2, "seen": 2,
                                                             "total": 1.0, "seconds": 0.5}}
    _handed(stage, "mid-epoch.pt", within)
    (stage / "metrics.json").write_text(json.dumps([{"epoch": 0}]))
    keep()
    assert torch.load(keep.work / "mid-epoch.pt", weights_only=True)["epoch"] == 1
    os.unlink(stage / "mid-epoch.pt")   # (removed by a training whose last.pt is not of its epoch: left)
    keep()
    assert (keep.work / "mid-epoch.pt").exists()
    _handed(stage, "mid-epoch.pt", within)
    keep()
    _handed(stage, "last.pt", _epochs(users, 2))
    os.unlink(stage / "mid-epoch.pt")
    keep()
    assert not (keep.work / "mid-epoch.pt").exists() and (keep.work / "metrics.json").read_text() == '[{"epoch": 0}]'
    assert torch.load(keep.work / "last.pt", weights_only=True)["epoch"] == 1
