"""Stability of the hard scenes (scene/generators.py) under Box2D's solver, ours and Box2D v3's.

Each case runs a scene for its steps with one solver and start, and measures:
  finite       no NaN or inf in any body state or impulse
  penetration  the deepest contact over the last quarter of the run, when the scene has settled:
               -separation (Box2D's skinned surfaces), at most 3 x linear slop. The deepest one
               at any time (impacts, which discrete collision only sees once they overlap) is
               reported beside it, not judged.
  energy rise  total mechanical energy (kinetic + gravitational) above its value at the start, or
               just after the last body removal; allowed: lifting every remaining body by one
               linear slop (what position correction may do), or 0.1% of the energy without gravity
  top drift    stacks only: how far the top box moves from where it started, under 1 cm
  rest         a scene that settles (not the confined circles, not the bullet): every body ends
               slower than 5 cm/s (a body that leaves the scene and falls for ever keeps its energy)
Where a case fails at the scene's iteration count, the iteration count is doubled until it
passes (up to a cap), and that count is recorded: the criteria are never loosened.

    dc study stability [--fast] [-o FILE.md]
"""
import math
import time
from dataclasses import dataclass

import numpy as np

from deepcontact import workers
from deepcontact._box2d import linear_slop
from deepcontact.scene.generators import generate, parameters
from deepcontact.simulate import stepping
from deepcontact.simulate.engines import ENGINES, Box2D
from deepcontact.solver.methods import is_native
from deepcontact.solver.settings import SolveSettings
from deepcontact.solver.metrics import deepest, energy, positions
from deepcontact.studies import units
from .efforts import counted, effort

PENETRATION_LIMIT = 3 * linear_slop
TOP_DRIFT_LIMIT = 0.01
REST_SPEED = 0.05   # m/s: at the end of a scene that settles, every body slower than this
MAX_ITERATIONS = 65536


@dataclass
class Case:
    label: str
    generator: str
    params: dict
    stack_top: bool = False
    rests: bool = True     # the scene settles: every body must be at rest at the end


FULL = [
    Case("stack 20", "stack", dict(count=20), stack_top=True),
    Case("stack 24", "stack", dict(count=24), stack_top=True),
    Case("pyramid 20", "pyramid", dict(base=20)),
    Case("mass ratio 10:1", "mass-ratio", dict(ratio=10.0)),
    Case("mass ratio 100:1", "mass-ratio", dict(ratio=100.0)),
    Case("mass ratio 400:1", "mass-ratio", dict(ratio=400.0)),
    Case("card house 3", "card-house", dict(levels=3)),
    Case("arch 9", "arch", dict(blocks=9)),
    Case("confined 625", "confined", dict(count=625), rests=False),   # (no gravity, no friction)
    Case("warm-start energy", "warm-start-energy", {}),
    Case("bullet", "bullet", {}, rests=False),   # (the shot flies on)
]

FAST = [
    Case("stack 8", "stack", dict(count=8, steps=240), stack_top=True),
    Case("pyramid 6", "pyramid", dict(base=6, steps=240)),
    Case("mass ratio 100:1", "mass-ratio", dict(ratio=100.0, steps=240)),
    Case("mass ratio 400:1", "mass-ratio", dict(ratio=400.0, steps=240)),
    Case("card house 2", "card-house", dict(levels=2, steps=240)),
    Case("arch 5", "arch", dict(blocks=5, steps=240)),
    Case("confined 64", "confined", dict(count=64, steps=240), rests=False),
    Case("warm-start energy", "warm-start-energy", dict(remove_step=60, steps=180)),
    Case("bullet", "bullet", dict(stack=4, steps=120), rests=False),
]

# (solver, start, w, acceleration): Box2D's own, and ours from zero, from Box2D's warm start and
# from garbage, plain, over-relaxed (PSOR at w = 1.7, the best w on the thesis pile in replay) and
# with conjugate directions (NNCG, plain and at w = 1.3, the best in the loop), and with Newton
# steps, subspace minimization or the solve in body space (plain, and with a lagged factor) after
# the sweeps (to 1e-12, the count capping the sweeps); guards included.
RELAXED = 1.7
CONFIGS = [("box2d", "builtin", 1.0, "none"), ("pgs", "zero", 1.0, "none"), ("pgs", "builtin", 1.0, "none"),
           ("pgs", "garbage", 1.0, "none"), ("pgs", "zero", RELAXED, "none"), ("pgs", "builtin", RELAXED, "none"),
           ("pgs", "zero", 1.0, "nncg"), ("pgs", "builtin", 1.0, "nncg"), ("pgs", "builtin", 1.3, "nncg"),
           ("pgs", "zero", 1.0, "newton"), ("pgs", "builtin", 1.0, "newton"), ("pgs", "builtin", 1.0, "subspace"),
           ("pgs", "builtin", 1.0, "bodyspace"), ("pgs", "builtin", 1.0, "lagged"),
           # every other engine registered, at its own default effort (a new engine joins by registering)
           *((name, "builtin", 1.0, "none") for name in ENGINES.builtin() if name != "box2d")]

# An engine with an effort of its own (v3's substeps, pymunk's and MuJoCo's iterations) is doubled from
# its default up to this many times it.
OWN_CAP = 16


@dataclass
class Result:
    case: str
    solver: str
    start: str
    iterations: int
    finite: bool
    penetration: float         # at rest: the last quarter of the run
    peak_penetration: float    # at any time
    energy_rise: float
    energy_allowed: float
    top_drift: float
    sanitized: int
    seconds: float
    final_speed: float = float("nan")   # the fastest dynamic body's speed at the end (m/s): at rest?
    capped: int | None = None           # steps a cap stopped short of the tolerance: the project's sweep cap, or
                                        # an engine's own where it says so (MuJoCo's); None: nothing says
    rests: bool = False                 # the scene settles (Case.rests): final_speed is judged

    @property
    def passed(self):
        return (self.finite and self.penetration <= PENETRATION_LIMIT and self.energy_rise <= self.energy_allowed
                and (math.isnan(self.top_drift) or self.top_drift < TOP_DRIFT_LIMIT)
                and (not self.rests or self.final_speed < REST_SPEED))


def label(start, relaxation, accelerate="none"):
    return start + ("" if accelerate == "none" else f"+{accelerate}") + ("" if relaxation == 1.0 else f"@{relaxation:g}")


def own_rest(case: Case, solver: str) -> dict:
    """The case's parameters with its resting contacts placed where the engine rests them: Box2D
    2.4.1 (and the project's solver, which keeps its position correction) one linear slop into
    each other's skins, the generators' default (a circle on the ground: on the edge itself, its
    skin overlapped whole); Box2D v3 skins touching (overlap 0: v3 pushes any overlap out, which
    would lift a stack from 2.4.1's rest)."""
    if not _engine_class(solver).rests_in_skin and "overlap" in parameters(case.generator) \
            and "overlap" not in case.params:
        return {**case.params, "overlap": 0.0}
    return case.params


def _engine_class(solver):
    """The engine a configuration's solver names (pgs: the project's solver in 2.4.1's loop)."""
    from deepcontact.simulate.engines import ENGINES
    return ENGINES.load("box2d" if solver == "pgs" else solver)


def case_scene(case: Case, warm_starting=True, params=None):
    """The case's scene (seed 0; its parameters, or `params`); warm starting off where asked."""
    scene = generate(case.generator, 0, case.params if params is None else params)
    scene.solver.warm_starting = scene.solver.warm_starting and warm_starting
    return scene


def stepper(scene, solver, start, iterations, relaxation=1.0, accelerate="none", tolerance=0.0, record=True,
            engine_settings=None):
    """(world, step function) of one configuration: pgs (the project's solver, `iterations`
    sweeps at most, stopping at the residual `tolerance` if it is > 0), or an engine's name with its
    effort at `iterations` (efforts.counted: Box2D 2.4.1's velocity iterations, v3's substeps,
    pymunk's and MuJoCo's iterations)."""
    scene.solver.velocity_iterations = iterations
    engine = (Box2D(solver=SolveSettings(mode="float64", max_iterations=iterations, tolerance=tolerance,
                                         relaxation=relaxation, accelerate=accelerate), start=start)
              if solver == "pgs" else counted(_engine_class(solver), iterations, **(engine_settings or {})))
    world = engine.build(scene)
    if solver == "pgs" and not is_native(accelerate):
        # a plug-in method solves in a process of its own (deepcontact.contest), judged there as in dc evaluate
        from deepcontact.contest import RemoteMethod
        from deepcontact.simulate.pgs_loop import PGSStepper
        remote = RemoteMethod(accelerate)
        return world, _Remote(PGSStepper(world, scene, engine.solver, start, record=record, solve_fn=remote.solve).step,
                              remote)
    return world, engine.stepper(world, scene, record=record)


class _Remote:
    """A step function whose solves go to a plug-in's process: `remote.take_transport()` gives the
    round trips of the step just taken, and close() ends the process."""

    def __init__(self, step, remote):
        self.step, self.remote = step, remote

    def __call__(self):
        return self.step()

    def close(self):
        self.remote.close()


def close(step):
    """Ends what a stepper's step function holds (a plug-in method's process), if anything."""
    if isinstance(step, _Remote):
        step.close()


def run_case(case: Case, solver: str, start: str, iterations: int, relaxation=1.0, accelerate="none", *,
             tolerance=0.0, warm_starting=True, trail=None, params=None, engine_settings=None) -> Result:
    """One case under one configuration (see stepper), judged by the criteria, from the engine's
    own rest (own_rest) unless `params` says otherwise. trail: a list to which each step's body
    positions are appended (metrics.positions), for drift."""
    scene = case_scene(case, warm_starting, own_rest(case, solver) if params is None else params)
    world, step = stepper(scene, solver, start, iterations, relaxation, accelerate, tolerance,
                          engine_settings=engine_settings)
    try:
        return _judged(case, scene, world, step, tolerance, iterations, trail, solver, label(start, relaxation, accelerate))
    finally:
        close(step)


def _judged(case, scene, world, step, tolerance, iterations, trail, solver, start_label):
    """run_case's measurement of one stepped run (its criteria)."""
    gravity = scene.effects.gravity or (0.0, 0.0)
    bodies = world.bodies()
    # the top body, by its index: removals shift the rows of the arrays
    top = int(bodies["index"][np.argmax(np.where(bodies["type"] == 2, bodies["center"][:, 1], -np.inf))])
    top_start = bodies["center"][bodies["index"] == top][0].astype(np.float64)

    def allowance(b):
        mass = float(np.sum(b["mass"][b["type"] == 2]))
        if scene.effects.gravity:
            return mass * float(np.hypot(*gravity)) * linear_slop
        return 1e-3 * max(energy(b, gravity), 1e-12)

    baseline, allowed = energy(bodies, gravity), allowance(bodies)
    finite, penetration, peak, drift, sanitized, capped = True, 0.0, 0.0, 0.0, 0, 0
    judged = False   # whether anything said, step by step, if a cap stopped the solve short
    rise, worst_allowed, excess = -np.inf, allowed, -np.inf
    settled = scene.steps - scene.steps // 4

    def rebase(k):   # a removal is an external cause: energy is measured from here on
        nonlocal baseline, allowed
        baseline, allowed = energy(world.bodies(), gravity), allowance(world.bodies())

    t0 = time.perf_counter()
    for done in stepping.steps(world, scene, step, after_removal=rebase):
        k, contacts, solution = done.index, done.contacts, done.solution
        if solution is not None:
            judged = True
            sanitized += sum(solution.sanitized.values())
            capped += tolerance > 0 and solution.iterations >= iterations and not solution.residual <= tolerance
        elif done.engine_stats and "converged" in done.engine_stats:
            judged = True   # (an engine that says whether its own cap stopped it short of its own tolerance)
            capped += not done.engine_stats["converged"]
        bodies = world.bodies()
        if trail is not None:
            trail.append(positions(bodies))
        arrays = [bodies["position"], bodies["velocity"], bodies["omega"], contacts["normal_impulse"],
                  contacts["tangent_impulse"]]
        if not all(np.isfinite(a).all() for a in arrays):
            finite = False
            break
        depth = deepest(contacts)
        peak = max(peak, depth)
        if k >= settled:
            penetration = max(penetration, depth)
        e = energy(bodies, gravity) - baseline
        if e / allowed > excess:
            excess, rise, worst_allowed = e / allowed, e, allowed
        if case.stack_top and np.any(bodies["index"] == top):
            drift = max(drift, float(np.linalg.norm(bodies["center"][bodies["index"] == top][0] - top_start)))
    return Result(case=case.label, solver=solver, start=start_label, iterations=iterations, finite=finite,
                  penetration=penetration, peak_penetration=peak, energy_rise=float(rise),
                  energy_allowed=worst_allowed,
                  top_drift=drift if case.stack_top else float("nan"), sanitized=sanitized,
                  seconds=time.perf_counter() - t0, final_speed=_fastest(bodies) if finite else float("inf"),
                  capped=int(capped) if judged else None, rests=case.rests)


def _fastest(bodies):
    dynamic = bodies["type"] == 2
    if not dynamic.any():
        return 0.0
    return float(np.hypot(*bodies["velocity"][dynamic].astype(np.float64).T).max())


def passing(case, solver, start, relaxation=1.0, first=8, cap=MAX_ITERATIONS, accelerate="none"):
    """(result at the default count, result at the smallest passing count or the cap). Each run
    a unit of work kept (units: a resumed study reuses those it finished)."""
    def run(n):
        return units.kept({"case": case, "run": [solver, start, n, relaxation, accelerate]},
                          lambda: run_case(case, solver, start, n, relaxation, accelerate), Result)
    default = run(first)
    if default.passed:
        return default, default
    n, result = first, default
    while not result.passed and n < cap:
        n *= 2
        result = run(n)
    return default, result


def applicable(case, solver):
    # Our solver cannot drive continuous collision (Box2D's sub-steps solve contacts internally).
    return not (solver == "pgs" and case.generator == "bullet")


def tasks(cases, configs=CONFIGS):
    """(case, configuration) of every run the study makes, in order (what its progress counts)."""
    return [(case, config) for case in cases for config in configs if applicable(case, config[0])]


def study(cases, configs=CONFIGS, log=None, jobs=1, progress=None):
    """(default, found) for every case and applicable configuration, in order; log(row) as each
    row is known; progress(1) as each configuration is done. jobs > 1: configurations side by side
    in worker processes (the same rows)."""
    todo = tasks(cases, configs)
    rows = []
    with workers.for_jobs(jobs, todo, progress) as pool:
        for default, found in pool.imap(_passing, todo):
            rows.append((default, found))
            if log:
                log(format_row(default, found))
    return rows


def _passing(task):
    case, (solver, start, relaxation, accelerate) = task
    first = effort(_engine_class(solver)).default if solver != "pgs" else None
    before = units.measured()
    if first is not None:   # (an engine of its own default effort: from there, doubled up to 16x it)
        found = passing(case, solver, start, relaxation, first=first, cap=OWN_CAP * first)
    else:
        found = passing(case, solver, start, relaxation, accelerate=accelerate)
    workers.progress(1, kept=units.measured() == before)   # (kept: every run of it read back)
    return found


CRITERIA = (
    "A configuration passes a scene when every body state stays finite, the deepest contact over the last "
    "quarter of the run is within 3 linear slops (1.5 cm), no energy is gained beyond the allowance (lifting every "
    "dynamic body by one linear slop, what position correction may do; 0.1% of the energy without gravity), a "
    "stack's top moves less than 1 cm, and, in a scene that settles (every one but the confined circles and the "
    f"bullet), every body ends slower than {REST_SPEED * 100:g} cm/s (a body that leaves the scene falls for "
    "ever without gaining energy). The allowance is the remaining bodies': after a body is removed it is "
    "recomputed, so one scene's rows can show two allowances when their worst moments fall on either side of the "
    "removal. Where a configuration fails at the scene's 8 iterations, the count is doubled until it passes (up "
    f"to {MAX_ITERATIONS:,}); the criteria are never loosened. An engine with an effort of its own counts it from its "
    f"own default up to {OWN_CAP} times it: Box2D v3 (solver box2d3) its substeps from 4, pymunk its iterations from "
    "10, MuJoCo its iterations from 100 (at its tolerance, 1e-8). Box2D v3 and MuJoCo start each scene from their "
    "own rest (resting skins touching, where 2.4.1 and pymunk, whose collision slop is 2.4.1's linear slop, rest "
    "them one linear slop into each other).")


def markdown(rows, fast, protocol_text):
    """stability.md: a heading naming the setting, the criteria, how it was measured, the table."""
    setting = "fast (the test suite's small variants)" if fast else "full"
    return (f"# Stability of the hard scenes: {setting}\n\n{CRITERIA}\n\n{protocol_text}\n\n" + table(rows))


def format_row(default, found):
    passes_at = (str(found.iterations) if found.passed else f"> {found.iterations}")
    r = found
    drift = "" if math.isnan(r.top_drift) else f"{r.top_drift * 100:.2f}"
    return (f"| {r.case} | {r.solver} | {r.start} | {'yes' if default.passed else 'no'} | {passes_at} | "
            f"{r.penetration * 100:.2f} | {r.peak_penetration * 100:.2f} | "
            f"{r.energy_rise:.3g} / {r.energy_allowed:.3g} | {drift} | "
            f"{r.sanitized} |")


HEADER = ("| scene | solver | start | passes at the default (8; v3: 4 substeps; pymunk: 10; MuJoCo: 100) | "
          "passes at (iterations; v3: substeps) | "
          "penetration at rest (cm) | "
          "peak penetration (cm) | energy rise / allowed (J) | top drift (cm) | starts sanitised |\n"
          "| --- | --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: |")


def table(rows):
    """The markdown table of study()'s rows."""
    return HEADER + "\n" + "\n".join(format_row(d, f) for d, f in rows) + "\n"
