"""Builtin's twin: a plug-in start that hands back exactly Box2D's warm start.

Used by the check that the same values cost the same whoever gives them (docs/results/warm-starts.md):
named as `--starts builtin,twin_start:Twin` with this folder on PYTHONPATH, it runs in its own
sandbox like any plug-in; a verdict that names it the fastest beyond noise is the judge's error.
"""
import numpy as np

import deepcontact as dc


class Twin:
    """Box2D's warm start, as builtin gives it."""

    def __call__(self, ctx):
        return dc.StartValue(np.asarray(ctx.problem.start_normal, np.float64),
                             np.asarray(ctx.problem.start_tangent, np.float64), {})
