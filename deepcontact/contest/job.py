"""A whole dc command run fenced: a plug-in that is a job rather than a call (a study, the training
of a plug-in network) runs in `dc ARGS` inside a JobSandbox, and the process that started it
keeps the output rules (staging, checks, the swap) and the user's stop.

The job sees the file system read-only and writes only in the folders given; its standard output
and error are the caller's (copied where the caller's stream has no descriptor: click's
CliRunner); the contestants it runs are started by this process on its behalf (broker.py); the
user's stop (Terminated, KeyboardInterrupt) ends it at once, with everything it started.
"""
import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

from . import sandbox
from .broker import ENV as BROKER_ENV, Broker

COMMAND_LINE = "DC_COMMAND_LINE"   # the user's command line, for the job's reports (not the staged one)
POLL = 0.5                         # seconds between a caller's polls (run)


def python_path():
    """This process's import path, for the job's interpreter: it imports what the caller can."""
    return os.pathsep.join(p or os.getcwd() for p in sys.path)


def run(dc_args, writable, private, env_extra=None, command_line=None, devices=(), poll=None):
    """Runs `dc DC_ARGS` in a JobSandbox writing in `writable` (its TMPDIR `private`, one of
    them); returns its exit status (how(): in words). env_extra: more of its environment;
    devices: device files it may use (an accelerator's); poll(): called every POLL seconds while
    it runs (what the caller keeps up to date from what it writes)."""
    broker = Broker()
    box = sandbox.JobSandbox(writable=writable, devices=devices)
    env = dict(os.environ, TMPDIR=str(private), PYTHONPATH=python_path())
    env.update({BROKER_ENV: str(broker.job_fd), COMMAND_LINE: command_line or "", **(env_extra or {})})
    env.setdefault("MPLCONFIGDIR", _matplotlib_dir(private))
    if type(sys.stdout).__name__ == "ClosedStdout":
        env["DC_STDOUT_CLOSED"] = "1"
    out, out_pipe = _stream(sys.stdout)
    err, err_pipe = _stream(sys.stderr)
    copiers = []
    try:
        box.start([sys.executable, "-m", "deepcontact.cli.main", *dc_args], pass_fds=[broker.job_fd], env=env,
                  stdout=out, stderr=err)
        broker.job_started()
        for pipe, sink, fd in ((out_pipe, sys.stdout, out), (err_pipe, sys.stderr, err)):
            if pipe is not None:   # (a caller's buffer: copied)
                os.close(fd)
                copiers.append(_copier(pipe, sink))
        while True:
            try:
                code = box.process.wait(None if poll is None else POLL)
                break
            except subprocess.TimeoutExpired:
                poll()
    finally:
        box.kill()
        broker.close()
        for t in copiers:
            t.join(5)
    return code


def how(code):
    """A job's exit status in words ("exit status 9", "killed by SIGSEGV")."""
    if code > 128 and sandbox._bwrap() is not None:   # (bubblewrap passes its child's signal on as 128 + it)
        code = 128 - code
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


def _copier(source, sink):
    """Copies a pipe's text to a stream (our stdout or stderr when it has no descriptor: a caller's
    buffer, click's CliRunner)."""
    def copy():
        with os.fdopen(source, "r", errors="replace") as f:
            for line in f:
                sink.write(line)
                sink.flush()
    t = threading.Thread(target=copy, daemon=True)
    t.start()
    return t


def _stream(stream):
    """(what the job's process gets for stream, the read end to copy from or None)."""
    if stream is None or type(stream).__name__ == "ClosedStdout":   # (the shell closed it: so is the job's)
        return subprocess.DEVNULL, None
    if sandbox._has_fileno(stream):
        stream.flush()
        return stream.fileno(), None
    read, write = os.pipe()
    return write, read


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
