"""Solver methods: how a step's contact problem goes from a start to an answer (`--accelerate`).

One registry, SOLVERS, holds the built-ins (the native solver's variants, solver/pgs.py) and the
plug-ins a user names (entry point group ``deepcontact.solvers``, or ``package.module:Name``):

    none      plain (P)SOR sweeps
    nncg      sweeps plus conjugate directions
    newton    sweeps, then semismooth Newton steps on the whole step (float64)
    subspace  the same, each Newton system solved by conjugate gradients (float64)
    bodyspace sweeps, then augmented-Lagrangian iterations on the bodies' velocities (float64)
    lagged    the same, each Newton system preconditioned by a factor kept from an earlier one
              (float64; in the native loop the factor is carried from step to step)

`solve` is the one switch: a built-in runs natively (and can run inside the native stepping
loop); a plug-in is called as

    method(problem, start_normal, start_tangent, settings) -> MethodResult

with `settings` a SolveSettings (solver/settings.py), and its answer is checked (one impulse per
contact point, finite, no pull) and judged as given by the project's own residual, never by the
plug-in's word.
"""
import copy
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import arguments
from .._box2d import Acceleration, is_global
from ..errors import InputError
from ..plugins import PluginError, guest
from .pgs import MEASURES, Solution, require_problem
from .registry import SOLVERS
from .pgs import solve as native_solve
from .settings import SolveSettings

if TYPE_CHECKING:   # (for the annotations only)
    from .problem import StepProblem

# built-ins whose work is not only sweeps (and which are float64 only): the native table says which
GLOBAL = tuple(name for name, a in Acceleration.__members__.items() if is_global(a))


@dataclass
class MethodResult:
    """What a plug-in method returns: one normal and one tangent impulse per contact point (float64,
    N·s) and the residual after each of its iterations (its length is the iteration count)."""
    normal: np.ndarray
    tangent: np.ndarray
    residuals: np.ndarray


class Native:
    """A variant of the native solver, picked by its acceleration name."""
    native = True

    def __init__(self, accelerate):
        self.accelerate = accelerate


for _name in Acceleration.__members__:
    SOLVERS.register(_name, lambda _n=_name: Native(_n), native=True)
BUILTIN = tuple(SOLVERS.builtin())
_instances = {}

# What each built-in method is, in a word or two: the CLI's help lists them from here.
DESCRIBED = {
    "none": "sweeps alone",
    "nncg": "conjugate directions on top of the sweeps",
    "newton": "sweeps, then semismooth Newton steps on the whole step; float64",
    "subspace": "the same, each system solved by conjugate gradients; float64",
    "bodyspace": "an augmented Lagrangian on the bodies' velocities; float64",
    "lagged": "the same, each system preconditioned by a factor kept from an earlier one (in the loop, an "
              "earlier step); float64",
}


def takes_relaxation(name) -> bool:
    """Whether the method `name` uses an over-relaxation w: every built-in does; a plug-in only when
    its class says `takes_relaxation = True` (otherwise its settings carry relaxation None, and no w
    is recorded for it)."""
    if is_native(name):
        return True
    factory = SOLVERS.resolved(name)
    if factory is None and name in SOLVERS.described:   # (described from its own process, never imported here)
        return bool(SOLVERS.described[name]["takes_relaxation"])
    return bool(getattr(factory, "takes_relaxation", False))


def method_origin(name):
    """Where the solver method `name` comes from (SOLVERS.origin) and whether it runs natively or
    in Python: the record manifests and reports keep."""
    return dict(SOLVERS.origin(name), runs="native" if is_native(name) else "python")


def methods_help():
    """Every built-in method with what it is, and that plug-ins are accepted (a command's help)."""
    return ("; ".join(f"{name} ({DESCRIBED.get(name, 'a built-in method')})" for name in BUILTIN)
            + "; or a plug-in: an installed one's name, or package.module:Name (docs/api.md)")


def method(name):
    """The method object named `name`: a built-in or a plug-in already loaded by an explicit choice
    (SOLVERS.load, as the CLI does for the names it is given)."""
    if name not in _instances:
        factory = SOLVERS.resolved(name)
        if factory is None:
            factory = SOLVERS.load(name)
        with guest(f"the solver method {name!r}", "cannot be made:"):
            _instances[name] = factory()
    return _instances[name]


def is_native(name) -> bool:
    """Whether `name` is one of the native solver's variants (which the native loop can run)."""
    return name in BUILTIN


def judge(problem: "StepProblem", normal: np.ndarray, tangent: np.ndarray) -> Solution:
    """These impulses judged as an answer, without a sweep: their residual (every solve's measure,
    `.residual`) and the body velocities they give (`.velocity`, `.omega`). They are measured as
    given: a tangent beyond the friction cone is not clamped, its excess counts in the residual, so
    a solve's answer is judged to the residual the solve reported."""
    require_problem(problem)
    normal, tangent = (arguments.vector(v, name, problem.points) for v, name in ((normal, "normal"), (tangent, "tangent")))
    return native_solve(problem, normal, tangent, max_iterations=0, cone=False)


def solve(problem: "StepProblem", start_normal: np.ndarray | None = None, start_tangent: np.ndarray | None = None, *, accelerate: str = "none", mode: str = "float64",
          max_iterations: int | None = None, tolerance: float = 0.0, stop_on: str = "residual",
          relaxation: float = 1.0, history: bool = False, final_residual: bool = True, guard: bool = True,
          prune: bool = True, settings: SolveSettings | None = None, carry: "_box2d.World | None" = None) -> Solution:
    """Solve the step's contact problem from a start with the method `accelerate` (a built-in or a
    loaded plug-in); the keywords as solver.pgs.solve's, or `settings` (a SolveSettings: its mode,
    cap, tolerance, stop_on, relaxation, method, guard and sweep order, in place of those keywords). A plug-in
    stops on the residual only and runs in float32 or float64. carry: the loop's native World,
    whose carried state a built-in method uses as the native loop's step would."""
    arguments.flag(history, "history")
    if settings is None:
        arguments.text(accelerate, "accelerate")
        if is_native(accelerate):
            return native_solve(problem, start_normal, start_tangent, mode=mode, max_iterations=max_iterations,
                                tolerance=tolerance, stop_on=stop_on, relaxation=1.0 if relaxation is None else relaxation,
                                history=history, final_residual=final_residual, guard=guard, accelerate=accelerate,
                                prune=prune, carry=carry)
        require_problem(problem)
        cap = problem.velocity_iterations if max_iterations is None else max_iterations
        # (checked as every solve's settings are, before any number is read from them)
        settings = SolveSettings(mode=mode, max_iterations=cap, tolerance=tolerance, stop_on=stop_on,
                                 relaxation=relaxation, accelerate=accelerate, guard=guard)
    arguments.instance(settings, "settings", SolveSettings, "a SolveSettings (or None: the keywords say it)")
    if is_native(settings.accelerate):   # (the settings themselves, down to the native struct)
        return native_solve(problem, start_normal, start_tangent, history=history, final_residual=final_residual,
                            prune=prune, carry=carry,
                            settings=settings if settings.relaxation is not None else settings.but(relaxation=1.0))
    return _plugin_solve(problem, start_normal, start_tangent, history, _plugin_settings_of(settings))


def _plugin_solve(problem, start_normal, start_tangent, history, settings):
    """A plug-in method's solve, on its own copy of the step, its answer checked and judged here."""
    accelerate = settings.accelerate
    n = problem.start_normal if start_normal is None else start_normal
    t = problem.start_tangent if start_tangent is None else start_tangent
    solver = method(accelerate)
    # its own copy of the step: what it changes there, no other method and no later row sees
    with guest(f"the solver method {accelerate!r}"):
        out = solver(copy.deepcopy(problem), np.array(n, np.float64), np.array(t, np.float64), settings)
    normal, tangent, residuals = _checked(accelerate, out, problem, settings.max_iterations)
    after = judge(problem, normal, tangent)
    check_plausible(accelerate, problem, normal, tangent)
    trace = np.full((len(residuals), len(MEASURES)), np.nan)
    trace[:, MEASURES.index("residual")] = residuals
    if len(residuals):   # the last iterate's residual is the project's, not the plug-in's
        trace[-1, MEASURES.index("residual")] = after.residual
    return Solution(normal_impulse=normal, tangent_impulse=tangent, velocity=after.velocity, omega=after.omega,
                    iterations=len(residuals), history=trace if history else np.zeros((0, len(MEASURES))),
                    residual=after.residual, sanitized={}, stats={}, relaxation=settings.relaxation)


def check_plausible(name, problem, normal, tangent):
    """PluginError where a plug-in method's answer is no answer a step could need: together its
    impulses would move a contact faster than Box2D lets a body travel (judge measures an answer as
    given; the start check says whether the whole answer is plausible)."""
    if native_solve(problem, normal, tangent, max_iterations=0, final_residual=False).sanitized.get("implausible"):
        raise PluginError(f"the solver method {name!r} returned impulses no step could need (together they "
                          f"would move a contact faster than Box2D lets a body travel)")


def call_plugin(problem, start_normal, start_tangent, settings):
    """A plug-in method's own answer (normal, tangent, its residuals), its form checked, neither
    judged nor copied for: what a contestant's process does with a step that is its own (the
    judge judges the answer, from its own copy of the step)."""
    asked = _plugin_settings_of(settings)
    name = asked.accelerate
    with guest(f"the solver method {name!r}"):
        out = method(name)(problem, np.array(start_normal, np.float64), np.array(start_tangent, np.float64), asked)
    return _checked(name, out, problem, asked.max_iterations)


def _plugin_settings_of(s):
    """_plugin_settings for a SolveSettings s."""
    return _plugin_settings(s.accelerate, s.mode, int(s.max_iterations), float(s.tolerance), s.stop_on, s.relaxation,
                            s.guard)


def _plugin_settings(name, mode, cap, tolerance, stop_on, relaxation, guard):
    """The SolveSettings a plug-in method is handed, or InputError for what it cannot be asked:
    exact mode, a stop on another measure than the residual, a w it does not take."""
    if mode == "exact":
        raise InputError(f"the solver method {name!r} cannot run in exact mode (Box2D's own PGS)")
    if tolerance > 0 and stop_on != "residual":
        raise InputError(f"the solver method {name!r} stops on the residual only (--stop-on residual)")
    taken = takes_relaxation(name)
    if not taken and relaxation not in (None, 1.0):
        raise InputError(f"the solver method {name!r} takes no over-relaxation (its class does not say "
                         f"takes_relaxation = True): leave w at 1")
    relaxation = float(1.0 if relaxation is None else relaxation) if taken else None
    return SolveSettings(mode=mode, max_iterations=cap, tolerance=tolerance, relaxation=relaxation, accelerate=name,
                         guard=guard)


def _checked(name, out, problem, cap):
    """A plug-in's answer, or PluginError naming it and what is wrong."""
    def wrong(what):
        return PluginError(f"the solver method {name!r} {what}")

    if not isinstance(out, MethodResult):
        raise wrong(f"returned {type(out).__name__}, not a deepcontact.solver.methods.MethodResult")
    try:
        normal, tangent, residuals = (np.asarray(a, dtype=np.float64) for a in (out.normal, out.tangent, out.residuals))
    except (TypeError, ValueError) as e:
        raise wrong(f"returned something that is not numbers: {e}") from None
    points = problem.points
    for label, a in (("normal", normal), ("tangent", tangent)):
        if a.shape != (points,):
            raise wrong(f"returned {label} impulses of shape {a.shape}; the step has {points} contact points")
        if not np.isfinite(a).all():
            raise wrong(f"returned a non-finite {label} impulse")
    if residuals.ndim != 1 or len(residuals) > cap:
        raise wrong(f"returned {residuals.shape} residuals; one per iteration, at most {cap}")
    if np.any(normal < 0):
        raise wrong("returned a negative normal impulse (a contact cannot pull)")
    return normal, tangent, residuals
