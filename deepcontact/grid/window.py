"""The window a grid covers: the one given, the scenes' static box, or where the bodies went."""
import numpy as np

from ..errors import InputError
from .spec import GridSpec


def default_window(sims, pad):
    """The scenes' static box where they have one (the same for all), else the extent of every
    body over the runs, widened by pad on each side; and a phrase saying which it is. `sims`: the
    dataset's simulations (their `box`) or a run's (the manifest's `static_box`)."""
    boxes = {getattr(s, "box", None) or s.static_box for s in sims}
    if None not in boxes:
        if len(boxes) > 1:
            raise InputError(f"the simulations have different boxes ({', '.join(map(str, sorted(boxes)))}); "
                             f"give one --window x0,y0,x1,y1 for all")
        return boxes.pop(), "the scenes' static box"
    if any(s.extent is None for s in sims):
        raise InputError("a scene has no static box, and its run records no extent of the bodies (a run from "
                         "an older version); give --window x0,y0,x1,y1")
    e = np.array([s.extent for s in sims])
    window = (e[:, 0].min() - pad, e[:, 1].min() - pad, e[:, 2].max() + pad, e[:, 3].max() + pad)
    return tuple(float(v) for v in window), "where the bodies went over the runs (no static box)"


def grid_for(sims, cell, h, kernel, renormalize, window=None):
    """The grid over window, or over default_window's choice; the spec and a phrase for the log."""
    which = "given"
    if window is None:
        window, which = default_window(sims, pad=h + cell)
    return GridSpec.over(window, cell, h, kernel, renormalize), which
