"""Checking at the speed of making: `dc validate` and `dc rasterize` of one thesis pile (600 steps)
against the `dc simulate` that made it, as whole processes (start-up included, one thread, -j 1),
the three interleaved round after round in the same run. The goals: validate at most 2x
and rasterize at most 1.5x the time of simulate. Also the README's run of the project's solver
(`--solver pgs --tolerance 1e-4 --max-iterations 1000 --relaxation 1.7`) and `dc validate
--residuals` of it, which recomputes every step's residual, goal at most 2x that simulate, in the
same rounds; and the XSD's own validation of every file (what dc validate did before the
schema's table, step/strict.py), for scale.

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


PSOR = ["--solver", "pgs", "--tolerance", "1e-4", "--max-iterations", "1000", "--relaxation", "1.7"]   # the README's
# (name, arguments, (the command it is measured against, its goal))
COMMANDS = [("simulate", ["simulate", "pile", "-q", "--overwrite", "-o", "run"], ("simulate", None)),
            ("validate", ["validate", "-q", "run"], ("simulate", 2.0)),
            ("rasterize", ["rasterize", "-q", "run", "--overwrite", "-o", "grid"], ("simulate", 1.5)),
            ("simulate --solver pgs", ["simulate", "pile", *PSOR, "-q", "--overwrite", "-o", "psor"],
             ("simulate --solver pgs", None)),
            ("validate --residuals", ["validate", "--residuals", "-q", "psor"], ("simulate --solver pgs", 2.0))]


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
        times = {name: [] for name, _, _ in COMMANDS}
        for _ in range(args.rounds):
            for name, command, _ in COMMANDS:
                times[name].append(timed(command, tmp))
        xsd = xsd_of_every_file(Path(tmp) / "run")
    print(f"the thesis pile, 600 steps, whole processes, median of {args.rounds} interleaved rounds")
    for name, _, (base, goal) in COMMANDS:
        t, made = statistics.median(times[name]), statistics.median(times[base])
        print(f"  dc {name:22s} {t:6.2f} s  {t / made:5.2f}x {base}" + (f"   (goal: at most {goal}x)" if goal else ""))
    made = statistics.median(times["simulate"])
    print(f"  (the XSD itself on every file, in this process: {xsd:.2f} s, {xsd / made:.2f}x simulate)")


if __name__ == "__main__":
    main()
