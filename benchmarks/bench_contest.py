"""What does a contestant's sandbox cost, against the same contestant as a bare process?

Every way runs the same guest (deepcontact/contest/guest.py) and the same judge's call:
  forked  a fork of the contestants' zygote (contest/zygote.py) that fences itself as a contestant:
          its own namespaces, view, /proc, control group from birth, seccomp (what dc evaluate
          uses where the machine lends it)
  fresh   a fresh interpreter started by bubblewrap in the same fence (DC_NO_ZYGOTE=1: the way
          before the zygote, and where a machine refuses a fork's fence)
  bare    a plain process of its own, no namespace, no control group (what a machine without
          bubblewrap or user namespaces gets, its missing fences stated in the report)
Measured in the same run, one thread, on a settled step of the thesis pile (100 circles):
  start   seconds from asking for a contestant to its "ready", and its setup (making the builtin
          start), best of --starts, the ways interleaved (the zygote's own start, once, before);
          and, fenced, the CPU its control group used to the end of its setup (median: what a
          thousand contestants cost a machine); and the wall time of ending it (median)
  call    the round trip of a solve request capped at one sweep, the median of --calls calls per
          way, the ways alternating call by call
--network: every contestant is given a trained network's checkpoint (a tiny one, trained here
first), as dc evaluate gives every variant where one start uses a network: each loads torch and
the network before its clock (forked: from a zygote of its own that has torch loaded).

Usage: python benchmarks/bench_contest.py [--calls N] [--starts N] [--network]
"""
import argparse
import os
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


WAYS = ("forked", "fresh", "bare")


def contestant(way, checkpoint=None):
    bare(way == "bare")
    os.environ["DC_NO_ZYGOTE"] = "1" if way == "fresh" else "0"
    try:
        t0 = time.perf_counter()
        c = Contestant("builtin", "builtin", Builtin(), "none", checkpoint=checkpoint).begin()
        return c, time.perf_counter() - t0
    finally:
        bare(False)
        os.environ.pop("DC_NO_ZYGOTE")


def ended(c):
    t0 = time.perf_counter()
    c.close()
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=400)
    ap.add_argument("--starts", type=int, default=5)
    ap.add_argument("--network", action="store_true", help="each contestant given a trained network's checkpoint")
    a = ap.parse_args()
    tmp_folder = tempfile.TemporaryDirectory()
    tmp = tmp_folder.name
    simulate_run(lambda seed: generate("pile", seed=seed), [0], Path(tmp) / "run")
    files = sorted((Path(tmp) / "run").rglob("step-000350.xml"))
    problem = StepProblem.from_step_file(files[0])
    checkpoint = tiny_checkpoint(Path(tmp)) if a.network else None
    request = {"op": "solve", "problem": pickle.dumps(unanswered(problem)), "normal": problem.start_normal,
               "tangent": problem.start_tangent, "settings": SolveSettings().but(max_iterations=1)}
    starts, setups, cpu, ends = ({w: [] for w in WAYS} for _ in range(4))
    ended(contestant("forked", checkpoint)[0])   # (the zygote started, once)
    for _ in range(a.starts):
        for way in WAYS:
            c, took = contestant(way, checkpoint)
            starts[way].append(c.start_s)
            setups[way].append(c.setup_s)
            if c.cpu_last is not None:   # (its group's CPU when its setup ended)
                cpu[way].append(c.cpu_last)
            ends[way].append(ended(c))
    assert os.environ.get("DC_NO_ZYGOTE") is None
    pair = {way: contestant(way, checkpoint)[0] for way in WAYS}
    kinds = {way: type(c.sandbox.process).__name__ for way, c in pair.items()}
    calls = {way: [] for way in WAYS}
    try:
        for c in pair.values():   # (warmed)
            for _ in range(20):
                c.call(request)
        for _ in range(a.calls):
            for way, c in pair.items():
                t0 = time.perf_counter()
                c.call(request)
                calls[way].append(time.perf_counter() - t0)
    finally:
        for c in pair.values():
            c.close()
    tmp_folder.cleanup()
    print(protocol_line(current()))
    print(f"step: {problem.points} contact points; fences here: {machine.describe_fences()}"
          + ("; every contestant given a trained network's checkpoint (torch loaded before its clock)"
             if checkpoint else ""))
    print(f"deadline rule: {client.deadline_rule()}; processes: {kinds}")
    print(f"{'':8} {'start ms (best)':>16} {'setup ms (best)':>16} {'start+setup CPU ms (median)':>28} "
          f"{'end ms (median)':>16} {'call ms (median)':>17} {'call ms (p90)':>14}")
    for way in WAYS:
        c = np.array(calls[way]) * 1e3
        used = f"{1e3 * np.median(cpu[way]):28.1f}" if cpu[way] else f"{'-':>28}"
        print(f"{way:8} {1e3 * min(starts[way]):16.1f} {1e3 * min(setups[way]):16.2f} {used} "
              f"{1e3 * np.median(ends[way]):16.1f} {np.median(c):17.4f} {np.percentile(c, 90):14.4f}")
    extra = np.median(calls["forked"]) - np.median(calls["bare"])
    print(f"the fork's sandbox adds {1e3 * extra:.4f} ms a call (median) and "
          f"{1e3 * (min(starts['forked']) - min(starts['bare'])):.1f} ms of start a contestant over bare")


def tiny_checkpoint(tmp):
    """A checkpoint of a tiny network trained for one epoch on a few steps of a small pile."""
    from deepcontact.grid.dataset import DatasetSettings, write_dataset
    from deepcontact.model.config import TrainConfig
    from deepcontact.model.train import train
    from dataclasses import replace
    small = {"count": 12, "box": 12, "sigma": 2.5}
    simulate_run(lambda seed: replace(generate("pile", seed=seed, params=small), steps=60), [0, 1], tmp / "small",
                 skip_contactless=True)
    write_dataset([tmp / "small"], tmp / "ds", DatasetSettings(cell=1.0, h=1.0, validation_fraction=0.5))
    train(tmp / "ds", tmp / "m", TrainConfig(model="fcn", fcn_width=4, fcn_depth=2, epochs=1, batch_size=8), plots=False)
    return str(tmp / "m" / "last.pt")


if __name__ == "__main__":
    main()
