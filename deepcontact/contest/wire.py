"""The wire between the judge and a contestant: requests (the judge's own data, pickled) and
answers (a JSON header and float64 arrays, never unpickled: an answer is data, not code). One
place packs an answer and one place reads it, its header held to its form by the one checker of
every message (shape.py: each field's type and bounds, the header's bytes, its depth) before the
judge uses it: a field of the wrong type, a number that is not finite, an array of the wrong
length, a header nested or sized past its form, is one line naming the contestant."""
import json
import re
import struct

import numpy as np

from .._box2d import answer_fault
from ..plugins import PluginError
from . import shape

ANSWER_MAX = 1 << 28   # bytes an answer may take (three float64 arrays of 10 million contact points): no more is read
HEADER_MAX = 1 << 20   # bytes of its header (every field's text and entries bounded by its form: shape.ANSWER)

# A loop step's answer as the guest packs it, byte for byte: its header read without the parser
# (the closed loop reads two a step). Each number a whole one of at most 18 digits, no leading
# zero: what JSON and shape.ANSWER allow of it; any other header is parsed and checked in full.
_WHOLE = rb"(0|[1-9][0-9]{0,17})"
_STEP_ANSWER = re.compile(rb'\{"seconds": \{\}, "seq": ' + _WHOLE + rb', "arrays": \[\["normal", ' + _WHOLE
                          + rb'\], \["tangent", ' + _WHOLE + rb'\]\]\}')


def pack(header, arrays=None):
    """An answer's bytes: its JSON header (naming each array and its length) and the arrays."""
    arrays = {k: np.ascontiguousarray(v, np.float64) for k, v in (arrays or {}).items()}
    if list(header) == ["seconds", "seq"] and header["seconds"] == {} and type(header["seq"]) is int \
            and list(arrays) == ["normal", "tangent"]:
        # (a loop step's answer with no stages timed: the bytes json.dumps writes, without it)
        head = (f'{{"seconds": {{}}, "seq": {header["seq"]}, "arrays": [["normal", {arrays["normal"].size}], '
                f'["tangent", {arrays["tangent"].size}]]}}').encode()
        return struct.pack("<I", len(head)) + head + arrays["normal"].tobytes() + arrays["tangent"].tobytes()
    header = dict(header, arrays=[[k, int(v.size)] for k, v in arrays.items()])
    head = json.dumps(header, allow_nan=False).encode()
    return struct.pack("<I", len(head)) + head + b"".join(v.tobytes() for v in arrays.values())


def unpack(data, who):
    """(header, arrays) of an answer, its header held to its form (shape.ANSWER); PluginError
    naming `who` for bytes that are not one."""
    try:
        (n,) = struct.unpack_from("<I", data)
        if 4 + n > len(data):
            raise ValueError("its header runs past the answer's end")
        step = _STEP_ANSWER.fullmatch(data, 4, 4 + n)
        if step is not None:
            seq, normal, tangent = map(int, step.groups())
            header, entries = {"seconds": {}, "seq": seq}, (("normal", normal), ("tangent", tangent))
        else:
            header = shape.parsed(data[4:4 + n], "answer", HEADER_MAX)
            entries = header.pop("arrays")
        arrays = _arrays(data, 4 + n, entries)
    except (ValueError, struct.error) as e:
        raise PluginError(f"{who} answered with something that is not an answer ({e})") from None
    return header, arrays


def _arrays(data, at, entries):
    """The arrays an answer's header names ([name, length] each), read from `data` at `at` on."""
    arrays = {}
    for name, size in entries:
        if name in arrays:
            raise ValueError(f"it names the array {name[:60]!r} twice")
        if at + 8 * size > len(data):
            raise ValueError("an array runs past the answer's end")
        arrays[name] = np.frombuffer(data, np.float64, size, at).copy()
        at += 8 * size
        if name not in ("normal", "tangent") and not np.all(np.isfinite(arrays[name])):
            raise ValueError(f"its {name} hold a value that is not finite")   # (impulses: checked_answer)
    if at != len(data):
        raise ValueError("trailing bytes")
    return arrays


def checked_answer(label, arrays, points, also=()):
    """A contestant's impulses (normal, tangent), checked by the judge: one finite value per
    contact point, no pull, and no array beside them but those named in `also` (a solve's
    claims: what the judge keeps of an answer is what it reads); PluginError naming `label`
    otherwise."""
    held = ("normal", "tangent", *also)
    for name in arrays:
        if name not in held:
            raise PluginError(f"the variant {label!r} answered an array {name[:60]!r}, which no answer holds "
                              f"(this one holds {', '.join(held)})")
    normal, tangent = (_shaped(label, arrays, what, points) for what in ("normal", "tangent"))
    # (one native pass over both: the loop reads two answers a step)
    fault = answer_fault(normal, tangent)
    if fault in (1, 2):
        raise PluginError(f"the variant {label!r} answered a non-finite {('normal', 'tangent')[fault - 1]} impulse")
    if fault == 3:
        raise PluginError(f"the variant {label!r} answered a negative normal impulse (a contact only pushes)")
    return [normal, tangent]


def _shaped(label, arrays, what, points):
    """An answer's `what` impulses held to one a contact point, PluginError naming `label` otherwise;
    where the tangent's are not, a non-finite normal is named first (as a look at each array in
    turn names it)."""
    a = arrays.get(what)
    if a is None or a.shape != (points,):
        if what == "tangent" and not np.all(np.isfinite(arrays["normal"])):
            raise PluginError(f"the variant {label!r} answered a non-finite normal impulse")
        raise PluginError(f"the variant {label!r} answered {what} impulses of shape "
                          f"{None if a is None else a.shape}; the step has {points} contact points, so ({points},)")
    return a


def held_claims(label, header, arrays, cap):
    """A plug-in method's claims held to the sweeps it was asked to stop at (`cap`): its claimed
    iterations and its residuals ("claims", one a sweep) at most `cap` each, as its own process
    checks them (solver.methods), so what the judge keeps of an answer is at most one float64 a
    sweep of the cap; PluginError naming `label` otherwise. Returns the claims."""
    claims = arrays.get("claims", np.zeros(0))
    claimed = max(int(header.get("iterations", 0)), len(claims))
    if claimed > cap:
        raise PluginError(f"the variant {label!r} claimed {claimed:,} iterations (or residuals) for a solve "
                          f"asked to stop at {cap:,} sweeps")
    return claims


def unanswered(problem):
    """The step's problem without the impulses recorded for it (what a contestant is sent)."""
    import dataclasses
    return dataclasses.replace(problem, normal_impulse=None, tangent_impulse=None)
