"""A whole dc command run fenced: a plug-in that is a job rather than a call (a study, the training
of a plug-in network) runs in `dc ARGS` inside a job's fence (fence.JOB, TRAINING, DRAWING), and the process that started it
keeps the output rules (staging, checks, the swap) and the user's stop.

The job sees the file system read-only and writes only in the folders given; its standard output
and error are pipes this process relays to its own (contest/relay.py, bounded: no descriptor of
dc's own stream is the job's); the contestants it runs are started by this process on its behalf (broker.py); the
user's stop (Terminated, KeyboardInterrupt) ends it at once, with everything it started.
"""
import os
import shutil
import stat
import subprocess
import sys
import tempfile
from contextlib import ExitStack, contextmanager
from pathlib import Path

from .. import output, protocol
from ..errors import InputError, show_path
from ..output.argument import output_argument   # noqa: F401  (job.output_argument: the callers' name)
from ..output.trees import open_folder_under
from ..plugins import PluginError
from . import machine, result, sandbox, zygote
from .broker import ENV as BROKER_ENV, Broker

COMMAND_LINE = "DC_COMMAND_LINE"   # the user's command line, for the job's reports (not the staged one)
POLL = 0.5                         # seconds between a caller's polls (run)


def python_path():
    """This process's import path, for the job's interpreter: it imports what the caller can."""
    return os.pathsep.join(p or os.getcwd() for p in sys.path)


def run(dc_args, writable, private, env_extra=None, command_line=None, devices=(), poll=None, who="a plug-in's job",
        profile="job"):
    """Runs `dc DC_ARGS` in a job's fence (fence.PROFILES[profile]: "job", "training", "drawing")
    writing in `writable` (its TMPDIR `private`, one of them); returns its exit status (how(): in
    words; ended(private): its own record of its end). env_extra: more of its environment;
    devices: device files it may use (an accelerator's); poll(): called every POLL seconds while
    it runs (what the caller keeps up to date from what it writes); who: how a refusal names it
    (it is plug-in code: where its fence cannot be built it runs only with --unfenced).
    PluginError, in one line, where one of its limits stopped it."""
    sandbox.refuse_bare(who, [f for f in sandbox.JOB_FENCES if f in machine.missing_fences()])
    broker = Broker(writable)
    box = sandbox.JobSandbox(writable=writable, devices=devices, profile=profile)
    env = dict(os.environ, TMPDIR=str(private), PYTHONPATH=python_path())
    env.update({BROKER_ENV: str(broker.job_fd), COMMAND_LINE: command_line or "", **(env_extra or {}),
                result.ENV: os.path.join(private, result.NAME)})
    env.setdefault("MPLCONFIGDIR", _matplotlib_dir(private))
    if type(sys.stdout).__name__ == "ClosedStdout":
        env["DC_STDOUT_CLOSED"] = "1"
    for stream in (sys.stdout, sys.stderr):   # (what dc said so far comes before what the job says)
        if stream is not None:
            stream.flush()
    try:
        start(box, ["-m", "deepcontact.cli.main", *dc_args], broker.job_fd, env)
        broker.job_started()
        while True:
            try:
                code = box.process.wait(None if poll is None else POLL)
                break
            except subprocess.TimeoutExpired:
                poll()
    finally:
        box.kill()
        broker.close()
    if box.stopped_by is not None:
        raise PluginError(f"{who} was stopped at {box.stopped_by} ({how(code)}): nothing it wrote was published")
    return code


def warm(fence, env):
    """The jobs' zygote a job of `fence` and environment `env` would fork from, started now where
    one is used: a deadline counted after this is the job's own, not the zygote's start."""
    if zygote.usable_for_job(fence):
        try:
            zygote.live_job(env, torch=fence.profile in zygote.TORCH_PROFILES)
        except zygote.Refused as e:
            zygote.refused_job(e)


def start(box, argv, fd, env):
    """`python ARGV` ("-m MODULE ARGS" or "-c CODE ARGS") started in box's fence (a job's), given
    the descriptor fd: a fork of the jobs' zygote where this machine lends one (zygote.py), else
    a fresh interpreter; the same fence either way."""
    def made():   # (None where its folder or PYTHONPATH holds its own copy of a module the zygote loaded)
        used = zygote.live_job(env, torch=box.fence.profile in zygote.TORCH_PROFILES)
        return None if zygote.shadowed(used, env, box.fence.cwd or os.getcwd()) is not None else used

    if zygote.usable_for_job(box.fence) and zygote.forked_start(
            box, made, lambda used: box.start_job_forked(used, argv, fd, env), zygote.refused_job):
        return
    box.start([sys.executable, *argv], pass_fds=[fd], env=env)


def how(code, record=None):
    """A job's exit status in words ("exit status 9", "killed by SIGSEGV"); record: its own
    (ended()), which says the process ended itself, so that a status over 128 is no signal."""
    return sandbox.exit_words(code, ended_itself=record is not None)


def ended(private):
    """The record the job wrote of its end in its private folder (contest/result.py), or None."""
    return result.read(os.path.join(private, result.NAME))


def refuse_unordered(code, record, who, target=None):
    """PluginError where a job's end is no order to publish (nothing was): a crash, a signal, an
    exit status its record does not give, a status beyond 0-2; None where it ended in order, or
    failed with its own line said (exit 1 or 2: returned as it is)."""
    if result.ended_in_order(record, code):
        return
    if record is not None and record["ended"] == result.FAILED and record["code"] == code in (1, 2):
        return   # (its own line said why: an error, click's usage)
    kept = f"; {show_path(target)} is as it was" if target is not None else ""
    if code in (0, 1):
        raise PluginError(f"{who} ended its process ({how(code, record)}) without saying it ended in order (a "
                          f"crash?): nothing it wrote was published{kept}")
    raise PluginError(f"{who} ended its process ({how(code, record)}): nothing it wrote was published{kept}")


# --- A fenced command's output -----------------------------------------------------------------------------------

def check_output(path, command, overwrite, writes):
    """A fenced command's output checked before any work, by the rules of every command's: never
    through a link, never a mount point (swapped in by renaming), an existing file or non-empty
    folder only with --overwrite, and a folder then only one dc `command` wrote, holding only what
    it wrote. writes: what its -o is ("folder", "file" or "text")."""
    path = Path(path)
    if writes != "folder":
        output.check_file(path, overwrite)
        return
    output.check_folder(path)
    if path.is_dir() and any(path.iterdir()):
        output.check_owned_folder(path, command, overwrite)


OUTPUT_DEPTH = 64   # folders a fenced command's output may nest (a walk past it is no output of ours)


def _check_contents(produced, target, who):
    """Refuses (InputError naming the user's output) a staged output that is, or holds, anything
    but files and folders, or folders nested deeper than OUTPUT_DEPTH. Walked through descriptors,
    one folder opened at a time from the staged one, never by path (past PATH_MAX a path names
    nothing) and never through a link (the staged path itself a link published the folder it
    named, the user's files moved into the output)."""
    def refuse(parts, what):
        raise InputError(f"the output of {who} {what}: not published (a fenced command writes files and folders "
                         f"only)", Path(target, *parts))
    mode = os.lstat(produced).st_mode
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        refuse((), "is a link" if stat.S_ISLNK(mode) else "is a special file")
    todo = [()] if stat.S_ISDIR(mode) else []
    while todo:
        parts = todo.pop()
        fd = open_folder_under(produced, parts)
        try:
            with os.scandir(fd) as found:
                for entry in found:
                    mode = entry.stat(follow_symlinks=False).st_mode
                    if stat.S_ISDIR(mode):
                        if len(parts) >= OUTPUT_DEPTH:
                            refuse(parts, f"nests folders deeper than {OUTPUT_DEPTH}")
                        todo.append((*parts, entry.name))
                    elif not stat.S_ISREG(mode):
                        refuse((*parts, entry.name), f"holds a {'link' if stat.S_ISLNK(mode) else 'special file'}")
        finally:
            os.close(fd)



def publish(produced, target, command, who):
    """What the fenced command wrote in its staging folder, swapped in at target; whether it
    wrote anything there."""
    produced, target = Path(produced), Path(target)
    if not os.path.lexists(produced):
        return False
    _check_contents(produced, target, who)
    if stat.S_ISDIR(os.lstat(produced).st_mode):
        if os.path.lexists(target) and not target.is_dir():
            raise InputError(f"is a file, and {who} wrote a folder: refusing to replace it", target)
        with output.folder(target, command=command) as work:
            for entry in os.listdir(produced):
                if entry != output.RECORD:
                    os.replace(produced / entry, work / entry)
    else:
        output.check_replaceable(target)
        os.replace(produced, target)
    return True


@contextmanager
def _staging(target, command):
    """A folder beside target the fenced command writes its output in, held by dc's record as a
    partial output (so the next command on target removes it if this one is killed); removed at
    the end."""
    target = Path(target)
    stage = Path(tempfile.mkdtemp(prefix=f".{output.short_name(target.name)}.partial-{os.getpid()}-",
                                  dir=target.parent))
    output.hold_building(stage, command)
    try:
        yield stage
    finally:
        output.remove_tree_quietly(stage)   # (whatever the job left there: any depth)
        output.release_building(stage)


def run_with_output(head, args, command, writes, env_extra, who, aside=None, profile="job"):
    """Runs `dc HEAD ARGS` fenced, its -o staged beside the output and published when it ends in
    order (exit 0, or 1 with a verdict); returns its exit status. command: the output's record
    ("study engines"); writes(): what its -o is ("folder", "file", "text"), asked only when there
    is one; who: how its errors name it. aside(target): where there is an output, a context
    manager entered under its lock for what the job keeps beside it across runs (a study's
    finished units: studies.units.Beside), giving the folders it may write (`writable`), what it
    is told (`env`) and published(), called once the output is published."""
    args = list(args)
    where, prefix, target, overwrite = output_argument(args)
    with ExitStack() as stack:
        private = stack.enter_context(output.private_folder("job"))
        writable, staged, kept = [private], None, None
        if target is not None:
            kind = writes()
            check_output(target, command, overwrite, kind)
            output.make_folder_for(target)
            stack.enter_context(output.locked(target))
            output.recover(target)
            check_output(target, command, overwrite, kind)   # (as it is now that no other command holds it)
            stage = stack.enter_context(_staging(target, command))
            writable.append(str(stage))
            staged = stage / Path(target).name
            if aside is not None:   # (kept beside the output across runs: outlives the staging folder)
                kept = stack.enter_context(aside(target))
                writable += kept.writable
                env_extra = {**(env_extra or {}), **kept.env}
            args[where] = prefix + str(staged)
            env_extra = {**(env_extra or {}), "DC_OUTPUT_STAGED": str(staged), "DC_OUTPUT_SHOWN": str(target)}
        code = run([*head, *args], writable, private, env_extra, protocol.command_line, who=who, profile=profile)
        record = ended(private)
        if staged is not None and result.ended_in_order(record, code):
            if publish(staged, target, command, who) and kept is not None:
                kept.published()
        refuse_unordered(code, record, who, target)
    return code


def _matplotlib_dir(private):
    """A writable matplotlib folder for the job (its own is read-only there), seeded with the
    user's font list so that matplotlib does not rebuild it (seconds) in every job."""
    home = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "matplotlib"
    folder = Path(private) / "matplotlib"
    folder.mkdir(exist_ok=True)
    for cached in home.glob("fontlist-*.json") if home.is_dir() else ():
        try:
            shutil.copyfile(cached, folder / cached.name)
        except OSError:
            pass
    return str(folder)
