"""Stepping Box2D with the project's solver in the loop (docs/solver.md, "The loop"):

    Collide → gather the contacts → our PGS from a chosen start → write the impulses into the
    manifold points → Step(dt, 0 velocity iterations, position iterations)

With zero velocity iterations Box2D's warm start applies exactly the impulses written (its
second Collide keeps them, matched by feature id), so the step moves with our answer. This needs
continuous collision and sleeping off (time-of-impact sub-steps and sleeping islands are solved
or skipped inside Box2D), and Box2D's warm-start scale dtRatio held at exactly 1.

Starts from zero or from Box2D's warm start run the whole step in one native call
(deepcontact._box2d.pgs_step); a start made in Python, `garbage`, a plug-in solver method and the
steps on which `auto` tries every w take the same path in pieces. The two give identical trajectories
(tests/test_replay_and_loop.py).
"""
from dataclasses import dataclass

import numpy as np

from .._box2d import PGSStepSettings, StepSettings, pgs_step
from ..errors import InputError
from ..solver.methods import is_native, solve
from ..solver.pgs import Solution
from ..solver.pgs import options as solve_options
from ..solver.problem import StepProblem
from ..solver.relaxation import AutoRelaxation

STARTS = ("zero", "builtin", "garbage")
# A deliberately broken start, for stability tests: huge, not a number, negative, in turn.
GARBAGE = np.array([1e30, np.nan, -1.0])


@dataclass
class LoopOptions:
    start: str = "builtin"
    mode: str = "float64"
    max_iterations: int = 8
    tolerance: float = 0.0
    stop_on: str = "residual"
    relaxation: object = 1.0     # w in (0, 2), "auto" (solver.relaxation.AutoRelaxation), or None: a
                                 # plug-in method that takes no w
    accelerate: str = "none"     # a solver method (solver.methods.SOLVERS)


def check_options(o: LoopOptions, own_start=False) -> None:
    """The rules of the loop's options, checked once for the command line and the library alike;
    OptionError naming the option that breaks one. own_start: the caller makes the starts."""
    from ..errors import OptionError
    from ..solver.methods import check_mode, takes_relaxation
    if not own_start and o.start not in STARTS:
        raise OptionError(f"unknown start {o.start!r}; choose from {', '.join(STARTS)}", "--start")
    if o.mode == "exact" and o.relaxation != 1.0:
        raise OptionError("--mode exact is Box2D's PGS: it takes no over-relaxation", "--relaxation")
    if o.mode == "exact" and o.accelerate != "none":
        raise OptionError("--mode exact is Box2D's PGS: it takes no acceleration", "--accelerate")
    check_mode(o.accelerate, o.mode)
    if not takes_relaxation(o.accelerate) and o.relaxation not in (None, 1.0):
        raise OptionError(f"the solver method {o.accelerate} takes no over-relaxation (its class does not say "
                          f"takes_relaxation = True)", "--relaxation")
    if o.relaxation == "auto" and not o.tolerance:
        raise OptionError("auto counts sweeps to a tolerance: give --tolerance", "--relaxation")


def unit_dt_ratio_inv(dt) -> np.float32:
    """A float32 x with float32(x * dt) == 1 exactly, so Box2D applies written impulses as they are."""
    dt = np.float32(dt)
    x = np.float32(1.0) / dt
    for candidate in (x, np.nextafter(x, np.float32(np.inf)), np.nextafter(x, np.float32(0))):
        if np.float32(candidate * dt) == np.float32(1.0):
            return np.float32(candidate)
    raise InputError(f"dt = {dt} has no float32 inverse with dt * inverse == 1; choose another dt")


def check_scene_for_loop(scene, source=None):
    if scene.effects.continuous:
        raise InputError("--solver pgs cannot run a scene with continuous collision: Box2D solves its "
                         "time-of-impact sub-steps internally", source)
    if scene.solver.sleeping:
        raise InputError("--solver pgs needs sleeping off: Box2D skips the contacts of sleeping islands",
                         source)


@dataclass
class LoopStep:
    """What one step of the loop did."""
    bodies: dict         # the bodies before the step, as a step file records them (None unless recording)
    contacts: dict       # the contacts solved, with the impulses applied (None unless recording)
    solution: Solution   # None when the step had no contact points
    deepest: float       # the deepest penetration among the step's contact points (m), >= 0
    dt_ratio: float = None   # Box2D's warm-start scale, where Box2D's own solver reports it


class PGSStepper:
    """Steps a world with the project's PGS; step() returns a LoopStep."""

    def __init__(self, world, scene, options: LoopOptions, start_fn=None, record=True, native=True):
        """start_fn(bodies, contacts, problem, builtin_n, builtin_t) -> (normal, tangent), if given,
        makes the first iterate instead of options.start (dc evaluate --closed-loop). record: keep
        the bodies and contacts of each step (step files need them; a timed loop does not).
        native=False steps in pieces through Python even where one native call could."""
        self.start_fn = start_fn
        check_options(options, own_start=start_fn is not None)
        check_scene_for_loop(scene)
        auto = options.relaxation == "auto"
        try:
            self.solve_options = solve_options(
                dt=scene.dt, mode=options.mode, max_iterations=options.max_iterations, tolerance=options.tolerance,
                stop_on=options.stop_on, relaxation=1.0 if auto or options.relaxation is None else options.relaxation,
                accelerate=options.accelerate if is_native(options.accelerate) else "none")
        except ValueError as e:
            raise InputError(str(e)) from None
        self.world, self.scene, self.options, self.record = world, scene, options, record
        self.gravity = scene.effects.gravity or (0.0, 0.0)
        self.inv_dt = unit_dt_ratio_inv(scene.dt)
        self.first = True
        self.relaxation = options.relaxation
        if auto:
            self.relaxation = AutoRelaxation(options.tolerance, options.stop_on, options.max_iterations, options.mode,
                                             accelerate=options.accelerate)
        # (a plug-in solver method is Python: its steps go through Python too)
        self.native = native and start_fn is None and options.start in ("zero", "builtin") \
            and is_native(options.accelerate)
        if self.native:
            self.settings = PGSStepSettings(
                step=StepSettings(dt=scene.dt, gravity=self.gravity, block_solve=scene.solver.block_solve),
                solve=self.solve_options, start=options.start, warm_scale=0.0, inv_dt0=self.inv_dt,
                position_iterations=scene.solver.position_iterations, record=record)
        world.find_new_contacts()   # Step would do this itself, after our Collide

    def step(self) -> LoopStep:
        # `auto` tries every w on a step now and then: that step goes through Python
        auto = callable(self.relaxation)
        if not self.native or (auto and self.relaxation.wants_trial()):
            return self._python_step()
        done = self._native_step(self.relaxation.w if auto else self.relaxation)
        if auto and done.solution is not None:
            self.relaxation.solved_without_trial()
        return done

    def _native_step(self, w):
        self.settings.warm_scale = 0.0 if self.first else 1.0
        if w != self.solve_options.relaxation:
            self.solve_options.relaxation = w
            self.settings.solve = self.solve_options
        out = pgs_step(self.world, self.settings)
        self.first = False
        solution = None if out is None else Solution.from_native(out, w)
        deepest = 0.0 if out is None else out["deepest"]
        if not self.record:
            return LoopStep(None, None, solution, deepest)
        before, recorded = self.world.recorded()
        # Box2D applied what we wrote; the step file records our start as the step's start.
        # (Box2D's recorder saw our solution carried over as its warm start.)
        n = len(recorded["normal_impulse"])
        same = out is not None and len(out["start_normal"]) == n
        recorded["start_normal_impulse"] = out["start_normal"].astype(np.float32) if same else np.zeros(n, np.float32)
        recorded["start_tangent_impulse"] = out["start_tangent"].astype(np.float32) if same else np.zeros(n, np.float32)
        return LoopStep(before, recorded, solution, deepest)

    def _python_step(self):
        world, scene, o = self.world, self.scene, self.options
        bodies = world.bodies()
        world.collide()
        contacts = world.contacts()
        # Box2D's own warm start: the impulses carried over by feature id, times dtRatio (0 on
        # the first step, when nothing was carried).
        ratio = np.float32(0.0 if self.first else 1.0)
        builtin_n = ratio * contacts["normal_impulse"]
        builtin_t = ratio * contacts["tangent_impulse"]
        problem = None
        if len(contacts["manifold"]):
            problem = StepProblem.from_arrays(bodies, contacts, dt=scene.dt, gravity=self.gravity,
                                              block_solve=scene.solver.block_solve,
                                              velocity_iterations=o.max_iterations)
        if self.start_fn is not None:
            start_n, start_t = (np.zeros(0), np.zeros(0)) if problem is None else \
                self.start_fn(bodies, contacts, problem, builtin_n, builtin_t)
        elif o.start == "builtin":
            start_n, start_t = builtin_n, builtin_t
        elif o.start == "garbage":
            start_n = np.resize(GARBAGE, len(builtin_n))
            start_t = np.roll(start_n, 1)
        else:
            start_n = np.zeros_like(builtin_n)
            start_t = np.zeros_like(builtin_t)
        solution = None
        if problem is not None:
            w = self.relaxation(problem, start_n, start_t) if callable(self.relaxation) else self.relaxation
            solution = solve(problem, start_n, start_t, mode=o.mode, max_iterations=o.max_iterations,
                             tolerance=o.tolerance, stop_on=o.stop_on, relaxation=w, accelerate=o.accelerate)
            world.set_manifold_impulses(solution.normal_impulse.astype(np.float32),
                                        solution.tangent_impulse.astype(np.float32))
        world.inv_dt0 = self.inv_dt
        self.first = False
        deepest = max(0.0, float(-contacts["separation"].min())) if len(contacts["separation"]) else 0.0
        out = world.step(scene.dt, 0, scene.solver.position_iterations, record=self.record)
        if not self.record:
            return LoopStep(None, None, solution, deepest)
        before, recorded = out
        # What Box2D applied is what we wrote; record our start as the step's start.
        # (a garbage start is recorded as sanitised: no NaN ever reaches a file)
        used_n, used_t = (start_n, start_t) if o.start != "garbage" else (np.zeros_like(builtin_n),) * 2
        if len(used_n) != len(builtin_n):
            used_n, used_t = np.zeros_like(builtin_n), np.zeros_like(builtin_t)
        recorded["start_normal_impulse"] = used_n.astype(np.float32)
        recorded["start_tangent_impulse"] = used_t.astype(np.float32)
        return LoopStep(before, recorded, solution, deepest)
