"""What every benchmark script starts with: its options, and a line saying how its times are taken."""
import argparse
import subprocess
import sys
import time
from itertools import islice

from deepcontact.protocol import current, protocol_line

DC = [sys.executable, "-m", "deepcontact.cli.main"]   # dc, as this interpreter runs it


def arguments(doc, at_least_one=(), **defaults):
    """The script's options (--name for each keyword, typed by its default; the names in
    at_least_one never below 1, a count of things each round must have), parsed, after the
    protocol line (threads, -j, versions, CPU, load, command) is printed."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name, default in defaults.items():
        ap.add_argument("--" + name.replace("_", "-"), type=_typed(default, 1 if name in at_least_one else 0),
                        default=default)
    args = ap.parse_args()
    if getattr(args, "pinned", 0):
        pin_to_one_cpu()
    print(protocol_line(current()) + "\n")   # how these times were taken (the CPUs held to, where pinned)
    return args


def pin_to_one_cpu():
    """Holds this process, and every process it starts (a contestant's sandbox among them), to the
    highest-numbered CPU it may run on: a call to a contestant is then a switch on one core, not a
    wake-up of another (whose cost the host's scheduler decides, run by run)."""
    import os
    one = {max(os.sched_getaffinity(0))}
    for tid in os.listdir("/proc/self/task"):   # (every thread: numpy's pool's, started at its import, too)
        try:
            os.sched_setaffinity(int(tid), one)
        except OSError:
            pass


def _typed(default, least=0):
    """The option's type, a number never below `least` where its default is not below zero (a
    count, a size, a step: --base -1 was a traceback from the scene's generator): argparse's one
    line and exit 2."""
    kind = type(default)
    if kind not in (int, float) or default < 0:
        return kind

    def at_least(text):
        value = kind(text)
        if not value >= least:
            raise argparse.ArgumentTypeError(f"must be at least {least}, got {text}")
        return value
    at_least.__name__ = kind.__name__   # (argparse names the type in its message)
    return at_least


def timed(args):
    """(wall seconds, peak resident MB) of one whole command, which must succeed. The peak is
    measured by GNU time around the command: a child forked from this (large) process would count
    this process's memory at the fork as its own."""
    t = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-f", "%M", *DC, *args], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        sys.exit(f"failed: dc {' '.join(args)}\n{proc.stderr[-2000:]}")
    return wall, int(proc.stderr.strip().splitlines()[-1]) / 1024


def block_seconds(step, block):
    """The thread's CPU seconds a call of `step` takes, called `block` times in a row: the first
    untimed where block > 1 (the world's data back in the cache, as a world stepped alone has it),
    the others timed together (--block in bench_step_price.py and bench_equal_time.py)."""
    if block > 1:
        step()
    timed = max(block - 1, 1)
    t = time.thread_time()
    for _ in range(timed):
        step()
    return (time.thread_time() - t) / timed


def settled_and_samples(scene, settle, samples, every):
    """The bodies of the scene after `settle` steps of Box2D's own 8 iterations, and the contact
    problems of `samples` steps from there (every `every`-th) of the same run (bench_equal_time.py,
    bench_sweep_order.py)."""
    from deepcontact.simulate.engines import Box2D
    from deepcontact.simulate.problems import problems
    taken = list(islice(problems(scene, Box2D(velocity_iterations=8), first=settle, every=every), samples))
    return taken[0][0].bodies, [problem for _, problem in taken]
