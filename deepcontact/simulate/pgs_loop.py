"""Stepping Box2D with the project's solver in the loop (docs/solver.md, "The loop"):

    Collide → gather the contacts → our PGS from a chosen start → write the impulses into the
    manifold points → Step(dt, 0 velocity iterations, position iterations)

With zero velocity iterations Box2D's warm start applies exactly the impulses written, so the
step moves with our answer; Box2D's Step runs without its own Collide (it would rebuild the
same manifolds and carry the written impulses onto themselves by feature id: the same step,
bit for bit, at twice the collision's cost). This needs
continuous collision and sleeping off (time-of-impact sub-steps and sleeping islands are solved
or skipped inside Box2D), Box2D's warm-start scale dtRatio held at exactly 1 and its warm starting on
for the Step (a world with it off starts each step from zero, as Box2D's own solver does).

Starts from zero or from Box2D's warm start run the whole step in one native call
(deepcontact._box2d.pgs_step); a start made in Python is asked between its two halves (pgs_pose,
pgs_finish) where the step is not recorded; `garbage`, a recorded step with a start of one's own, a
plug-in solver method and the steps on which `auto` tries every w take the same path in pieces. They
give identical trajectories (tests/test_replay_and_loop.py): a start is held to solve's rule on
either path, and what it changes in the step it is handed no path reads back.
"""
import math
from dataclasses import dataclass, replace

import numpy as np

from .._box2d import PGSStepSettings, StepSettings, pgs_finish, pgs_pose, pgs_step
from ..errors import InputError, OptionError
from ..solver.methods import is_native, solve, takes_relaxation
from ..solver.pgs import Solution, check_solvable, held_start, start_impulses
from ..solver.problem import StepProblem
from ..solver.relaxation import AutoRelaxation
from ..solver.settings import SolveSettings

STARTS = ("zero", "builtin", "garbage")
# A deliberately broken start, for stability tests: huge, not a number, negative, in turn.
GARBAGE = np.array([1e30, np.nan, -1.0])


def check_loop(settings: SolveSettings, start: str = "builtin", own_start=False) -> None:
    """The loop's own rules over a solve's settings (which checked their own when made), checked
    once for the command line and the library alike; OptionError naming the option that breaks
    one. own_start: the caller makes the starts."""
    o = settings
    if not own_start and start not in STARTS:
        raise OptionError(f"unknown start {start!r}; choose from {', '.join(STARTS)}", "--start")
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
    """What one step of an engine did: what every engine's step function returns (the Box2D loop's
    and any engine of one's own; docs/engines.md, "An engine of your own", lists every field of the
    two tables with its dtype, shape and unit)."""
    bodies: dict         # the bodies before the step: field -> array, as empty_bodies (None unless recording)
    contacts: dict       # the contact points the step solved, impulses applied: as empty_contacts (None
                         # unless recording)
    solution: Solution = None   # the project's solver's answer; None for another engine's step or no contacts
    deepest: float = 0.0   # the deepest penetration among the step's contact points (m), >= 0
    dt_ratio: float = None   # Box2D's warm-start scale, where Box2D's solver or the loop reports it (another engine: 1.0)
    engine_stats: dict = None   # another engine's own account of its solve, name -> number or text
                                # (MuJoCo's iterations, ...): the step file's <engine_step>


def _private(problem):
    """A copy of the problem's arrays, taken before a start made in Python is asked on the problem:
    what the step in pieces solves (and sends a plug-in method), whatever the start then changes in
    the step it was handed, as the step between the native halves reads nothing back from Python."""
    def columns(d):
        return {k: v.copy() for k, v in d.items()}
    arrays = ("start_normal", "start_tangent", "normal_impulse", "tangent_impulse", "keys")
    return replace(problem, bodies=columns(problem.bodies), contacts=columns(problem.contacts),
                   **{k: getattr(problem, k).copy() for k in arrays if getattr(problem, k) is not None})


def _builtin(contacts, ratio, warm):
    """Box2D's own warm start: the impulses Collide carried over by feature id, times dtRatio; zero
    where the world's warm starting is off (Box2D's own solver then starts from zero)."""
    carried = ratio if warm else np.float32(0.0)
    return carried * contacts["normal_impulse"], carried * contacts["tangent_impulse"]


class PGSStepper:
    """Steps a world with the project's PGS; step() returns a LoopStep."""

    def __init__(self, world, scene, settings: SolveSettings, start="builtin", start_fn=None, record=True,
                 native=True, solve_fn=None, residual=None):
        """settings: the solve's (its mode, tolerance, cap, w and method); start: zero, builtin
        (Box2D's warm start) or garbage. start_fn(bodies, contacts, problem, builtin_n, builtin_t)
        -> (normal, tangent), if given, makes the first iterate instead (dc evaluate --closed-loop;
        held to solve's rule; problem's start is Box2D's warm start, builtin_n and builtin_t). A
        start_fn may also offer from_world(world, carried, points) -> (normal, tangent) or None: the
        start of the posed step read from the world itself (carried: Box2D's warm-start scale, 0
        where warm starting is off), asked first where a step is posed between the native halves;
        None, and it is called as above (the closed loop's contestants: _Adapter.from_world).
        record: keep the bodies and contacts of each step (step files need them; a timed loop does
        not). native=False steps in pieces through Python even where one native call could.
        solve_fn(problem, start_n, start_t, settings) -> Solution, if given, solves each step in place
        of solver.methods.solve (the closed loop's plug-in methods, in their own processes).
        residual: each step's solution reports its residual (solution.residual; NaN where not):
        by default where the step is recorded (a step file states it) or the solve has a tolerance
        (it stops on a measure); an unrecorded step at a fixed sweep count skips the pass after its
        sweeps and the scale before them, whose answer nothing reads (a built-in method's iterates
        are the same either way)."""
        self.start_fn, self.solve_fn = start_fn, solve_fn
        check_loop(settings, start, own_start=start_fn is not None)
        check_scene_for_loop(scene)
        auto = settings.relaxation == "auto"
        # (w: "auto" and None stand as 1; a plug-in method's steps sweep nothing natively)
        native_part = settings if is_native(settings.accelerate) else settings.but(accelerate="none")
        self.residual = (record or settings.tolerance > 0) if residual is None else bool(residual)
        self.solve_options = native_part.native(dt=scene.dt, final_residual=self.residual)
        self.world, self.scene, self.settings, self.start, self.record = world, scene, settings, start, record
        self.gravity = scene.effects.gravity or (0.0, 0.0)
        self.inv_dt = unit_dt_ratio_inv(scene.dt)
        self.stepped_inv_dt0 = float(np.float32(1.0) / np.float32(scene.dt))   # (what Step leaves in inv_dt0)
        self.first = True
        # (None stands as 1 for a built-in method, as solve takes it; a plug-in's stays None)
        self.relaxation = 1.0 if settings.relaxation is None and is_native(settings.accelerate) else settings.relaxation
        if auto:
            self.relaxation = AutoRelaxation(settings)
        # (a plug-in solver method is Python: its steps go through Python too)
        self.native = native and start_fn is None and solve_fn is None and start in ("zero", "builtin") \
            and is_native(settings.accelerate)
        # a start made in Python (start_fn) between the native step's halves (pgs_pose, pgs_finish):
        # the world read out and the problem posed once, natively, as pgs_step poses it
        self.posed = native and start_fn is not None and solve_fn is None and not record \
            and is_native(settings.accelerate)
        if self.native or self.posed:
            self.step_settings = PGSStepSettings(
                step=StepSettings(dt=scene.dt, gravity=self.gravity, block_solve=scene.solver.block_solve,
                                  prune=settings.prunes),
                solve=self.solve_options, start=start, warm_scale=0.0, inv_dt0=self.inv_dt,
                position_iterations=scene.solver.position_iterations, record=record)
        world.find_new_contacts()   # Step would do this itself, after our Collide

    def step(self) -> LoopStep:
        # `auto` tries every w on a step now and then: that step goes through Python
        auto = callable(self.relaxation)
        if self.posed and not auto:
            return self._posed_step()
        if not self.native or (auto and self.relaxation.wants_trial()):
            return self._python_step()
        done = self._native_step(self.relaxation.w if auto else self.relaxation)
        if auto and done.solution is not None:
            self.relaxation.solved_without_trial()
        return done

    def _carried_scale(self):
        """Box2D's warm-start scale for this step, dtRatio, as b2World::Step computes it (float32
        inv_dt0 * dt): on the loop's first step of a world, what Box2D's own next step would carry
        (0 for a new world; about 1 after Box2D's own steps at this dt, so a world switched to the
        loop goes on as one pile); after the loop's steps exactly 1 (unit_dt_ratio_inv), unless a
        step at another dt (Box2D's own, in between) left another inv_dt0."""
        inv_dt0 = self.world.inv_dt0
        if not self.first and inv_dt0 == self.stepped_inv_dt0:
            return np.float32(1.0)
        return np.float32(np.float32(inv_dt0) * np.float32(self.scene.dt))

    def _applying(self, warm, step, *args, **kw):
        """step(*args, **kw) with the world's warm starting on (warm: it is already): Box2D applies
        the written impulses only as its warm start (off, it dropped the loop's answer and the bodies
        fell through). Its own solver starts such a world's steps from zero: so does the loop."""
        if warm:
            return step(*args, **kw)
        self.world.warm_starting = True
        try:
            return step(*args, **kw)
        finally:
            self.world.warm_starting = False

    def _set_step(self, w):
        """The native step's settings for this step, (dtRatio, the world's warm starting): Box2D's
        warm-start scale (0 where warm starting is off) and w."""
        ratio, warm = self._carried_scale(), self.world.warm_starting
        self.step_settings.warm_scale = float(ratio) if warm else 0.0
        if w != self.solve_options.relaxation:
            self.solve_options.relaxation = w
            self.step_settings.solve = self.solve_options
        return ratio, warm

    def _native_step(self, w):
        scale, warm = self._set_step(w)
        out = self._applying(warm, pgs_step, self.world, self.step_settings)
        self.first = False
        solution = None if out is None else Solution.from_native(out, w)
        deepest = 0.0 if out is None else out["deepest"]
        if not self.record:
            return LoopStep(None, None, solution, deepest, dt_ratio=float(scale))
        before, recorded = self.world.recorded()
        # Box2D applied what we wrote; the step file records our start as the step's start.
        # (Box2D's recorder saw our solution carried over as its warm start.)
        n = len(recorded["normal_impulse"])
        same = out is not None and len(out["start_normal"]) == n
        recorded["start_normal_impulse"] = out["start_normal"].astype(np.float32) if same else np.zeros(n, np.float32)
        recorded["start_tangent_impulse"] = out["start_tangent"].astype(np.float32) if same else np.zeros(n, np.float32)
        return LoopStep(before, recorded, solution, deepest, dt_ratio=float(scale))

    def _posed_step(self):
        """A step whose start start_fn makes, between the native step's halves: posed (Collide, the
        islands, each contact's rows and Box2D's carried start) by pgs_pose, the start asked for on
        the contacts World.contacts() reads (the posed step's points, in its order), then solved,
        written and stepped by pgs_finish: the bits of the step in pieces (_python_step), without
        its second posing in Python and in Box2D's own Step. A start_fn's from_world is asked
        first, and the step read out into Python only where it answers None."""
        world, scene, w = self.world, self.scene, self.relaxation
        ratio, warm = self._set_step(w)
        points = pgs_pose(world, self.step_settings)   # (Collide and the pose read no warm-starting flag)
        # (a start_fn that reads the posed step from the world itself, as the closed loop's contestants'
        # channel can: None where it cannot, and it is asked as any start_fn)
        from_world = getattr(self.start_fn, "from_world", None) if points else None
        start = None if from_world is None else from_world(world, ratio if warm else np.float32(0.0), points)
        if start is not None:
            start_n, start_t = (held_start(name, a, points, a) for name, a in zip(("start_normal", "start_tangent"), start))
        elif points:
            bodies, contacts = world.bodies(), world.contacts()
            builtin_n, builtin_t = _builtin(contacts, ratio, warm)
            problem = StepProblem._from_world(bodies, contacts, dt=scene.dt, gravity=self.gravity,
                                              block_solve=scene.solver.block_solve,
                                              velocity_iterations=self.settings.max_iterations)
            start_n, start_t = self._posed_start(bodies, contacts, problem, builtin_n, builtin_t)
        else:
            start_n = start_t = np.zeros(0)
        out = self._applying(warm, pgs_finish, world, self.step_settings, start_n, start_t)
        self.first = False
        solution = None if out is None else Solution.from_native(out, w)
        deepest = 0.0 if out is None else out["deepest"]
        return LoopStep(None, None, solution, deepest, dt_ratio=float(ratio))

    def _asked(self, bodies, contacts, problem, builtin_n, builtin_t):
        """(the problem to solve, start_fn's start held as solve holds it, as the posed step holds
        it) for the step in pieces: the problem's start Box2D's warm start (what a plug-in method is
        sent with it), solved as it was before the start was asked (_private)."""
        problem.start_normal, problem.start_tangent = builtin_n, builtin_t
        solved = _private(problem)
        return (solved, *self._ask(bodies, contacts, problem, builtin_n, builtin_t))

    def _ask(self, bodies, contacts, problem, builtin_n, builtin_t):
        """start_fn's start, held to solve's rule (both paths)."""
        start_n, start_t = self.start_fn(bodies, contacts, problem, builtin_n, builtin_t)
        return start_impulses(problem, start_n, start_t)

    def _posed_start(self, bodies, contacts, problem, builtin_n, builtin_t):
        """start_fn's start for the posed step, as the step in pieces has it: the problem's start
        Box2D's warm start, the start held to solve's rule, and a world gone non-finite refused as
        solve refuses it (pgs_finish would step it on)."""
        problem.start_normal, problem.start_tangent = builtin_n, builtin_t
        start_n, start_t = self._ask(bodies, contacts, problem, builtin_n, builtin_t)
        # (the bodies' state, what a step can make non-finite, in one sum: NaN or inf in any of it
        # makes it so; a sum that overflows only costs the check)
        if not math.isfinite(sum(float(bodies[k].sum()) for k in ("angle", "center", "velocity", "omega"))):
            check_solvable(problem)
        return start_n, start_t

    def _python_step(self):
        world, scene, o = self.world, self.scene, self.settings
        bodies = world.bodies()
        world.collide()
        contacts = world.contacts()
        ratio, warm = self._carried_scale(), world.warm_starting
        builtin_n, builtin_t = _builtin(contacts, ratio, warm)
        problem = None
        if len(contacts["manifold"]):
            problem = StepProblem._from_world(bodies, contacts, dt=scene.dt, gravity=self.gravity,
                                              block_solve=scene.solver.block_solve,
                                              velocity_iterations=o.max_iterations)
        # (measured before a start made in Python is handed the contacts)
        deepest = max(0.0, float(-contacts["separation"].min())) if len(contacts["separation"]) else 0.0
        if self.start_fn is not None:
            start_n, start_t = (np.zeros(0), np.zeros(0))
            if problem is not None:
                problem, start_n, start_t = self._asked(bodies, contacts, problem, builtin_n, builtin_t)
        elif self.start == "builtin":
            start_n, start_t = builtin_n, builtin_t
        elif self.start == "garbage":
            start_n = np.resize(GARBAGE, len(builtin_n))
            start_t = np.roll(start_n, 1)
        else:
            start_n = np.zeros_like(builtin_n)
            start_t = np.zeros_like(builtin_t)
        solution = None
        if problem is not None:
            w = self.relaxation(problem, start_n, start_t) if callable(self.relaxation) else self.relaxation
            # (the world's carried state, as the native step offers it: the two paths agree)
            solution = (solve(problem, start_n, start_t, settings=o.but(relaxation=w), carry=world,
                              final_residual=self.residual)
                        if self.solve_fn is None else self.solve_fn(problem, start_n, start_t, o.but(relaxation=w)))
            world.set_manifold_impulses(solution.normal_impulse.astype(np.float32),
                                        solution.tangent_impulse.astype(np.float32))
        world.inv_dt0 = self.inv_dt
        self.first = False
        # (collided: Box2D's Step skips its own Collide, which would rebuild the same manifolds)
        out = self._applying(warm, world.step, scene.dt, 0, scene.solver.position_iterations, record=self.record,
                             collided=True)
        if not self.record:
            return LoopStep(None, None, solution, deepest, dt_ratio=float(ratio))
        before, recorded = out
        # What Box2D applied is what we wrote; record our start as the step's start.
        # (a garbage start is recorded as sanitised: no NaN ever reaches a file)
        used_n, used_t = (start_n, start_t) if self.start != "garbage" else (np.zeros_like(builtin_n),) * 2
        # (the rows Box2D's step recorded may not be the ones collided: a body placed since the last
        # step gave its Step pairs of its own; then, as the native step records it, no start)
        n = len(recorded["normal_impulse"])
        if len(used_n) != len(builtin_n) or len(used_n) != n:
            used_n = used_t = np.zeros(n)
        recorded["start_normal_impulse"] = used_n.astype(np.float32)
        recorded["start_tangent_impulse"] = used_t.astype(np.float32)
        return LoopStep(before, recorded, solution, deepest, dt_ratio=float(ratio))
