"""What a solve is asked to do, as one frozen value: from a command's options down to the native
struct (`native`), checked once, on construction.

TOLERANCE and CAP are the defaults of every command and function that solves to a tolerance
(dc evaluate, dc simulate --solver pgs --tolerance, the studies): named here and nowhere else.
"""
from dataclasses import dataclass, replace

import numpy as np

from .._box2d import Acceleration, SolveOptions, is_global
from ..errors import OptionError
from .registry import SOLVERS

TOLERANCE = 1e-4   # the residual a solve to a tolerance stops below, unless told otherwise
# dc evaluate's cap: a verdict needs variants that reach the tolerance on every step, and at 1000
# every variant left 3-16% of the held-out pile's steps above 1e-4 (builtin's p95 is 1698 sweeps,
# replayed), so no README line named any; at this cap every builtin and prev step reaches it.
VERDICT_CAP = 10_000
CAP = 1000         # sweeps at most when a tolerance is asked for (a scene's own 8 would stop short of it)

# Box2D moves a body at most b2_maxTranslation = 2 m per step; a start whose impulses together
# change some contact's velocity by more than twice that speed is not an answer the step could need
# (judged as a whole: impulses that balance each other may each be large).
MAX_TRANSLATION = 2.0

# The option that sets each field, for the one-line errors (OptionError names it).
FLAGS = {"mode": "--mode", "max_iterations": "--max-iterations", "tolerance": "--tolerance",
         "stop_on": "--stop-on", "relaxation": "--relaxation", "accelerate": "--accelerate", "order": "--order"}


@dataclass(frozen=True)
class SolveSettings:
    """A solve's settings: stop once the measure `stop_on` (solver/pgs.py) falls below `tolerance`,
    or after `max_iterations` iterations (tolerance 0: exactly that many; by default, a residual of
    TOLERANCE within CAP sweeps); `mode` float32, float64
    or exact (Box2D's own PGS); `relaxation` the over-relaxation w (a number in (0, 2), "auto" where
    a caller tunes it, or None for a plug-in method that takes none); `accelerate` the solver method
    (solver.methods); `guard` drops over-relaxation when the residual climbs tenfold; `order` the
    order a sweep visits the manifolds in: island (Box2D's, as posed) or gravity (from the highest
    to the lowest along gravity: a stack's weight carried down in one sweep).

    Constructing one checks it (the native solver's own rules): an OptionError naming the flag.
    A plug-in method receives one (with relaxation None unless it takes a w)."""
    mode: str = "float64"
    max_iterations: int = CAP
    tolerance: float = TOLERANCE
    stop_on: str = "residual"
    relaxation: float | str | None = 1.0
    accelerate: str = "none"
    guard: bool = True
    order: str = "island"

    def __post_init__(self):
        key = tuple((type(v), v) for v in (self.mode, self.max_iterations, self.tolerance, self.stop_on,
                                            self.relaxation, self.accelerate, self.guard, self.order))
        try:
            if key in _CHECKED:   # (a solve makes one per call: the same request, types and all, is checked once)
                return
        except TypeError:   # a field that cannot be hashed (a list, an array) is of no type it may have
            key = None
        self._check_types()
        unheld = relaxation_unheld(self.relaxation) if isinstance(self.relaxation, (int, float)) else None
        if unheld:
            raise _error(unheld, "relaxation")
        if self.mode == "exact" and self.relaxation != 1.0:   # (the native rule, but naming the flag)
            raise _error("--mode exact is Box2D's PGS: it takes no over-relaxation", "relaxation")
        if self.mode == "exact" and self.order != "island":
            raise _error("--mode exact is Box2D's PGS: it sweeps in Box2D's island order", "order")
        if self.mode == "exact" and self.accelerate != "none":
            raise _error("--mode exact is Box2D's PGS: it takes no acceleration", "accelerate")
        if self.order != "island" and isinstance(self.accelerate, str) and \
                self.accelerate not in Acceleration.__members__:
            raise _error(f"--order {self.order} is the built-in sweeps' order; the plug-in method "
                         f"{self.accelerate!r} sweeps in its own", "order")
        check_mode(self.accelerate, self.mode)   # (the native rule, but naming the flag)
        # the native rules, checked where they are written (a plug-in method's name stands as
        # plain sweeps: its own rules are its own)
        self._native(1.0, self.accelerate if self.accelerate in Acceleration.__members__ else "none")
        if len(_CHECKED) > 4096:
            _CHECKED.clear()
        if key is not None:
            _CHECKED.add(key)

    def _check_types(self):
        """OptionError for a field of the wrong type (before the native struct would refuse it)."""
        real = (int, float)
        for name, kinds in (("max_iterations", (int,)), ("tolerance", real)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, kinds + _numpy_kinds(name)):
                raise OptionError(f"{name} must be a number, got {value!r}", FLAGS[name])
        if not (self.relaxation is None or isinstance(self.relaxation, str) and self.relaxation == "auto" or
                (isinstance(self.relaxation, real + _numpy_kinds("tolerance")) and not isinstance(self.relaxation, bool))):
            raise OptionError(f"relaxation must be a number, got {self.relaxation!r}", FLAGS["relaxation"])
        if self.max_iterations > 2 ** 31 - 1:   # (the native int: the rest of the range is the native check's)
            raise OptionError(f"max_iterations must be at most {2 ** 31 - 1}, got {self.max_iterations}",
                              FLAGS["max_iterations"])
        if not isinstance(self.stop_on, str):
            raise OptionError(f"stop_on must be a measure's name, got {self.stop_on!r}", FLAGS["stop_on"])
        for name in ("mode", "accelerate", "order"):
            if not isinstance(getattr(self, name), str):
                raise OptionError(f"{name} must be a name, got {getattr(self, name)!r}", FLAGS[name])
        if not isinstance(self.guard, bool):   # (the native struct's bool: pybind11's refusal otherwise)
            raise OptionError(f"guard must be True or False, got {self.guard!r}", None)
        if self.accelerate not in Acceleration.__members__:
            _check_method_name(self.accelerate)

    def native(self, *, dt, history=False, final_residual=True, cone=True):
        """The native solver's SolveOptions for a step of length dt (the only place one is made):
        names become its enums, a tolerance of 0 a fixed sweep count, and a start whose impulses
        together move a contact faster than Box2D lets a body travel counts as implausible. "auto" and
        None stand as w = 1 (a caller that tunes w sets it per solve). OptionError for a method
        the native solver does not have."""
        return self._native(dt, self.accelerate, history, final_residual, cone)

    def _native(self, dt, accelerate, history=False, final_residual=True, cone=True):
        w = 1.0 if self.relaxation is None or self.relaxation == "auto" else self.relaxation
        try:
            return SolveOptions(mode=self.mode, max_iterations=self.max_iterations, tolerance=self.tolerance,
                                stop_on=self.stop_on if self.tolerance > 0 else "none", relaxation=w,
                                accelerate=accelerate, history=history, max_velocity=2.0 * MAX_TRANSLATION / dt,
                                final_residual=final_residual, guard=self.guard, cone=cone, order=self.order)
        except (ValueError, TypeError) as e:   # the native check: "<field> must ..."
            field = str(e).split()[0] if str(e) else ""
            raise OptionError(str(e), FLAGS.get(field)) from None

    @property
    def prunes(self) -> bool:
        """Whether its problem leaves out the rows and terms a scene does not need (the answer is the
        same up to the sign of a zero): not in the exact mode, which is Box2D's arithmetic whole."""
        return self.mode != "exact"

    def but(self, **changes) -> "SolveSettings":
        """These settings with some fields changed (checked again)."""
        return replace(self, **changes)


def relaxation_unheld(w):
    """The one line saying a w in (0, 2) is 0 or 2 in float32, or None: a step file (and the
    float32 solver) keeps w in float32, where it would be outside (0, 2), and the file would fail
    the schema it was written by."""
    if 0.0 < w < 2.0 and float(np.float32(w)) in (0.0, 2.0):
        return f"relaxation must be in (0, 2), and {w!r} is {float(np.float32(w)):g} in float32, in which a step keeps it"
    return None


def _error(message, field):
    return OptionError(message, FLAGS[field])


def check_mode(accelerate: str, mode: str) -> None:
    """The rule a method puts on the arithmetic: the native table's global methods (newton,
    subspace, bodyspace, lagged) are float64 only. OptionError naming --accelerate where it is broken (a
    plug-in method's name passes: its rules are its own)."""
    if accelerate in Acceleration.__members__ and is_global(Acceleration.__members__[accelerate]) \
            and mode != "float64":
        raise _error(f"{accelerate} is float64 only: use --mode float64", "accelerate")


def _check_method_name(name):
    """OptionError naming --accelerate unless `name` could name a solver method (registered,
    installed, or package.module:Name): a name no registry can resolve would be refused only at
    the first step that solves. (A name's code is loaded where the method runs, never here.)"""
    if not SOLVERS.is_name(name):
        raise _error(f"accelerate must be one of {', '.join(Acceleration.__members__)}, not {name!r}, or a plug-in's "
                     "name: an installed one's, or package.module:Name", "accelerate")


_CHECKED = set()   # requests already checked (frozen values: equal ones pass the same checks)


def _numpy_kinds(name):
    import numpy as np
    return (np.integer,) if name == "max_iterations" else (np.integer, np.floating)
