"""Closed loop: each start drives the simulation through the project's solver.

Unlike replay, errors feed back: a start that leaves the solver short of the answer changes the
next state. Every variant runs alike: its start (and a plug-in method) in a sandbox of its own
(deepcontact/contest), each step through Python; every call is charged here, as replay's: the
larger of its wall time and its sandbox's CPU in the call, each less the null contestant's least
over the run, and the CPU no call can have used (between calls: work left running; or beyond what
its granted threads could run in a call) spread over its steps (contest/charge.py),
so a start that gives what Box2D's warm start gives measures what builtin does, and work it leaves
running is charged to it, on its typical step too. What the path itself costs over
one native call a step (Python stepping, the request built) is measured and stated. Every start runs the
same scene from the same initial state under the same stopping rule; the reference trajectory is
the one stepped with each step's reference solution (float64 PGS to a residual of 1e-12).
Reported per start: iterations per step, time per step (prediction included), how far the bodies
drift from the reference trajectory, the energy error against it, the deepest contact, and
whether anything became non-finite.

`box2d_iterations` runs the same comparison for Box2D's own solver at fixed velocity iteration
counts: what its accuracy costs in time.
"""
from dataclasses import dataclass, replace

import numpy as np

from .. import arguments, workers
from ..contest import RemoteMethod, deadline_for
from ..contest.charge import StepCharges, unasked_pool
from ..contest.arena import StepChannel
from ..contest.keyed import KeyedImpulses, KeySet
from ..contest.wire import checked_answer
from ..scene.check import check_scene
from ..scene.model import Scene
from ..simulate import stepping
from ..simulate.engines import Box2D
from ..simulate.pgs_loop import PGSStepper
from ..solver.methods import is_native
from ..solver.metrics import drift, energy, positions
from ..solver.reference import reference_solution
from ..solver.settings import SolveSettings
from ..warmstart.starts import ORACLE_TRAITS, StepContext, make_starts
from . import reference_cache
from .reference_cache import Trajectory
from .replay import open_contestants, timed_twice, variants, visible_context


@dataclass
class LoopResult:
    start: str
    steps: int
    iterations: np.ndarray
    ms_per_step: np.ndarray
    predict_ms: np.ndarray     # per step, the start's share of ms_per_step (0 where the step asked it nothing:
                               # no contact point), so that both are taken over the same steps; with the
                               # CPU its sandbox used that no call can have used, spread (contest/charge.py)
    drift: np.ndarray          # max over surviving bodies of |position - reference position|, per step
    penetration: float
    finite: bool
    energy_error: float = float("nan")   # max over steps of |E - E_ref|, relative to |E_ref| at step 0
    relaxation: float = 1.0
    residuals: np.ndarray = None   # per step, the project's residual of the solution applied (NaN: no contact,
                                   # or Box2D's own solver)
    ms_again: np.ndarray = None    # Box2D's warm start only: the same run timed a second time (A/A)
    oracle: bool = False           # the start asks for the step's answer (its description: starts.described)
    ours: bool = True              # the project's solver (False: Box2D's own at k iterations)
    transport_ms: np.ndarray = None   # per step: its wall time not charged (the round trips in it, less its
                                      # calls' charges: contest/charge.py), subtracted
    path_ms: float = 0.0           # the contestants' path's cost a step over the native loop (in ms_per_step)
    setup_ms: float = 0.0          # its contestant's setup, charged (beyond the null contestant's), in its total


class _Adapter:
    """A variant's contestant (its own sandbox: replay.open_contestants) as the loop's start_fn, and
    for a plug-in method as its solve_fn; every call and the null contestant's round trip of the
    same request recorded (contest/charge.py) and charged once the run is over, each answer checked
    and judged here. Remembers the solution applied, for the prev start."""

    def __init__(self, label, contestant, null):
        self.name, self.contestant, self.null = label, contestant, null
        self.setup_ms = max(contestant.setup_s - null.setup_s, 0.0) * 1e3
        self.needs_reference = contestant.traits["needs_reference"]   # (the reference costs a solve a step)
        # (the same description that says what its ctx holds: starts.described)
        self.oracle = any(contestant.traits[k] for k in ORACLE_TRAITS)
        # (the step's contact keys, and those of the step before, as arrays: contest/keyed.py)
        self.keys, self.known, self.previous = None, KeySet(), KeyedImpulses()
        self.charges = StepCharges()
        # per step, once settled: seconds not charged, the CPU no call can have used, the start's charge
        self.transport = self.unasked = self.timing = np.zeros(0)
        self.method = None   # a plug-in method's RemoteMethod, in the same process
        # (its steps' ctx in shared memory; the columns only an oracle sees in an arena of their own)
        self.channel = StepChannel(contestant.traits["needs_reference"] or contestant.traits["needs_recorded"])

    def __call__(self, bodies, contacts, problem, builtin_n, builtin_t):
        problem.start_normal, problem.start_tangent = builtin_n, builtin_t
        self.keys = np.ascontiguousarray(problem.keys, np.int64)
        persisted = self.known.find(self.keys)[0]
        self.known = KeySet(self.keys)
        reference = reference_solution(problem) if self.needs_reference else None
        ctx = StepContext(problem=problem, bodies=bodies, contacts=contacts, reference=reference,
                          persisted=persisted, previous=self.previous, index=int(problem.index),
                          variant=self.name, trajectory="loop")
        # (written once into the variant's shared arenas; read by the null contestant, just before,
        # and by the variant's, each from its own copy: contest/arena.py)
        return self._asked(self.channel.write(visible_context(ctx, self.contestant.traits, self.name)), problem.points)

    def from_world(self, world, carried, points):
        """The start of the step `world` holds (posed), its ctx written straight from the world
        into the channel (StepChannel.write_world: the bytes __call__ writes of it); None where it
        cannot be, and the loop asks __call__."""
        if self.needs_reference:
            return None
        # (the loop poses each step's problem with index 0, and __call__'s ctx takes the problem's)
        done = self.channel.write_world(world, carried, self.known.keys, self.previous, (0, 0))
        if done is None:
            return None
        request, self.keys = done
        self.known = KeySet(self.keys)
        return self._asked(request, points)

    def _asked(self, request, points):
        """The answer to a step's request (written in the channel): the null contestant's round
        trip first, then the variant's, recorded; its impulses checked."""
        deadline = deadline_for(points)
        self.null.call_step(self.channel, request, deadline)
        arrays = self.contestant.call_step(self.channel, request, deadline)[2]
        self.charges.record("start", self.contestant, self.null)
        return tuple(checked_answer(self.name, arrays, points))

    def solve(self, problem, start_n, start_t, settings):
        """A plug-in method's solve, in the contestant's process (RemoteMethod); its answer judged here."""
        if self.method is None:
            self.method = RemoteMethod(settings.accelerate, self.contestant, self.null, self.charges)
        return self.method.solve(problem, start_n, start_t, settings)

    def solved(self, solution):
        self.previous = KeyedImpulses() if solution is None else \
            KeyedImpulses(self.keys, solution.normal_impulse, solution.tangent_impulse)
        self.charges.step_done()   # (a step without contact points asked nothing: charged 0, not left out)

    def settle(self):
        """Once the run is over (the null's least round trips over it known): per step, the
        seconds not charged (transport), the CPU no call can have used (unasked, spread over the
        steps that asked it: contest/charge.py) and the start's charge with it (timing)."""
        self.transport = self.charges.uncharged()
        self.unasked = self.charges.unasked(unasked_pool(self.contestant, self.null))
        self.timing = self.charges.charged(("start",)) + self.unasked


def run_loop(scene, start_fn, settings, steps, start="builtin", solved=None, report=True, solve_fn=None):
    """The scene stepped `steps` times with the project's solver (a SolveSettings) from `start_fn`,
    or, if None, from `start`, in one native call per step. report: each step to workers.progress
    (not for the A/A run, which the progress total does not count). solve_fn: PGSStepper's."""
    engine = Box2D(solver=settings, start=start, start_fn=start_fn)
    world = engine.build(scene)
    stepper = PGSStepper(world, scene, engine.solver, start, start_fn=start_fn, record=False, solve_fn=solve_fn,
                         residual=True)
    return _follow(world, scene, steps, stepper.step, solved, report)


class _Follower:
    """What a loop records of each step it takes (Trajectory), one step at a time (take), so that
    several loops can be stepped in turn."""

    def __init__(self, world, scene, solved=None, report=True):
        self.world, self.gravity, self.solved, self.report = world, scene.effects.gravity or (0.0, 0.0), solved, report
        self.trail, self.energies, self.iterations, self.seconds, self.residuals = [], [], [], [], []
        self.deepest, self.finite = 0.0, True

    def take(self, done):
        """Records the step `done`; False once the bodies are no longer finite (the loop ends)."""
        if self.report:
            workers.progress(1)
        self.seconds.append(done.seconds)
        if self.solved is not None:
            self.solved(done.solution)
        self.iterations.append(0 if done.solution is None else done.solution.iterations)
        self.residuals.append(np.nan if done.solution is None else done.solution.residual)
        b = self.world.bodies()
        if not (np.all(np.isfinite(b["position"])) and np.all(np.isfinite(b["velocity"]))):
            self.finite = False
            return False
        self.deepest = max(self.deepest, done.deepest)
        self.trail.append(positions(b))
        self.energies.append(energy(b, self.gravity))
        return True

    def trajectory(self):
        return Trajectory(self.trail, np.array(self.energies), np.array(self.iterations), np.array(self.seconds),
                          self.deepest, self.finite, np.array(self.residuals, dtype=np.float64))


def _follow(world, scene, steps, step, solved=None, report=True):
    follower = _Follower(world, scene, solved, report)
    for done in stepping.steps(world, scene, step, steps):
        if not follower.take(done):
            break
    return follower.trajectory()


# How the reference trajectory's steps are solved (each from its reference solution): part of the
# key its kept copy is found by (reference_cache.py).
REFERENCE_SETTINGS = SolveSettings(mode="float64", max_iterations=100_000, tolerance=1e-12, stop_on="residual")


def reference_trajectory(scene, steps, report=True):
    """The scene stepped with every step's reference solution (float64 PGS to 1e-12). report: each
    step to workers.progress (a caller that counts other units, a study's settings, says False)."""

    def reference_fn(bodies, contacts, problem, builtin_n, builtin_t):
        r = reference_solution(problem)
        return r.normal_impulse, r.tangent_impulse
    return run_loop(scene, reference_fn, REFERENCE_SETTINGS, steps, report=report)


def _compare(t, ref):
    n = min(len(t.positions), len(ref.positions))
    distance = np.array([drift(t.positions[k], ref.positions[k]) for k in range(n)])
    scale = max(abs(ref.energies[0]), 1e-300) if len(ref.energies) else 1.0
    err = float(np.abs(t.energies[:n] - ref.energies[:n]).max() / scale) if n else float("nan")
    return distance, err


def closed_loop(scene: "Scene", starts: dict, *, settings: SolveSettings = SolveSettings(),
                steps: int | None = None, relaxations: tuple = (1.0,), reference: object = None,
                accelerations: tuple = ("none",)) -> list:
    """Every start (a make_starts table) with every acceleration and w driving the scene from its
    first state for `steps` steps (the scene's by default), each step solved as `settings` asks
    (by default to a residual of TOLERANCE within CAP sweeps; each variant's w and method replace
    its own): one LoopResult each (iterations, times, drift from the reference
    trajectory, penetration, energy, residuals). reference: a reference_trajectory to reuse. Each
    step stepped is reported to workers.progress."""
    arguments.instance(scene, "scene", Scene, "a Scene (read_scene or generate makes one)")
    arguments.instance(settings, "settings", SolveSettings, "a SolveSettings (SolveSettings(tolerance=1e-4), ...)")
    check_scene(scene)   # (what a scene file is held to: an edited scene must not abort in Box2D)
    arguments.starts(starts, "starts")
    steps = scene.steps if steps is None else arguments.whole(steps, "steps", 1)
    ref = reference or reference_trajectory(scene, steps)
    table = variants(starts, relaxations, accelerations)
    runs = [(v, settings.but(relaxation=v.relaxation, accelerate=v.accelerate), True) for v in table]
    runs += [(v, asked, False) for v, asked, _ in runs if timed_twice(v)]   # the noise floor: builtin again (A/A)
    done = _interleaved(scene, runs, steps)
    results = []
    for (v, asked, counted), (t, adapter, ms) in zip(runs, done):
        if not counted:
            continue
        again = next((ms2 for (v2, _, c2), (_, _, ms2) in zip(runs, done) if not c2 and v2 is v), None)
        drift, err = _compare(t, ref)
        results.append(LoopResult(start=v.label, steps=len(t.iterations), iterations=t.iterations,
                                  ms_per_step=ms, predict_ms=np.array(adapter.timing) * 1e3, drift=drift,
                                  penetration=t.deepest, finite=t.finite, energy_error=err,
                                  relaxation=v.relaxation if v.relaxation != "auto" else float("nan"),
                                  residuals=t.residuals, ms_again=again, oracle=adapter.oracle,
                                  transport_ms=np.array(adapter.transport[:len(t.seconds)]) * 1e3,
                                  setup_ms=adapter.setup_ms + adapter.contestant.after_s * 1e3))
    # The path every variant takes (each step through Python, its start's request built and sent)
    # costs what the native loop does not: measured as builtin through it against builtin in one
    # native call per step (the same trajectory, bit for bit) and stated; the variants are
    # compared with it in (all pay it alike), Box2D's own rows are without it.
    fixed = _path_cost(scene, settings, steps, results)
    for r in results:
        r.path_ms = fixed
    return results


def _interleaved(scene, runs, steps):
    """[(trajectory, adapter, ms per step less the round trips, with what its contestant used
    between them)] of each run (variant, its
    settings, whether progress counts it): each variant's start (and a plug-in method) in a
    process of its own, each step through Python, the variants stepped in turn, step by step, in
    an order shuffled per step by a fixed seed, so that a busy moment of the machine, or the
    judge warming up, touches them all alike (run one after the other, the first ran 20-30%
    slower)."""
    loops, contestants, null = [], [], None
    try:
        contestants, null = open_contestants([v for v, _, _ in runs], runs[0][1])
        for (v, asked, counted), contestant in zip(runs, contestants):
            adapter = _Adapter(v.label, contestant, null)
            loops.append(adapter)
            engine = Box2D(solver=asked, start="builtin", start_fn=adapter)
            world = engine.build(scene)
            stepper = PGSStepper(world, scene, engine.solver, "builtin", start_fn=adapter, record=False,
                                 solve_fn=None if is_native(v.accelerate) else adapter.solve, residual=True)
            adapter.follower = _Follower(world, scene, adapter.solved, counted)
            adapter.stepping = stepping.steps(world, scene, stepper.step, steps)
        going = list(range(len(loops)))
        rng = np.random.default_rng(0)
        while going:
            for i in [going[k] for k in rng.permutation(len(going))]:
                done = next(loops[i].stepping, None)
                if done is None or not loops[i].follower.take(done):
                    going.remove(i)
    finally:
        for c in (*contestants, *([null] if null is not None else [])):
            c.close()
        for adapter in loops:
            adapter.channel.close()
    out = []
    for adapter in loops:
        adapter.settle()
        t = adapter.follower.trajectory()
        n = len(t.seconds)
        out.append((t, adapter, (t.seconds - adapter.transport[:n] + adapter.unasked[:n]) * 1e3))
    return out


def _path_cost(scene, settings, steps, results):
    """The median per-step cost (ms) of the contestants' path over the native loop, for builtin
    (the same trajectory both ways, bit for bit: a cost of the path, not of a start)."""
    base = settings.but(relaxation=1.0, accelerate="none")
    native = run_loop(scene, None, base, steps, "builtin", report=False).seconds * 1e3
    plain = next((r.ms_per_step for r in results if r.start == "builtin"), None)
    if plain is None:   # (builtin is not among the variants: through the path once, off the count)
        v = variants(make_starts(["builtin"]))[0]
        plain = _interleaved(scene, [(v, base, False)], steps)[0][2]
    n = min(len(native), len(plain))
    return float(np.median(plain[:n] - native[:n])) if n else 0.0


BOX2D_COUNTS = (1, 2, 4, 8, 16, 32, 64, 128, 256)   # Box2D's own solver's iterations, beside ours


def box2d_iterations(scene, counts=BOX2D_COUNTS, steps=None, reference=None):
    """Box2D's own solver at fixed velocity iteration counts against the reference trajectory:
    drift, energy error and deepest contact, and the measured time per step (a run without
    recording; the contacts come from a second, identical, recorded run)."""
    steps = steps or scene.steps
    ref = reference or reference_trajectory(scene, steps)
    results = []
    for k in counts:
        engine = Box2D(velocity_iterations=k)
        bare, rec = engine.build(scene), engine.build(scene)
        timed = _follow(bare, scene, steps, engine.stepper(bare, scene, record=False))
        recorded = _follow(rec, scene, steps, engine.stepper(rec, scene))
        drift, err = _compare(timed, ref)
        results.append(LoopResult(start=f"box2d {k} iterations", steps=len(timed.positions),
                                  iterations=np.full(len(timed.positions), k), ms_per_step=timed.seconds * 1e3,
                                  predict_ms=np.zeros(0), drift=drift, penetration=recorded.deepest,
                                  finite=timed.finite and recorded.finite, energy_error=err,
                                  residuals=np.full(len(timed.positions), np.nan), ours=False))
    return results


def loop_simulation(task):
    """One simulation's closed-loop rows: every start, and Box2D's iteration counts when asked,
    against one reference trajectory. task: (scene, starts, options, budgets, the folder its
    reference is kept in or None); a function of its own so that worker processes can run
    simulations side by side."""
    scene, starts, options, budgets, kept = task
    steps = options.get("steps") or scene.steps
    reference = (reference_trajectory(scene, steps) if kept is None
                 else reference_cache.cached(scene, steps, kept, REFERENCE_SETTINGS,
                                             lambda: reference_trajectory(scene, steps)))
    results = closed_loop(scene, starts, reference=reference, **options)
    if budgets:
        results += box2d_iterations(scene, steps=steps, reference=reference)
    return results


def steps_stepped(scenes, variants, budgets, steps=None):
    """How many steps every_simulation steps (its progress bar's total): per simulation, the
    reference, each variant, and with budgets Box2D at each iteration count twice (timed, recorded)."""
    per = 1 + variants + (2 * len(BOX2D_COUNTS) if budgets else 0)
    return sum((steps or scene.steps) * per for scene in scenes)


def every_simulation(scenes, starts, *, budgets=False, jobs=1, progress=None, references=None, **options):
    """The closed loop on every scene (one per simulation: its seed's initial state), side by side
    in `jobs` worker processes; returns one list of LoopResult per scene, in order. options:
    those of closed_loop. progress(n): n more steps stepped (steps_stepped in all). references:
    for each scene, the folder its reference trajectory is kept in (reference_cache.py), or None."""
    tasks = [(scene, starts, options, budgets, None if references is None else references[k])
             for k, scene in enumerate(scenes)]
    with workers.for_jobs(jobs, tasks, progress) as pool:
        return list(pool.imap(loop_simulation, tasks))


def pooled(per_simulation):
    """One row per start over every simulation: iterations, times and predictions pooled, the
    drift at each step the largest of any simulation's, the worst penetration and energy error,
    finite only if every simulation stayed finite."""
    rows = []
    for same in zip(*per_simulation):
        n = min(len(r.drift) for r in same)
        rows.append(replace(
            same[0], steps=sum(r.steps for r in same),
            iterations=np.concatenate([r.iterations for r in same]),
            ms_per_step=np.concatenate([r.ms_per_step for r in same]),
            predict_ms=np.concatenate([r.predict_ms for r in same]),
            drift=np.max([r.drift[:n] for r in same], axis=0) if n else np.zeros(0),
            penetration=max(r.penetration for r in same), finite=all(r.finite for r in same),
            energy_error=max(r.energy_error for r in same),
            residuals=_joined(same, "residuals"), ms_again=_joined(same, "ms_again"),
            transport_ms=_joined(same, "transport_ms"), setup_ms=sum(r.setup_ms for r in same)))
    return rows


def _joined(rows, field):
    """The rows' arrays of a field end to end, or None where any row has none."""
    parts = [getattr(r, field) for r in rows]
    return None if any(p is None for p in parts) else np.concatenate(parts)
