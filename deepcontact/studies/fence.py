"""A study from an installed distribution runs fenced, as every plug-in does (docs/reliability.md,
"Plug-ins are guests"): `dc study NAME ARGS` starts the study in a sandbox of its own
(contest.sandbox.JobSandbox) and dc's own process only checks, stages and publishes its output.

In the sandbox the study sees the whole file system read-only (it reads the user's inputs where
they are) and writes in two folders only: a private TMPDIR, and a staging folder beside its -o
output, which dc's own process swaps in, by the output rules of every command, once the study
has ended in order (exit 0, or 1 with its verdict). Its processes are in a PID namespace of their
own: it cannot name, signal or read a process outside, and nothing it starts outlives it; it has
no network and no AF_UNIX socket (the sockets on the file system are out of reach). Contestants
it runs are started by dc's process on its behalf (contest.broker). The user's stop ends it at
once. Its output is checked before it is published: no link, device or FIFO in it.

A study registered in code runs in the caller's process: it is the caller's code already.
"""
import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
from contextlib import ExitStack, contextmanager
from pathlib import Path

from .. import atomic
from ..contest import job, sandbox
from ..errors import InputError
from ..plugins import PluginError

INSIDE = "DC_STUDY_FENCED"   # set for the study's own process: the study NAME it runs in place


def fenced(name):
    """Whether `dc study NAME` runs fenced here: an installed study, unless this process is the
    sandbox that runs it."""
    from . import STUDIES
    return os.environ.get(INSIDE) != name and name not in STUDIES.builtin()


# --- The output -----------------------------------------------------------------------------------

def output_argument(args):
    """(index of the -o/--output value in args or None, the text before the path in that argument,
    the path or None, whether --overwrite is given) of a study's arguments, read as click reads
    them: the last -o wins, nothing after --."""
    where, prefix, path, overwrite, k = None, "", None, False, 0
    while k < len(args):
        a = args[k]
        if a == "--":
            break
        if a in ("-o", "--output") and k + 1 < len(args):
            where, prefix, path = k + 1, "", args[k + 1]
            k += 2
            continue
        if a.startswith("--output="):
            where, prefix, path = k, "--output=", a[len("--output="):]
        elif a.startswith("-o") and len(a) > 2:
            where, prefix, path = k, "-o", a[2:]
        elif a == "--overwrite":
            overwrite = True
        k += 1
    return where, prefix, (path if path not in (None, "", "-") else None), overwrite


def check_output(path, name, overwrite, writes):
    """The study's output checked before any work, by the rules of every command's: never through
    a link, never a mount point (swapped in by renaming), an existing file or non-empty folder only
    with --overwrite, and a folder then only one this study wrote, holding only what it wrote.
    writes: what the study says its -o is ("folder", "file" or "text")."""
    path = Path(path)
    if path.is_symlink():
        raise InputError("is a symbolic link: refusing to write through it or replace it", path)
    if writes != "folder":
        atomic.check_replaceable(path)
    elif os.path.lexists(path) and not path.is_dir():
        raise InputError("exists and is not a folder", path)
    if path.is_dir():
        if os.path.ismount(path):
            raise InputError(f"is a mount point: an output is swapped in by renaming, which a mount point "
                             f"refuses; give a folder inside it (-o {path / 'out'})", path)
        if any(path.iterdir()):
            atomic.check_owned_folder(path, f"study {name}", overwrite)
    elif os.path.lexists(path):
        atomic.check_replaceable(path)
        if not overwrite:
            raise InputError("file exists; use --overwrite to replace it", path)


def _check_contents(produced, target):
    """Refuses (InputError) a study's output that holds anything but files and folders."""
    for root, dirs, files in os.walk(produced):
        for entry in dirs + files:
            mode = os.lstat(os.path.join(root, entry)).st_mode
            if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
                shown = Path(target) / os.path.relpath(os.path.join(root, entry), produced)
                raise InputError(f"the study's output holds a {'link' if stat.S_ISLNK(mode) else 'special file'}: "
                                 f"not published (a study writes files and folders only)", shown)


def publish(produced, target, name):
    """What the study wrote in its staging folder, swapped in at target."""
    produced, target = Path(produced), Path(target)
    if not os.path.lexists(produced):
        return
    _check_contents(produced, target)
    if produced.is_dir():
        if os.path.lexists(target) and not target.is_dir():
            raise InputError("is a file, and the study wrote a folder: refusing to replace it", target)
        with atomic.folder(target, command=f"study {name}") as work:
            for entry in os.listdir(produced):
                if entry != atomic.RECORD:
                    os.replace(produced / entry, work / entry)
    else:
        atomic.check_replaceable(target)
        os.replace(produced, target)


@contextmanager
def _staging(target, name):
    """A folder beside target the study writes its output in, held by dc's record as a partial
    output (so the next command on target removes it if this one is killed); removed at the end."""
    target = Path(target)
    stage = Path(tempfile.mkdtemp(prefix=f".{atomic.short_name(target.name)}.partial-{os.getpid()}-",
                                  dir=target.parent))
    atomic.hold_building(stage, f"study {name}")
    try:
        yield stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        atomic.release_building(stage)


# --- The run --------------------------------------------------------------------------------------

def run(name, args):
    """Runs `dc study NAME ARGS` fenced; returns its exit status. The output (-o) is checked
    before the study starts and swapped in after it ends in order; the user's stop ends it."""
    from .. import protocol
    args = list(args)
    where, prefix, target, overwrite = output_argument(args)
    with ExitStack() as stack:
        private = stack.enter_context(tempfile.TemporaryDirectory(prefix="dc-study-"))
        writable, staged = [private], None
        if target is not None:
            healthy, broken = survey([name])
            if name in broken:
                raise PluginError(broken[name])
            writes = healthy[0]["writes"] if healthy else "folder"
            check_output(target, name, overwrite, writes)
            atomic.make_folder_for(target)
            stack.enter_context(atomic.locked(target))
            atomic.recover(target)
            check_output(target, name, overwrite, writes)   # (as it is now that no other command holds it)
            stage = stack.enter_context(_staging(target, name))
            writable.append(str(stage))
            staged = stage / Path(target).name
            args[where] = prefix + str(staged)
        code = job.run(["study", name, *args], writable, private, {INSIDE: name}, protocol.command_line)
        if staged is not None and code in (0, 1):
            publish(staged, target, name)
    if code not in (0, 1, 2):
        raise PluginError(f"the study {name!r} ended its process ({job.how(code)}): nothing it wrote was published")
    return code


# --- The list -------------------------------------------------------------------------------------

def survey(names=None):
    """(the healthy installed studies as [{"name", "summary", "order", "writes"}], {name: line} of
    the broken ones), of every one or of `names`, loaded in a sandbox of their own: listing
    imports every study's code, which runs fenced like the rest of it."""
    box = sandbox.JobSandbox()
    env = dict(os.environ, PYTHONPATH=job.python_path(), **{INSIDE: "-"})
    read, write = os.pipe()
    try:
        box.start([sys.executable, "-c", "import sys; from deepcontact.studies.fence import _survey_here; "
                   "_survey_here(sys.argv[1:] or None)", *(names or [])],
                  env=env, stdout=write, stderr=subprocess.DEVNULL)
        os.close(write)
        write = None
        with os.fdopen(read, "rb") as f:
            read = None
            data = f.read(4 << 20)
        code = box.process.wait()
    finally:
        box.kill()
        for fd in (read, write):
            if fd is not None:
                os.close(fd)
    try:
        found = json.loads(data)
        healthy, broken = found["healthy"], found["broken"]
    except (ValueError, KeyError, TypeError):
        raise PluginError(f"the installed studies could not be listed: their process ended ({job.how(code)}) "
                          f"without a list") from None
    return healthy, broken


def _survey_here(names=None):
    """In the survey's sandbox: the installed studies (or those named), loaded, as JSON on stdout."""
    from . import STUDIES, survey as loaded
    builtin = set(STUDIES.builtin())
    healthy, broken = loaded(names)
    out = {"healthy": [{"name": s.name, "summary": str(s.summary), "order": float(s.order), "writes": str(s.writes)}
                       for s in healthy if s.name not in builtin],
           "broken": {k: v for k, v in broken.items() if k not in builtin}}
    sys.stdout.write(json.dumps(out))
    sys.stdout.flush()
