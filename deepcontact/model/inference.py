"""From a trained checkpoint to starting impulses for a step's contacts.

    predictor = Predictor("runs/train/best.pt")
    start = predictor.predict(bodies, contacts)      # arrays as World.step(record=True) gives them
    start.normal, start.tangent, start.seconds       # projected onto ln >= 0, |lt| <= mu ln

The step is rasterized with the dataset's recorded settings, the network predicts the impulse
images, bilinear interpolation takes them to the contact points, and the result is projected
onto the friction cone. Time is reported per stage: rasterize, model, interpolate.
"""
import os
import time
from dataclasses import dataclass

import numpy as np
import torch

from .. import arguments
from ..grid.interpolate import bilinear
from ..grid.spec import GridSpec
from ..grid.splat import rasterize
from .networks import build, check_network, require_named
from .checkpoint import load_checkpoint


@dataclass
class Start:
    normal: np.ndarray
    tangent: np.ndarray
    seconds: dict      # rasterize, model, interpolate
    projected: int     # values moved onto the feasible set


class Predictor:
    """A trained network as a warm start: rasterize a step, run the network, interpolate its
    impulse images back to the contact points. threads: torch's threads, 1 unless asked (the
    timed default; torch's own, a thread per core, spins against other processes)."""

    def __init__(self, checkpoint: str | os.PathLike, threads: int = 1):
        threads = arguments.whole(threads, "threads", 1, 1024)
        ck = load_checkpoint(arguments.path(checkpoint, "checkpoint"))
        # (a contestant process loads its own, from another working folder: the path made absolute)
        self.checkpoint, self.threads = os.path.abspath(checkpoint), threads
        self.network = ck["network"]["model"]
        self.spec = GridSpec.from_dict(ck["dataset"]["grid"])   # (checked by load_checkpoint)
        self.inputs = list(ck["dataset"]["inputs"])
        self.targets = list(ck["targets"])
        require_named(self.network)   # (checked now; a plug-in's code is imported only where it is built)
        self._checkpoint, self._model = ck, None
        torch.set_num_threads(threads or 1)

    @property
    def model(self):
        """The network, built on first use (the judge's process reads a checkpoint's grid and
        names and never builds a plug-in network: its contestants do, in their sandboxes)."""
        if self._model is None:
            self.build()
        return self._model

    def build(self):
        """Builds the network and loads its weights now (a contestant does at setup, on its clock)."""
        ck = self._checkpoint
        model = build(ck["network"])
        model.load_state_dict(ck["model"])
        check_network(model, ck["network"])
        model.eval()
        self._model = model
        return model

    @torch.no_grad()
    def images(self, x):
        """The network's impulse images (targets, ny, nx) for one input image (inputs, ny, nx)."""
        return self.model(torch.from_numpy(np.require(x, np.float32, ['C', 'W']))[None])[0].numpy()

    def predict(self, bodies, contacts) -> Start:
        t0 = time.perf_counter()
        x = rasterize(self.spec, bodies, contacts, self.inputs)
        t1 = time.perf_counter()
        pred = self.images(x)
        t2 = time.perf_counter()
        values, _ = bilinear(pred, self.spec, contacts["position"])
        values = values * self.spec.impulse_scale
        n = len(contacts["position"])
        normal = values[self.targets.index("normal_impulse")] if "normal_impulse" in self.targets else np.zeros(n)
        tangent = values[self.targets.index("tangent_impulse")] if "tangent_impulse" in self.targets else np.zeros(n)
        normal = np.nan_to_num(np.asarray(normal, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        tangent = np.nan_to_num(np.asarray(tangent, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        bound = contacts["friction"].astype(np.float64) * np.maximum(normal, 0.0)
        projected = int(np.count_nonzero(normal < 0) + np.count_nonzero(np.abs(tangent) > bound))
        normal = np.maximum(normal, 0.0)
        tangent = np.clip(tangent, -bound, bound)
        t3 = time.perf_counter()
        return Start(normal=normal, tangent=tangent, projected=projected,
                     seconds={"rasterize": t1 - t0, "model": t2 - t1, "interpolate": t3 - t2})
