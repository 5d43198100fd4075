"""A warm start as a plug-in: Box2D's own warm start, scaled down.

The contract (docs/api.md, "Bring your own start"): a class (or function) the registry calls with
the keyword arguments it declares, of `spec` (the grid) and `predictor` (a trained model); what it
returns is called once per step with a `deepcontact.warmstart.StepContext` and returns a
`StartValue(normal, tangent, seconds)`: one float64 impulse per contact point (N·s, Box2D's
units), and the seconds spent predicting by stage (counted as prediction time, not solving).
"""
import time

import numpy as np

from deepcontact.warmstart import StartValue


class DampedBuiltin:
    """Box2D's warm start times `factor`: a start that undershoots on purpose, so that the
    comparison with `builtin` shows what a start's error costs in sweeps."""

    needs_reference = False   # (it never reads ctx.reference: the closed loop need not compute it)

    def __init__(self, factor=0.8):
        self.factor = factor

    def __call__(self, ctx):
        t0 = time.perf_counter()
        normal = self.factor * np.asarray(ctx.problem.start_normal, np.float64)
        tangent = self.factor * np.asarray(ctx.problem.start_tangent, np.float64)
        return StartValue(normal, tangent, {"scale": time.perf_counter() - t0})
