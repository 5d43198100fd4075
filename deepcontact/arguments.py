"""Checks of a public function's arguments, each failure the project's InputError naming the
argument: a library caller gets one line saying which argument is wrong and what it must be, never
Python's TypeError from three calls down (or a file descriptor taken for a path)."""
import math
import numbers
import os

import numpy as np

from .errors import InputError

INT32_MAX = 2 ** 31 - 1   # the native solver's and the step files' whole numbers


def _shown(value):
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def refuse(name, what, value):
    """InputError: argument `name` must be `what`, with the value it got."""
    return InputError(f"argument {name!r} must be {what}, got {_shown(value)}")


def path(value, name):
    """A path: str or os.PathLike (an int would be taken for an open file descriptor)."""
    if isinstance(value, (str, os.PathLike)):
        return value
    raise refuse(name, "a path (str or os.PathLike)", value)


def paths(value, name, also=()):
    """A list (or tuple) of paths (or of the types `also`: runs already read, say)."""
    if isinstance(value, (str, os.PathLike)) or not isinstance(value, (list, tuple)) or not value:
        raise refuse(name, "a non-empty list of paths", value)
    return [v if isinstance(v, also) else path(v, f"{name}[{i}]") for i, v in enumerate(value)]


def whole(value, name, low=0, high=INT32_MAX):
    """A whole number in [low, high] (numpy's integers too, never a bool or a float)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not low <= value <= high:
        raise refuse(name, f"a whole number from {low} to {high}", value)
    return int(value)


def number(value, name, low=-math.inf, high=math.inf):
    """A finite real number in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) \
            or not low <= value <= high:
        raise refuse(name, f"a finite number from {low:g} to {high:g}", value)
    return float(value)


def flag(value, name):
    """True or False (numpy's bool too; never a str, whose every non-empty value is true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise refuse(name, "True or False", value)
    return bool(value)


def text(value, name):
    """A str."""
    if not isinstance(value, str):
        raise refuse(name, "a str", value)
    return value


def texts(value, name):
    """A list (or tuple) of str."""
    if isinstance(value, str) or not isinstance(value, (list, tuple)):
        raise refuse(name, "a list of str", value)
    return [text(v, f"{name}[{i}]") for i, v in enumerate(value)]


def mapping(value, name, keys=()):
    """A dict holding `keys`."""
    if not isinstance(value, dict):
        raise refuse(name, "a dict", value)
    missing = [k for k in keys if k not in value]
    if missing:
        raise InputError(f"argument {name!r} must hold {', '.join(map(repr, missing))}; it holds "
                         f"{_shown(sorted(map(str, value)))}")
    return value


def starts(value, name):
    """A starts table: {name: start}, each start callable (make_starts makes one)."""
    if not isinstance(value, dict) or not value:
        raise refuse(name, "a non-empty dict of starts {name: start} (make_starts makes one)", value)
    for key, start in value.items():
        if not isinstance(key, str) or not callable(start):
            raise InputError(f"argument {name!r} must map names (str) to starts (callables); "
                             f"{_shown(key)} maps to {_shown(start)}")
    return value


def instance(value, name, kind, what):
    """An instance of kind (`what` says it in words)."""
    if not isinstance(value, kind):
        raise refuse(name, what, value)
    return value


def vector(value, name, n):
    """n finite numbers, as a float64 array of shape (n,)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise refuse(name, f"{n} numbers (an array of shape ({n},))", value) from None
    if a.shape != (n,):
        raise InputError(f"argument {name!r} must have shape ({n},), got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"argument {name!r} must be finite; element {int(np.argmax(~np.isfinite(a)))} is "
                         f"{a[~np.isfinite(a)][0]}")
    return a
