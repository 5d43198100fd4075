"""Rasterizing one step on the thesis grid (61 x 61, d = h = 0.5, Poly6, renormalised), the
pile with 100 circles, all channels (mass, vx, vy, spin, nx, ny; normal and tangent impulse),
next to the thesis code's approach in the same run: a k-d tree query per particle, then a
Python loop over particles, nodes and channels.

Usage: python benchmarks/bench_rasterize.py [--steps N]
"""
import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

from deepcontact.grid.kernels import weight
from deepcontact.grid.spec import GridSpec, scene_box
from deepcontact.grid.splat import (BODY_CHANNELS, CONTACT_CHANNELS, DEFAULT_INPUTS, DEFAULT_LABELS,
                                    rasterize_step)
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.protocol import current, protocol_line


def python_loop(spec, bodies, contacts, channels):
    """The straightforward way: per particle, a k-d tree query for nodes within h, then loops."""
    xs = spec.x0 + spec.cell * np.arange(spec.nx)
    ys = spec.y0 + spec.cell * np.arange(spec.ny)
    X, Y = np.meshgrid(xs, ys)
    nodes = np.stack([X.ravel(), Y.ravel()], axis=1)
    tree = cKDTree(nodes)
    grid = np.zeros((len(channels), spec.ny * spec.nx))
    moving = bodies["type"] != 0
    sets = [(bodies["center"][moving], {n: f(bodies)[moving] for n, f in BODY_CHANNELS.items()}),
            (contacts["position"], {n: f(contacts) for n, f in CONTACT_CHANNELS.items()})]
    for points, values in sets:
        for i, q in enumerate(points):
            near = tree.query_ball_point(q, spec.h)
            w = [float(weight(spec.kernel, np.hypot(*(nodes[j] - q)), spec.h)) for j in near]
            total = sum(w)
            for j, wj in zip(near, w):
                for c, name in enumerate(channels):
                    if name in values:
                        grid[c, j] += wj / total * float(values[name][i])
    return grid.reshape(len(channels), spec.ny, spec.nx)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=50)
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")   # how these times were taken
    scene = generate("pile", 0)
    spec = GridSpec.over(scene_box(scene), 0.5, 0.5)
    world = build_world(scene)
    steps = []
    for k in range(600):
        b, c = world.step(scene.dt, 8, 3, record=True)
        if k >= 600 - args.steps:
            steps.append((b, c))
    channels = list(DEFAULT_INPUTS) + list(DEFAULT_LABELS)
    points = np.mean([len(c["manifold"]) for _, c in steps])

    for b, c in steps[:3]:   # warm up
        rasterize_step(spec, b, c, DEFAULT_INPUTS, DEFAULT_LABELS)
    t = time.perf_counter()
    for b, c in steps:
        rasterize_step(spec, b, c, DEFAULT_INPUTS, DEFAULT_LABELS)
    ours = (time.perf_counter() - t) / len(steps)

    sample = steps[: max(3, len(steps) // 10)]
    t = time.perf_counter()
    for b, c in sample:
        ref = python_loop(spec, b, c, channels)
    loop = (time.perf_counter() - t) / len(sample)
    b, c = sample[-1]
    got = np.concatenate(rasterize_step(spec, b, c, DEFAULT_INPUTS, DEFAULT_LABELS))
    assert np.allclose(got, ref, rtol=1e-4, atol=1e-5), "the two ways disagree"

    print(f"thesis grid {spec.nx} x {spec.ny}, d = h = {spec.cell}, poly6, renormalised; pile, 100 circles, "
          f"{points:.0f} contact points per step, {len(channels)} channels")
    print(f"  deepcontact (native splat)        {ours * 1e3:8.3f} ms / step")
    print(f"  k-d tree + Python loops (thesis)  {loop * 1e3:8.3f} ms / step")
    print(f"  speed-up                          {loop / ours:8.0f}x   (target: <= 0.1 ms, >= 75x)")


if __name__ == "__main__":
    main()
