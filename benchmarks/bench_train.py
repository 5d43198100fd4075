"""Training throughput and inference latency of both networks on the thesis grid (6 x 61 x 61
inputs, 2 x 61 x 61 labels), on this machine's CPU.

  training   samples per second of forward + masked loss + backward + SGD step, batch 64,
             on random tensors of the dataset's shapes (the values do not change the cost)
  inference  one pile step (100 circles) through the Predictor: rasterize, model, interpolate

Usage: python benchmarks/bench_train.py [--threads N] [--batches N]
"""
import tempfile
import time

import numpy as np
import torch

from deepcontact.grid.spec import GridSpec
from deepcontact.model import losses
from deepcontact.model.inference import Predictor
from deepcontact.model.networks import build, parameter_count
from deepcontact.model.checkpoint import CHECKPOINT_FORMAT
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world

from common import arguments

INPUTS = ["mass", "vx", "vy", "spin", "nx", "ny"]


def config(name):
    return dict(model=name, in_channels=6, out_channels=2, height=61, width=61, final_relu=name == "thesis")


def training_rate(name, batches, batch=64):
    torch.manual_seed(0)
    model = build(config(name))
    opt = torch.optim.SGD(model.parameters(), lr=1e-3, momentum=0.9)
    x = torch.randn(batch, 6, 61, 61)
    y = torch.randn(batch, 2, 61, 61) * (torch.rand(batch, 2, 61, 61) < 0.05)
    for i in range(batches + 1):
        if i == 1:
            t = time.perf_counter()
        opt.zero_grad()
        losses.masked_mse(model(x), y).backward()
        opt.step()
    return batches * batch / (time.perf_counter() - t)


def inference(name, steps):
    spec = GridSpec.over((0, 0, 30, 30), 0.5, 0.5)
    model = build(config(name))
    with tempfile.NamedTemporaryFile(suffix=".pt") as f:
        torch.save({"format": CHECKPOINT_FORMAT, "model": model.state_dict(), "network": config(name),
                    "targets": ["normal_impulse", "tangent_impulse"],
                    "dataset": {"grid": spec.as_dict(), "inputs": INPUTS}}, f.name)
        predictor = Predictor(f.name)
    times = {"rasterize": [], "model": [], "interpolate": []}
    for b, c in steps:
        start = predictor.predict(b, c)
        for k, v in start.seconds.items():
            times[k].append(v)
    return {k: float(np.median(v[2:])) * 1e3 for k, v in times.items()}


def main():
    args = arguments(__doc__, threads=2, batches=5)
    torch.set_num_threads(args.threads)
    scene = generate("pile", 0)
    world = build_world(scene)
    steps = []
    for k in range(400):
        b, c = world.step(scene.dt, 8, 3, record=True)
        if k >= 380:
            steps.append((b, c))
    print(f"thesis grid 6 x 61 x 61 -> 2 x 61 x 61, {args.threads} CPU threads, torch {torch.__version__}")
    print(f"{'model':8s}{'weights':>14s}{'train samples/s':>17s}{'rasterize ms':>14s}{'model ms':>10s}"
          f"{'interpolate ms':>16s}")
    for name in ("fcn", "thesis"):
        rate = training_rate(name, args.batches)
        t = inference(name, steps)
        print(f"{name:8s}{parameter_count(build(config(name)))[0]:14,d}{rate:17.1f}{t['rasterize']:14.3f}"
              f"{t['model']:10.2f}{t['interpolate']:16.3f}")


if __name__ == "__main__":
    main()
