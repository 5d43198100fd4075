"""What a dc evaluate report's pictures cost: the same evaluation with and without them.

A 30-circle pile (150 steps) is simulated once; then `dc evaluate` (in this process, as the CLI
runs it) replays every 40th step from builtin and zero, with its budgets, repeatedly, the two
settings interleaved round by round: with the pictures (convergence, iterations and pareto, PNG
and SVG each) and with --no-plots. Medians; the ratio is the tables-only run's time to the full
report's in the same run.

Usage: python benchmarks/bench_report.py [--repeats N]
"""
import statistics
import sys
import tempfile
import time
from pathlib import Path

from click.testing import CliRunner

from deepcontact.cli.main import cli

sys.path.insert(0, str(Path(__file__).parent))
from common import arguments  # noqa: E402


def main():
    args = arguments(__doc__, repeats=7)
    runner = CliRunner()
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        made = runner.invoke(cli, ["simulate", "pile", "--param", "count=30", "--param", "box=16", "--param",
                                   "sigma=4", "--steps", "150", "-q", "-o", str(run)])
        assert made.exit_code == 0, made.output
        base = ["evaluate", str(run), "--starts", "builtin,zero", "--every", "40", "-q", "--overwrite"]
        variants = {"full report (6 pictures)": [], "--no-plots": ["--no-plots"]}
        times = {name: [] for name in variants}
        for k in range(args.repeats + 1):
            for name, extra in variants.items():
                t = time.perf_counter()
                r = runner.invoke(cli, base + extra + ["-o", str(Path(tmp) / name.split()[0])])
                if k:   # (the first round warms the imports)
                    times[name].append(time.perf_counter() - t)
                assert r.exit_code == 0, r.output
    full = statistics.median(times["full report (6 pictures)"])
    print(f"dc evaluate, a 30-circle pile, 4 steps x 2 starts with budgets; median of {args.repeats}")
    print(f"{'':28s} {'median s':>9s} {'x full':>7s}")
    for name, values in times.items():
        m = statistics.median(values)
        print(f"{name:28s} {m:9.3f} {m / full:7.2f}")


if __name__ == "__main__":
    main()
