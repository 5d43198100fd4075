"""A study is a guest too: an installed study runs in a sandbox of its own (deepcontact/studies/
fence.py), sees the file system read-only, writes only its staged output (swapped in by dc's own
process, by the output rules), reaches no process and no socket of the user's, runs its
contestants through the judge's process (contest/broker.py), and every way out of it is one line
naming it. Each study here is a hostile one, installed for the test as a distribution of its own."""
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from conftest import dc, dc_command, one_line_error
from deepcontact import output
from deepcontact.contest import fences

pytestmark = pytest.mark.skipif(not all(fences().values()),
                                reason=f"a fence is missing here: {fences()}")

STUDY = textwrap.dedent("""
    import json, os, signal, socket, sys, time
    import click
    from deepcontact.studies import Study

    def _out(path, what):
        with open(path, "w") as f:
            json.dump(what, f)

    @click.command("reach")
    @click.option("-o", "--output", "out")
    @click.option("--victim", type=int)
    @click.option("--user-file")
    @click.option("--socket-path")
    @click.option("--overwrite", is_flag=True)
    def reach(out, victim, user_file, socket_path, overwrite):
        '''Tries every way out of its fence, and writes what it reached.'''
        seen = {}
        try:
            os.kill(victim, signal.SIGTERM)
            seen["signal"] = "sent"
        except OSError as e:
            seen["signal"] = type(e).__name__
        try:
            with open(user_file, "a") as f:
                f.write("reached")
            seen["write"] = "written"
        except OSError as e:
            seen["write"] = type(e).__name__
        try:
            os.unlink(user_file)
            seen["unlink"] = "removed"
        except OSError as e:
            seen["unlink"] = type(e).__name__
        with open(user_file) as f:
            seen["read"] = f.read()
        try:
            s = socket.socket(socket.AF_UNIX)
            s.connect(socket_path)
            seen["socket"] = "connected"
        except OSError as e:
            seen["socket"] = type(e).__name__
        import ctypes   # (socket() with the family's high bits set: the kernel reads 32 of them, AF_UNIX)
        libc = ctypes.CDLL(None, use_errno=True)
        libc.syscall.restype = ctypes.c_long
        fd = libc.syscall(ctypes.c_long(41), ctypes.c_long((1 << 32) | socket.AF_UNIX),
                          ctypes.c_long(socket.SOCK_STREAM), ctypes.c_long(0))
        seen["high socket"] = "made" if fd >= 0 else os.strerror(ctypes.get_errno())
        from deepcontact.contest import broker
        a, b = socket.socketpair()
        asks = {   # (what the broker lent a job before: bubblewrap's options, the whole host, many fds)
            "options": {"argv": ["--bind", "/", "/tmp/x", "true"], "readable": ["/"], "fd_numbers": [b.fileno()]},
            "root": {"grant": {"names": [], "modules": [], "files": ["/"]}},
            "fds": {"grant": {"names": [], "modules": [], "files": []}},   # (two descriptors passed: below)
        }
        for name, fields in asks.items():
            try:
                broker.remote("start", fds=[b.fileno()] * (2 if name == "fds" else 1), **fields)
                seen[f"broker {name}"] = "started"
            except broker.BrokerError as e:
                seen[f"broker {name}"] = str(e)
        seen["processes"] = sorted(int(p) for p in os.listdir("/proc") if p.isdigit())
        from deepcontact.contest import fences, sandbox
        from deepcontact.contest.client import Contestant
        seen["fences"] = fences()
        null = Contestant.null()
        seen["contestant"] = type(null.sandbox).__name__
        seen["charged"] = null.sandbox.cpu_seconds() is not None
        null.close()
        click.echo("reached what it could")
        _out(out, seen)

    @click.command("leave")
    @click.option("-o", "--output", "out")
    @click.option("--how")
    @click.option("--overwrite", is_flag=True)
    @click.option("-q", "--quiet", is_flag=True)
    def leave(out, how, overwrite, quiet):
        '''Ends its process its own way, after writing its output.'''
        _out(out, {"written": True})
        if how == "exit":
            os._exit(9)
        if how in ("exit 1", "exit 200"):   # (a crash that exits as a verdict does; a status above 128)
            os._exit(int(how.split()[1]))
        if how == "deep":   # (a staging folder deeper than a recursive removal or PATH_MAX reaches)
            os.remove(out)
            os.mkdir(out)
            fd = os.open(out, os.O_RDONLY)
            for _ in range(3000):
                os.mkdir("level-of-a-deep-tree", dir_fd=fd)
                child = os.open("level-of-a-deep-tree", os.O_RDONLY, dir_fd=fd)
                os.close(fd)
                fd = child
            os.fchmod(fd, 0)
            os._exit(3)
        if how in ("link out", "link out folder"):   # (its staged output itself a link: to the user's file)
            os.remove(out)
            os.symlink(os.environ["VICTIM"], out)
        if how == "exit 2":
            os._exit(2)
        if how == "sys.exit":
            sys.exit(0)
        if how == "refuse":   # (its own error, naming its output as it sees it: the staged path)
            from deepcontact.errors import InputError
            raise InputError("cannot be written as asked", out)
        if how == "raise":
            raise ZeroDivisionError("half-way")
        if how == "verdict":
            from deepcontact.errors import StudyFailed
            raise StudyFailed("a configuration never met its criteria")
        if how == "signal":
            os.kill(os.getpid(), signal.SIGSEGV)
        if how == "link":
            os.remove(out)
            os.mkdir(out)
            os.symlink("/etc/passwd", os.path.join(out, "passwd"))
        if how == "stubborn":
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            click.echo("working", err=True)
            while True:
                time.sleep(0.05)

    class Reach(Study):
        name, summary, order, writes = "reach", "tries to leave its fence", 90, "file"
        command = staticmethod(lambda: reach)

    class Leave(Study):
        name, summary, order, writes = "leave", "ends its own process", 91, "file"
        command = staticmethod(lambda: leave)
""")


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """The hostile studies, installed as the distribution dc-hostile-studies (an entry point each)."""
    lib = tmp_path / "lib"
    info = lib / "dc_hostile_studies-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dc-hostile-studies\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[deepcontact.studies]\nreach = dc_hostile_study:Reach\n"
                                           "leave = dc_hostile_study:Leave\n")
    (lib / "dc_hostile_study.py").write_text(STUDY)
    monkeypatch.syspath_prepend(str(lib))
    yield lib
    sys.modules.pop("dc_hostile_study", None)


def test_a_study_reaches_no_process_file_or_socket_of_the_users(installed, tmp_path):
    user_file = tmp_path / "notes.txt"
    user_file.write_text("mine")
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(tmp_path / "agent.sock"))
    listener.listen()
    victim = subprocess.Popen(["sleep", "60"])
    try:
        out = tmp_path / "reach.json"
        r = dc("study", "reach", "-o", out, "--victim", victim.pid, "--user-file", user_file,
               "--socket-path", tmp_path / "agent.sock")
        assert r.returncode == 0, r.stderr
        assert "reached what it could" in r.stdout   # (its standard output is the user's)
        seen = json.loads(out.read_text())
        assert victim.poll() is None and seen["signal"] == "ProcessLookupError"   # (its own PID namespace)
        assert seen["write"] == seen["unlink"] == "OSError" and user_file.read_text() == "mine"
        assert seen["read"] == "mine"                                     # (it reads the user's inputs)
        assert seen["socket"] == "PermissionError"
        assert seen["high socket"] == os.strerror(1), seen   # (EPERM: the family's low 32 bits compared)
        assert seen["broker options"].startswith("refused") and "broker root" in seen, seen
        assert "must be a regular file" in seen["broker root"] and "one descriptor" in seen["broker fds"], seen
        assert len(seen["processes"]) <= 3, seen["processes"]             # (bubblewrap's init, itself, a child)
        # its contestants: started by dc's process, in a contestant's fence, charged
        assert seen["contestant"] == "RemoteSandbox" and seen["charged"] and seen["fences"] == fences()
        assert not [p for p in tmp_path.iterdir() if ".partial-" in p.name or p.name.endswith(".lock")]
    finally:
        victim.kill()
        listener.close()


@pytest.mark.parametrize("how, needle", [
    ("exit", "exit status 9"), ("signal", "killed by SIGSEGV"),
    # a crash exits 1 as a failed verdict does, and was published over the user's output
    ("exit 1", "without saying it ended in order"), ("raise", "ZeroDivisionError: half-way"),
    ("exit 200", "exit status 200"),   # (was "killed by signal 72")
])
def test_a_study_that_ends_its_own_process_is_one_line_and_publishes_nothing(installed, tmp_path, how, needle):
    out = tmp_path / "out.json"
    out.write_text("earlier")
    one_line_error(dc("study", "leave", "-o", out, "--how", how, "--overwrite"), "the study 'leave'", needle)
    assert out.read_text() == "earlier" and sorted(p.name for p in tmp_path.iterdir()) == ["lib", "out.json"]


def test_what_a_killed_job_leaves_is_removed_whatever_its_depth(installed, tmp_path):
    """A staging folder 3,000 folders deep (past PATH_MAX, past a recursive removal) was left
    beside the output and made every later run there fail; a killed run's private TMPDIR was
    never swept."""
    import tempfile
    dead = subprocess.Popen(["true"])
    dead.wait()   # (a process that is gone: its folder is a killed run's)
    left = Path(tempfile.mkdtemp(prefix=f"dc-job-{dead.pid}-"))
    (left / "checkpoint-copy").write_bytes(b"x" * 1000)
    (left / ".dc-alive").write_text("")   # (its lock, freed as its run was killed)
    alive = Path(tempfile.mkdtemp(prefix="dc-job-1-"))   # (a live run's, perhaps in another PID namespace)
    (alive / ".dc-alive").write_text("")
    held = os.open(alive / ".dc-alive", os.O_RDONLY)
    import fcntl
    fcntl.flock(held, fcntl.LOCK_EX)
    out = tmp_path / "out.json"
    one_line_error(dc("study", "leave", "-o", out, "--how", "deep"), "the study 'leave'", "exit status 3")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lib"]
    r = dc("study", "leave", "-o", out, "--how", "in order")
    assert r.returncode == 0, r.stderr
    assert json.loads(out.read_text()) == {"written": True} and not left.exists() and alive.exists()
    os.close(held)
    output.remove_tree(alive)


def test_a_staged_output_that_is_a_link_is_not_published(installed, tmp_path, monkeypatch):
    """The staged path itself a link was published: the user's file named by it became the output."""
    victim = tmp_path / "secret.txt"
    victim.write_text("mine")
    monkeypatch.setenv("VICTIM", str(victim))
    out = tmp_path / "out.json"
    out.write_text("earlier")
    one_line_error(dc("study", "leave", "-o", out, "--how", "link out", "--overwrite"), "is a link", "not published")
    assert out.read_text() == "earlier" and not out.is_symlink() and victim.read_text() == "mine"


@pytest.mark.parametrize("how, needle", [("exit 2", "exit status 2"), ("sys.exit", "the study 'leave' (")])
def test_a_study_that_exits_its_own_way_is_named(installed, tmp_path, how, needle):
    """os._exit(2) was exit 2 and no line; sys.exit(0) was "something the command ran called
    sys.exit(0) (a plug-in?)", naming nobody."""
    one_line_error(dc("study", "leave", "-o", tmp_path / "out.json", "--how", how), needle)


def test_short_options_together_stage_the_output_too(installed, tmp_path):
    """`-qo OUT` (click's short options together) was not found: nothing was staged, and the
    study failed at its end on the read-only file system."""
    r = dc("study", "leave", "-qo", tmp_path / "out.json", "--how", "in order")
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "out.json").read_text()) == {"written": True}


def test_a_studys_error_names_the_users_output_not_its_staging_folder(installed, tmp_path):
    out = tmp_path / "out.json"
    line = one_line_error(dc("study", "leave", "-o", out, "--how", "refuse"), f"{out}: cannot be written as asked")
    assert ".partial-" not in line


def test_a_study_whose_verdict_is_a_failure_is_published(installed, tmp_path):
    out = tmp_path / "out.json"
    out.write_text("earlier")
    one_line_error(dc("study", "leave", "-o", out, "--how", "verdict", "--overwrite"), "never met its criteria")
    assert json.loads(out.read_text()) == {"written": True}


@pytest.fixture
def no_bubblewrap(tmp_path, monkeypatch):
    """This process as on a machine without bubblewrap: a PATH that finds no bwrap."""
    from deepcontact.contest import machine
    monkeypatch.setenv("PATH", os.path.dirname(sys.executable))
    machine.bwrap.cache_clear()
    yield
    monkeypatch.undo()
    machine.bwrap.cache_clear()


def test_without_its_fence_a_study_runs_only_when_the_user_says_so(installed, tmp_path, no_bubblewrap):
    """Without bubblewrap, an installed study ran as a plain process with the user's write access,
    and nothing said so."""
    out = tmp_path / "out.json"
    out.write_text("earlier")
    one_line_error(dc("study", "leave", "-o", out, "--how", "in order", "--overwrite"), "the study 'leave'",
                   "cannot build its fence (missing: namespaces", "only with --unfenced")
    assert out.read_text() == "earlier"
    listed = dc("study", "--help")
    assert "the study 'leave' is plug-in code, and this machine cannot build" in " ".join(listed.stdout.split())
    r = dc("study", "leave", "-o", out, "--how", "in order", "--overwrite", "--unfenced")
    assert r.returncode == 0, r.stderr
    assert json.loads(out.read_text()) == {"written": True}
    assert r.stderr.strip().splitlines()[-1] == ("dc study leave: plug-in code ran without its sandbox, as --unfenced "
                                                 "allowed (missing here: namespaces, read-only view, seccomp)")
    assert "leave" in dc("study", "--unfenced", "--help").stdout


def test_a_link_in_a_studys_output_is_not_published(installed, tmp_path):
    out = tmp_path / "out"
    one_line_error(dc("study", "leave", "-o", out, "--how", "link"), "holds a link", "not published")
    assert not os.path.lexists(out)


def test_a_studys_output_is_checked_before_it_runs(installed, tmp_path):
    out = tmp_path / "out.json"
    out.write_text("earlier")
    r = dc("study", "reach", "-o", out)
    one_line_error(r, "file exists; use --overwrite")
    assert out.read_text() == "earlier"
    folder = tmp_path / "folder"
    folder.mkdir()
    (folder / "mine.txt").write_text("mine")
    # (a study that writes a file, never put in a folder's place; it does not run: it would end with exit 9)
    one_line_error(dc("study", "leave", "-o", folder, "--overwrite", "--how", "exit"), "is a folder, not a regular file")
    assert (folder / "mine.txt").read_text() == "mine"


def test_a_mount_point_is_refused_before_the_study_runs():
    """(it was found at the end, when the finished output could not be renamed into place)"""
    one_line_error(dc("study", "engines", "--fast", "-o", "/proc"), "/proc: is a mount point")


def test_the_users_stop_ends_a_stubborn_study_at_once(installed, tmp_path):
    out = tmp_path / "out.json"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(installed), *sys.path]))
    p = subprocess.Popen([*dc_command(), "study", "leave", "-o", str(out), "--how", "stubborn"], env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = p.stderr.readline()
    assert "working" in line, line
    stopped = time.monotonic()
    p.send_signal(signal.SIGTERM)
    p.wait(10)
    assert time.monotonic() - stopped < 2 and p.returncode == 128 + signal.SIGTERM, p.stderr.read()
    assert "interrupted (SIGTERM)" in p.stderr.read()
    assert sorted(q.name for q in tmp_path.iterdir()) == ["lib"]


def test_dc_study_help_lists_installed_studies_without_importing_them(installed):
    r = dc("study", "--help")
    assert r.returncode == 0 and "tries to leave its fence" in r.stdout and "stability" in r.stdout
    assert "dc_hostile_study" not in sys.modules   # (listed from a sandbox: never imported here)


# --- A plug-in network's training is a job too ------------------------------------------------------

NETWORK = textwrap.dedent("""
    import os, signal, time
    from torch import nn

    USER_FILE = {user_file!r}

    class Reacher(nn.Sequential):
        '''Tries to leave its fence while it is built, then trains as a plain convolution.'''
        def __init__(self, in_channels, out_channels, height, width):
            super().__init__(nn.Conv2d(in_channels, out_channels, 1))
            if str(next(self.parameters()).device) == "meta":
                return
            try:
                with open(USER_FILE, "a") as f:
                    f.write("reached")
            except OSError:
                pass

    class Exits(nn.Sequential):
        def __init__(self, in_channels, out_channels, height, width):
            super().__init__(nn.Conv2d(in_channels, out_channels, 1))
        def forward(self, x):
            os._exit(7)

    class Stubborn(nn.Sequential):
        '''Ignores every stop signal once it has trained an epoch.'''
        def __init__(self, in_channels, out_channels, height, width):
            super().__init__(nn.Conv2d(in_channels, out_channels, 1))
            self.calls = 0
        def forward(self, x):
            self.calls += 1
            if self.calls > 2:
                signal.signal(signal.SIGTERM, signal.SIG_IGN)
                signal.signal(signal.SIGINT, signal.SIG_IGN)
                time.sleep(0.05)
            return super().forward(x)

    class Litters(nn.Sequential):
        '''Leaves a file of its own in the run's folder (through the working folder it is given).'''
        def __init__(self, in_channels, out_channels, height, width):
            super().__init__(nn.Conv2d(in_channels, out_channels, 1))
        def forward(self, x):
            for root, dirs, files in os.walk(os.environ.get("TMPDIR", "/tmp")):
                if "last.pt" in files or os.path.basename(root) == "run":
                    open(os.path.join(root, "notes.txt"), "w").write("mine")
            return super().forward(x)
""")


@pytest.fixture
def network(tmp_path, monkeypatch):
    lib = tmp_path / "netlib"
    lib.mkdir()
    user_file = tmp_path / "notes.txt"
    user_file.write_text("mine")
    (lib / "dc_hostile_net.py").write_text(NETWORK.format(user_file=str(user_file)))
    monkeypatch.syspath_prepend(str(lib))
    yield lib, user_file
    sys.modules.pop("dc_hostile_net", None)


TRAIN = ["--epochs", "2", "--batch-size", "4", "-q"]


def test_a_plug_in_network_trains_fenced(dataset, tmp_path, network):
    lib, user_file = network
    out = tmp_path / "m"
    r = dc("train", dataset, "-o", out, "--arch", "dc_hostile_net:Reacher", *TRAIN)
    assert r.returncode == 0, r.stderr
    assert user_file.read_text() == "mine" and "dc_hostile_net" not in sys.modules
    assert {p.name for p in out.iterdir()} >= {"last.pt", "best.pt", "metrics.json"}
    # resumed, fenced too: from a copy of the run, written back in place
    r = dc("train", dataset, "-o", out, "--arch", "dc_hostile_net:Reacher", "--resume", "--epochs", "3", "-q")
    assert r.returncode == 0, r.stderr
    assert len(json.loads((out / "metrics.json").read_text())) == 3


def test_a_network_that_ends_its_process_is_one_line(dataset, tmp_path, network):
    r = dc("train", dataset, "-o", tmp_path / "m", "--arch", "dc_hostile_net:Exits", *TRAIN)
    one_line_error(r, "dc_hostile_net:Exits")


def test_what_a_network_leaves_in_its_run_is_not_kept(dataset, tmp_path, network):
    out = tmp_path / "m"
    r = dc("train", dataset, "-o", out, "--arch", "dc_hostile_net:Litters", *TRAIN)
    # (the keeper's refusal is the last line; the training may have said its own first, having
    # found the file in its folder: which comes first is the network's timing)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and "Traceback" not in r.stderr and 1 <= len(lines) <= 2, r.stderr
    assert "'notes.txt', which a training run never writes" in lines[-1], r.stderr
    assert not (out / "notes.txt").exists()


def test_the_users_stop_ends_a_stubborn_network_and_keeps_its_last_epoch(dataset, tmp_path, network):
    lib, _ = network
    out = tmp_path / "m"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(lib), *sys.path]))
    p = subprocess.Popen([*dc_command(), "train", str(dataset), "-o", str(out), "--arch", "dc_hostile_net:Stubborn",
                          "--epochs", "100000", "--batch-size", "4"], env=env, stderr=subprocess.PIPE, text=True)
    line = p.stderr.readline()
    while line and not line.startswith("epoch 1 of"):
        line = p.stderr.readline()
    time.sleep(1)   # (what it writes reaches the output within job.POLL, half a second)
    stopped = time.monotonic()
    p.send_signal(signal.SIGINT)
    p.wait(10)
    assert time.monotonic() - stopped < 2 and p.returncode == 130, p.stderr.read()
    assert (out / "last.pt").exists() and json.loads((out / "metrics.json").read_text())
    assert not [q for q in tmp_path.iterdir() if ".partial-" in q.name or q.name.endswith(".lock")]


def test_dc_evaluate_never_builds_a_plug_in_network_in_its_own_process(run, dataset, tmp_path, network, monkeypatch):
    """The judge read the checkpoint's grid and names, but also built the network (its code ran
    in dc's process); now only the contestants do, in their sandboxes. And a --checkpoint given
    relative to the working folder is found from theirs (it was "no such checkpoint")."""
    monkeypatch.chdir(tmp_path)
    assert dc("train", dataset, "-o", "m", "--arch", "dc_hostile_net:Reacher", *TRAIN).returncode == 0
    r = dc("evaluate", "--no-plots", run, "--starts", "builtin,cnn", "--checkpoint", "m/best.pt", "--arch",
           "dc_hostile_net:Reacher", "--every", "40", "-q", "-o", "r")
    assert r.returncode == 0, r.stderr
    assert "dc_hostile_net" not in sys.modules
    assert "| cnn |" in (tmp_path / "r" / "report.md").read_text()
    from deepcontact.model.arch import NETWORKS
    monkeypatch.setattr(NETWORKS, "_chosen", set())   # (as a new process finds it: nothing chosen yet)
    one_line_error(dc("evaluate", "--no-plots", run, "--starts", "builtin,cnn", "--checkpoint", "m/best.pt",
                      "--every", "40", "-q", "-o", "r2"), "name it with --arch dc_hostile_net:Reacher")


def test_dc_render_with_a_plug_in_network_draws_fenced(dataset, tmp_path, network):
    lib, user_file = network
    assert dc("train", dataset, "-o", tmp_path / "m", "--arch", "dc_hostile_net:Reacher", *TRAIN).returncode == 0
    out = tmp_path / "sample.png"
    r = dc("render", dataset, "-o", out, "--checkpoint", tmp_path / "m" / "best.pt", "--arch", "dc_hostile_net:Reacher")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(out) and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert user_file.read_text() == "mine" and "dc_hostile_net" not in sys.modules
    assert not [p for p in tmp_path.iterdir() if ".partial-" in p.name]


NOISY = {
    "dc_noisy_print": ("import sys\nsys.stdout.write('{\"healthy\": []}' + 'x' * (5 << 20))\nsys.stdout.flush()\n"
                       "from deepcontact.studies import Study\n"
                       "class Printer(Study):\n    name, summary, order, writes = 'printer', 'prints at import', 80, "
                       "'text'\n    command = staticmethod(lambda: __import__('click').command('printer')(lambda: None))\n"),
    "dc_noisy_long": ("from deepcontact.studies import Study\n"
                      "class Long(Study):\n    name, summary, order, writes = 'long', 'a' * 100000 + '\\nmore', 81, "
                      "'text'\n    command = staticmethod(lambda: __import__('click').command('long')(lambda: None))\n"),
    "dc_noisy_block": "import time\ntime.sleep(600)\n",
    "dc_noisy_fine": ("import click\nfrom deepcontact.studies import Study\n@click.command('fine')\ndef fine():\n"
                      "    '''Fine.'''\nclass Fine(Study):\n    name, summary, order, writes = 'fine', 'a fine study', 83, "
                      "'text'\n    command = staticmethod(lambda: fine)\n"),
}


@pytest.fixture
def noisy(tmp_path, monkeypatch):
    """Studies whose listing misbehaves: one prints 5 MB at import, one has a 100,000-character
    summary, one's import blocks; and a fine one listed after the blocking one."""
    from deepcontact.studies import fence
    lib = tmp_path / "lib"
    info = lib / "dc_noisy_studies-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dc-noisy-studies\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[deepcontact.studies]\nprinter = dc_noisy_print:Printer\n"
                                           "long = dc_noisy_long:Long\nblock = dc_noisy_block:Block\n"
                                           "fine = dc_noisy_fine:Fine\n")
    for module, text in NOISY.items():
        (lib / f"{module}.py").write_text(text)
    monkeypatch.syspath_prepend(str(lib))
    monkeypatch.setattr(fence, "SURVEY_DEADLINE", 4.0)
    yield lib
    for module in NOISY:
        sys.modules.pop(module, None)


def test_a_study_that_prints_stalls_or_runs_long_at_listing_hides_no_other(noisy):
    """A study printing at import made `dc study --help` a traceback hiding every study; one whose
    import blocked made it hang."""
    t0 = time.monotonic()
    r = dc("study", "--help")
    assert r.returncode == 0 and "Traceback" not in r.stdout + r.stderr, r.stdout + r.stderr
    flat = " ".join(r.stdout.split())
    for name in ("stability", "printer", "fine"):
        assert f" {name} " in flat, flat
    assert "the study 'block' could not be listed: loading it took over 4 s" in flat
    assert " long aaaa" in flat and "a" * 301 not in flat and "more" not in flat
    assert time.monotonic() - t0 < 60
