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
once. Its output is checked before it is published: no link, device or FIFO in it. Beside its
output it may also write the folder of its finished units (units.py), which outlives a stopped
run for --resume and is removed once the output is published.

A study registered in code runs in the caller's process: it is the caller's code already.
"""
import json
import os
import subprocess
import sys

from ..contest import job, sandbox
from ..plugins import PluginError
from . import STUDIES, survey as loaded, units

INSIDE = "DC_STUDY_FENCED"   # set for the study's own process: the study NAME it runs in place


def fenced(name):
    """Whether `dc study NAME` runs fenced here: an installed study, unless this process is the
    sandbox that runs it."""
    return os.environ.get(INSIDE) != name and name not in STUDIES.builtin()


# --- The run --------------------------------------------------------------------------------------

def run(name, args):
    """Runs `dc study NAME ARGS` fenced; returns its exit status. The output (-o) is checked
    before the study starts and swapped in after it ends in order; the user's stop ends it."""
    def writes():   # (what the study's -o is: from its own class, read in a sandbox of its own)
        healthy, broken = survey([name])
        if name in broken:
            raise PluginError(broken[name])
        return healthy[0]["writes"] if healthy else "folder"
    return job.run_with_output(["study", name], list(args), f"study {name}", writes, {INSIDE: name},
                               f"the study {name!r}", aside=units.Beside)


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
    builtin = set(STUDIES.builtin())
    healthy, broken = loaded(names)
    out = {"healthy": [{"name": s.name, "summary": str(s.summary), "order": float(s.order), "writes": str(s.writes)}
                       for s in healthy if s.name not in builtin],
           "broken": {k: v for k, v in broken.items() if k not in builtin}}
    sys.stdout.write(json.dumps(out))
    sys.stdout.flush()
