"""Contestants forked from a sandboxed zygote (contest/zygote.py, contest/forked.py): a fork
fences itself by the contestant's fence record before any code of its own runs, so that what it
sees and may do is what a fresh sandbox's contestant sees and may do. Each probe below runs inside
a contestant, forked and fresh, and the two must agree; where the zygote cannot fence a fork,
the contestant starts fresh."""
import json
import os
import sys
import textwrap
from dataclasses import replace

import pytest

from deepcontact.contest import fence, machine, zygote
from deepcontact.contest.broker import GuestSandbox
from deepcontact.contest.client import Contestant
from deepcontact.plugins import PluginError

pytestmark = pytest.mark.skipif(not zygote.usable(fence.CONTESTANT),
                                reason="this machine forks no fenced contestant (zygote.usable)")

PROBE = textwrap.dedent("""
    import ctypes, json, os, time
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    SECRET = {secret!r}

    def refused(result):
        return 0 if result != -1 else ctypes.get_errno()

    class Probe:
        def __init__(self, token):
            self.token = token

        def __call__(self, ctx):
            out = {{"pids": sorted(int(p) for p in os.listdir("/proc") if p.isdigit()), "uid": os.getuid()}}
            status = dict(l.split(":", 1) for l in open("/proc/self/status").read().splitlines() if ":" in l)
            for key in ("CapEff", "CapPrm", "CapBnd", "NoNewPrivs", "Seccomp"):
                out[key] = status[key].strip()
            out["unshare"] = refused(libc.unshare(0x10000000))
            out["mount"] = refused(libc.mount(b"none", b"/tmp", b"tmpfs", 0, None))
            child = libc.syscall(56, ctypes.c_long(0x10000000 | 17), 0, 0, 0, 0)   # clone(CLONE_NEWUSER)
            if child == 0:
                os._exit(0)
            if child > 0:
                os.waitpid(child, 0)
            out["clone_newuser"] = refused(child)
            out["socket_unix"] = refused(libc.syscall(41, ctypes.c_long(1), 1, 0))
            out["socket_unix_high_bits"] = refused(libc.syscall(41, ctypes.c_long(1 | (1 << 32)), 1, 0))
            out["ptrace"] = refused(libc.syscall(101, ctypes.c_long(16), ctypes.c_long(1), 0, 0))
            try:   # (its CPUs, the judge's, asked again: it may not set them at all)
                os.sched_setaffinity(0, os.sched_getaffinity(0))
                out["sched_setaffinity"] = 0
            except OSError as e:
                out["sched_setaffinity"] = e.errno
            for name in ("environ", "mem"):   # (its namespace's PID 1)
                try:
                    with open("/proc/1/" + name, "rb") as f:
                        if name == "mem":   # (at its first mapped byte)
                            with open("/proc/1/maps") as maps:
                                f.seek(int(maps.readline().split("-")[0], 16))
                        data = f.read(1 if name == "mem" else 1 << 20)
                    out["init_" + name] = "the judge's variable" if b"judges-own-value" in data else "read"
                except OSError as e:
                    out["init_" + name] = e.errno
            try:
                open(SECRET).read()
                out["secret"] = "read"
            except OSError as e:
                out["secret"] = type(e).__name__
            for folder in ("/dev/shm", "/tmp"):
                with open(os.path.join(folder, "token-" + self.token), "w") as f:
                    f.write("x")
                out[folder] = sorted(n for n in os.listdir(folder) if n.startswith("token-"))
            out["root"] = sorted(os.listdir("/"))
            out["read_only_root"] = refused(libc.mkdir(b"/new", 0o755))
            raise RuntimeError("PROBE" + json.dumps(out))

    class Spin:
        def __call__(self, ctx):
            end = time.process_time() + 0.3
            while time.process_time() < end:
                pass
            raise RuntimeError("SPUN")
""")


@pytest.fixture
def probe_module(tmp_path, monkeypatch):
    folder = tmp_path / "plug"
    folder.mkdir()
    secret = tmp_path / "secret.txt"
    secret.write_text("the user's")
    (folder / "zygote_probe.py").write_text(PROBE.format(secret=str(secret)))
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.delitem(sys.modules, "zygote_probe", raising=False)   # (each test's own copy)
    import importlib
    importlib.invalidate_caches()
    return importlib.import_module("zygote_probe")


def probed(contestant):
    with pytest.raises(PluginError) as e:
        contestant.call({"op": "start", "ctx": None})
    said = str(e.value)
    assert "PROBE" in said, said
    return json.loads(said[said.index("PROBE") + 5:])


def probe_two(module):
    """Two contestants side by side, each probed; (kind of process, their findings)."""
    a = Contestant("a", "zygote_probe", start=module.Probe("a")).begin()
    b = Contestant("b", "zygote_probe", start=module.Probe("b")).begin()
    try:
        return type(a.sandbox.process).__name__, probed(a), probed(b)
    finally:
        a.close()
        b.close()


def test_a_forked_contestant_sees_and_may_do_what_a_fresh_one_may(probe_module, monkeypatch):
    monkeypatch.setenv("DC_TEST_JUDGES_OWN", "judges-own-value")   # (a variable of dc's, a token say)
    kind, forked_a, forked_b = probe_two(probe_module)
    assert kind == "ForkedProcess"
    monkeypatch.setenv("DC_NO_ZYGOTE", "1")
    kind, fresh_a, fresh_b = probe_two(probe_module)
    assert kind == "Popen"
    # (bubblewrap leaves its root folder writable, a tmpfs of no size limit; a fork's root is
    # read-only: stricter, never looser; its bounding set is the one thing else that may differ)
    assert forked_b["read_only_root"] == 30 and fresh_b["read_only_root"] in (0, 30)
    # (its PID 1: a fork's is the copy of the zygote it was forked from, which it holds itself;
    # bubblewrap's is its own small init, which holds the contestant's command line and none of
    # dc's environment: it held every variable of dc's, a token say)
    for found in (forked_a, forked_b, fresh_a, fresh_b):
        assert found["init_environ"] in ("read", 13) and found["init_mem"] in ("read", 13), found
    for found in (forked_a, forked_b, fresh_a, fresh_b):
        found.pop("CapBnd"), found.pop("read_only_root"), found.pop("init_environ"), found.pop("init_mem")
    assert forked_a == fresh_a and forked_b == fresh_b
    eperm = 1
    assert forked_b["pids"] == [1, 2]   # (its own namespace: neither the zygote nor a rival)
    assert forked_b["CapEff"] == forked_b["CapPrm"] == "0000000000000000"
    assert (forked_b["NoNewPrivs"], forked_b["Seccomp"], forked_b["uid"]) == ("1", "2", 65534)
    for call in ("unshare", "mount", "clone_newuser", "socket_unix", "socket_unix_high_bits", "ptrace",
                 "sched_setaffinity"):
        assert forked_b[call] == eperm, (call, forked_b)
    assert forked_b["secret"] == "FileNotFoundError"
    assert forked_b["/dev/shm"] == forked_b["/tmp"] == ["token-b"]   # (nothing of a's)


def test_a_forked_contestant_is_charged_its_cpu_from_its_own_group(probe_module):
    c = Contestant("spin", "zygote_probe", start=probe_module.Spin()).begin()
    try:
        assert type(c.sandbox.process).__name__ == "ForkedProcess"
        before = c.sandbox.cpu_seconds()
        with pytest.raises(PluginError, match="SPUN"):
            c.call({"op": "start", "ctx": None})
        assert c.sandbox.cpu_seconds() - before >= 0.3
    finally:
        c.close()
    assert c.sandbox.exit_description() == "killed by SIGKILL"


def test_where_the_zygote_cannot_fence_a_fork_the_contestant_starts_fresh(tmp_path, monkeypatch):
    # (a file in the machine's /dev/shm: the zygote has a /dev/shm of its own, so its fork cannot
    # bind it; a fresh sandbox can)
    shared = f"/dev/shm/dc-zygote-test-{os.getpid()}"
    with open(shared, "w") as f:
        f.write("x")
    monkeypatch.setattr(zygote, "_refused", [])
    try:
        box = GuestSandbox(replace(fence.CONTESTANT, readable=(shared,)), name="the test's contestant")
        import socket
        ours, theirs = socket.socketpair()
        try:
            box.start_guest(theirs.fileno())
            assert type(box.process).__name__ == "Popen"
            assert zygote._refused and "could not fence itself" in zygote._refused[0]
            assert not zygote.usable(fence.CONTESTANT)
        finally:
            theirs.close()
            ours.close()
            box.kill()
    finally:
        os.unlink(shared)


def test_the_zygotes_fence_is_a_profile_of_the_one_record():
    argv = fence.bwrap_argv(fence.ZYGOTE, ["x"])
    assert "--disable-userns" not in argv   # (its forks make their namespaces)
    assert argv[argv.index("--bind") + 1:argv.index("--bind") + 3] == ["/proc", "/proc"]
    assert "--disable-userns" in fence.bwrap_argv(fence.CONTESTANT, ["x"])
    # its seccomp lets it mount and unshare (for its forks); a contestant's refuses both, and clone of a namespace
    assert machine.seccomp_program("zygote") != machine.seccomp_program("contestant")
    assert {"mount", "unshare"} <= set(machine.ZYGOTE_ALLOWED)


def test_a_zygote_first_asked_for_by_a_thread_that_ends_serves_on(probe_module):
    # (a broker's line thread starts contestants for a job and ends with it: bubblewrap's
    # --die-with-parent follows the thread that started the zygote, and took every contestant
    # forked from it along)
    import threading
    zygote.close_all()
    kinds, started, go_on = [], threading.Event(), threading.Event()

    def first():
        c = Contestant("first", "zygote_probe", start=probe_module.Spin()).begin()
        kinds.append(type(c.sandbox.process).__name__)
        started.set()
        go_on.wait(60)
        c.close()
    t = threading.Thread(target=first)
    t.start()
    started.wait(60)
    c = Contestant("later", "zygote_probe", start=probe_module.Spin()).begin()
    go_on.set()
    t.join()
    try:
        assert kinds == ["ForkedProcess"] and type(c.sandbox.process).__name__ == "ForkedProcess"
        with pytest.raises(PluginError, match="SPUN"):
            c.call({"op": "start", "ctx": None})
    finally:
        c.close()


# --- A hostile contestant's tries (each must find what a fresh sandbox's contestant finds) -----------

HOSTILE = textwrap.dedent("""
    import json, os, resource, signal, time

    class SignalsItsInit:
        '''SIGINT to its namespace's PID 1: a fresh sandbox's (bubblewrap) takes no signal from inside.'''
        def __call__(self, ctx):
            os.kill(1, signal.SIGINT)
            time.sleep(0.3)
            raise RuntimeError("ALIVE")

    class SignalsItsGroup:
        '''SIGINT to its process group: a fresh sandbox's is the namespace's own (--new-session).'''
        def __call__(self, ctx):
            os.kill(0, signal.SIGINT)   # (the guest itself ignores SIGINT)
            time.sleep(0.3)
            raise RuntimeError("ALIVE" + json.dumps([os.getpgid(0), os.getsid(0)]))

    class Loopback:
        '''Its own 127.0.0.1 (bubblewrap brings a new network namespace's loopback up).'''
        def __call__(self, ctx):
            import socket
            try:
                socket.create_connection(("127.0.0.1", 9), timeout=5).close()
                found = 0
            except OSError as e:
                found = e.errno
            raise RuntimeError("ERRNO" + json.dumps(found))

    class Inherited:
        '''Its descriptors, its PID 1's, and its mounts.'''
        def __call__(self, ctx):
            def targets(pid):
                out = []
                for fd in os.listdir(f"/proc/{pid}/fd"):
                    try:
                        out.append(os.readlink(f"/proc/{pid}/fd/{fd}"))
                    except OSError:   # (the listing's own descriptor, closed)
                        pass
                return sorted(out)
            mounts = [line.split()[4] for line in open("/proc/self/mountinfo")]
            raise RuntimeError("FOUND" + json.dumps({"own": targets("self"), "init": targets(1), "mounts": mounts}))

    class Limits:
        def __call__(self, ctx):
            raise RuntimeError("LIMITS" + json.dumps({"as": resource.getrlimit(resource.RLIMIT_AS)}))

    class TorchDraws:
        '''torch's seed and first draws (torch seeds itself afresh as an interpreter starts).'''
        def __call__(self, ctx):
            import torch
            raise RuntimeError("DRAWS" + json.dumps([torch.initial_seed(), torch.rand(4).tolist()]))
""")


@pytest.fixture
def hostile(tmp_path, monkeypatch):
    folder = tmp_path / "hostile"
    folder.mkdir()
    (folder / "zygote_hostile.py").write_text(HOSTILE)
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.delitem(sys.modules, "zygote_hostile", raising=False)
    import importlib
    importlib.invalidate_caches()
    return importlib.import_module("zygote_hostile")


def said_by(contestant):
    """What the contestant's start raised (its one line), and how its process was started."""
    try:
        with pytest.raises(PluginError) as e:
            contestant.call({"op": "start", "ctx": None})
        return type(contestant.sandbox.process).__name__, str(e.value)
    finally:
        contestant.close()


@pytest.mark.parametrize("fresh", [False, True])
@pytest.mark.parametrize("probe", ["SignalsItsInit", "SignalsItsGroup"])
def test_a_contestant_signals_no_process_that_ends_its_namespace(hostile, monkeypatch, fresh, probe):
    # (a fork's PID 1 is a fork of the zygote's Python, which handles SIGINT: the contestant ended
    # itself, said as exit status 0; and its process group was the outer fork's, outside its PID
    # namespace, which a SIGINT to the group ended: exit status 1)
    if fresh:
        monkeypatch.setenv("DC_NO_ZYGOTE", "1")
    kind, said = said_by(Contestant("sig", "zygote_hostile", start=getattr(hostile, probe)()).begin())
    assert kind == ("Popen" if fresh else "ForkedProcess")
    assert "ALIVE" in said, said
    if probe == "SignalsItsGroup":
        assert json.loads(said[said.index("ALIVE") + 5:]) == [1, 1]   # (its group and session: its namespace's first process's)


def test_without_a_memory_group_contestants_are_forked_with_their_address_space_limit(hostile, monkeypatch):
    # (where the machine lends no memory group, a sandbox's memory is its address space: the
    # zygote's own (4 GiB, hard) was under a contestant's, which a fork cannot raise, so every fork
    # was refused and every contestant started fresh)
    roots = {k: v for k, v in machine.cgroup_roots().items() if k != "memory"}
    monkeypatch.setattr(machine, "cgroup_roots", lambda: roots)
    monkeypatch.setattr(zygote, "_refused", [])
    zygote.close_all()
    try:
        kind, said = said_by(Contestant("as", "zygote_hostile", start=hostile.Limits()).begin())
    finally:
        zygote.close_all()   # (the next test's zygote starts with the machine's groups)
    assert zygote._refused == [] and kind == "ForkedProcess", zygote._refused
    soft, hard = json.loads(said[said.index("LIMITS") + 6:])["as"]
    assert soft == hard >= fence.MEMORY_FLOOR


def test_a_fork_of_the_judge_starts_its_own_zygote_and_leaves_its_parents_alone(probe_module):
    # (a -j worker forked from a process that had a zygote waited forever for the keeper thread,
    # which a fork does not copy; and the parent's zygote is not the worker's to end)
    import signal
    first = Contestant("parent", "zygote_probe", start=probe_module.Spin()).begin()
    first.close()
    pid = os.fork()
    if pid == 0:
        signal.alarm(60)
        code = 1
        try:
            c = Contestant("child", "zygote_probe", start=probe_module.Spin()).begin()
            try:
                c.call({"op": "start", "ctx": None})
            except PluginError as e:
                code = 0 if "SPUN" in str(e) and type(c.sandbox.process).__name__ == "ForkedProcess" else 3
            c.close()
            zygote.close_all()
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    later = Contestant("parent again", "zygote_probe", start=probe_module.Spin()).begin()
    try:
        with pytest.raises(PluginError, match="SPUN"):
            later.call({"op": "start", "ctx": None})
    finally:
        later.close()


def test_a_judge_holding_many_files_starts_and_ends_forked_contestants(hostile):
    # (the judge waited for a fork's status with select, which refuses a descriptor numbered 1024
    # or more: a library user's process holding many files got a traceback, and dc's way out
    # (kill_all) stopped at that contestant, ending none after it)
    import resource
    if resource.getrlimit(resource.RLIMIT_NOFILE)[0] < 1200:
        pytest.skip("this process may not hold 1200 files")
    held = [os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC) for _ in range(1100)]
    try:
        kind, said = said_by(Contestant("many", "zygote_hostile", start=hostile.Limits()).begin())
    finally:
        for fd in held:
            os.close(fd)
    assert kind == "ForkedProcess" and "LIMITS" in said, said


def test_a_contestant_with_a_memory_group_has_no_address_space_limit_of_its_zygotes(hostile, monkeypatch):
    # (a zygote started where no memory group was lent has an address space limit; a contestant
    # forked from it into a memory group of its own inherited it, where a fresh one has none)
    roots = machine.cgroup_roots()
    monkeypatch.setattr(zygote, "_refused", [])
    zygote.close_all()
    monkeypatch.setattr(machine, "cgroup_roots", lambda: {k: v for k, v in roots.items() if k != "memory"})
    zygote.live()
    monkeypatch.setattr(machine, "cgroup_roots", lambda: roots)
    try:
        kind, said = said_by(Contestant("as", "zygote_hostile", start=hostile.Limits()).begin())
    finally:
        zygote.close_all()
    assert kind == "ForkedProcess", said
    assert json.loads(said[said.index("LIMITS") + 6:])["as"] == [-1, -1]


@pytest.mark.parametrize("fresh", [False, True])
def test_a_contestants_loopback_is_up_and_its_own(hostile, monkeypatch, fresh):
    # (a fork's new network namespace had its loopback down: 127.0.0.1 unreachable, where a fresh
    # sandbox's answers; a listener of its own is all it reaches either way: no port is open)
    if fresh:
        monkeypatch.setenv("DC_NO_ZYGOTE", "1")
    kind, said = said_by(Contestant("lo", "zygote_hostile", start=hostile.Loopback()).begin())
    assert kind == ("Popen" if fresh else "ForkedProcess")
    import errno
    assert json.loads(said[said.index("ERRNO") + 5:]) == errno.ECONNREFUSED, said


def test_a_forked_contestant_holds_no_descriptor_or_mount_of_the_zygotes(hostile):
    kind, said = said_by(Contestant("fds", "zygote_hostile", start=hostile.Inherited()).begin())
    assert kind == "ForkedProcess"
    found = json.loads(said[said.index("FOUND") + 5:])
    own = [t for t in found["own"] if t != "/dev/null"]
    assert len(own) == 3 and sum(t.startswith("socket:") for t in own) == 1, found   # (its line, its two streams)
    assert all(t.startswith("pipe:") for t in own if not t.startswith("socket:")), found
    assert found["init"] == ["/dev/null"] * 3, found   # (its PID 1 holds nothing of the zygote's)
    # (its root first, then only what its fence record names: no /proc of the machine's, no old root)
    assert found["mounts"][0] == "/" and found["mounts"].count("/") == 1 and found["mounts"].count("/proc") == 1
    allowed = ("/proc", "/dev", "/tmp", *fence.SYSTEM, "/etc/", sys.prefix, sys.base_prefix,
               os.path.dirname(os.path.realpath(sys.executable)))
    import deepcontact
    allowed += (os.path.dirname(os.path.dirname(deepcontact.__file__)),)
    import site
    allowed += tuple(site.getsitepackages())
    strays = [m for m in found["mounts"][1:] if not m.startswith(allowed)]
    assert not strays, strays


def _loads_torch(box):
    """Whether a process of the sandbox `box` has torch's library mapped."""
    _, folder = box.groups["pids"]
    with open(os.path.join(folder, "cgroup.procs")) as f:
        pids = f.read().split()
    found = False
    for pid in pids:
        try:
            with open(f"/proc/{pid}/maps") as f:
                found = found or "libtorch" in f.read()
        except OSError:
            pass
    return found


def test_a_network_contestant_is_forked_from_a_zygote_of_its_own_with_torch_loaded():
    # (torch loaded once in a zygote of its own, not in each such contestant; the other
    # contestants' zygote never loads it, so no other contestant finds it loaded)
    import socket
    box = GuestSandbox(fence.CONTESTANT, name="the test's contestant")
    ours, theirs = socket.socketpair()
    try:
        box.start_guest(theirs.fileno(), torch=True)
        assert type(box.process).__name__ == "ForkedProcess"
        with_torch, plain = zygote.live(torch=True), zygote.live()
        assert with_torch is not plain and with_torch.alive() and plain.alive()
        assert _loads_torch(with_torch.box) and not _loads_torch(plain.box)
    finally:
        theirs.close()
        ours.close()
        box.kill()


def test_a_zygote_that_ends_before_it_is_ready_is_refused_and_contestants_start_fresh(monkeypatch):
    import socket
    monkeypatch.setattr(zygote, "_refused", [])
    monkeypatch.setattr(zygote, "ZYGOTE_COMMAND", "import sys; sys.exit(3)")
    zygote.close_all()
    box = GuestSandbox(fence.CONTESTANT, name="the test's contestant")
    ours, theirs = socket.socketpair()
    try:
        box.start_guest(theirs.fileno())
        assert type(box.process).__name__ == "Popen"
        assert zygote._refused == ["the zygote ended as it started"]
    finally:
        theirs.close()
        ours.close()
        box.kill()
        zygote.close_all()


def test_contestants_forked_with_torch_loaded_draw_torchs_random_numbers_of_their_own(hostile, tmp_path):
    # (every fork of the torch zygote had its generator's seed and state: two contestants drew the
    # same numbers, where two fresh ones, each seeded afresh by torch as it starts, do not)
    checkpoint = tmp_path / "net.pt"
    checkpoint.write_bytes(b"")   # (torch loaded before its clock; this start never reads it)
    draws = []
    for name in ("a", "b"):
        kind, said = said_by(Contestant(name, "zygote_hostile", start=hostile.TorchDraws(),
                                        checkpoint=str(checkpoint)).begin())
        assert kind == "ForkedProcess" and "DRAWS" in said, said
        draws.append(json.loads(said[said.index("DRAWS") + 5:]))
    assert draws[0][0] != draws[1][0] and draws[0][1] != draws[1][1], draws


def started_kind(torch=False):
    """The kind of process a contestant (given torch or not) started as; ended before this returns."""
    import socket
    box = GuestSandbox(fence.CONTESTANT, name="the test's contestant")
    ours, theirs = socket.socketpair()
    try:
        box.start_guest(theirs.fileno(), torch=torch)
        return type(box.process).__name__
    finally:
        theirs.close()
        ours.close()
        box.kill()


def started_kinds(torches):
    """started_kind of each of torches in turn, every zygote ended after them."""
    try:
        return [started_kind(torch) for torch in torches]
    finally:
        zygote.close_all()


def test_a_torch_zygote_that_is_never_ready_leaves_the_plain_one_forking(monkeypatch):
    # (torch's import failing in its zygote, or slower than READY_DEADLINE, says nothing of the
    # machine's fence: it refused every later contestant its fork, the plain ones too)
    monkeypatch.setattr(zygote, "_refused", [])
    monkeypatch.setattr(zygote, "_unready", [], raising=False)
    monkeypatch.setattr(zygote, "ZYGOTE_COMMAND", "import sys; sys.argv[4:] == ['torch'] and sys.exit(3); "
                        + zygote.ZYGOTE_COMMAND)
    zygote.close_all()
    kinds = started_kinds((True, False, True))
    assert kinds == ["Popen", "ForkedProcess", "Popen"] and zygote._refused == [], (kinds, zygote._refused)
    assert zygote._unready == ["the zygote ended as it started"]


def test_a_zygote_that_ends_under_a_request_is_replaced_and_forks_go_on(monkeypatch):
    # (killed, or out of memory, between the judge's check that it lives and its request: every
    # later contestant of the process started fresh, though the machine's fence held)
    monkeypatch.setattr(zygote, "_refused", [])
    zygote.close_all()
    real, asked = zygote.live, []

    def live_then_ended(torch=False):
        z = real(torch)
        if not asked:
            z.box.kill()   # (its processes and groups gone; this process still holds it)
        asked.append(z)
        return z
    monkeypatch.setattr(zygote, "live", live_then_ended)
    kinds = started_kinds((False, False))
    assert kinds == ["ForkedProcess", "ForkedProcess"] and zygote._refused == [], (kinds, zygote._refused)
    assert asked[1] is not asked[0]


def test_a_zygote_whose_interpreter_is_killed_is_replaced_though_bubblewrap_has_not_noticed(monkeypatch):
    # (the out-of-memory killer ends the zygote's interpreter, not the bubblewrap around it, which
    # ends a moment later: taken for alive then, the refused fork refused every later one)
    import signal
    import time
    monkeypatch.setattr(zygote, "_refused", [])
    zygote.close_all()
    try:
        z = zygote.live(False)
        os.kill(z.box.process.pid, signal.SIGSTOP)   # (bubblewrap's moment, held: it cannot end)
        folder = next(iter(z.box.groups.values()))[1]
        with open(os.path.join(folder, "cgroup.procs")) as f:
            pids = [int(p) for p in f.read().split()]
        interpreter = [p for p in pids if not os.readlink(f"/proc/{p}/exe").endswith("bwrap")]
        assert len(interpreter) == 1, pids
        os.kill(interpreter[0], signal.SIGKILL)
        due = time.monotonic() + 5
        while os.path.exists(f"/proc/{interpreter[0]}") and time.monotonic() < due:
            time.sleep(0.01)
        kind = started_kind()
    finally:
        zygote.close_all()
    assert kind == "ForkedProcess" and zygote._refused == [], (kind, zygote._refused)


def test_a_checkpoints_load_imports_no_compiler_of_torch(model):
    # (a checkpoint's load checks its network on torch's meta device, where the He init's normal_
    # imported torch._dynamo: 1.1-1.5 s of CPU in each load, so in each network contestant's
    # setup, forked or fresh, though torch's own import is before its clock; a process of its own:
    # this one may have imported it for another test)
    import subprocess
    code = ("import sys; from deepcontact.model.inference import Predictor; Predictor(sys.argv[1]).build(); "
            "print('torch._dynamo' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code, str(model / "best.pt")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and r.stdout.split() == ["False"], (r.stdout, r.stderr)


def test_a_fenced_jobs_contestant_given_a_network_is_forked_from_the_torch_zygote(monkeypatch):
    # (the broker's start for a job: its torch field picks the zygote, as the judge's own does)
    import socket
    from deepcontact.contest import broker, grants
    judge = broker.Broker()
    monkeypatch.setenv(broker.ENV, str(judge.job_fd))
    monkeypatch.setattr(broker, "_conn", None)
    ours, theirs = socket.socketpair()
    box = broker.RemoteSandbox(grants.Grant([], [], []))
    try:
        box.start_guest(theirs.fileno(), torch=True)
        started = judge.boxes[box.id]
        assert type(started.process).__name__ == "ForkedProcess"
        assert _loads_torch(started) and _loads_torch(zygote.live(torch=True).box)
    finally:
        box.kill()
        theirs.close()
        ours.close()
        judge.close()
        monkeypatch.setattr(broker, "_conn", None)
