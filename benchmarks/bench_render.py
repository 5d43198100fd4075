"""Rendering speed: frames per second drawing the 100-circle thesis pile (600 steps) into a GIF
with `dc render`, every step and every 4th, at 480 and 640 pixels; and a step picture (PNG) per
second. Whole commands, best of --repeats; the run is simulated first, in the same run.

Usage: python benchmarks/bench_render.py [--out DIR] [--repeats N]
"""
import argparse
import subprocess
import sys
import time
from pathlib import Path

from PIL import Image
from deepcontact.protocol import current, protocol_line

DC = [sys.executable, "-m", "deepcontact.cli.main"]


def best(args, repeats):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        subprocess.run(DC + args, check=True, stdout=subprocess.DEVNULL)
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="/tmp/dc-bench-render")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")   # how these times were taken
    out = Path(args.out)
    run = out / "pile"
    simulate = best(["simulate", "pile", "-q", "--overwrite", "-o", str(run)], 1)
    print(f"dc simulate pile (600 steps): {simulate:.2f} s\n")
    print("| picture | frames | seconds (whole command) | frames per second |")
    print("| --- | ---: | ---: | ---: |")
    for every, size in ((1, 480), (4, 480), (4, 640)):
        gif = out / f"pile-{every}-{size}.gif"
        wall = best(["render", str(run), "--every", str(every), "--size", str(size), "-q", "--overwrite", "-o",
                     str(gif)], args.repeats)
        frames = Image.open(gif).n_frames
        print(f"| GIF, every {every}, {size} px | {frames} | {wall:.2f} | {frames / wall:.1f} |")
    step = sorted(run.glob("seed-000000/step-*.xml"))[-1]
    wall = best(["render", str(step), "-q", "--overwrite", "-o", str(out / "step.png")], args.repeats)
    print(f"| PNG of one step, 640 px | 1 | {wall:.2f} | {1 / wall:.1f} |")
    print("\nGoal: at least 10 frames per second into a GIF (the 100-circle pile, 2 cores).")


if __name__ == "__main__":
    main()
