"""A fence is one record (as nsjail keeps every rule of a jail in one config): the namespaces, what
is readable and writable, the devices, the folder it starts in, its limits, its seccomp policy,
its environment and its standard streams. A contestant, a plug-in engine, a job (a study), a
training run, a drawing and a listing are profiles of it, values in PROFILES, never subclasses;
`bwrap_argv` is the one function that turns a fence into bubblewrap's arguments.

Every process inside carries one marker, MARKER (the profile's name): `inside()` reads it, and
`fenced()` alone says whether plug-in code is to be started in a fence of its own.
"""
import logging
import os
from dataclasses import dataclass, field, replace

from . import machine

MARKER = "DC_FENCE"   # set in every sandbox, to its profile's name

ALL_NAMESPACES = ("user", "pid", "mount", "ipc", "net", "uts", "cgroup")
# (a job keeps the cgroup namespace of its starter: its own group's files stay where the kernel shows them)
JOB_NAMESPACES = ("user", "pid", "mount", "ipc", "net", "uts")

# Files of /etc an interpreter reads (the loader's cache, names of users and zones); the rest of
# /etc is not a contestant's to read.
ETC = ("ld.so.cache", "ld.so.conf", "ld.so.conf.d", "localtime", "passwd", "group", "nsswitch.conf",
       "alternatives", "os-release")
SYSTEM = ("/usr", "/lib", "/lib64", "/lib32", "/libx32", "/bin", "/sbin")
# dc's variables a contestant keeps (its environment is otherwise cleared)
KEPT_ENV = ("PATH", "LANG", "LC_ALL", "TZ", "OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE")
# The thread pools a library starts at import (numpy's OpenBLAS, torch's OpenMP) size themselves to
# the machine's cores unless told: a contestant's are told its own thread count. MKL_DYNAMIC off:
# MKL (in torch) counts the cores at import by setting its affinity to each in turn, which a
# contestant's seccomp filter refuses (it may not move off its CPUs), and then takes one thread
# unless the count it is told is final.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

MEMORY_FLOOR = 1 << 30   # bytes: the least share of the machine's memory a sandbox gets


@dataclass(frozen=True)
class Limits:
    """What a fence's processes may use together: processes and threads at once, bytes of memory
    (at most `memory`, and at most the machine's share: memory_share), bytes of one file."""
    processes: int
    memory: int = None   # (None: the machine's share alone)
    file_size: int = 256 << 20


@dataclass(frozen=True)
class Streams:
    """Where a fence's standard output and error go: "relay" (a pipe dc owns, relayed to dc's own
    stream `to`, at most `cap` bytes, each line after `prefix` the fence's name where set) or
    "discard". Its standard input is always empty."""
    stdout: str = "relay"
    stderr: str = "relay"
    stdout_to: str = "stderr"   # (which of dc's streams a relayed output reaches)
    prefix: bool = True
    cap: int = 64 << 10


@dataclass(frozen=True)
class Fence:
    """One sandbox's every rule. view: "system" (the interpreter's folders and a few of /etc, then
    `readable`) or "root" (the whole file system read-only); tmp: a private /tmp of file_size
    bytes; environment: "clear" (KEPT_ENV only) or "given" (the caller's env); threads: the
    thread pools' size (None: theirs)."""
    profile: str
    namespaces: tuple = ALL_NAMESPACES
    view: str = "system"
    readable: tuple = ()
    writable: tuple = ()
    devices: tuple = ()
    cwd: str = "/tmp"   # (None: dc's current folder as it starts)
    tmp: bool = True
    limits: Limits = field(default_factory=lambda: Limits(64, 8 << 30))
    seccomp: str = "contestant"
    environment: str = "clear"
    threads: int = 1
    streams: Streams = Streams()
    accounted: bool = True   # (its CPU read from its control group)
    proc: str = "own"        # (its /proc: "own", or "host" bound, so that its forks may mount their own)
    nested: bool = False     # (whether it may make namespaces inside: the zygote's forks do)

    def with_paths(self, readable=(), writable=(), devices=(), cwd=None):
        """This fence with these folders (each made absolute; missing readable ones and devices dropped)."""
        return replace(self, readable=tuple(os.path.abspath(p) for p in readable if p and os.path.exists(p)),
                       writable=tuple(os.path.abspath(p) for p in writable),
                       devices=tuple(d for d in devices if os.path.exists(d)),
                       cwd=os.path.abspath(cwd) if cwd else self.cwd)


def _contestant():
    return Fence("contestant")


def _job(profile, streams=Streams(stdout_to="stdout", prefix=False, cap=256 << 20)):
    # (a job is dc's own command run fenced, in dc's current folder: its output is the command's,
    # so unprefixed; its contestants are started outside it, broker.py)
    return Fence(profile, namespaces=JOB_NAMESPACES, view="root", cwd=None, tmp=False,
                 limits=Limits(1024), seccomp="job", environment="given", threads=None, streams=streams)


def _zygote():
    # (dc's own code only: it imports the contestant's side once and forks each contestant,
    # which fences itself as CONTESTANT before any code of its own runs: forked.py)
    # (its /tmp the machine's, read-only: a plug-in's files may lie there, and its forks bind them)
    return Fence("zygote", view="root", tmp=False, limits=Limits(256, 4 << 30), seccomp="zygote", proc="host",
                 nested=True)


def _job_zygote():
    # (the jobs' zygote: dc's own code and the libraries a job imports (numpy, torch), made once;
    # each job is a fork that fences itself as its own profile (JOB, TRAINING, ...) before dc's
    # command runs in it: forked.py. A job's namespaces, so that its forks keep dc's control groups
    # where the kernel shows them; the caller's environment, which its libraries read as they load)
    return replace(_zygote(), profile="job-zygote", namespaces=JOB_NAMESPACES, environment="given", threads=None)


CONTESTANT = _contestant()
ENGINE = replace(_contestant(), profile="engine")   # (a plug-in engine's world: a guest as a contestant is)
JOB = _job("job")
TRAINING = _job("training")   # (given the accelerator's device files where it uses one)
DRAWING = _job("drawing")
LISTING = _job("listing", streams=Streams(stdout="discard", stderr="discard"))
ZYGOTE = _zygote()
JOB_ZYGOTE = _job_zygote()
PROFILES = {f.profile: f for f in (CONTESTANT, ENGINE, JOB, TRAINING, DRAWING, LISTING, ZYGOTE, JOB_ZYGOTE)}
JOB_FENCES = ("namespaces", "read-only view", "seccomp")   # what a job's fence needs of the machine


def inside():
    """The profile dc started this process under (in its fence, or bare where --unfenced let it
    run so), or None in a process dc started in no profile."""
    return os.environ.get(MARKER) or None


def fenced(plugin_code):
    """Who is fenced: whether code runs in a sandbox of its own, where `plugin_code` says it is a
    plug-in's: always, unless this process is one dc started under a profile (inside()), where it
    runs in place, its fence already around it."""
    return bool(plugin_code) and inside() is None


def memory_share(live):
    """Bytes of memory one of `live` + 1 sandboxes may hold: the machine's memory shared with the
    others and dc, never under MEMORY_FLOOR."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError):
        return None
    return max(MEMORY_FLOOR, total // (1 + live))


def memory_limit(fence, live):
    """The memory limit of `fence` started beside `live` sandboxes: its own cap, at most its share."""
    share = memory_share(live)
    caps = [m for m in (fence.limits.memory, share) if m is not None]
    return min(caps) if caps else None


def thread_env(fence):
    """The variables a fence sets besides the marker: its thread pools' (none where it keeps their
    defaults), and, in a cleared environment, Python's warnings off unless dc shows its own (-v):
    a library's warning in a contestant is advice to its author, not a line of dc's report, as in
    dc's own process (cli/terminal.setup_logging)."""
    out = {} if fence.threads is None else {**dict.fromkeys(THREAD_VARIABLES, str(fence.threads)),
                                            "MKL_DYNAMIC": "FALSE"}
    if fence.environment == "clear" and not logging.getLogger("py.warnings").isEnabledFor(logging.WARNING):
        out["PYTHONWARNINGS"] = "ignore"
    return out


def bwrap_argv(fence, command, seccomp_fd=None):
    """bubblewrap's arguments for `command` inside `fence`: the options, then "--", then the
    command (nothing of the command is ever read as bubblewrap's option). Without bubblewrap here,
    the command alone."""
    bwrap = machine.bwrap()
    if bwrap is None:
        return list(command)
    out = [bwrap, *_namespace_options(fence), *([] if fence.nested else ["--disable-userns"]),
           "--die-with-parent", "--new-session", "--cap-drop", "ALL"]
    out += _view_options(fence) + _environment_options(fence)
    if seccomp_fd is not None:
        out += ["--seccomp", str(seccomp_fd)]
    return out + ["--", *command]


def _namespace_options(fence):
    if set(fence.namespaces) == set(ALL_NAMESPACES):
        return ["--unshare-all", "--unshare-user", "--uid", "65534", "--gid", "65534"]
    out = [f"--unshare-{name}" for name in fence.namespaces if name != "mount"]   # (bubblewrap always makes one)
    # (a zygote's forks map the judge's own user onto its 65534: no user namespace may map its parent's root)
    return out + (["--uid", "65534", "--gid", "65534"] if fence.nested else [])


def _view_options(fence):
    """The mounts: the view, /proc and /dev, the private /tmp, the readable, writable and device binds."""
    out = []
    # (bubblewrap's own /proc covers parts of itself, and the kernel lets a namespace mount a new
    # /proc only where one is wholly visible: the zygote binds the host's, its forks cover it)
    proc = ["--bind", "/proc", "/proc"] if fence.proc == "host" else ["--proc", "/proc", *machine.proc_read_only()]
    if fence.view == "root":
        out += ["--ro-bind", "/", "/", "--dev", "/dev", *proc, "--tmpfs", "/dev/shm"]
    else:
        out += [*proc, "--dev", "/dev"]
    if fence.tmp:
        out += ["--size", str(fence.limits.file_size), "--tmpfs", "/tmp"]
    if fence.view == "system":
        for path in SYSTEM:
            if os.path.exists(path):
                out += ["--ro-bind", path, path] if not os.path.islink(path) else ["--symlink", os.readlink(path), path]
        out += [a for name in ETC if os.path.exists(f"/etc/{name}") for a in ("--ro-bind", f"/etc/{name}", f"/etc/{name}")]
    out += [a for p in dict.fromkeys(fence.readable) for a in ("--ro-bind", p, p)]
    out += [a for p in dict.fromkeys(fence.writable) for a in ("--bind", p, p)]
    out += [a for p in dict.fromkeys(fence.devices) for a in ("--dev-bind", p, p)]
    return out + ["--chdir", fence.cwd or os.getcwd()]


def environment(fence):
    """The variables a process inside `fence` starts with, in a cleared environment (KEPT_ENV,
    HOME, its own and the marker), or None where it is given the caller's (Popen's env)."""
    if fence.environment != "clear":
        return None
    out = {key: os.environ[key] for key in KEPT_ENV if key in os.environ}
    out.update(HOME="/tmp", PYTHONDONTWRITEBYTECODE="1", **thread_env(fence))
    out[MARKER] = fence.profile
    return out


def _environment_options(fence):
    """Its environment as bubblewrap's options: cleared to environment(fence), or the caller's
    (given to Popen) and the marker."""
    variables = environment(fence)
    if variables is None:
        return ["--setenv", MARKER, fence.profile]
    return ["--clearenv"] + [a for key, value in variables.items() for a in ("--setenv", key, value)]


def describe(fence):
    """{"sees", "writes", "limits", "streams"} of a profile, in words (a row of table())."""
    sees = ("the interpreter, its installed packages, deepcontact, the plug-in's own module's files and the files "
            "it is given" if fence.view == "system" else "the whole file system, read-only")
    if fence.proc == "host":
        sees += ", and the machine's /proc (each process it forks covers it with its own)"
    writes = (f"a private /tmp of {_size(fence.limits.file_size)}" if fence.tmp else
              "only the folders it is given: its TMPDIR and its output's staging folder (a listing: none)"
              if fence.cwd is None else "nothing")
    cap = f"at most {fence.limits.memory >> 30} GiB and " if fence.limits.memory else ""
    limits = (f"{fence.limits.processes} processes and threads; memory {cap}at most the machine's / (1 + live "
              f"sandboxes), never under {_size(MEMORY_FLOOR)}; {_size(fence.limits.file_size)} a file")
    s = fence.streams
    streams = "input empty; " + ("output and error discarded" if s.stdout == "discard" else
                                 f"output to dc's {s.stdout_to}, error to dc's stderr, relayed by dc"
                                 f"{', each line after its name' if s.prefix else ''}, {_size(s.cap)} each, the "
                                 f"rest counted")
    return {"sees": sees, "writes": writes, "limits": limits, "streams": streams}


def table():
    """The profiles as a Markdown table (docs/reliability.md and docs/api.md hold it as it is)."""
    rows = ["| profile | sees | writes | limits | streams | seccomp |", "|---|---|---|---|---|---|"]
    for name, fence in PROFILES.items():
        d = describe(fence)
        rows.append(f"| {name} | {d['sees']} | {d['writes']} | {d['limits']} | {d['streams']} | {fence.seccomp} |")
    return "\n".join(rows)


def _size(n):
    return f"{n >> 30} GiB" if n >= 1 << 30 else f"{n >> 20} MiB" if n >= 1 << 20 else f"{n >> 10} KiB"
