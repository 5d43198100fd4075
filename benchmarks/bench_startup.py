"""What a `dc` call costs before it does any work: whole processes, as a Makefile runs them.

Each command below runs as a fresh process, round-robin (every command once, then again, so a
busy moment of the machine touches them all alike), and the table gives the median and the
fastest of the runs, with the median's ratio to a bare `python -c "import numpy, click"` taken in
the same rounds (the floor any numpy CLI pays). `python -c pass` is the interpreter alone.

Goals: `dc --help` within 1.5x of the floor, `dc simulate pile --steps 1` within 2x (a Makefile
calling dc hundreds of times should not pay for the whole library at each call).
The interpreter is this one; `dc` is the console script beside it (not a version manager's shim,
which adds its own start-up). Bytecode is cached (in a temporary folder), as on a user's machine.

Usage: python benchmarks/bench_startup.py [--runs N]
"""
import os
import statistics
import subprocess
import sys
import tempfile
import time

from common import arguments

SUBCOMMANDS = ("simulate", "validate", "rasterize", "train", "evaluate", "study", "export", "render")
GOALS = {"dc --help": 1.5, "dc simulate pile --steps 1": 2.0}
FLOOR = "python -c 'import numpy, click'"


def dc_command():
    exe = os.path.join(os.path.dirname(sys.executable), "dc")
    return [exe] if os.path.exists(exe) else [sys.executable, "-m", "deepcontact.cli.main"]


def commands(tmp):
    dc = dc_command()
    rows = {
        "python -c pass": [sys.executable, "-c", "pass"],
        FLOOR: [sys.executable, "-c", "import numpy, click"],
        "dc --help": dc + ["--help"],
        "dc simulate pile --steps 1": dc + ["simulate", "pile", "--steps", "1", "-q", "--overwrite",
                                            "-o", os.path.join(tmp, "run")],
    }
    for name in SUBCOMMANDS:
        rows[f"dc {name} --help"] = dc + [name, "--help"]
    return rows


def wall_time(argv, env):
    t = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    return time.perf_counter() - t


def main():
    args = arguments(__doc__, runs=15)
    with tempfile.TemporaryDirectory() as tmp:
        rows = commands(tmp)
        # Compiled bytecode cached as on a user's machine, even where PYTHONDONTWRITEBYTECODE is
        # set (it is on this project's machines): in a folder of its own, not in the checkout.
        env = dict(os.environ, PYTHONPYCACHEPREFIX=os.path.join(tmp, "pycache"))
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        for argv in rows.values():   # once each first: the page cache, the bytecode
            wall_time(argv, env)
        times = {name: [] for name in rows}
        for _ in range(args.runs):
            for name, argv in rows.items():
                times[name].append(wall_time(argv, env))
    floor = statistics.median(times[FLOOR])
    print(f"whole processes, {args.runs} rounds, round-robin; seconds")
    print(f"{'command':34s}{'median':>8s}{'fastest':>9s}{'x floor':>9s}  goal")
    for name, ts in times.items():
        median = statistics.median(ts)
        goal = GOALS.get(name)
        verdict = "" if goal is None else f"<= {goal}x: {'met' if median / floor <= goal else 'NOT met'}"
        print(f"{name:34s}{median:8.3f}{min(ts):9.3f}{median / floor:9.2f}  {verdict}")


if __name__ == "__main__":
    main()
