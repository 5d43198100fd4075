"""A study from an installed distribution runs fenced, as every plug-in does (docs/reliability.md,
"Plug-ins are guests"): `dc study NAME ARGS` starts the study in a sandbox of its own
(contest.sandbox.JobSandbox: the profile fence.JOB) and dc's own process only checks, stages and publishes its output.

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
import time

from ..contest import fence as fences, job, machine, sandbox
from ..plugins import PluginError
from . import STUDIES, units

def fenced(name):
    """Whether `dc study NAME` runs fenced here: an installed study, unless this process is a
    sandbox dc started (contest.fence.fenced)."""
    return fences.fenced(name not in STUDIES.builtin())


# --- The run --------------------------------------------------------------------------------------

def run(name, args):
    """Runs `dc study NAME ARGS` fenced; returns its exit status. The output (-o) is checked
    before the study starts and swapped in after it ends in order; the user's stop ends it."""
    def writes():   # (what the study's -o is: from its own class, read in a sandbox of its own)
        healthy, broken = survey([name])
        if name in broken:
            raise PluginError(broken[name])
        return healthy[0]["writes"] if healthy else "folder"
    return job.run_with_output(["study", name], list(args), f"study {name}", writes, {},
                               f"the study {name!r}", aside=units.Beside)


# --- The list -------------------------------------------------------------------------------------

def survey(names=None):
    """(the healthy installed studies as [{"name", "summary", "order", "writes"}], {name: line} of
    the broken ones), of every one or of `names`, loaded in a sandbox of their own: listing
    imports every study's code, which runs fenced like the rest of it: where its fence cannot be
    built, each is listed as broken, saying so, unless --unfenced allows it bare."""
    who = f"the study {names[0]!r}" if names and len(names) == 1 else "the installed studies' code"
    try:
        sandbox.refuse_bare(who, [f for f in sandbox.JOB_FENCES if f in machine.missing_fences()])
    except PluginError as e:
        why = str(e).split(", and ", 1)[-1]
        return [], {name: f"the study {name!r} is plug-in code, and {why}"
                    for name in (names or [n for n in STUDIES.names() if n not in STUDIES.builtin()])}
    wanted = list(names or [n for n in STUDIES.names() if n not in STUDIES.builtin()])
    healthy, broken = [], {}
    job.warm(fences.PROFILES["listing"], os.environ)   # (the zygote's start is not the listing's time)
    # (each round at most SURVEY_DEADLINE, the whole listing twice that: stalling studies share it)
    ends = time.monotonic() + 2 * SURVEY_DEADLINE
    while wanted:   # (a study that ends or stalls its listing is broken; the ones after it are listed again)
        if time.monotonic() >= ends:
            broken.update({n: f"the study {n!r} could not be listed: the listing took over {2 * SURVEY_DEADLINE:g} s"
                           for n in wanted})
            break
        found, stalled = _survey_round(wanted, min(ends, time.monotonic() + SURVEY_DEADLINE))
        for entry in (found[name] for name in wanted if name in found):
            if "broken" in entry:
                broken[entry["name"]] = entry["broken"]
            else:
                healthy.append(entry)
        if stalled is None:
            break
        broken[stalled[0]] = f"the study {stalled[0]!r} could not be listed: {stalled[1]}"
        wanted = wanted[wanted.index(stalled[0]) + 1:]
    return sorted(healthy, key=lambda s: (s["order"], s["name"])), broken


SURVEY_DEADLINE = float(os.environ.get("DC_SURVEY_DEADLINE", 60))   # seconds a listing may take
_LINE_MAX = 8 << 10                                                 # bytes of one study's entry


def _survey_round(names, deadline):
    """({name: entry} the listing process reported, over a pipe of its own, one line a study as
    each loads; (the study being loaded when it ended or stalled, how) or None)."""
    box = sandbox.JobSandbox(profile="listing")   # (its streams discarded: the pipe below is its channel)
    env = dict(os.environ, PYTHONPATH=job.python_path())
    read, write = os.pipe()
    try:
        job.start(box, ["-c", "import sys; from deepcontact.studies.listing import survey_here; "
                        "survey_here(int(sys.argv[1]), sys.argv[2:])", str(write), *names], write, env)
        os.close(write)
        write = None
        data, ended = _read_until(read, deadline, len(names) * _LINE_MAX)
    finally:
        box.kill()
        for fd in (read, write):
            if fd is not None:
                os.close(fd)
    found = _entries(data, names)
    missing = [n for n in names if n not in found]
    if not missing:
        return found, None
    how = (f"loading it ended the listing's process ({job.how(box.process.returncode)})" if ended
           else f"loading it took over {SURVEY_DEADLINE:g} s")
    return found, (missing[0], how)


def _read_until(fd, deadline, limit):
    """(what a pipe gave until its writer closed it, the deadline or the limit; whether it closed)."""
    import select
    chunks, size = [], 0
    while size <= limit:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            return b"".join(chunks), False
        chunk = os.read(fd, 65536)
        if not chunk:
            return b"".join(chunks), True
        chunks.append(chunk)
        size += len(chunk)
    return b"".join(chunks), False


def _entries(data, names):
    """{name: entry} from the listing's lines, each checked (typed, a study asked for); anything
    else on the pipe is ignored."""
    found = {}
    for line in data.split(b"\n"):
        try:
            e = json.loads(line) if len(line) <= _LINE_MAX else None
        except (ValueError, RecursionError):
            continue
        if not isinstance(e, dict) or e.get("name") not in names or e["name"] in found:
            continue
        if isinstance(e.get("broken"), str):
            found[e["name"]] = {"name": e["name"], "broken": e["broken"]}
        elif (isinstance(e.get("summary"), str) and type(e.get("order")) in (int, float)
              and e.get("writes") in ("folder", "file", "text")):
            found[e["name"]] = {k: e[k] for k in ("name", "summary", "order", "writes")}
    return found
