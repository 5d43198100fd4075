"""Does the order of a sweep buy accuracy at Box2D's low counts? On a stack the weight of the
top boxes reaches the bottom contacts one row a sweep in island order; sweeping the manifolds
top-down (each pushed before those under it) or bottom-up might carry it further a sweep.

The scene (--scene pyramid --base B, or --scene pile --count N) is settled by Box2D at its 8
iterations and stepped on, as bench_equal_time.py samples it; each sample's contact problem is
solved at k sweeps from Box2D's warm start in its island order (Box2D's own) and with its
manifolds reordered by the height of their higher body's centre, top-down and bottom-up, each
manifold's points kept together and in their order. The one-step residual (the project's), the
median over the samples, as a ratio to island order's at the same k in the same arithmetic
(float32 PGS, or Box2D's exact): below 1, the order is the better one at that count. A sweep
costs the same in any order; sorting the manifolds is not timed.

Usage: python benchmarks/bench_sweep_order.py [--scene pyramid] [--base 40] [--count 1000] [--settle 500]
       [--samples 6] [--every 10]
"""
import dataclasses
import sys
from pathlib import Path

import numpy as np

from deepcontact.scene.generators import generate
from deepcontact.solver.methods import solve
from deepcontact.solver.settings import SolveSettings

sys.path.insert(0, str(Path(__file__).parent))
from common import arguments, settled_and_samples  # noqa: E402

COUNTS = (1, 2, 3, 4, 8)
ORDERS = {"top-down": -1.0, "bottom-up": 1.0}   # (the sign the manifolds' heights are sorted by)


def reordered(problem, sign):
    """The problem with its manifolds sorted by sign * the height of their higher body's centre
    (a stable sort: ties keep island order), each manifold's points together, numbered anew."""
    c = problem.contacts
    manifold = c["manifold"]
    first = np.flatnonzero(np.r_[True, manifold[1:] != manifold[:-1]])
    end = np.r_[first[1:], len(manifold)]
    y = problem.bodies["center"][:, 1]
    height = np.maximum(y[c["row_a"]], y[c["row_b"]])[first]
    order = np.argsort(sign * height, kind="stable")
    rows = np.concatenate([np.arange(first[m], end[m]) for m in order])
    contacts = {k: v[rows] for k, v in c.items()}
    contacts["manifold"] = np.repeat(np.arange(len(order)), (end - first)[order]).astype(manifold.dtype)
    return dataclasses.replace(problem, contacts=contacts, start_normal=problem.start_normal[rows],
                               start_tangent=problem.start_tangent[rows], normal_impulse=None, tangent_impulse=None,
                               keys=None)


def main():
    args = arguments(__doc__, scene="pyramid", base=40, count=1000, settle=500, samples=6, every=10)
    steps = args.settle + args.samples * args.every + 10
    if args.scene == "pyramid":
        params, name = dict(base=args.base), f"the pyramid of base {args.base} (seed 9)"
    elif args.scene == "pile":
        big = args.count > 1000   # (bench_equal_time.py's piles)
        params = dict(count=args.count, box=300.0 if big else 95.0, sigma=60.0 if big else 19.0)
        name = f"the {args.count:,}-circle pile (seed 9)"
    else:
        sys.exit(f"--scene: pyramid or pile, not {args.scene!r}")
    _, samples = settled_and_samples(generate(args.scene, 9, dict(params, steps=steps)), args.settle, args.samples,
                                     args.every)
    ways = {"island (Box2D's)": samples, **{o: [reordered(p, s) for p in samples] for o, s in ORDERS.items()}}
    print(f"{name}, settled {args.settle} steps; {len(samples)} samples (every {args.every}th step), about "
          f"{int(np.median([p.points for p in samples])):,} contact points a sample; the one-step residual, median, "
          "as a ratio to island order's at the same count\n")
    print("| sweeps | island order (Box2D's), residual (exact) | " + " | ".join(f"{o}, {m}" for o in ORDERS
                                                                          for m in ("float32", "exact")) + " |")
    print("| ---: | ---: | " + " | ".join("---:" for _ in range(2 * len(ORDERS))) + " |")
    for k in COUNTS:
        def median(problems, mode):
            s = SolveSettings(mode=mode, max_iterations=k, tolerance=0)
            return float(np.median([solve(p, settings=s).residual for p in problems]))
        island = {m: median(ways["island (Box2D's)"], m) for m in ("float32", "exact")}
        cells = [f"{median(ways[o], m) / island[m]:.3f}x" for o in ORDERS for m in ("float32", "exact")]
        print(f"| {k} | {island['exact']:.4g} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
