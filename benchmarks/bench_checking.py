"""Checking at the speed of making: `dc validate` and `dc rasterize` of one thesis pile (600 steps)
against the `dc simulate` that made it, as whole processes (start-up included, one thread, -j 1),
the three interleaved round after round in the same run. The goals: validate at most 2x
and rasterize at most 1.5x the time of simulate. Also the README's run of the project's solver
(`--solver pgs --tolerance 1e-4 --max-iterations 1000 --relaxation 1.7`) and `dc validate
--residuals` of it, which recomputes every step's residual, goal at most 2x that simulate, in the
same rounds; and, in this process, the schema's table (step/strict.py) and the XSD's own
validation on every file: dc validate runs the XSD only where the table does not accept a file
(what the XSD everywhere would cost, for scale).

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


def every_file(run, check, passes=3):
    """CPU seconds to check every step file of run with check(path), the least of `passes` passes
    (CPU, not wall: a loaded machine's other processes count less)."""
    files = [str(f) for f in sorted(Path(run).rglob("step-*.xml"))]
    best = float("inf")
    for _ in range(passes):
        t = time.process_time()
        for f in files:
            check(f)
        best = min(best, time.process_time() - t)
    return best


def table_and_xsd(run):
    """(the schema's table alone, the XSD itself: the native validator) on every step file of run,
    in this process: the table's verdict is final where it accepts a file, so the XSD runs on no
    file dc wrote; running it everywhere (the other rule) would cost the difference."""
    from deepcontact._box2d import check_step_table, validate_step_file
    from deepcontact.step.reader import step_schema, strict_table
    return (every_file(run, lambda f: check_step_table(f, strict_table())),
            every_file(run, lambda f: validate_step_file(f, step_schema(), 1)))


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
        table, xsd = table_and_xsd(Path(tmp) / "run")
    print(f"the thesis pile, 600 steps, whole processes, median of {args.rounds} interleaved rounds")
    for name, _, (base, goal) in COMMANDS:
        t, made = statistics.median(times[name]), statistics.median(times[base])
        print(f"  dc {name:22s} {t:6.2f} s  {t / made:5.2f}x {base}" + (f"   (goal: at most {goal}x)" if goal else ""))
    made = statistics.median(times["simulate"])
    print(f"  (in this process, every file, CPU, least of 3 passes: the schema's table {table:.2f} s, the XSD "
          f"itself {xsd:.2f} s)")


if __name__ == "__main__":
    main()
