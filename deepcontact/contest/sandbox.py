"""A fence around one command, built the way contest judges build theirs (IOI's isolate, DOMjudge's
runguard): its rules are one record (fence.py: a contestant's, a job's, ...); a contestant is a
fresh interpreter started by bubblewrap in namespaces of its own (user, PID, mount, IPC, network,
UTS, cgroup), in a control group of its own that the judge owns.

What it sees: a read-only view of the interpreter, the installed packages, deepcontact and the
plug-in's own module (and a checkpoint it is given); a private /tmp; its own /proc, which shows
only its own processes. No run folder, no output being written, no other process: a rival or the
judge cannot be named, so cannot be signalled, reniced, traced or read. Seccomp refuses ptrace,
cross-process memory reads and the calls that would change the fence; no new privileges; no
capabilities. Limits: processes, memory (the control group where the kernel lends one, else the
address space), file size. Its standard input is empty; its output and error are pipes dc relays
(relay.py): no descriptor of dc's is inherited.

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
import time

from ..leftovers import at_end, own_processes
from ..output import record
from ..plugins import PluginError
from . import fence as fences, forked, kernel, machine, relay

# A contestant's limits (fence.CONTESTANT): its threads are told their count (THREAD_VARIABLES),
# so that neither its charge (OpenBLAS's idle pool cost each start 0.1 s of CPU on two cores) nor
# its answer depends on the machine.
MEMORY_LIMIT = fences.CONTESTANT.limits.memory
PROCESS_LIMIT = fences.CONTESTANT.limits.processes
FILE_LIMIT = fences.CONTESTANT.limits.file_size
THREAD_VARIABLES = fences.THREAD_VARIABLES


# --- Fail closed ------------------------------------------------------------------------------------

UNFENCED_OPTION = "--unfenced"
UNFENCED_ENV = "DC_UNFENCED"   # set by the option; a job's environment carries it to the job's own checks
JOB_FENCES = fences.JOB_FENCES
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


def _forget_in_child():
    # (a fork of this process, a -j worker, ends none of its parent's sandboxes on its way out)
    _live.clear()


os.register_at_fork(after_in_child=_forget_in_child)


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


class ForkRefused(Exception):
    """A fork of the zygote could not fence itself here (the line says which step): contestants
    then start as fresh sandboxes (zygote.py)."""


# --- One sandbox -----------------------------------------------------------------------------------

class Sandbox:
    """One fence (a fence.Fence: a contestant's, a job's, ...) around one command: its control
    groups and its bubblewrap process. `start(argv, fds)` runs the command inside; `cpu_seconds()`
    is everything its processes have used; `kill()` ends them all and removes the groups;
    `stopped_by` then names the limit that stopped it, if one did."""

    _count = 0

    def __init__(self, fence=fences.CONTESTANT, name=None):
        Sandbox._count += 1
        self.fence = fence
        self.name = f"{_PREFIX}{os.getpid()}-{Sandbox._count}"
        self.label = name or fence.profile   # (how its relayed lines are named)
        self.groups = {}   # {controller: folder}
        self.process = None
        self.stopped_by = None
        self._cpu_file = None
        self._relays = []

    def _make_groups(self, memory):
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
        for controller, (kind, folder) in list(self.groups.items()):
            for name, value in _group_limits(controller, kind, self.fence.limits.processes, memory):
                try:
                    with open(os.path.join(folder, name), "w") as f:
                        f.write(str(value))
                except OSError:
                    if not name.startswith("memory.memsw"):   # (swap accounting is the kernel's option)
                        del self.groups[controller]
                        break
        if "cpu" in self.groups:
            kind, folder = self.groups["cpu"]
            try:   # (kept open and read from offset 0 after every call: an open a call cost 30 us)
                self._cpu_file = (kind, os.open(os.path.join(folder, "cpu.stat" if kind == "v2" else "cpuacct.usage"),
                                                os.O_RDONLY | os.O_CLOEXEC))
            except OSError:
                del self.groups["cpu"]

    def _enter(self, memory):
        """In the child, before exec: into the control groups, the limits on."""
        for _, folder in dict.fromkeys(self.groups.values()):
            with open(os.path.join(folder, "cgroup.procs"), "w") as f:
                f.write("0")
        # (an accelerator's driver maps more address space than memory: no such limit with one; a
        # zygote's forks set their own limits, which no process may raise past its hard one: its
        # own are soft, under no hard limit)
        space = memory if "memory" not in self.groups and not self.fence.devices else None
        kernel.set_limits(self.fence.limits.file_size, space, soft_only=self.fence.nested)
        os.setsid()

    def start(self, argv, pass_fds=(), env=None):
        """Starts argv inside the fence: its standard input empty, its output and error pipes this
        process relays (fence.Streams), no descriptor of ours but `pass_fds`."""
        _registered()
        memory = fences.memory_limit(self.fence, len(_live))
        _live.add(self)
        self._make_groups(memory)
        seccomp_fd = None
        program = machine.seccomp_program(self.fence.seccomp) if machine.bwrap() is not None else None
        if program is not None:
            seccomp_fd = os.memfd_create("dc-seccomp", 0)
            os.write(seccomp_fd, program)
            os.lseek(seccomp_fd, 0, os.SEEK_SET)
        if machine.bwrap() is None:   # (else set inside: fence.bwrap_argv; a bare run is marked all the same)
            env = dict(os.environ if env is None else env, **fences.thread_env(self.fence),
                       **{fences.MARKER: self.fence.profile})
        elif fences.environment(self.fence) is not None:
            # (a cleared environment is bubblewrap's to set; bubblewrap itself, whose PID 1 in the
            # namespace its contestant can read through /proc/1, is given none of dc's)
            env = {}
        out, err = (self._stream(which) for which in ("stdout", "stderr"))
        try:
            self.process = subprocess.Popen(
                fences.bwrap_argv(self.fence, argv, seccomp_fd),
                pass_fds=[*pass_fds, *([seccomp_fd] if seccomp_fd is not None else [])], close_fds=True,
                stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=env, preexec_fn=lambda: self._enter(memory))
        finally:
            for fd in (seccomp_fd, out, err):
                if isinstance(fd, int) and fd >= 0:
                    os.close(fd)
        _started.add(self.process.pid)
        return self.process

    def start_forked(self, zygote, channel):
        """Starts the guest on `channel` as a fork of `zygote` (zygote.Zygote: the torch one for a
        contestant that loads a trained network) that fences itself by this fence's record before
        any code of its own runs, charged to this sandbox's groups from its birth; returns once it
        is fenced (ForkRefused where it cannot be)."""
        return self._forked(zygote, channel, {"env": fences.environment(self.fence)})

    def start_job_forked(self, zygote, argv, fd, env):
        """Starts `python ARGV` (a job of view "root": "-m MODULE ARGS" or "-c CODE ARGS") as a fork
        of the jobs' zygote that fences itself by this fence's record before ARGV runs, as start()
        would run it fresh: its environment `env`, the descriptor `fd` at its number (pass_fds),
        its writable folders attached from detached trees of them (kernel.detached_trees)."""
        # (a request's descriptors: its line, streams, status, seccomp, up to three groups, the trees)
        if 5 + 3 + len(self.fence.writable) > forked.FDS_MAX:
            raise ForkRefused(f"more writable folders than a request carries ({len(self.fence.writable)})")
        try:
            trees = kernel.detached_trees(self.fence.writable)
        except OSError as e:
            raise ForkRefused(f"the job's writable folders could not be handed to it ({e})") from None
        try:
            return self._forked(zygote, fd, {"env": dict(env), "job": {
                "argv": list(argv), "fd": fd, "trees": list(self.fence.writable), "user": [os.getuid(), os.getgid()]}},
                trees)
        finally:
            for tree in trees:
                os.close(tree)

    def _forked(self, zygote, channel, request, trees=()):
        from dataclasses import asdict, replace
        _registered()
        memory = fences.memory_limit(self.fence, len(_live))
        _live.add(self)
        self._make_groups(memory)
        if "cpu" not in self.groups or "pids" not in self.groups:
            raise ForkRefused("no control group for its CPU or its processes")
        ours = []   # (every descriptor made here, closed once the zygote has its copies)
        try:
            ours += [os.open(os.path.join(folder, "cgroup.procs"), os.O_WRONLY | os.O_CLOEXEC)
                     for _, folder in dict.fromkeys(self.groups.values())]
            seccomp = os.memfd_create("dc-seccomp", os.MFD_CLOEXEC)
            ours.append(seccomp)
            os.write(seccomp, machine.seccomp_program(self.fence.seccomp))
            os.lseek(seccomp, 0, os.SEEK_SET)
            out, err = (self._stream(which) for which in ("stdout", "stderr"))
            out, err = (os.open(os.devnull, os.O_WRONLY | os.O_CLOEXEC) if fd == subprocess.DEVNULL else fd
                        for fd in (out, err))
            ours += [out, err]
            # (a job's folder, where its record leaves it to dc's: dc's current one, as bubblewrap's)
            record = asdict(replace(self.fence, cwd=self.fence.cwd or os.getcwd()))
            request = {"fence": record, **request, "memory": memory if "memory" not in self.groups else None,
                       # (the CPUs of the thread that asks, as a fresh sandbox inherits them: the
                       # zygote's are those of the thread that started it, maybe before `taskset`)
                       "cpus": sorted(os.sched_getaffinity(0))}
            self.process = zygote.fork(request, [channel, out, err, seccomp, *ours[:-3], *trees])
        finally:
            for fd in ours:
                os.close(fd)
        self.process.wait_fenced()
        return self.process

    def _stream(self, which):
        """What the fenced process gets for its stream `which`: DEVNULL (discarded), or the write
        end of a pipe whose read end a thread of ours relays."""
        streams = self.fence.streams
        if getattr(streams, which) != "relay":
            return subprocess.DEVNULL
        to = streams.stdout_to if which == "stdout" else "stderr"
        read, write = os.pipe()
        prefix = f"[{self.label}] " if streams.prefix else ""
        self._relays.append(relay.start(read, to, prefix, streams.cap))
        return write

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
        """How the sandbox's process ended, in words, with the limit it reached if one stopped it
        ("killed by SIGKILL at its memory limit (8192 MiB)"; "" while running)."""
        code = None if self.process is None else self.process.poll()
        if code is None:
            return ""
        limit = self.stopped_by or _limit_reached(self.groups, self.fence.limits)
        return exit_words(code) + (f" at {limit}" if limit else "")

    def kill(self):
        """Ends everything the sandbox runs (its PID namespace ends with its first process), notes
        the limit that stopped it (stopped_by), removes its control groups and waits for its relays."""
        if self.fence.view == "root":
            self._kill_first_inside()
        if self.process is not None and self.process.pid is not None and self.process.poll() is None:
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
        self.stopped_by = (self.stopped_by or _limit_reached(self.groups, self.fence.limits)
                           or _file_at_limit(self.fence.writable, self.fence.limits.file_size))
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
        _remove_groups(self.groups)
        self.groups = {}
        for t in self._relays:
            t.join(5)
        _live.discard(self)
        if self.process is not None and self.process.returncode is not None:   # (reaped: its pid may be reused)
            _started.discard(self.process.pid)

    def _kill_first_inside(self):
        """A job's namespace's first process killed first, so that bubblewrap reaps it and ends
        (killed first, bubblewrap would leave it to dc, the reaper of orphans, to find)."""
        if self.process is None or self.process.pid is None or self.process.poll() is not None:
            return   # (a fork of the jobs' zygote: ended by its control groups)
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


def JobSandbox(writable=(), cwd=None, devices=(), profile="job"):
    """A whole job's fence (a study, a training run, a drawing: fence.PROFILES): the whole file
    system read-only, writable only in the folders given (its output's staging folder and a
    private TMPDIR), its own /proc, /dev and /dev/shm; seccomp as a contestant's, no
    socket(AF_UNIX); limits on processes, memory and file size. Its contestants are started by
    the judge's process on its behalf (broker.py): bubblewrap inside bubblewrap cannot mount a new
    /proc."""
    return Sandbox(fences.PROFILES[profile].with_paths(writable=writable, devices=devices, cwd=cwd))


def _group_limits(controller, kind, processes, memory):
    """[(file, value)] that set a group's limits for `controller`."""
    if controller == "pids":
        return [("pids.max", processes)]
    if controller != "memory" or memory is None:
        return []
    if kind == "v2":
        return [("memory.max", memory), ("memory.swap.max", 0)]
    return [("memory.limit_in_bytes", memory), ("memory.memsw.limit_in_bytes", memory)]


def _limit_reached(groups, limits):
    """The limit a sandbox's control groups say it reached, in words, or None."""
    checks = {"memory": (("memory.events", "oom_kill "), ("memory.oom_control", "oom_kill ")),
              "pids": (("pids.events", "max "),)}
    for controller, files in checks.items():
        if controller not in groups:
            continue
        for name, key in files:
            try:
                with open(os.path.join(groups[controller][1], name)) as f:
                    counts = [int(line.split()[1]) for line in f if line.startswith(key)]
            except (OSError, ValueError, IndexError):
                continue
            if counts and counts[0] > 0:
                return (f"its memory limit ({_mib(_group_memory(groups))})" if controller == "memory"
                        else f"its process limit ({limits.processes} processes and threads)")
    return None


FILES_LOOKED_AT = 10000   # entries of a job's writable folders searched for a file cut at its limit


def _file_at_limit(folders, size):
    """The file size limit in words where a file in `folders` is exactly `size` bytes (a write
    that crossed the limit stops there: the file is cut, whatever its writer did next), or None."""
    seen = 0
    for folder in folders:
        for where, _, names in os.walk(folder):
            for name in names:
                seen += 1
                try:
                    if os.lstat(os.path.join(where, name)).st_size == size:
                        return f"its file size limit ({_mib(size)}: {name} was cut there)"
                except OSError:
                    pass
                if seen > FILES_LOOKED_AT:
                    return None
    return None


def _group_memory(groups):
    kind, folder = groups["memory"]
    try:
        with open(os.path.join(folder, "memory.max" if kind == "v2" else "memory.limit_in_bytes")) as f:
            return int(f.read())
    except (OSError, ValueError):
        return None


def _mib(n):
    return "?" if n is None else f"{n / (1 << 20):.0f} MiB"


def _remove_groups(groups):
    for _, folder in dict.fromkeys(groups.values()):
        # (the kernel empties a group as its processes exit; waited for up to 5 s, where it was
        # 1 s, so that none is still alive when dc looks for what outlives the command)
        # (polled from 0.5 ms up to 10 ms: a killed contestant's group empties within a few ms)
        deadline, pause = time.monotonic() + 5.0, 0.0005
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
                time.sleep(pause)
                pause = min(2 * pause, 0.01)


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
