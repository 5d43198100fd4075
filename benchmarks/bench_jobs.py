"""What does a fenced job's start cost, forked from the jobs' zygote against a fresh sandbox?

A job (a plug-in study, a plug-in network's training or drawing, the studies' listing) runs a
whole interpreter in a job's fence (contest/job.py). Two ways, the same fence record (fence.JOB):
  forked  a fork of the jobs' zygote (contest/zygote.py: numpy loaded once, and for a training or
          a drawing torch and its compiler) that fences itself as the job before its command runs
  fresh   a fresh interpreter started by bubblewrap (DC_NO_ZYGOTE=1: the way before, and where
          a machine refuses a fork's fence)
Two commands, each run to its end, the ways interleaved round by round:
  dc --version        what every job pays before its own work: the interpreter and dc's CLI (a
                      study's profile: forked from the zygote without torch)
  a first step        what a training job's interpreter pays before its first epoch: torch, a
                      network and its optimiser's first step, which imports torch's compiler (the
                      training profile: forked from the zygote with torch)
For each: the median and least wall time from asking for the job to its end, and the median CPU
its control group used (every process it ran, bubblewrap's too), over --rounds rounds; each jobs'
zygote's own start (wall, CPU), paid once a dc process, before.

Usage: python benchmarks/bench_jobs.py [--rounds N]
"""
import os
import statistics
import tempfile
import time
from dataclasses import replace

from common import arguments
from deepcontact.contest import fence, job, machine, sandbox, zygote

COMMANDS = {   # (the profile, as a study's and a training's, and the command)
    "dc --version": ("job", ["-m", "deepcontact.cli.main", "--version"]),
    "a first step": ("training", ["-c", "import torch, torch.nn as nn; m = nn.Conv2d(3, 3, 1); "
                                  "o = torch.optim.Adam(m.parameters()); m(torch.zeros(1, 3, 8, 8)).sum().backward(); "
                                  "o.step()"]),
}
WAYS = ("forked", "fresh")


def quiet(profile):
    """A job's fence of `profile`, its output not shown."""
    return replace(fence.PROFILES[profile], streams=fence.Streams(stdout="discard"))


def one(way, profile, argv, tmp):
    """(wall seconds, CPU seconds of its group, exit status) of one job run to its end."""
    os.environ["DC_NO_ZYGOTE"] = "1" if way == "fresh" else "0"
    private = tempfile.mkdtemp(dir=tmp)
    box = sandbox.Sandbox(quiet(profile).with_paths(writable=[private]))
    env = dict(os.environ, TMPDIR=private, PYTHONPATH=job.python_path())
    read, write = os.pipe()
    try:
        start = time.monotonic()
        job.start(box, argv, write, env)
        os.close(write)
        write = None
        code = box.process.wait()
        wall = time.monotonic() - start
        cpu = box.cpu_seconds()
    finally:
        box.kill()
        for fd in (read, write):
            if fd is not None:
                os.close(fd)
    return wall, cpu, code


def main():
    args = arguments(__doc__, rounds=10)
    if not zygote.usable_for_job(quiet("job")):
        raise SystemExit(f"no job can be forked here (fences: {machine.fences()})")
    with tempfile.TemporaryDirectory() as tmp:
        for torch in (False, True):
            start = time.monotonic()
            made = zygote.live_job(dict(os.environ, PYTHONPATH=job.python_path()), torch=torch)
            print(f"the jobs' zygote{' with torch' if torch else ''}, its start, once: "
                  f"{time.monotonic() - start:.2f} s wall, {made.box.cpu_seconds():.2f} s of CPU")
        print()
        print("| command | way | wall s, median | wall s, least | CPU s, median (its group) |")
        print("| --- | --- | ---: | ---: | ---: |")
        rows = {}
        for _ in range(args.rounds):
            for name, (profile, argv) in COMMANDS.items():
                for way in WAYS:
                    wall, cpu, code = one(way, profile, argv, tmp)
                    if code != 0:
                        raise SystemExit(f"{name} ({way}) ended with exit status {code}")
                    rows.setdefault((name, way), []).append((wall, cpu))
        for (name, way), seen in rows.items():
            walls, cpus = [w for w, _ in seen], [c for _, c in seen]
            print(f"| {name} | {way} | {statistics.median(walls):.3f} | {min(walls):.3f} | {statistics.median(cpus):.3f} |")
        for name in COMMANDS:
            ratio = (statistics.median(c for _, c in rows[(name, 'forked')])
                     / statistics.median(c for _, c in rows[(name, 'fresh')]))
            print(f"\n{name}: forked / fresh CPU {ratio:.2f}", end="")
        print()


if __name__ == "__main__":
    main()
