"""Bodies and contacts of a step → grid channels (the native splatter does the work)."""
from collections.abc import Sequence

import numpy as np

from .. import arguments
from .._box2d import splat as _splat
from ..errors import InputError
from .kernels import KERNELS
from .spec import GridSpec

# Channel name → (particles, how to get the value per particle)
BODY_CHANNELS = {
    "mass": lambda b: b["mass"],
    "vx": lambda b: b["velocity"][:, 0],
    "vy": lambda b: b["velocity"][:, 1],
    "spin": lambda b: b["omega"],
}
CONTACT_CHANNELS = {
    "nx": lambda c: c["normal"][:, 0],
    "ny": lambda c: c["normal"][:, 1],
    "normal_impulse": lambda c: c["normal_impulse"],
    "tangent_impulse": lambda c: c["tangent_impulse"],
}
# the column each channel reads (of the bodies', or the contacts')
COLUMN = {"mass": "mass", "vx": "velocity", "vy": "velocity", "spin": "omega", "nx": "normal", "ny": "normal",
          "normal_impulse": "normal_impulse", "tangent_impulse": "tangent_impulse"}
DEFAULT_INPUTS = ("mass", "vx", "vy", "spin", "nx", "ny")
DEFAULT_LABELS = ("normal_impulse", "tangent_impulse")
ALL_CHANNELS = tuple(BODY_CHANNELS) + tuple(CONTACT_CHANNELS)


def check_channels(names, what):
    unknown = [n for n in names if n not in ALL_CHANNELS]
    if unknown or not names:
        raise InputError(f"unknown {what} channel(s) {', '.join(unknown) or '(none given)'}; "
                         f"choose from {', '.join(ALL_CHANNELS)}")
    if len(set(names)) != len(names):
        raise InputError(f"a {what} channel is listed twice")


def splat_points(spec, points, values):
    """(C, H, W) float32 for particles at points (n, 2) carrying values (n, C)."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    return _splat(np.asarray(points, dtype=np.float64).reshape(-1, 2), values, spec.x0, spec.y0, spec.cell,
                  spec.nx, spec.ny, spec.h, KERNELS[spec.kernel], spec.renormalize)


def rasterize_step(spec, bodies, contacts, inputs, labels):
    """(inputs (C_in, H, W), labels (C_out, H, W)) of one step, with one splat per particle set."""
    grids = rasterize(spec, bodies, contacts, list(inputs) + [n for n in labels if n not in inputs])
    names = list(inputs) + [n for n in labels if n not in inputs]
    return grids[:len(inputs)], grids[[names.index(n) for n in labels]]


def rasterize(spec: "GridSpec", bodies: dict, contacts: dict,
              channels: "Sequence[str]" = DEFAULT_INPUTS + DEFAULT_LABELS) -> np.ndarray:
    """The named channels of one step (bodies and contacts as a step file or World.step gives
    them) on the grid `spec`: (len(channels), H, W) float32. Body channels are splatted from the
    centres of mass of dynamic and kinematic bodies, contact channels from the contact points;
    the names are ALL_CHANNELS' (by default the network's inputs, then its labels)."""
    arguments.instance(spec, "spec", GridSpec, "a GridSpec")
    channels = arguments.texts(list(channels) if isinstance(channels, tuple) else channels, "channels")
    if not channels:
        raise arguments.refuse("channels", f"a non-empty list of channels from {', '.join(ALL_CHANNELS)}", channels)
    check_channels(channels, "rasterize")
    # (the columns read_step and World.step give that these channels read)
    arguments.mapping(bodies, "bodies", ("type", "center", *sorted({COLUMN[n] for n in channels if n in BODY_CHANNELS})))
    arguments.mapping(contacts, "contacts", ("position", *sorted({COLUMN[n] for n in channels if n in CONTACT_CHANNELS})))
    out = np.empty((len(channels), spec.ny, spec.nx), dtype=np.float32)
    moving = bodies["type"] != 0
    body_names = [n for n in channels if n in BODY_CHANNELS]
    contact_names = [n for n in channels if n in CONTACT_CHANNELS]
    if body_names:
        vals = np.stack([BODY_CHANNELS[n](bodies)[moving] for n in body_names], axis=1)
        grids = splat_points(spec, bodies["center"][moving], vals)
        for n, g in zip(body_names, grids):
            out[channels.index(n)] = g
    if contact_names:
        vals = np.stack([CONTACT_CHANNELS[n](contacts) for n in contact_names], axis=1)
        grids = splat_points(spec, contacts["position"], vals)
        for n, g in zip(contact_names, grids):
            out[channels.index(n)] = g
    return out
