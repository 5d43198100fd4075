"""What a run's records may hold: the manifest's record of the project's solver (`pgs`) and of
each simulation's steps above the tolerance, and each step file's <solve>, checked for type,
range and agreement with the run, so that an edited or hand-made record is one line naming its
file instead of a number every reader trusts (dc validate, rasterize, evaluate, export)."""
import gzip
from itertools import islice
import math

import numpy as np

from .._box2d import Acceleration, Order, is_global
from ..errors import InputError
from ..xmltext import held

MODES = ("exact", "float32", "float64")
MEASURES = ("thesis", "velocity", "residual")
ORDERS = tuple(Order.__members__)   # (the order a sweep visits the manifolds in)
TOLERANCE_MAX = 1e3       # (the residual is relative: 1 at a zero start; past this a tolerance stops nothing)
ITERATIONS_MAX = 2**31 - 1
ORIGINS = ("built-in", "plug-in")
EXACT_TOLERANCE = 1e-12   # what a global method solves to at tolerance 0 (native solve_options.hpp, kExactTolerance)


def _number(value, low, high, what, path, whole=False):
    ok = (type(value) is int) if whole else (type(value) in (int, float))
    if not ok or not math.isfinite(value) or not low <= value <= high:
        kind, span = ("a whole number", f"{low} to {high}") if whole else ("a finite number", f"{low:g} to {high:g}")
        raise InputError(f"the manifest's {what} is {value!r}, not {kind} from {span}", path)
    return value


def check_pgs(record, path, builtin_methods=None):
    """The manifest's `pgs` record (a run the project's solver stepped), checked; InputError
    naming the manifest otherwise. builtin_methods: the names of the built-in solver methods,
    where the caller knows them (dc validate: the solver's floor lies above this one)."""
    if not isinstance(record, dict):
        raise InputError(f"the manifest's pgs record is {type(record).__name__}, not an object", path)
    _number(record.get("tolerance"), 0.0, TOLERANCE_MAX, "pgs tolerance", path)
    _number(record.get("max_iterations"), 1, ITERATIONS_MAX, "pgs max_iterations", path, whole=True)
    for key, allowed in (("mode", MODES), ("stop_on", MEASURES), ("order", ORDERS)):
        if record.get(key, "island" if key == "order" else None) not in allowed:
            raise InputError(f"the manifest's pgs {key} is {record.get(key)!r}, not one of {', '.join(allowed)}", path)
    if record["mode"] == "exact" and record.get("order", "island") != "island":
        raise InputError(f"the manifest's pgs record sweeps Box2D's exact mode in {record['order']!r} order; exact "
                         f"mode is Box2D's own, island order", path)
    w = record.get("relaxation")
    if w is not None and w != "auto" and (type(w) not in (int, float) or not math.isfinite(w) or not 0 < w < 2):
        raise InputError(f"the manifest's pgs relaxation is {w!r}, not a w in (0, 2), \"auto\" or null", path)
    if not isinstance(record.get("accelerate"), str) or not isinstance(record.get("start"), str):
        raise InputError("the manifest's pgs record names no start or method", path)
    _check_origin(record, path, builtin_methods)
    return record


def _check_origin(record, path, builtin_methods):
    """The pgs record's accelerate_origin, where it has one: built-in or plug-in, and a built-in
    one of the built-in methods' names (where the caller knows them)."""
    origin = record.get("accelerate_origin")
    if not isinstance(origin, dict):
        return
    if origin.get("origin") not in ORIGINS:
        raise InputError(f"the manifest's pgs accelerate_origin is {origin.get('origin')!r}, not built-in or "
                         f"plug-in", path)
    if origin["origin"] == "built-in" and builtin_methods is not None and record["accelerate"] != "none" \
            and record["accelerate"] not in builtin_methods:
        raise InputError(f"the manifest says the built-in method {record['accelerate']!r} stepped the run, but no "
                         f"built-in method has that name", path)


def check_above(record, path):
    """A simulation's count of steps above the tolerance (`above_tolerance`), where it has one:
    a whole number from 0 to its steps; InputError naming the manifest otherwise."""
    claimed = record.get("above_tolerance")
    if claimed is None:
        return None
    steps = record.get("steps")
    high = steps if type(steps) is int and steps >= 0 else ITERATIONS_MAX
    if type(claimed) is not int or not 0 <= claimed <= high:
        raise InputError(f"simulation {record.get('seed')!r}: above_tolerance is {claimed!r}, not a count of its "
                         f"{high} steps", path)
    return claimed


def check_solve(solve, record, path):
    """A step file's <solve> against its run's manifest: every field both record (the start, mode,
    stop rule, tolerance, cap, w and method, and where the method comes from); `record` the run's
    pgs record, or None for a run the project's solver did not step. InputError naming the step
    file and its <solve>'s line otherwise."""
    if record is None:
        if solve is not None:
            raise InputError("the step file records a <solve> of the project's solver, but its run was not stepped "
                             "by it (copied or edited?)", path, solve_line(path))
        return
    if solve is None:
        raise InputError("the step file records no <solve>, but its run's manifest says the project's solver "
                         "stepped it (edited?)", path, 1)
    origin = record.get("accelerate_origin") or {}
    wanted = {"start": record.get("start"), "mode": record.get("mode"), "stop_on": record.get("stop_on"),
              "accelerate": record.get("accelerate"), "origin": origin.get("origin", "built-in")}
    if solve.get("order", "island") != record.get("order", "island"):   # (island where neither says)
        _disagrees(solve, "order", repr(record.get("order", "island")), path)
    if wanted["origin"] == "plug-in":   # (and which plug-in: a built-in's step names none)
        wanted.update({key: origin.get(key) for key in ("target", "distribution", "version")})
    for key, value in wanted.items():
        if solve.get(key) != (None if value is None else held(value)):   # (as the file holds it: \x01)
            _disagrees(solve, key, repr(value), path)
    for key in ("tolerance", "max_iterations"):
        if not _same(solve.get(key), record.get(key)):
            _disagrees(solve, key, repr(record.get(key)), path)
    _same_relaxation(solve, record.get("relaxation"), path)


def _same_relaxation(solve, w, path):
    """The step's w is the manifest's; any w in (0, 2) where the manifest's is "auto" (tuned as the
    run went: check_solve_itself bounds it); none where the manifest's is null (a method that takes
    no w)."""
    if w == "auto":
        if solve.get("relaxation") is None:
            _disagrees(solve, "relaxation", "'auto': a w in (0, 2) each step", path)
    elif w is None:
        if solve.get("relaxation") is not None:
            _disagrees(solve, "relaxation", "null: the method takes no w", path)
    elif not _same(solve.get("relaxation"), w):
        _disagrees(solve, "relaxation", repr(w), path)


def _same(text, value):
    """Whether a <solve> value (float32 text) is the manifest's number, to float32's rounding."""
    try:
        return math.isclose(float(text), float(value), rel_tol=1e-6, abs_tol=0.0)
    except (TypeError, ValueError):
        return False


def _disagrees(solve, key, manifest_says, path):
    shown = "" if solve.get(key) is None else f'="{solve.get(key)}"'
    raise InputError(f"the step file's <solve {key}{shown}> disagrees with its run's manifest ({manifest_says})",
                     path, solve_line(path))


def check_solve_itself(solve, path):
    """A step file's <solve> against itself, in a run or alone: its mode, stop rule and origin
    ones the solver has, its cap and tolerance in the manifest's ranges, a finite residual, w in
    (0, 2), at most its cap in iterations, and a built-in method that stopped before its cap
    stopped on its tolerance (_stops_below). InputError naming the step file and its <solve>'s line otherwise."""
    def wrong(what):
        return InputError(f"the step file's <solve> {what}", path, solve_line(path))

    for key, allowed in (("mode", MODES), ("stop_on", MEASURES), ("origin", ORIGINS), ("order", ORDERS)):
        if solve.get(key, {"origin": "built-in", "order": "island"}.get(key)) not in allowed:
            raise wrong(f'{key}="{solve.get(key)}" is not one of {", ".join(allowed)}')
    if solve["mode"] == "exact" and solve.get("order", "island") != "island":
        raise wrong(f'mode="exact" is Box2D\'s own order, not order="{solve["order"]}"')
    cap = _in_range(solve, "max_iterations", (1, float(ITERATIONS_MAX)), "a whole number", wrong)
    iterations = _whole(solve.get("iterations"))
    if iterations is None or not 0 <= iterations <= cap:
        why = "is past its own cap" if iterations is not None and iterations > cap else "is no count up to its cap"
        raise wrong(f'iterations="{solve.get("iterations")}" {why}, max_iterations="{cap}"')
    tolerance = _in_range(solve, "tolerance", (0, TOLERANCE_MAX), "a finite number", wrong)
    residual = _in_range(solve, "residual", (0, math.inf), "a finite number", wrong)
    if "relaxation" in solve and not 0 < (_finite(solve["relaxation"]) or 0) < 2:
        raise wrong(f'relaxation="{solve["relaxation"]}" is not a w in (0, 2)')
    stops_at = _stops_below(solve, tolerance)
    if solve.get("origin", "built-in") == "built-in" and solve["stop_on"] == "residual" and iterations < cap \
            and np.float32(residual) > np.float32(stops_at):   # (the built-in methods stop only there or at the cap)
        own = "" if tolerance > 0 else f" (at 0, the method's own: {stops_at:g})"
        raise wrong(f'stopped after {iterations} of its {cap} sweeps with residual="{solve["residual"]}", '
                    f'above its tolerance="{solve["tolerance"]}"{own}')


def _stops_below(solve, tolerance):
    """The residual below which a built-in method stops before its cap: the tolerance, or at 0 the
    method's own: a global method's EXACT_TOLERANCE, the sweeps' none (0: they go on to the cap). The
    residual is recorded rounded to float32, so it is compared as float32 (rounding keeps order)."""
    if tolerance > 0:
        return tolerance
    method = Acceleration.__members__.get(str(solve.get("accelerate", "none")))
    return EXACT_TOLERANCE if method is not None and is_global(method) else 0.0


def _in_range(solve, key, span, kind, wrong):
    """A <solve> value in span (low, high), as an int where kind is "a whole number"; else wrong's
    InputError."""
    value = (_whole if kind == "a whole number" else _finite)(solve.get(key))
    low, high = span
    if value is None or not low <= value <= high:
        upto = f"from {low} to {high:.10g}" if math.isfinite(high) else f"of at least {low}"
        raise wrong(f'{key}="{solve.get(key)}" is not {kind} {upto}')
    return value


def _whole(text):
    """A <solve> count as an int, or None where it is none."""
    try:
        return int(text)
    except (TypeError, ValueError):
        return None


def _finite(text):
    """A <solve> value as a finite float, or None where it is none."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def solve_line(path, within=64):
    """The line of a step file's <solve> element (its header's first lines; .xml or .xml.gz), for
    an error naming it; 1 where it is not there. Read only when there is an error to report."""
    opener = gzip.open if str(path).endswith(".gz") else open
    try:
        with opener(path, "rt", encoding="utf-8", errors="replace") as f:
            for number, line in enumerate(islice(f, within), 1):
                if "<solve " in line:
                    return number
    except (OSError, EOFError):
        pass
    return 1
