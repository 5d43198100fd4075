"""The wire between the judge and a contestant: requests (the judge's own data, pickled) and
answers (a JSON header and float64 arrays, never unpickled: an answer is data, not code). One
place packs an answer and one place reads it, checking every field before the judge uses it: a
field of the wrong type, a number that is not finite, an array of the wrong length, is one line
naming the contestant."""
import json
import math
import struct

import numpy as np

from .. import jsontext
from ..plugins import PluginError

ANSWER_MAX = 1 << 28   # bytes an answer may take (three float64 arrays of 10 million contact points): no more is read

# The fields an answer's header may hold, with their checks: (type, lowest value).
FIELDS = {"iterations": (int, 0), "fallback": (int, 0), "factorizations": (int, 0), "traits": (dict, None),
          "seconds": (dict, None), "described": (dict, None), "error": (str, None), "traceback": (str, None),
          "ready": (int, 0), "engine": (dict, None), "layout": (dict, None), "stats": (dict, None),
          "dt_ratio": (float, 0.0), "deepest": (float, 0.0), "built": (int, 0)}


def _no_constant(name):
    raise ValueError(f"{name} is not a number JSON allows")


def pack(header, arrays=None):
    """An answer's bytes: its JSON header (naming each array and its length) and the arrays."""
    arrays = {k: np.ascontiguousarray(v, np.float64) for k, v in (arrays or {}).items()}
    header = dict(header, arrays=[[k, int(v.size)] for k, v in arrays.items()])
    head = json.dumps(header, allow_nan=False).encode()
    return struct.pack("<I", len(head)) + head + b"".join(v.tobytes() for v in arrays.values())


def unpack(data, who):
    """(header, arrays) of an answer, every header field checked (FIELDS); PluginError naming
    `who` for bytes that are not one."""
    try:
        (n,) = struct.unpack_from("<I", data)
        header = jsontext.loads(data[4:4 + n], parse_constant=_no_constant)
        if not isinstance(header, dict):
            raise ValueError("its header is not an object")
        arrays, at = {}, 4 + n
        entries = header.pop("arrays", None)
        if not isinstance(entries, list):
            raise ValueError("its header names no arrays")
        for entry in entries:
            if not (isinstance(entry, list) and len(entry) == 2 and isinstance(entry[0], str)
                    and type(entry[1]) is int and entry[1] >= 0):
                raise ValueError("a bad array entry")
            name, size = entry
            if at + 8 * size > len(data):
                raise ValueError("an array runs past the answer's end")
            arrays[name] = np.frombuffer(data, np.float64, size, at).copy()
            at += 8 * size
            if name not in ("normal", "tangent") and not np.all(np.isfinite(arrays[name])):
                raise ValueError(f"its {name} hold a value that is not finite")   # (impulses: checked_answer)
        if at != len(data):
            raise ValueError("trailing bytes")
        for key, value in header.items():
            _check_field(key, value)
    except (ValueError, TypeError, KeyError, struct.error) as e:
        raise PluginError(f"{who} answered with something that is not an answer ({e})") from None
    return header, arrays


def _check_field(key, value):
    if key not in FIELDS:
        raise ValueError(f"an unknown field {key!r}")
    kind, lowest = FIELDS[key]
    if kind is int and (type(value) is not int or value < lowest):
        raise ValueError(f"{key} is {value!r}, not a whole number >= {lowest}")
    if kind is float and (type(value) not in (int, float) or not math.isfinite(value) or value < lowest):
        raise ValueError(f"{key} is {value!r}, not a finite number >= {lowest}")
    if kind not in (int, float) and not isinstance(value, kind):
        raise ValueError(f"{key} is {type(value).__name__}, not {kind.__name__}")
    if key == "seconds" and not all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0
                                    for v in value.values()):
        raise ValueError("seconds holds a value that is not a finite number >= 0")


def checked_answer(label, arrays, points):
    """A contestant's impulses (normal, tangent), checked by the judge: one finite value per
    contact point, no pull; PluginError naming `label` otherwise."""
    out = []
    for what in ("normal", "tangent"):
        a = arrays.get(what)
        if a is None or a.shape != (points,):
            raise PluginError(f"the variant {label!r} answered {what} impulses of shape "
                              f"{None if a is None else a.shape}; the step has {points} contact points, so ({points},)")
        if not np.all(np.isfinite(a)):
            raise PluginError(f"the variant {label!r} answered a non-finite {what} impulse")
        out.append(a)
    if np.any(out[0] < 0):
        raise PluginError(f"the variant {label!r} answered a negative normal impulse (a contact only pushes)")
    return out


def unanswered(problem):
    """The step's problem without the impulses recorded for it (what a contestant is sent)."""
    import dataclasses
    return dataclasses.replace(problem, normal_impulse=None, tangent_impulse=None)
