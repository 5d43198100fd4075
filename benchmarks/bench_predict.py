"""Can a reader trust the prediction time `dc evaluate` reports for a learned start?

Two checks, in one process and one run: (1) the median prediction time `dc evaluate` reports
for the cnn start against a bare prediction loop (Predictor.predict on the same steps) — within
20% is the goal; (2) the same report with one busy process per core competing, against the quiet
figure — within 2x with the default (one torch thread) is the goal; torch's own default (a thread
per core) is shown beside it for contrast. The model is an FCN trained 2 epochs on a small pile;
what matters here is the cost of a forward pass, not its accuracy.

Usage: python benchmarks/bench_predict.py [--out DIR] [--every N]
"""
import argparse
import contextlib
import csv
import io
import json
import multiprocessing
import os
import statistics
import sys
import time
from pathlib import Path

import torch

from deepcontact.cli.main import cli
from deepcontact.model.inference import Predictor
from deepcontact.protocol import protocol, protocol_line
from deepcontact.step.reader import read_step
from deepcontact.step.run_folder import step_path


def dc(*args):
    """A dc command in this process (the same process as the bare loop), its table not printed."""
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            cli([str(a) for a in args], standalone_mode=False)
    except SystemExit as e:
        if e.code:
            raise


def reported(run, model, out, every, threads):
    dc("evaluate", run, "--starts", "cnn", "--checkpoint", model, "--every", every, "--no-budgets", "--threads", threads,
       "-q", "--overwrite", "-o", out)
    summary = json.loads((out / "summary.json").read_text())
    return summary["starts"]["cnn"]["predict_ms_median"]


def bare(report, model):
    """Predictor.predict on the step files dc evaluate solved (its steps.csv), in its order."""
    p = Predictor(model, threads=1)
    with open(report / "steps.csv") as f:
        rows = list(csv.DictReader(f))
    files = [step_path(Path(r["run"]) / f"seed-{int(r['seed']):06d}", int(r["step"])) for r in rows]
    times = []
    for f in files:
        _, bodies, contacts = read_step(f)
        t = time.perf_counter()
        p.predict(bodies, contacts)
        times.append(time.perf_counter() - t)
    return 1e3 * statistics.median(times)


def busy(stop):
    while not stop.is_set():
        pass


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="/tmp/dc-bench-predict")
    ap.add_argument("--every", type=int, default=10)
    args = ap.parse_args()
    out = Path(args.out)
    run, data, model = out / "run", out / "data", out / "model"
    dc("simulate", "pile", "--steps", "300", "--seeds", "0..1", "-q", "--overwrite", "-o", run)
    dc("rasterize", run, "--validation", "0.5", "-q", "--overwrite", "-o", data)
    dc("train", data, "--epochs", "2", "--optimizer", "adam", "-q", "--overwrite", "-o", model)
    ck = model / "best.pt"
    quiet = reported(run, ck, out / "r-quiet", args.every, 1)
    quiet_bare = bare(out / "r-quiet", ck)
    cores = os.cpu_count()
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=busy, args=(stop,)) for _ in range(cores)]
    for h in hogs:
        h.start()
    try:
        time.sleep(1)
        loaded = reported(run, ck, out / "r-loaded", args.every, 1)
        loaded_all = reported(run, ck, out / "r-loaded-all", args.every, cores)
    finally:
        stop.set()
        for h in hogs:
            h.join()
    print(protocol_line(protocol(1, 1)) + "\n")
    print("| measurement | prediction ms (median) | ratio |")
    print("| --- | ---: | ---: |")
    print(f"| bare loop, quiet (Predictor.predict, 1 thread) | {quiet_bare:.3f} | 1 |")
    print(f"| dc evaluate reports, quiet (default --threads 1) | {quiet:.3f} | {quiet / quiet_bare:.2f} x bare |")
    print(f"| dc evaluate reports, {cores} busy processes (default --threads 1) | {loaded:.3f} | "
          f"{loaded / quiet:.2f} x quiet |")
    print(f"| dc evaluate reports, {cores} busy processes (--threads {cores}, torch's default) | {loaded_all:.3f} | "
          f"{loaded_all / quiet:.2f} x quiet |")
    ok = abs(quiet / quiet_bare - 1) <= 0.2 and loaded / quiet <= 2
    print(f"\ngoals (within 20% of the bare loop; within 2x under load): {'met' if ok else 'NOT met'}")
    torch.set_num_threads(1)
    return 0   # (a measurement, not a test: the verdict is printed)


if __name__ == "__main__":
    sys.exit(main())
