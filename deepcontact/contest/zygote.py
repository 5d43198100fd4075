"""The judge's side of the contestants' zygote (forked.py is the zygote's): the interpreter and
its libraries are made once, in a sandbox of their own (fence.ZYGOTE), and each contestant is a
fork of it that fences itself as a contestant before any code of its own runs. What a contestant
sees, is charged and may do is its fence record's (fence.CONTESTANT), whichever way it starts:
only the start is cheaper (a fork in place of a fresh interpreter).

One zygote serves every contestant of this process (one a setting of Python's warnings, which an
interpreter reads as it starts); it is a Sandbox like any (ended with them, kill_all). Where the machine cannot fork fenced
contestants (no bubblewrap, no writable control groups for CPU and processes, a kernel that
refuses a fork's namespace or mount), `usable` is False or the first fork says so (Refused), and
contestants start as fresh sandboxes, as before: the fence is the same, only slower.
"""
import json
import logging
import os
import queue
import select
import socket
import struct
import subprocess
import sys
import threading
import time

from . import fence as fences, forked, grants, machine, sandbox

# seconds a fork may take to fence itself (about 20 ms; a loaded machine's hiccup allowed for):
# past it the zygote is taken for stopped, and the contestant starts fresh
FENCE_DEADLINE = 10.0
# seconds a zygote may take to load its libraries (numpy; torch for a network's contestants)
READY_DEADLINE = 120.0
# (deepcontact imported from the judge's own folder, put first: the interpreter's own path found
# another copy where the judge's came from PYTHONPATH or its working directory, and a fork then
# lacked every module the zygote had not imported)
ZYGOTE_COMMAND = ("import sys; sys.path.insert(0, sys.argv[2]); from deepcontact.contest.forked import main; "
                  "main(int(sys.argv[1]), sys.argv[3], torch='torch' in sys.argv[4:], job='job' in sys.argv[4:])")
# A job's variables that are its own, set in its fork (its folders, dc's DC_* to it; where a shell
# or a test runner is, which changes from command to command and no library reads as it loads):
# any other may be read as an interpreter starts or a library loads (TZ, OMP_NUM_THREADS, CXX), so
# the jobs' zygote is made with them, one zygote for each set
JOB_OWN_VARIABLES = ("TMPDIR", "PYTHONPATH", "MPLCONFIGDIR", "PWD", "OLDPWD", "_", "PYTEST_CURRENT_TEST")
# The job profiles whose zygote has torch loaded (a network's training, a drawing with one); a
# study and the listing fork from one without it, which starts in a fraction of a second
TORCH_PROFILES = ("training", "drawing")
_zygotes = {}           # {the variables its contestants start with: Zygote}
_refused = []           # why a fork could not be fenced here (then no zygote is used again)
_unready = []           # why the torch zygote was never ready (then contestants given torch start fresh)

log = logging.getLogger(__name__)


Refused = sandbox.ForkRefused   # (a fork could not fence itself here: the line says which step)


class Unready(Refused):
    """A zygote that ended, or was not ready in time, before any fork was asked of it."""


def usable(fence, torch=False):
    """Whether a contestant of `fence` may be forked from a zygote here: a contestant's fence of
    one thread (the zygote's libraries are loaded for one) on a machine that lends bubblewrap,
    seccomp and control groups for CPU and processes, and no fork refused before (torch: nor the
    torch zygote's start)."""
    roots = machine.cgroup_roots()
    return (not _refused and not (torch and _unready) and fence.seccomp == "contestant" and fence.threads == 1
            and fence.view == "system" and fence.environment == "clear" and machine.bwrap() is not None
            and machine.seccomp_program(fence.seccomp) is not None and "cpu" in roots and "pids" in roots
            and os.environ.get("DC_NO_ZYGOTE") != "1")


def live(torch=False):
    """This process's live zygote (started the first time it is asked for): every contestant's
    fence is carried by its request, so one serves them all; torch: the one whose interpreter has
    torch and the model's side loaded too (a contestant that loads a trained network), apart, so
    that no other contestant finds torch already loaded."""
    # (its interpreter started with the variables its contestants' would: the warnings' setting
    # among them, which Python reads as it starts)
    key = (tuple(sorted((k, v) for k, v in fences.environment(fences.ZYGOTE).items() if k != fences.MARKER)),
           bool(torch))
    with _lock:
        zygote = _zygotes.get(key)
        if zygote is None or not zygote.alive():
            if zygote is not None:
                zygote.close()
            zygote = _zygotes[key] = _by_keeper(torch=bool(torch))
        return zygote


def usable_for_job(fence):
    """Whether a job of `fence` may be forked from the jobs' zygote here: a job's view of the
    whole file system, no device files (an accelerator's driver is loaded by the job itself), a
    machine that lends bubblewrap, seccomp and control groups for CPU and processes, and no job's
    fork refused before."""
    roots = machine.cgroup_roots()
    return (not _job_refused and fence.view == "root" and not fence.devices and fence.environment == "given"
            and machine.bwrap() is not None and machine.seccomp_program(fence.seccomp) is not None
            and machine.seccomp_program(fences.JOB_ZYGOTE.seccomp) is not None and "cpu" in roots
            and "pids" in roots and os.environ.get("DC_NO_ZYGOTE") != "1")


def job_environment(env):
    """The part of a job's environment its zygote is made with: all but its own variables
    (JOB_OWN_VARIABLES, DC_*), which each fork sets (forked._job)."""
    return {key: value for key, value in env.items() if key not in JOB_OWN_VARIABLES and not key.startswith("DC_")}


def live_job(env, torch=False):
    """This process's live jobs' zygote for a job of environment `env` (its interpreter and
    libraries loaded with env's job_environment); torch: the one with torch loaded too."""
    start = job_environment(env)
    key = ("job", tuple(sorted(start.items())), bool(torch))
    with _lock:
        zygote = _zygotes.get(key)
        if zygote is None or not zygote.alive():
            if zygote is not None:
                zygote.close()
            # (one of each kind kept: another environment's, none of whose jobs still runs, ended;
            # a job dies with its zygote)
            for other, idle in list(_zygotes.items()):
                if other[0] == "job" and other[2] == key[2] and not idle.busy():
                    idle.close()
                    del _zygotes[other]
            zygote = _zygotes[key] = _by_keeper(torch=bool(torch), job_env=start)
        return zygote


_job_refused = []   # why a job's fork could not be fenced here (then jobs start fresh)


def shadowed(zygote, env, cwd):
    """The first of the modules the jobs' zygote loaded (its libraries, the standard library's,
    deepcontact) that a job of environment `env` in folder `cwd` would import from another copy
    (its folder or PYTHONPATH holds one), or None: such a job starts fresh, as the fork's copy is
    the zygote's."""
    from importlib.machinery import PathFinder
    first = [cwd, *(p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p)]
    for name, origin in zygote.origins.items():
        try:
            found = PathFinder.find_spec(name, first)
        except (ImportError, ValueError):
            found = None
        if found is not None and found.origin and os.path.realpath(found.origin) != os.path.realpath(origin):
            return name
    return None


def refused_job(error):
    """Notes that forking a fenced job failed here; later jobs start as fresh sandboxes."""
    if not _job_refused:
        log.info("dc: jobs start as fresh sandboxes: %s", error)
    _job_refused.append(str(error))


_lock = threading.Lock()
_asks = queue.Queue()
_keeper = []


def _by_keeper(**made):
    """A new Zygote, started by a thread that lives as long as this process: bubblewrap's
    --die-with-parent follows the thread that started it, and a broker's line thread, which
    ends with its job, left every later contestant without its zygote."""
    if not _keeper:
        _keeper.append(threading.Thread(target=_keep, name="dc-zygote-keeper", daemon=True))
        _keeper[0].start()
    done, answer = threading.Event(), []
    _asks.put((done, answer, made))
    done.wait()
    if isinstance(answer[0], BaseException):
        raise answer[0]
    return answer[0]


def _forget_in_child():
    """In a fork of this process (a -j worker): the parent's zygotes are not its own to use or
    end (its copies of their lines closed, nothing killed), and the keeper thread was not forked
    (a worker that asked it for a zygote waited forever): it starts its own."""
    global _lock, _asks
    for zygote in _zygotes.values():
        if zygote.line is not None:
            zygote.line.close()
            zygote.line = None
    _zygotes.clear()
    _keeper.clear()
    _lock, _asks = threading.Lock(), queue.Queue()


os.register_at_fork(after_in_child=_forget_in_child)


def _keep():
    while True:
        done, answer, made = _asks.get()
        try:
            answer.append(Zygote(**made))
        except BaseException as e:
            answer.append(e)
        done.set()


def forked_start(box, made, fork, refuse):
    """Whether box's process was started as `fork(zygote)` of the zygote `made()` gives (None:
    this one starts fresh, say nothing). A refused fork leaves box as it was before: a zygote that
    ended under the request (killed or out of memory: nothing of the machine's fence) is made
    again, once; else refuse(error) notes it and False is returned."""
    for again in (True, False):
        used = None
        try:
            used = made()
            if used is None:
                return False
            fork(used)
            return True
        except Refused as e:
            box.kill()
            box.stopped_by, box.process = None, None
            if again and used is not None and not used.alive():
                continue
            refuse(e)
            return False
    return False


def refused(error, torch=False):
    """Notes that forking fenced contestants failed here (error: Refused); later ones start fresh.
    Where the torch zygote was never ready (torch's import, not the machine's fence), only those
    given torch do."""
    if torch and isinstance(error, Unready):
        log.info("dc: contestants given a network start as fresh sandboxes: %s", error)
        _unready.append(str(error))
        return
    if not _refused:
        log.info("dc: contestants start as fresh sandboxes: %s", error)
    _refused.append(str(error))


class Zygote:
    """One zygote in its sandbox and the line to it (torch: its interpreter has torch loaded)."""

    def __init__(self, torch=False, job_env=None):
        job = job_env is not None
        self._forks = []
        self.box = sandbox.Sandbox(fences.JOB_ZYGOTE if job else fences.ZYGOTE,
                                   name="the jobs' zygote" if job else "the contestants' zygote")
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            package = grants.package_folder()
            self.box.start([sys.executable, "-c", ZYGOTE_COMMAND, str(theirs.fileno()), os.path.dirname(package),
                            package, *(["torch"] if torch else []), *(["job"] if job else [])],
                           pass_fds=[theirs.fileno()],
                           # (the jobs' zygote: a folder to write in for an import that asks for one,
                           # torch's compiler's; its own /dev/shm, which each fork covers)
                           env=None if not job else {**job_env, "TMPDIR": "/dev/shm"})
        except BaseException:
            ours.close()
            self.box.kill()
            raise
        finally:
            theirs.close()
        self.line = ours
        # (its libraries loaded before any fork is asked of it: torch takes seconds on a busy
        # machine, which the first fork's fence deadline is not for)
        said = ours.recv(1 << 16) if _ready(ours.fileno(), READY_DEADLINE) else None
        self.origins = json.loads(said[1:]) if said and said.startswith(forked.READY) and len(said) > 1 else {}
        if not said or not said.startswith(forked.READY):
            self.close()
            raise Unready("the zygote " + ("ended as it started" if said is not None else
                                           f"was not ready within {READY_DEADLINE:.0f} s"))

    def busy(self):
        """Whether a process forked from it may still run (its end would end them): one whose
        status line its last writer has not closed. Asked without reading it (its own thread reads)."""
        return any(p.returncode is None and p.fd is not None and not _hung_up(p.fd) for p in list(self._forks))

    def alive(self):
        # (its line hung up: the interpreter ended, killed or out of memory, though the bubblewrap
        # around it has not yet; taken for alive, its refused fork refused every later one)
        return (self.box.process is not None and self.box.process.poll() is None and self.line is not None
                and not _hung_up(self.line.fileno()))

    def fork(self, request, fds):
        """Asks for a contestant: request (its fence record, variables, limits) and its descriptors
        [line, output, error, seccomp, cgroup.procs files...]; its ForkedProcess (the status pipe
        put after its error)."""
        status, status_w = os.pipe()
        try:
            socket.send_fds(self.line, [json.dumps(request).encode()], [*fds[:3], status_w, *fds[3:]])
        except OSError as e:
            os.close(status)
            raise Refused(f"the zygote did not take the request ({e})") from None
        finally:
            os.close(status_w)
        forked = ForkedProcess(status)
        self._forks = [p for p in self._forks if p.returncode is None and p.fd is not None] + [forked]
        return forked

    def close(self):
        if self.line is not None:
            self.line.close()
            self.line = None
        self.box.kill()


def close_all():
    """Ends every zygote of this process."""
    for zygote in list(_zygotes.values()):
        zygote.close()
    _zygotes.clear()


def _hung_up(fd):
    """Whether the other end of the socket fd has closed."""
    waiting = select.poll()
    waiting.register(fd, 0)   # (a hang-up is reported whatever is asked)
    return any(events & (select.POLLHUP | select.POLLERR) for _, events in waiting.poll(0))


def _ready(fd, timeout):
    """Whether fd has something to read (or its end) within timeout seconds. By poll: select
    refuses a descriptor numbered 1024 or more, which a process holding many files gets."""
    waiting = select.poll()
    waiting.register(fd, select.POLLIN)
    return bool(waiting.poll(max(timeout, 0) * 1000))


class ForkedProcess:
    """The part of a Popen a sandbox uses, for a contestant forked by the zygote, read from its
    status pipe (forked.py): "J" fenced, "X" and its exit code, or "E" and why it could not be
    fenced. pid is None: the judge ends it through its control groups (Sandbox.kill)."""

    pid = None

    def __init__(self, status_fd):
        self.fd = status_fd
        self.returncode = None
        self.fenced = False
        self.error = None
        self._data = b""

    def _read(self, timeout):
        if self.fd is None:
            return
        if not _ready(self.fd, timeout):
            return
        chunk = os.read(self.fd, 4096)
        self._data += chunk
        self.fenced = self.fenced or self._data.startswith(b"J")
        if chunk:
            return
        os.close(self.fd)
        self.fd = None
        body = self._data[1:] if self.fenced else self._data
        if body.startswith(b"E"):
            self.error = body[1:].split(b"\0")[0].decode(errors="replace") or "no reason given"
            self.returncode = 1
        elif body.startswith(b"X") and len(body) >= 5:
            self.returncode = struct.unpack("i", body[1:5])[0]
        else:   # (its fork outside the namespace killed: by the judge, or at a limit)
            self.returncode = -9

    def wait_fenced(self, timeout=FENCE_DEADLINE):
        """Waits until the contestant's fence is up; Refused where it could not be built."""
        due = time.monotonic() + timeout
        while not self.fenced and self.returncode is None and time.monotonic() < due:
            self._read(due - time.monotonic())
        if not self.fenced:
            raise Refused(f"a fork of the zygote could not fence itself: {self.error or 'it did not say it was fenced'}")

    def poll(self):
        self._read(0)
        while self.fd is not None and self._readable():
            self._read(0)
        return self.returncode

    def _readable(self):
        return _ready(self.fd, 0)

    def wait(self, timeout=None):
        due = None if timeout is None else time.monotonic() + timeout
        while self.returncode is None:
            if due is not None and time.monotonic() >= due:
                raise subprocess.TimeoutExpired("contestant", timeout)
            self._read(1.0 if due is None else min(1.0, due - time.monotonic()))
        return self.returncode

    def kill(self):
        """(its sandbox ends it, by its control groups)"""

    def close(self):
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
