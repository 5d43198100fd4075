"""Is the honest over-relaxing control named, run after run? (the verdict's power, stated)

The control (benchmarks/controls/psor_control.py) is a plug-in solver method that honestly runs
the project's projected SOR at w = 1.7: in the judge's eyes a plug-in like any other, fenced,
its setup charged. This script runs the same `dc evaluate` --runs times on the held-out thesis pile,
Box2D's warm start with plain sweeps against the control,

    dc evaluate HELDOUT --starts builtin --accelerate none,psor_control:PSOR --every 5 --no-plots --no-budgets

and prints each run's verdict line (its report's "Verdict" and "Power" sentences) and how many
runs named the control the fastest. The pile is simulated first unless --heldout names it.

--twin 1: builtin's twin in place of the control (benchmarks/controls/twin_start.py: a plug-in
start handing back exactly Box2D's warm start), `--starts builtin,twin_start:Twin`; it should
never be named, and the count is of runs that named it.

Usage: python benchmarks/bench_control_power.py [--runs 10] [--every 5] [--heldout DIR] [--twin 0]
"""
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import DC, arguments

CONTROLS = Path(__file__).resolve().parent / "controls"
CONTROL = "psor_control:PSOR"
TWIN = "twin_start:Twin"


def heldout_pile(folder):
    """The held-out thesis pile (seeds 1000 and 1001), simulated into `folder`."""
    subprocess.run([*DC, "simulate", "pile", "--seeds", "1000..1001", "-q", "-o", str(folder)], check=True)
    return folder


def verdict(heldout, every, output, twin=False):
    """(seconds, the report's verdict line) of one evaluation of builtin against the control (or
    against its twin)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(CONTROLS), os.environ.get("PYTHONPATH")]))}
    t = time.perf_counter()
    variants = ["--starts", f"builtin,{TWIN}"] if twin else ["--starts", "builtin", "--accelerate", f"none,{CONTROL}"]
    subprocess.run([*DC, "evaluate", str(heldout), *variants,
                    "--every", str(every), "--no-plots", "--no-budgets", "-q", "-o", str(output)],
                   check=True, env=env, stdout=subprocess.DEVNULL)
    report = (output / "report.md").read_text()
    return time.perf_counter() - t, re.search(r"^\*\*Verdict\*\*:.*$", report, flags=re.M).group(0)


def named(line, who=CONTROL):
    """Whether a verdict line names `who` the fastest."""
    return line.startswith("**Verdict**: the fastest") and re.search(r"is \*\*[^*]*" + re.escape(who) + r"\*\*", line) is not None


def main():
    args = arguments(__doc__, runs=10, every=5, heldout="", twin=0)
    with tempfile.TemporaryDirectory(prefix="dc-power-") as scratch:
        heldout = Path(args.heldout) if args.heldout else heldout_pile(Path(scratch) / "heldout")
        count = 0
        for run in range(args.runs):
            seconds, line = verdict(heldout, args.every, Path(scratch) / f"run{run}", bool(args.twin))
            count += named(line, TWIN if args.twin else CONTROL)
            print(f"run {run + 1} ({seconds:.0f} s, load {os.getloadavg()[0]:.1f}): {line}\n", flush=True)
        if args.twin:
            print(f"builtin's twin named the fastest in {count} of {args.runs} runs")
            return 0 if count == 0 else 1
        print(f"the control named the fastest in {count} of {args.runs} runs")
    return 0 if count == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
