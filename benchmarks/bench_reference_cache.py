"""What the closed loop's kept reference trajectory saves: `dc evaluate --closed-loop` on a run of
a 1000-circle pile, twice. The first run steps the reference (float64 PGS to 1e-12 a step) and
keeps it beside the run (deepcontact/evaluate/reference_cache.py); the second reads it back.
Prints both wall times and their ratio: the second is the loop itself, the first the loop and the
reference. Times are whole processes, one thread, -j 1; ratios within one run of this script.
Then the loop itself: `closed_loop` in this process on the same scene, steps and settings, the kept
reference given (read untimed), timed twice (the smaller taken), so that the second command's
time over it is what the command adds to its loop: start-up, the run read, the reference read
back and checked, the report written.

    python benchmarks/bench_reference_cache.py [--count 1000] [--steps 40] [--settle 200]
"""
import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DC = [sys.executable, "-m", "deepcontact.cli.main"]


def timed(args):
    t0 = time.perf_counter()
    subprocess.run(DC + args, check=True)
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=40, help="closed-loop steps evaluated")
    ap.add_argument("--settle", type=int, default=200, help="steps simulated (the pile settles)")
    a = ap.parse_args()
    from deepcontact.protocol import current, protocol_line
    print(protocol_line(current(jobs=1)))
    box, sigma = round(3 * a.count ** 0.5), round(0.6 * a.count ** 0.5)
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        subprocess.run(DC + ["simulate", "pile", "--param", f"count={a.count}", "--param", f"box={box}", "--param",
                             f"sigma={sigma}", "--steps", str(a.settle), "-q", "-o", str(run)], check=True)
        loop = ["evaluate", str(run), "--closed-loop", "--starts", "builtin", "--steps", str(a.steps),
                "--no-budgets", "--no-plots", "-q", "-j", "1"]
        first = timed(loop + ["-o", str(Path(tmp) / "first")])
        again = timed(loop + ["-o", str(Path(tmp) / "again")])
        itself = min(loop_itself(run, a.steps) for _ in range(2))
    print(f"pile of {a.count} circles, {a.steps} closed-loop steps: first {first:.1f} s (the reference stepped), "
          f"again {again:.1f} s (read back): {first / again:.2f}x")
    print(f"the loop itself (closed_loop in-process, builtin and its A/A, the path's native run): {itself:.1f} s; "
          f"the second command {again / itself:.2f}x it")


def loop_itself(run, steps):
    """Wall seconds of closed_loop on the run's scene with builtin, as the command runs it (its
    default settings), the kept reference given (read before the clock starts)."""
    from deepcontact.evaluate import reference_cache
    from deepcontact.evaluate.closed_loop import REFERENCE_SETTINGS, closed_loop
    from deepcontact.evaluate.replay import box2d_runs
    from deepcontact.scene.xml import read_scene
    from deepcontact.solver.settings import VERDICT_CAP, SolveSettings
    from deepcontact.warmstart.starts import make_starts
    sim = box2d_runs([run])[0].simulations[0]
    scene = read_scene(sim.scene_file())
    reference = reference_cache.cached(scene, steps, reference_cache.folder_for(run), REFERENCE_SETTINGS,
                                       lambda: sys.exit("the kept reference was not found"))
    t0 = time.perf_counter()
    closed_loop(scene, make_starts(["builtin"]), steps=steps, reference=reference,
                settings=SolveSettings(max_iterations=VERDICT_CAP))
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
