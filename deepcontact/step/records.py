"""What a run's records may hold: the manifest's record of the project's solver (`pgs`) and of
each simulation's steps above the tolerance, and each step file's <solve>, checked for type,
range and agreement with the run, so that an edited or hand-made record is one line naming its
file instead of a number every reader trusts (dc validate, rasterize, evaluate, export)."""
import math

from ..errors import InputError

MODES = ("exact", "float32", "float64")
MEASURES = ("thesis", "velocity", "residual")
TOLERANCE_MAX = 1e3       # (the residual is relative: 1 at a zero start; past this a tolerance stops nothing)
ITERATIONS_MAX = 2**31 - 1
ORIGINS = ("built-in", "plug-in")


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
    for key, allowed in (("mode", MODES), ("stop_on", MEASURES)):
        if record.get(key) not in allowed:
            raise InputError(f"the manifest's pgs {key} is {record.get(key)!r}, not one of {', '.join(allowed)}", path)
    w = record.get("relaxation")
    if w is not None and w != "auto" and (type(w) not in (int, float) or not math.isfinite(w) or not 0 < w < 2):
        raise InputError(f"the manifest's pgs relaxation is {w!r}, not a w in (0, 2), \"auto\" or null", path)
    if not isinstance(record.get("accelerate"), str) or not isinstance(record.get("start"), str):
        raise InputError("the manifest's pgs record names no start or method", path)
    origin = record.get("accelerate_origin")
    if isinstance(origin, dict):
        if origin.get("origin") not in ORIGINS:
            raise InputError(f"the manifest's pgs accelerate_origin is {origin.get('origin')!r}, not built-in or "
                             f"plug-in", path)
        if origin["origin"] == "built-in" and builtin_methods is not None and record["accelerate"] != "none" \
                and record["accelerate"] not in builtin_methods:
            raise InputError(f"the manifest says the built-in method {record['accelerate']!r} stepped the run, but no "
                             f"built-in method has that name", path)
    return record


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
    """A step file's <solve> against its run's manifest: `record` the run's pgs record, or None
    for a run the project's solver did not step. InputError naming the step file otherwise."""
    if record is None:
        if solve is not None:
            raise InputError("the step file records a <solve> of the project's solver, but its run was not stepped "
                             "by it (copied or edited?)", path, 1)
        return
    if solve is None:
        raise InputError("the step file records no <solve>, but its run's manifest says the project's solver "
                         "stepped it (edited?)", path, 1)
    origin = (record.get("accelerate_origin") or {}).get("origin", "built-in")
    wanted = {"start": record.get("start"), "mode": record.get("mode"), "stop_on": record.get("stop_on"),
              "accelerate": record.get("accelerate"), "origin": origin}
    for key, value in wanted.items():
        if str(solve.get(key)) != str(value):
            raise InputError(f"the step file's <solve {key}=\"{solve.get(key)}\"> disagrees with its run's manifest "
                             f"({value!r})", path, 1)
    for key in ("tolerance", "max_iterations"):
        try:
            same = math.isclose(float(solve.get(key)), float(record.get(key)), rel_tol=1e-6, abs_tol=0.0)
        except (TypeError, ValueError):
            same = False
        if not same:
            raise InputError(f"the step file's <solve {key}=\"{solve.get(key)}\"> disagrees with its run's manifest "
                             f"({record.get(key)!r})", path, 1)
