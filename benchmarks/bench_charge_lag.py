"""Why a contestant reads its own CPU clock before it answers: a task's CPU time reaches its
control group only at a scheduling event, a tick, or a read of its own CPU clock, so a judge that
reads the group as soon as the answer arrives can find a whole call's work not yet there.

A child process in a cgroup v1 cpuacct group of its own, on another CPU than the parent's where
there is one (the judge's on one core, the contestant's on the other), answers N requests on a
pipe: each one 100 us of work, then its answer, then 0-60 us more (drawn a call) before it waits
again (the tail a contestant runs between its answer and its next read: which of the judge's reads
lands before the child has waited again, and which after, changes from call to call). The parent,
as the judge does, reads the group's usage as soon as each answer arrives. Run both ways, the child
reading its CPU clock (`time.thread_time_ns()`, what contest/guest.py does: its thread's clock,
which a CPU timer armed for the process, a `ulimit -t`, does not stop from accounting) before it
answers or not. Printed for each: the least, the 5th percentile and the median CPU a call
(microseconds) and the calls read under 50 us. Without the clock read a call now and then reads as
no CPU at all, the work still unaccounted; the closed loop takes the null contestant's least CPU
over a run as the floor of every charge, so one such call raised every charge of the run by a
call's CPU (docs/results/loop- path.md, "Held to one CPU").

Needs a writable cgroup v1 cpuacct hierarchy (root); says so and measures nothing elsewhere.

Usage: python benchmarks/bench_charge_lag.py [--calls 2000] [--rounds 2]
"""
import os
import random
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import arguments  # noqa: E402

HIERARCHY = Path("/sys/fs/cgroup/cpuacct")


def spin(seconds):
    t = time.perf_counter()
    while time.perf_counter() - t < seconds:
        pass


def child(requests, answers, group, clock_read):
    try:
        (group / "cgroup.procs").write_text(str(os.getpid()))
    except OSError:
        os._exit(1)   # (the parent reads the end of its line: said there)
    os.write(answers, b"r")
    while os.read(requests, 1) == b"g":
        spin(100e-6)   # the call's work
        if clock_read:
            time.thread_time_ns()   # (as contest/guest.py's _send)
        os.write(answers, b"a")
        spin(random.uniform(0, 60e-6))   # its tail, before it waits again
    os._exit(0)


def one_way(calls, clock_read):
    """Each call's CPU (microseconds) as the group's usage read as its answer arrives."""
    group = HIERARCHY / f"dc_charge_lag_{os.getpid()}"
    group.mkdir()
    pid, cpus = None, sorted(os.sched_getaffinity(0))
    try:
        requests_r, requests_w = os.pipe()
        answers_r, answers_w = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(requests_w)
            os.close(answers_r)
            if len(cpus) > 1:
                os.sched_setaffinity(0, {cpus[-1]})
            child(requests_r, answers_w, group, clock_read)
        if len(cpus) > 1:
            os.sched_setaffinity(0, {cpus[0]})
        os.close(requests_r)   # (ours closed: a child that ends is an end of line here, not a wait)
        os.close(answers_w)
        if os.read(answers_r, 1) != b"r":
            sys.exit(f"the child could not join {group}")
        usage = group / "cpuacct.usage"
        last, out = int(usage.read_text()), []
        for _ in range(calls):
            os.write(requests_w, b"g")
            if os.read(answers_r, 1) != b"a":
                sys.exit("the child ended before its answer")
            now = int(usage.read_text())
            out.append((now - last) / 1e3)
            last = now
            time.sleep(200e-6)   # (the judge's step between calls)
    finally:
        os.sched_setaffinity(0, set(cpus))
        if pid:
            try:
                os.write(requests_w, b"q")
            except OSError:
                pass
            os.waitpid(pid, 0)
            for fd in (requests_w, answers_r):
                os.close(fd)
        group.rmdir()
    return out


def main():
    args = arguments(__doc__, calls=2000, rounds=2, at_least_one=("calls",))
    if not (HIERARCHY / "cgroup.procs").exists() or not os.access(HIERARCHY, os.W_OK):
        print(f"no writable cgroup v1 cpuacct hierarchy at {HIERARCHY} (root, cgroup v1): not measured")
        return
    for k in range(args.rounds):
        for clock_read in (False, True):
            d = sorted(one_way(args.calls, clock_read))
            print(f"round {k + 1}, {'with' if clock_read else 'without'} the clock read: CPU a call least "
                  f"{d[0]:.0f} us, 5th percentile {d[len(d) // 20]:.0f}, median {statistics.median(d):.0f}; "
                  f"under 50 us: {sum(x < 50 for x in d)} of {len(d)}", flush=True)


if __name__ == "__main__":
    main()
