"""Projected Gauss-Seidel on a StepProblem: the thin Pythonic face of the native solver.

Modes:
  exact      float32, Box2D's arithmetic and order, starts used as given: Box2D's velocity
             solver, bit for bit (checked by `dc validate --replay`).
  float32    the same arithmetic, but starts are sanitised first.
  float64    double precision; with relaxation w != 1 it is PSOR.

Acceleration (float32/float64): `nncg` adds to each sweep's result beta times the last search
direction (Fletcher-Reeves beta = |change|^2 / |last change|^2, restarting when beta > 1); the
next sweep projects it back. It costs two more passes over the contact points per sweep (about
1.5x a plain sweep, docs/results/faster.md, "Faster to the same accuracy").

Stopping: a fixed count (tolerance 0) or the first sweep whose chosen measure falls below the
tolerance, capped at max_iterations. Measures (per sweep, see docs/solver.md, "Measuring convergence"):
  thesis     max over contact points of |(d ln, d lt)|, the change of the iterate in the sweep
  velocity   max over rows of |d lambda| * k, the change of contact velocity it causes (m/s)
  residual   max over rows of the min-map residual of the LCP in velocity units, divided by the
             largest free relative velocity of the step (dimensionless)
"""
from dataclasses import dataclass

import numpy as np

from .._box2d import Acceleration, Mode, Order, World, contact_rows, solve_contacts
from .. import arguments
from ..errors import InputError
from .problem import StepProblem
from .settings import SolveSettings


def require_problem(problem):
    """A StepProblem, or InputError saying what was given instead (a library caller's None)."""
    if not isinstance(problem, StepProblem):
        raise InputError(f"argument 'problem' must be a StepProblem (StepProblem.from_step_file, .from_arrays), "
                         f"got {type(problem).__name__}")

MEASURES = ("thesis", "velocity", "residual")
# none: plain (P)SOR sweeps. nncg: after each sweep the iterate also moves along a conjugate
# direction (nonsmooth nonlinear conjugate gradient, Silcowitz, Niebe and Erleben 2010).
ACCELERATIONS = tuple(Acceleration.__members__)
MODES = tuple(Mode.__members__)
# The orders a sweep may visit the manifolds in (SolveSettings.order; native Order)
ORDERS = tuple(Order.__members__)


@dataclass
class Solution:
    normal_impulse: np.ndarray
    tangent_impulse: np.ndarray
    velocity: np.ndarray       # body velocities after the solve (v* plus the impulses)
    omega: np.ndarray
    iterations: int
    history: np.ndarray        # (iterations, 3): thesis, velocity, residual per sweep (if asked)
    residual: float            # normalised residual at the end
    sanitized: dict
    stats: dict
    relaxation_fallback: int = 0   # the sweep after which over-relaxation fell back to w = 1 (0: never)
    relaxation: float | None = 1.0  # the w it was asked to use (None: a plug-in method that takes none)
    factorizations: int = 0        # sparse factorizations (newton: one per Newton step tried; bodyspace: per Newton iteration)
    newton_fallbacks: int = 0      # Newton steps (bodyspace: outer iterations) that failed and handed back to sweeps
    newton_iterations: int = 0     # bodyspace: Newton iterations on the bodies' momentum balance
    outer_iterations: int = 0      # bodyspace: outer iterations (multipliers and friction bounds updated)
    pivoted: bool = False          # the reference finished by Lemke's pivoting (solver/reference.py)

    @classmethod
    def from_native(cls, out, relaxation):
        """From the dict the native solver returns (a loop step's has no body velocities)."""
        return cls(normal_impulse=out["normal_impulse"], tangent_impulse=out["tangent_impulse"],
                   velocity=out.get("velocity"), omega=out.get("omega"),
                   iterations=out["iterations"], history=out["history"], residual=out["residual"],
                   sanitized=out["sanitized"], stats=out["stats"], relaxation_fallback=out["relaxation_fallback"],
                   relaxation=float(relaxation), factorizations=out["factorizations"],
                   newton_fallbacks=out["newton_fallbacks"],
                   newton_iterations=out["newton_iterations"], outer_iterations=out["outer_iterations"])

    def measure(self, name):
        return self.history[:, MEASURES.index(name)]


def solve(problem: "StepProblem", start_normal: np.ndarray | None = None, start_tangent: np.ndarray | None = None, *,
          mode: str = "float64", max_iterations: int | None = None, tolerance: float = 0.0, stop_on: str = "residual",
          relaxation: float = 1.0, history: bool = False, prune: bool = True, final_residual: bool = True,
          guard: bool = True, accelerate: str = "none", cone: bool = True, carry: "World | None" = None,
          settings: SolveSettings | None = None) -> Solution:
    """Solve the step's contact problem from a start (default: Box2D's own warm start).

    With relaxation w != 1 (PSOR) or accelerate="nncg", and guard, a solve whose residual climbs
    tenfold above its best continues as plain PGS (checked every 4 sweeps;
    Solution.relaxation_fallback says when). A solve ends on a sweep's iterate, whose tangents can
    lie just outside the friction cone (as Box2D's do): the residual counts the excess. prune: leave
    out the rows and terms the scene does not need (the answer is the same, up to the sign of a
    zero); the exact mode, Box2D's arithmetic, never does. A start is
    projected onto the cone before use (cone=False: taken as given, which is how `judge` measures
    an answer, so it agrees with the solve that made it). carry: the native World whose carried
    state (the lagged method's factor and penalty) the solve uses and updates, as a step of the
    native loop does; a solve without it starts afresh. settings: a SolveSettings in place of the
    keywords mode ... accelerate (the one object a command's options become, down to the native
    struct: SolveSettings.native).
    Bad options raise OptionError (an InputError naming the flag)."""
    require_problem(problem)
    for value, name in ((history, "history"), (prune, "prune"), (final_residual, "final_residual"), (cone, "cone")):
        arguments.flag(value, name)
    if settings is None:
        settings = SolveSettings(mode=mode, tolerance=tolerance, stop_on=stop_on, relaxation=relaxation, guard=guard,
                                 accelerate=accelerate,
                                 max_iterations=problem.velocity_iterations if max_iterations is None else max_iterations)
    step = problem.settings(prune and settings.prunes)   # (its dt checked before the options divide by it)
    opts = settings.native(dt=problem.dt, history=history, final_residual=final_residual, cone=cone)
    starts = start_impulses(problem, start_normal, start_tangent)
    try:
        out = solve_contacts(problem.bodies, problem.contacts, *starts, step, opts, carry)
    except (ValueError, TypeError, KeyError, IndexError) as e:   # the native checks of the problem's arrays
        raise native_refusal(e) from None
    return Solution.from_native(out, settings.relaxation)


def start_impulses(problem: "StepProblem", start_normal=None, start_tangent=None) -> tuple:
    """A start as solve takes it, (normal, tangent): each float64, one real number a contact point
    (None: the problem's own start); InputError naming the argument otherwise. The loop's step
    between the native halves holds a start made in Python to this too (simulate/pgs_loop.py)."""
    return tuple(held_start(name, own if given is None else given, problem.points, given) for name, given, own in (
        ("start_normal", start_normal, problem.start_normal), ("start_tangent", start_tangent, problem.start_tangent)))


def held_start(name, values, points, given):
    """One array of a start (`name`: start_normal or start_tangent) as float64, one a contact
    point: real numbers (not held finite: a garbage start, NaN and all, is a stability test's
    input), never text, complex or objects; InputError naming it and `given` (what the caller
    handed: None where `values` is the problem's own) otherwise."""
    a = np.asarray(values)
    if a.dtype.kind not in "iuf" or a.shape != (points,):
        raise arguments.refuse(name, f"one value per contact point (a real number), an array of shape ({points},)", given)
    return a.astype(np.float64)


def check_solvable(problem: "StepProblem") -> None:
    """InputError where solve would refuse the problem's arrays (a column of another dtype or
    shape, a value not finite, a contact naming no body), with solve's message, without solving."""
    require_problem(problem)
    try:
        contact_rows(problem.bodies, problem.contacts, problem.settings())
    except (ValueError, TypeError, KeyError, IndexError) as e:
        raise native_refusal(e) from None


def native_refusal(e):
    """InputError for what the native solver refused in a problem's arrays (a column missing, of
    another dtype or shape, a contact naming no body): a StepProblem built or edited by hand."""
    message = e.args[0] if e.args and isinstance(e.args[0], str) else str(e)
    return InputError(f"the step's problem cannot be solved: {message} (StepProblem.from_arrays checks and "
                      "converts each column)")
