"""Box2D v3 beside Box2D 2.4.1 at scale: the 1000- and 10,000-circle piles and the 5050-box
pyramid (base 100), one run each.

For each scene and engine: the engine's own time per step (the world stepped in-process without
recording, one thread), then the whole commands a user runs on the run: `dc simulate` (with
--compress: the 10,000-circle pile's plain files would take 5 GB), `dc validate` and
`dc rasterize`, as wall seconds per step file with each one's peak memory (GNU time). The v3
runs must validate: a failing command stops the benchmark.

Usage: python benchmarks/bench_engines_scale.py [--out DIR] [--quick]
(--quick: the 1000-circle pile for 20 steps.)
"""
import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

from common import timed
from deepcontact.protocol import current, protocol_line
from deepcontact.scene.generators import generate
from deepcontact.simulate import stepping
from deepcontact.simulate.engines import Box2D, Box2D3, SoftStep

# name: (generator, parameters, steps)
FULL = {
    "pile 1,000": ("pile", {"count": "1000", "box": "95", "sigma": "19"}, 300),
    "pile 10,000": ("pile", {"count": "10000", "box": "300", "sigma": "60"}, 450),
    "pyramid 100": ("pyramid", {"base": "100"}, 60),
}
QUICK = {"pile 1,000": ("pile", {"count": "1000", "box": "95", "sigma": "19"}, 20)}
ENGINES = {"Box2D 2.4.1": "box2d", "Box2D v3": "box2d3"}


def engine_ms(generator, params, steps, engine):
    """Mean ms of a step of the engine alone (no recording)."""
    scene = generate(generator, 0, {**params, "steps": str(steps)})
    stepper = Box2D3(SoftStep()) if engine == "box2d3" else Box2D()
    world = stepper.build(scene)
    bare = stepper.stepper(world, scene, record=False)
    t = time.perf_counter()
    for _ in stepping.steps(world, scene, bare):
        pass
    return 1e3 * (time.perf_counter() - t) / steps


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=None, help="Work folder (default: a temporary one).")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")
    out = args.out or Path(tempfile.mkdtemp(prefix="dc-engines-scale-"))
    scenes = QUICK if args.quick else FULL
    print("| scene | engine | steps | engine ms / step | v3 / 2.4.1 | simulate --compress | validate | rasterize |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, (generator, params, steps) in scenes.items():
        base = None
        for label, engine in ENGINES.items():
            ms = engine_ms(generator, params, steps, engine)
            base = ms if base is None else base
            run = out / f"{name.replace(' ', '-').replace(',', '')}-{engine}"
            p = [a for k, v in params.items() for a in ("--param", f"{k}={v}")]
            cmds = {"simulate": ["simulate", generator, *p, "--engine", engine, "--steps", str(steps), "--compress",
                                 "-q", "--overwrite", "-o", str(run)],
                    "validate": ["validate", "-q", str(run)],
                    "rasterize": ["rasterize", "-q", "--overwrite", str(run), "-o", str(run) + "-data"]}
            cells = []
            for command in cmds.values():
                wall, mb = timed(command)
                cells.append(f"{wall / steps * 1e3:.1f} ms ({mb:.0f} MB)")
            print(f"| {name} | {label} | {steps} | {ms:.2f} | {ms / base:.2f}x | " + " | ".join(cells) + " |",
                  flush=True)
            shutil.rmtree(run, ignore_errors=True)
            shutil.rmtree(str(run) + "-data", ignore_errors=True)
    if args.out is None:
        shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
