"""Checking at the speed of making: `dc validate` and `dc rasterize` of one thesis pile (600 steps)
against the `dc simulate` that made it, as whole processes (start-up included, one thread, -j 1),
the three interleaved round after round in the same run. The goals: validate at most 2x
and rasterize at most 1.5x the time of simulate. Also the XSD's own validation of every file
(what dc validate did before the schema's table, step/strict.py), for scale.

Usage: python benchmarks/bench_checking.py [--rounds N]
"""
import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from deepcontact.protocol import current, protocol_line


def timed(args, cwd):
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "deepcontact.cli.main", *args], cwd=cwd, check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t


def xsd_of_every_file(run):
    """Seconds to validate every step file of run with the XSD itself (the native validator)."""
    from deepcontact._box2d import validate_step_file
    from deepcontact.step.reader import step_schema
    files = sorted(Path(run).rglob("step-*.xml"))
    t = time.perf_counter()
    for f in files:
        validate_step_file(str(f), step_schema(), 1)
    return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")   # how these times were taken
    with tempfile.TemporaryDirectory() as tmp:
        times = {"simulate": [], "validate": [], "rasterize": []}
        for _ in range(args.rounds):
            times["simulate"].append(timed(["simulate", "pile", "-q", "--overwrite", "-o", "run"], tmp))
            times["validate"].append(timed(["validate", "-q", "run"], tmp))
            times["rasterize"].append(timed(["rasterize", "-q", "run", "--overwrite", "-o", "grid"], tmp))
        xsd = xsd_of_every_file(Path(tmp) / "run")
    made = statistics.median(times["simulate"])
    print(f"the thesis pile, 600 steps, whole processes, median of {args.rounds} interleaved rounds")
    for name, goal in (("simulate", None), ("validate", 2.0), ("rasterize", 1.5)):
        t = statistics.median(times[name])
        print(f"  dc {name:10s} {t:6.2f} s  {t / made:5.2f}x simulate" + (f"   (goal: at most {goal}x)" if goal else ""))
    print(f"  (the XSD itself on every file, in this process: {xsd:.2f} s, {xsd / made:.2f}x simulate)")


if __name__ == "__main__":
    main()
