"""How a measurement was taken, recorded beside it: a time means little without the threads it
ran on, the worker processes beside it, the versions, the CPU and how busy the machine was.

Every report (`dc evaluate`'s report.md and summary.json, the closed loop, `dc study`'s
outputs) and every benchmark records `protocol()`; `protocol_line()` says it in one sentence.
Timed work runs on one torch thread unless the user asks for more (`--threads`): torch's
default, a thread per core, spins against other processes and moved a prediction time 100x on a
loaded machine.
"""
import os
import platform
import sys
import time

from . import __version__, _box2d
from ._box2d import box2d_version
from .escape import md_text

DEFAULT_THREADS = 1

# The command line as the user typed it, set by the `dc` entry point (None in-process).
command_line = None


# The thread count this process's command asked for (use_threads): what a plug-in that changed
# torch's count, or imported torch with its per-core default, is put back to (plugins.guest).
threads_asked = DEFAULT_THREADS


def use_threads(threads):
    """torch's intra-op threads for this process (and the workers it forks), if torch is used."""
    global threads_asked
    threads = threads_asked = threads or DEFAULT_THREADS
    keep_threads(threads)
    return threads


def keep_threads(wanted=None):
    """torch's intra-op threads set to `wanted` (the command's, threads_asked, unless given) where
    torch is loaded and has others: a plug-in that imported torch got its per-core default, or set
    its own."""
    torch = sys.modules.get("torch")
    wanted = threads_asked if wanted is None else wanted
    if torch is not None and torch.get_num_threads() != wanted:
        torch.set_num_threads(wanted)


def cpus_allowed():
    """The CPUs this process's threads may run on (their affinities, together), sorted; None where
    the system does not say. Its contestants are held to the CPUs of the thread that starts them
    (`taskset -c 1 dc ...` runs the judge and every contestant on CPU 1)."""
    if not hasattr(os, "sched_getaffinity"):
        return None
    try:
        threads = [int(tid) for tid in os.listdir("/proc/self/task")]
    except OSError:
        threads = [0]   # (this thread's alone)
    cpus = set()
    for tid in threads:
        try:
            cpus |= os.sched_getaffinity(tid)
        except OSError:   # (a thread that ended meanwhile)
            pass
    return sorted(cpus) or None


def _ranges(cpus):
    """CPUs as runs: [0, 1, 2, 5] -> "0-2, 5"."""
    runs = []
    for c in cpus:
        if runs and c == runs[-1][1] + 1:
            runs[-1][1] = c
        else:
            runs.append([c, c])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def _placement(p):
    """The CPUs the measurement was held to, where fewer than the machine's ("; run on CPU 1 only")."""
    cpus = p.get("cpus")
    if not cpus or p.get("cores") is None or len(cpus) >= p["cores"]:
        return ""
    return f"; run on CPU{'s' if len(cpus) != 1 else ''} {_ranges(cpus)} only"


def cpu_model():
    """The CPU's model name (Linux: /proc/cpuinfo), else what platform says."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(package):
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version(package)
    except PackageNotFoundError:
        return None


def protocol(threads=DEFAULT_THREADS, jobs=1):
    """A dict of how this process measures: threads, -j, versions, CPU, load, command line."""
    try:
        load = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = None
    return {
        "threads": threads, "jobs": jobs,
        "versions": {"deepcontact": __version__, "box2d": box2d_version, "numpy": _version("numpy"),
                     "torch": _version("torch"), "python": platform.python_version(),
                     "box2d3": getattr(_box2d, "box2d3_version", None),
                     # the peer engines' wheels (None where not installed)
                     "pymunk": _version("pymunk"), "mujoco": _version("mujoco")},
        "cpu": cpu_model(), "cores": os.cpu_count(), "cpus": cpus_allowed(), "load_average": load,
        "command": command_line, "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def current(jobs=1):
    """The protocol of this process as it stands: torch's thread count if torch is in use."""
    threads = DEFAULT_THREADS
    if "torch" in sys.modules:
        import torch
        threads = torch.get_num_threads()
    return protocol(threads, jobs)


def protocol_line(p):
    """The protocol in one sentence, for a markdown report. The command line is the user's text
    (run paths, plug-in names): escaped as text, never a code span, which a backtick in a path
    would close, leaving what follows live markdown."""
    v = p["versions"]
    load = "unknown" if p["load_average"] is None else ", ".join(f"{x:g}" for x in p["load_average"])
    command = f" Command: {md_text(p['command'])}." if p.get("command") else ""
    return (f"Measured with {p['threads']} torch thread{'s' if p['threads'] != 1 else ''} per process and "
            f"{p['jobs']} worker process{'es' if p['jobs'] != 1 else ''} (-j), on {md_text(p['cpu'])} ({p['cores']} cores{_placement(p)}; "
            f"load average {load} at the start); deepcontact {v['deepcontact']}, Box2D {v['box2d']}"
            f"{' and ' + v['box2d3'] if v.get('box2d3') else ''}"
            f"{', pymunk ' + v['pymunk'] if v.get('pymunk') else ''}{', MuJoCo ' + v['mujoco'] if v.get('mujoco') else ''}, numpy "
            f"{v['numpy']}, torch {v['torch']}, Python {v['python']}; {p['started']}.{command}"
            + _fences(p))


def _fences(p):
    """What the protocol says of the contestants' fences, where it records them (dc evaluate)."""
    if "missing_fences" not in p:
        return ""
    if not p["missing_fences"]:
        return " Contestants fenced: every fence held (namespaces, read-only view, seccomp, CPU accounting, limits)."
    return f" Contestants' fences MISSING on this machine: {', '.join(p['missing_fences'])}."
