"""Step files at scale: what simulating, reading, validating, rasterizing and replaying cost per
step as the scene grows, and the memory each whole command needs.

Part 1, the thesis pile (100 circles, 600 steps), whole commands, best of --repeats, as ratios
to `dc simulate` in the same run: simulate --compress, validate (and -j 2), validate --replay,
rasterize, and the run's size plain and compressed.

Part 2, per step at 100, 1000 and 10,000 circles and at pyramid bases 20 and 100 (5050 boxes):
the whole commands (simulate, validate, validate --replay, rasterize, evaluate from Box2D's warm
start) as wall seconds per step file with each one's peak memory (ru_maxrss), and reading one
step in-process (median over the run's last steps): the native reader, and the lxml reference
it replaced, in the same run. Reading cost per body shows whether it stays linear.

Usage: python benchmarks/bench_scale.py [--out DIR] [--repeats N] [--quick] [--part pile|scale|both]
(--quick: small sizes and few steps, a minute; the full run takes about twenty minutes and 5 GB
of disk: the piles are stepped until they settle, so that the steps read are full of contacts.)
"""
import argparse
import json
import os
import shutil
import statistics
import time
from pathlib import Path
from deepcontact.protocol import current, protocol_line

from common import timed

# name: (dc simulate arguments, steps, evaluate --every)
FULL = {
    "pile 100": (["pile"], 600, 25),
    "pile 1,000": (["pile", "--param", "count=1000", "--param", "box=95", "--param", "sigma=19"], 300, 100),
    "pile 10,000": (["pile", "--param", "count=10000", "--param", "box=300", "--param", "sigma=60"], 450, 150),
    "pyramid 20": (["pyramid", "--param", "base=20"], 60, 20),
    "pyramid 100": (["pyramid", "--param", "base=100"], 20, 10),
}
QUICK = {
    "pile 100": (["pile"], 120, 40),
    "pile 1,000": (["pile", "--param", "count=1000", "--param", "box=95", "--param", "sigma=19"], 20, 10),
    "pyramid 20": (["pyramid", "--param", "base=20"], 20, 10),
}


def best(args, repeats):
    runs = [timed(args) for _ in range(repeats)]
    return min(w for w, _ in runs), max(m for _, m in runs)


def size_mb(folder, pattern):
    return sum(f.stat().st_size for f in Path(folder).glob(pattern)) / 1e6


def thesis_pile(out, repeats, steps):
    run, packed = out / "pile", out / "pile-gz"
    sim = ["simulate", "pile", "--steps", str(steps), "-q", "--overwrite"]
    rows = [("simulate", best(sim + ["-o", str(run)], repeats)),
            ("simulate --compress", best(sim + ["--compress", "-o", str(packed)], repeats)),
            ("validate", best(["validate", "-q", str(run)], repeats)),
            ("validate -j 2", best(["validate", "-q", "-j", "2", str(run)], repeats)),
            ("validate (compressed run)", best(["validate", "-q", str(packed)], repeats)),
            ("validate --replay", best(["validate", "--replay", "-q", str(run)], repeats)),
            ("rasterize", best(["rasterize", "-q", "--overwrite", str(run), "-o", str(out / "data")], repeats)),
            ("rasterize (compressed run)",
             best(["rasterize", "-q", "--overwrite", str(packed), "-o", str(out / "data-gz")], repeats))]
    base = rows[0][1][0]
    print(f"\n## The thesis pile, {steps} steps: whole commands, best of {repeats}\n")
    print("| command | seconds | x dc simulate | peak MB |")
    print("| --- | ---: | ---: | ---: |")
    for name, (wall, mb) in rows:
        print(f"| {name} | {wall:.2f} | {wall / base:.2f} | {mb:.0f} |")
    plain, gz = size_mb(run, "seed-*/step-*.xml"), size_mb(packed, "seed-*/step-*.xml.gz")
    print(f"\nrun size: {plain:.1f} MB plain, {gz:.1f} MB compressed ({gz / plain:.3f} of plain)")


def read_costs(run, sample=5):
    """Median over the run's last `sample` steps of the best of 3 reads, in ms: native, grid
    fields, lxml (one read: it is slow)."""
    from deepcontact.step import reader, reader_lxml
    files = sorted(Path(run).glob("seed-*/step-*.xml"))[-sample:]
    out = {}
    for name, read in (("native", lambda f: reader.read_step(f, validate=False)),
                       ("grid", reader.read_step_for_grid),
                       ("lxml", lambda f: reader_lxml.read_step(f, validate=False))):
        times = []
        for f in files:
            best = float("inf")
            for _ in range(1 if name == "lxml" else 3):
                t = time.perf_counter()
                read(f)
                best = min(best, time.perf_counter() - t)
            times.append(best)
        out[name] = statistics.median(times) * 1e3
    header, bodies, contacts = reader.read_step(files[-1], validate=False)
    return out, len(bodies["index"]), len(contacts["manifold"]), files[-1].stat().st_size / 1e6


def scaling(out, scenes):
    print("\n## Per step as the scene grows (ms per step file; peak MB of each whole command)\n")
    print("| scene | bodies | contact points | MB / step | simulate | validate | validate --replay | "
          "rasterize | evaluate (per step solved) | read: native | read: lxml | lxml / native | "
          "native us per body |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, (args, steps, every) in scenes.items():
        run = out / name.replace(" ", "-").replace(",", "")
        cmds = {
            "simulate": ["simulate", *args, "--steps", str(steps), "-q", "--overwrite", "-o", str(run)],
            "validate": ["validate", "-q", str(run)],
            "validate --replay": ["validate", "--replay", "-q", str(run)],
            "rasterize": ["rasterize", "-q", "--overwrite", str(run), "-o", str(run) + "-data"],
            "evaluate": ["evaluate", str(run), "--starts", "builtin", "--every", str(every), "--no-budgets", "-q",
                         "--overwrite", "-o", str(run) + "-report"],
        }
        measured = {k: timed(v) for k, v in cmds.items()}
        files = len(list(run.glob("seed-*/step-*.xml")))
        solved = json.loads((Path(str(run) + "-report") / "summary.json").read_text())["settings"]["steps"]
        reads, bodies, points, mb = read_costs(run)
        cells = [f"{measured[k][0] / files * 1e3:.1f} ({measured[k][1]:.0f} MB)"
                 for k in ("simulate", "validate", "validate --replay", "rasterize")]
        cells.append(f"{measured['evaluate'][0] / solved * 1e3:.0f} ({measured['evaluate'][1]:.0f} MB)")
        print(f"| {name} | {bodies:,} | {points:,} | {mb:.2f} | " + " | ".join(cells) +
              f" | {reads['native']:.2f} | {reads['lxml']:.1f} | {reads['lxml'] / reads['native']:.0f}x | "
              f"{reads['native'] / bodies * 1e3:.1f} |")
        shutil.rmtree(run)   # the 10,000-circle run is large (4 GB)
        shutil.rmtree(str(run) + "-data", ignore_errors=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="/tmp/dc-bench-scale")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--part", choices=("pile", "scale", "both"), default="both",
                    help="the thesis pile's whole commands, the scaling table, or both")
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")   # how these times were taken
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"# bench_scale ({'quick' if args.quick else 'full'}), {os.cpu_count()} cores; "
          f"default memory limit of the commands: 8 GB")
    if args.part in ("pile", "both"):
        thesis_pile(out, 1 if args.quick else args.repeats, 120 if args.quick else 600)
    if args.part in ("scale", "both"):
        scaling(out, QUICK if args.quick else FULL)


if __name__ == "__main__":
    main()
