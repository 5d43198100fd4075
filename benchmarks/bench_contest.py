"""What does a contestant's sandbox cost, against the same contestant as a bare process?

Both ways run the same guest (deepcontact/contest/guest.py) and the same judge's call:
  fenced  bubblewrap namespaces, seccomp, its own control group, whose CPU the judge reads after
          every call (what dc evaluate uses where the machine lends every fence)
  bare    a plain process of its own, no namespace, no control group (what a machine without
          bubblewrap or user namespaces gets, its missing fences stated in the report)
Measured in the same run, one thread, on a settled step of the thesis pile (100 circles):
  start   seconds from asking for a contestant to its "ready" (a fresh interpreter with the solver
          imported), and its setup (making the builtin start), best of --starts, interleaved; and,
          fenced, the CPU its control group used to the end of its setup (median: what a thousand
          contestants cost a machine, its thread pools' start included)
  call    the round trip of a solve request capped at one sweep, the median of --calls calls per
          way, the two ways alternating call by call
The issue's goals: at most 0.1 ms a call and 150 ms of start a contestant over the bare path.

Usage: python benchmarks/bench_contest.py [--calls N] [--starts N]
"""
import argparse
import pickle
import tempfile
import time
from pathlib import Path

import numpy as np

from deepcontact.contest import Contestant, client, machine
from deepcontact.contest.wire import unanswered
from deepcontact.protocol import current, protocol_line
from deepcontact.scene.generators import generate
from deepcontact.simulate.run import run as simulate_run
from deepcontact.solver.problem import StepProblem
from deepcontact.solver.settings import SolveSettings
from deepcontact.warmstart.starts import Builtin


def bare(on):
    """Switches the fences off (the path a machine without them takes) or back on."""
    if on:
        machine.bwrap, machine.cgroup_roots = (lambda: None), (lambda: {})
    else:
        machine.bwrap, machine.cgroup_roots = _fenced


_fenced = (machine.bwrap, machine.cgroup_roots)


def contestant(fenced):
    bare(not fenced)
    try:
        t0 = time.perf_counter()
        c = Contestant("builtin", "builtin", Builtin(), "none").begin()
        return c, time.perf_counter() - t0
    finally:
        bare(False)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=400)
    ap.add_argument("--starts", type=int, default=5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        simulate_run(lambda seed: generate("pile", seed=seed), [0], Path(tmp) / "run")
        files = sorted((Path(tmp) / "run").rglob("step-000350.xml"))
        problem = StepProblem.from_step_file(files[0])
    request = {"op": "solve", "problem": pickle.dumps(unanswered(problem)), "normal": problem.start_normal,
               "tangent": problem.start_tangent, "settings": SolveSettings().but(max_iterations=1)}
    starts = {True: [], False: []}
    setups = {True: [], False: []}
    cpu = []
    for _ in range(a.starts):
        for fenced in (True, False):
            c, took = contestant(fenced)
            starts[fenced].append(c.start_s)
            setups[fenced].append(c.setup_s)
            if fenced and c.cpu_last is not None:
                cpu.append(c.cpu_last)
            c.close()
    pair = {fenced: contestant(fenced)[0] for fenced in (True, False)}
    calls = {True: [], False: []}
    try:
        for c in pair.values():   # (warmed)
            for _ in range(20):
                c.call(request)
        for _ in range(a.calls):
            for fenced, c in pair.items():
                t0 = time.perf_counter()
                c.call(request)
                calls[fenced].append(time.perf_counter() - t0)
    finally:
        for c in pair.values():
            c.close()
    print(protocol_line(current()))
    print(f"step: {problem.points} contact points; fences here: {machine.describe_fences()}")
    print(f"deadline rule: {client.deadline_rule()}")
    print(f"{'':8} {'start ms (best)':>16} {'setup ms (best)':>16} {'call ms (median)':>17} {'call ms (p90)':>14}")
    for fenced in (True, False):
        c = np.array(calls[fenced]) * 1e3
        print(f"{'fenced' if fenced else 'bare':8} {1e3 * min(starts[fenced]):16.1f} {1e3 * min(setups[fenced]):16.2f} "
              f"{np.median(c):17.4f} {np.percentile(c, 90):14.4f}")
    if cpu:
        print(f"fenced start and setup: {1e3 * np.median(cpu):.0f} ms of CPU (median of {len(cpu)})")
    extra = np.median(calls[True]) - np.median(calls[False])
    print(f"the sandbox adds {1e3 * extra:.4f} ms a call (median) and "
          f"{1e3 * (min(starts[True]) - min(starts[False])):.1f} ms of start a contestant")


if __name__ == "__main__":
    main()
