"""A contestant's fence, built the way contest judges build theirs (IOI's isolate, DOMjudge's
runguard): each contestant is a fresh interpreter started by bubblewrap in namespaces of its own
(user, PID, mount, IPC, network, UTS, cgroup), in a control group of its own that the judge owns.

What it sees: a read-only view of the interpreter, the installed packages, deepcontact and the
plug-in's own module (and a checkpoint it is given); a private /tmp; its own /proc, which shows
only its own processes. No run folder, no output being written, no other process: a rival or the
judge cannot be named, so cannot be signalled, reniced, traced or read. Seccomp refuses ptrace,
cross-process memory reads and the calls that would change the fence; no new privileges; no
capabilities. Limits: processes, memory (the control group where the kernel lends one, else the
address space), file size.

What it is charged: the CPU time of its control group, which counts every process and thread it
starts, detached ones included, from its start to its end; read by the judge, never asked of the
contestant. When the sandbox ends, its PID namespace ends with it: nothing it started survives.

Where the kernel or the machine refuses a fence (no bubblewrap, no user namespaces, no writable
control group), the project's own code (a built-in start, the null contestant) still runs, as a
plain process of its own, and `fences()` says which fences are missing: the report's protocol
line and the verdict print it. Plug-in code fails closed there (refuse_bare): it runs bare only
where the user's option --unfenced says so, and the command's last line names what was missing.
Nothing is dropped silently.
"""
import os
import signal
import subprocess
import sys
import time

from ..leftovers import at_end, own_processes
from ..output import record
from ..plugins import PluginError
from . import machine

MEMORY_LIMIT = 8 << 30     # bytes a contestant's processes may hold together
PROCESS_LIMIT = 64         # processes and threads a contestant may run at once
FILE_LIMIT = 256 << 20     # bytes one file it writes may reach (its /tmp is a private tmpfs of this size)
# The thread pools a library starts at import (numpy's OpenBLAS, torch's OpenMP) size themselves to
# the machine's cores unless told: a contestant's are told its own thread count, so that neither its
# charge (OpenBLAS's idle pool cost each start 0.1 s of CPU on two cores) nor its answer depends on
# the machine.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

# Files of /etc an interpreter reads (the loader's cache, names of users and zones); the rest of
# /etc is not the contestant's to read.
_ETC = ("ld.so.cache", "ld.so.conf", "ld.so.conf.d", "localtime", "passwd", "group", "nsswitch.conf",
        "alternatives", "os-release")
_SYSTEM = ("/usr", "/lib", "/lib64", "/lib32", "/libx32", "/bin", "/sbin")


# --- Fail closed ------------------------------------------------------------------------------------

UNFENCED_OPTION = "--unfenced"
UNFENCED_ENV = "DC_UNFENCED"   # set by the option; a job's environment carries it to the job's own checks
JOB_FENCES = ("namespaces", "read-only view", "seccomp")   # what a job's fence is made of (no control group)
ran_bare = set()               # the fences plug-in code of this command ran without (the option said so)


def refuse_bare(who, missing):
    """Plug-in code (`who` names it) about to run where the fences `missing` cannot be built:
    PluginError, one line naming them and the option, unless the user gave --unfenced; then
    noted in ran_bare, for the command's last line."""
    if not missing:
        return
    if os.environ.get(UNFENCED_ENV) != "1":
        raise PluginError(f"{who} is plug-in code, and this machine cannot build its fence (missing: "
                          f"{', '.join(missing)}): it runs bare, with your access to your files, only with "
                          f"{UNFENCED_OPTION}")
    ran_bare.update(missing)
    record.remarks["unfenced"] = sorted(ran_bare)   # (in the record of every output the command writes)


# --- Groups left behind ---------------------------------------------------------------------------

_PREFIX = "dc-contestant-"
_swept = set()
_live = set()        # the sandboxes this process runs (ended by kill_all on the way out)
_started = set()     # the pids of their first processes (bubblewrap) until reaped: dc's own, never a plug-in's


def _sweep(base):
    """Removes the empty groups a dc process that died (SIGKILL, power) left in `base`: named after
    a process that no longer runs. Once per folder and process."""
    if base in _swept:
        return
    _swept.add(base)
    try:
        names = [n for n in os.listdir(base) if n.startswith(_PREFIX)]
    except OSError:
        return
    for name in names:
        owner = name[len(_PREFIX):].split("-")[0]
        if owner.isdigit() and not os.path.exists(f"/proc/{owner}"):
            try:
                os.rmdir(os.path.join(base, name))
            except OSError:
                pass


def kill_all():
    """Ends every sandbox this process still runs (dc's way out: nothing it started outlives it)."""
    for box in list(_live):
        box.kill()


def _sandbox_process(pid):
    """Whether pid is a process of a sandbox dc started: its bubblewrap, or one in a PID namespace
    other than dc's (only a sandbox makes one; its first process outlives bubblewrap by a moment
    as it is killed, and was blamed on a plug-in)."""
    if pid in _started:
        return True
    try:
        return os.readlink(f"/proc/{pid}/ns/pid") != os.readlink("/proc/self/ns/pid")
    except OSError:
        return False


# --- One sandbox -----------------------------------------------------------------------------------

class Sandbox:
    """One contestant's fence: its control group and its bubblewrap process. `start(argv, fds)`
    runs the command inside; `cpu_seconds()` is everything its processes have used; `kill()` ends
    them all and removes the group."""

    _count = 0

    def __init__(self, readable=(), threads=1):
        Sandbox._count += 1
        self.name = f"{_PREFIX}{os.getpid()}-{Sandbox._count}"
        self.readable = [os.path.abspath(p) for p in readable if p and os.path.exists(p)]
        self.threads = threads   # (None: the thread pools' own defaults; a job sets its own)
        self.groups = {}   # {controller: folder}
        self.process = None
        self._cpu_file = None

    def _make_groups(self):
        for controller, (kind, base) in machine.cgroup_roots().items():
            _sweep(base)
            folder = os.path.join(base, self.name)
            try:
                os.mkdir(folder)
            except FileExistsError:
                pass
            except OSError:
                continue
            self.groups[controller] = (kind, folder)
        settings = {("pids", "v2"): ("pids.max", PROCESS_LIMIT), ("pids", "v1"): ("pids.max", PROCESS_LIMIT),
                    ("memory", "v2"): ("memory.max", MEMORY_LIMIT),
                    ("memory", "v1"): ("memory.limit_in_bytes", MEMORY_LIMIT)}
        for controller, (kind, folder) in list(self.groups.items()):
            if (controller, kind) in settings:
                name, value = settings[controller, kind]
                try:
                    with open(os.path.join(folder, name), "w") as f:
                        f.write(str(value))
                except OSError:
                    del self.groups[controller]
        if "cpu" in self.groups:
            kind, folder = self.groups["cpu"]
            try:   # (kept open and read from offset 0 after every call: an open a call cost 30 us)
                self._cpu_file = (kind, os.open(os.path.join(folder, "cpu.stat" if kind == "v2" else "cpuacct.usage"),
                                                os.O_RDONLY | os.O_CLOEXEC))
            except OSError:
                del self.groups["cpu"]

    def _enter(self):
        """In the child, before exec: into the control groups, the limits on."""
        import resource
        for _, folder in dict.fromkeys(self.groups.values()):
            with open(os.path.join(folder, "cgroup.procs"), "w") as f:
                f.write("0")
        resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_LIMIT, FILE_LIMIT))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        if "memory" not in self.groups:
            resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
        os.setsid()

    def _argv(self, argv, seccomp_fd):
        bwrap = machine.bwrap()
        if bwrap is None:
            return list(argv)
        out = [bwrap, "--unshare-all", "--unshare-user", "--uid", "65534", "--gid", "65534", "--disable-userns",
               "--die-with-parent", "--new-session", "--cap-drop", "ALL", "--proc", "/proc", "--dev", "/dev",
               "--size", str(FILE_LIMIT), "--tmpfs", "/tmp", "--chdir", "/tmp", "--clearenv"]
        for path in _SYSTEM:
            if os.path.exists(path):
                out += ["--ro-bind", path, path] if not os.path.islink(path) else \
                    ["--symlink", os.readlink(path), path]
        for name in _ETC:
            if os.path.exists(f"/etc/{name}"):
                out += ["--ro-bind", f"/etc/{name}", f"/etc/{name}"]
        for path in dict.fromkeys(self.readable):
            out += ["--ro-bind", path, path]
        for key in ("PATH", "LANG", "LC_ALL", "TZ", "OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE"):
            if key in os.environ:
                out += ["--setenv", key, os.environ[key]]
        out += ["--setenv", "HOME", "/tmp", "--setenv", "PYTHONDONTWRITEBYTECODE", "1"]
        for key, value in self._thread_env().items():
            out += ["--setenv", key, value]
        if seccomp_fd is not None:
            out += ["--seccomp", str(seccomp_fd)]
        return out + ["--"] + list(argv)   # ("--": nothing of the command is ever bubblewrap's option)

    job = False   # (JobSandbox: a whole job's fence, not a contestant's)

    def _thread_env(self):
        return {} if self.threads is None else dict.fromkeys(THREAD_VARIABLES, str(self.threads))

    def start(self, argv, pass_fds=(), env=None, stdout=None, stderr=None):
        """Starts argv inside the fence (its standard output and error sent to our standard error,
        or to the files given)."""
        _registered()
        _live.add(self)
        self._make_groups()
        seccomp_fd = None
        program = machine.seccomp_program(self.job) if machine.bwrap() is not None else None
        if program is not None:
            seccomp_fd = os.memfd_create("dc-seccomp", 0)
            os.write(seccomp_fd, program)
            os.lseek(seccomp_fd, 0, os.SEEK_SET)
        if self.threads is not None and machine.bwrap() is None:   # (else set inside: _argv)
            env = dict(os.environ if env is None else env, **self._thread_env())
        try:
            err = sys.stderr.fileno() if _has_fileno(sys.stderr) else subprocess.DEVNULL
            self.process = subprocess.Popen(
                self._argv(argv, seccomp_fd), pass_fds=[*pass_fds, *([seccomp_fd] if seccomp_fd is not None else [])],
                stdin=subprocess.DEVNULL, stdout=err if stdout is None else stdout,
                stderr=err if stderr is None else stderr, env=env, preexec_fn=self._enter)
        finally:
            if seccomp_fd is not None:
                os.close(seccomp_fd)
        _started.add(self.process.pid)
        return self.process

    def cpu_seconds(self):
        """CPU seconds used by every process the sandbox ran, from its start (None without accounting)."""
        if self._cpu_file is None:
            return None
        kind, fd = self._cpu_file
        try:
            text = os.pread(fd, 4096, 0).decode()
        except OSError:
            return None
        if kind == "v1":
            return int(text) * 1e-9
        for line in text.splitlines():
            if line.startswith("usage_usec "):
                return int(line.split()[1]) * 1e-6
        return None

    def processes(self):
        """(threads beyond each process's first, processes) running in the sandbox now, counted by
        the judge (None without a group)."""
        for _, folder in self.groups.values():
            try:
                with open(os.path.join(folder, "cgroup.procs")) as f:
                    procs = len(f.read().split())
                with open(os.path.join(folder, "cgroup.threads" if os.path.exists(os.path.join(folder, "cgroup.threads"))
                                       else "tasks")) as f:
                    threads = len(f.read().split())
                return threads - procs, procs
            except OSError:
                continue
        return None

    def exit_description(self):
        """How the sandbox's process ended, in words ("" while running)."""
        code = None if self.process is None else self.process.poll()
        if code is None:
            return ""
        return exit_words(code)

    def kill(self):
        """Ends everything the sandbox runs (its PID namespace ends with its first process) and
        removes its control groups."""
        if self.process is not None and self.process.poll() is None:
            try:
                os.killpg(self.process.pid, signal.SIGKILL)
            except OSError:
                pass
            try:
                self.process.kill()
            except OSError:
                pass
        if self._cpu_file is not None:
            os.close(self._cpu_file[1])
            self._cpu_file = None
        for kind, folder in self.groups.values():
            if kind == "v2" and os.path.exists(os.path.join(folder, "cgroup.kill")):
                try:
                    with open(os.path.join(folder, "cgroup.kill"), "w") as f:
                        f.write("1")
                except OSError:
                    pass
            else:
                _kill_listed(folder)
        if self.process is not None:
            try:
                self.process.wait(5)
            except subprocess.TimeoutExpired:
                pass
        for _, folder in dict.fromkeys(self.groups.values()):
            # (the kernel empties a group as its processes exit; waited for up to 5 s, where it was
            # 1 s, so that none is still alive when dc looks for what outlives the command)
            deadline = time.monotonic() + 5.0
            while True:
                try:
                    os.rmdir(folder)
                    break
                except FileNotFoundError:
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        break
                    _kill_listed(folder)
                    time.sleep(0.01)
        self.groups = {}
        _live.discard(self)
        if self.process is not None and self.process.returncode is not None:   # (reaped: its pid may be reused)
            _started.discard(self.process.pid)


class JobSandbox(Sandbox):
    """A whole job's fence (a study: hours of work that reads the user's inputs anywhere, writes
    one output and may run contestants of its own). Namespaces of its own (user, PID, mount, IPC,
    network, UTS; no new user namespace inside): the whole file system read-only, its own /proc,
    /dev and /dev/shm, writable only in the folders given (its output's staging folder and a
    private temporary folder, TMPDIR); seccomp as a contestant's, and no socket(AF_UNIX), which
    would reach sockets on the read-only file system. Its PID namespace ends with it. It cannot
    build namespaces for contestants of its own (bubblewrap inside bubblewrap cannot mount a new
    /proc), so they are started by the judge's process on its behalf (broker.py)."""

    job = True

    def __init__(self, writable=(), cwd=None, devices=()):
        super().__init__(threads=None)
        self.name = f"dc-job-{os.getpid()}-{Sandbox._count}"
        self.writable = [os.path.abspath(p) for p in writable]
        self.devices = [d for d in devices if os.path.exists(d)]
        self.cwd = os.path.abspath(cwd or os.getcwd())

    def _make_groups(self):
        pass   # (not charged: a job is the user's own measurement; its PID namespace ends it)

    def kill(self):
        """Ends the job: its namespace's first process first, so that bubblewrap reaps it and ends
        (killed first, bubblewrap would leave it to dc, the reaper of orphans, to find)."""
        if self.process is not None and self.process.poll() is None:
            try:
                with open(f"/proc/{self.process.pid}/task/{self.process.pid}/children") as f:
                    children = [int(p) for p in f.read().split()]
            except OSError:
                children = []
            for pid in children:
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            try:
                self.process.wait(2)
            except subprocess.TimeoutExpired:
                pass
        super().kill()

    def _enter(self):
        import resource
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        os.setsid()

    def _argv(self, argv, seccomp_fd):
        bwrap = machine.bwrap()
        if bwrap is None:
            return list(argv)
        out = [bwrap, "--unshare-user", "--unshare-pid", "--unshare-ipc", "--unshare-net", "--unshare-uts",
               "--disable-userns", "--die-with-parent", "--new-session", "--cap-drop", "ALL",
               "--ro-bind", "/", "/", "--dev", "/dev", "--proc", "/proc", "--tmpfs", "/dev/shm"]
        for path in dict.fromkeys(self.writable):
            out += ["--bind", path, path]
        for path in dict.fromkeys(self.devices):
            out += ["--dev-bind", path, path]
        out += ["--chdir", self.cwd]
        if seccomp_fd is not None:
            out += ["--seccomp", str(seccomp_fd)]
        return out + ["--"] + list(argv)


_NAMED_SIGNALS = {int(s) for s in signal.Signals}


def exit_words(code, ended_itself=False):
    """A sandboxed process's exit status in words ("exit status 9", "killed by SIGSEGV").
    Bubblewrap passes its child's signal on as 128 + it, which an exit status can also be: read as
    a signal only where it names one and the process did not say it ended itself (its record)."""
    if code - 128 in _NAMED_SIGNALS and not ended_itself and machine.bwrap() is not None:
        code = 128 - code
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


def _registered():
    """kill_all registered to run as the process ends (and before dc's own search for leftovers)."""
    if not _live and not getattr(_registered, "done", False):
        import atexit
        atexit.register(kill_all)
        at_end(kill_all)
        own_processes(_sandbox_process)
        _registered.done = True


def _kill_listed(folder):
    try:
        with open(os.path.join(folder, "cgroup.procs")) as f:
            pids = [int(p) for p in f.read().split()]
    except OSError:
        return
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def _has_fileno(stream):
    try:
        stream.fileno()
        return True
    except (AttributeError, OSError, ValueError):
        return False
