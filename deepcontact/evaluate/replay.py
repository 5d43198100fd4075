"""Replay: every recorded step solved from every start (and every over-relaxation w), on the
same problem.

For each step and variant, in the variant's own sandbox (deepcontact/contest): the start is made, then
the variant's method solves from it until the stopping measure falls below the tolerance or the
cap, in one call a step, timed and judged here (no other call of the step for it to answer from
memory; Box2D's warm start runs a second time in a sandbox of its own, the A/A noise floor, asked
exactly as every variant is); a built-in method's
convergence history is traced here, off the clock, from the same start. Recorded per step
and variant: iterations, whether the cap was hit, the history, the final residual, the errors
against the step's reference solution (in impulses, and in body velocities after the solve),
whether the PSOR guard fell back, prediction and solve time, and with `budgets` the measured time
and reached residual of fixed sweep budgets.
"""
import collections
from collections.abc import Callable
import copy
import dataclasses
from dataclasses import dataclass
from pathlib import Path
import pickle

import numpy as np

from .. import arguments, protocol, workers
from ..contest import Contestant, deadline_for, start_all
from ..contest.charge import NullFloors, call_charge, in_call, unasked_pool
from ..contest.client import packed
from ..contest.wire import checked_answer, held_claims, unanswered
from ..errors import InputError
from ..model.arch import NETWORKS
from ..plugins import PluginError
from ..solver.methods import check_plausible, is_native, judge, solve, takes_relaxation
from ..solver.pgs import MEASURES
from ..solver.problem import StepProblem, contact_keys, impulses_by_key
from ..solver.reference import reference_solution
from ..solver.relaxation import AutoRelaxation
from ..solver.settings import SolveSettings
from ..step.reader import check_origin, read_step
from ..step.run_folder import Run, read_run
from ..warmstart.starts import ANSWER_COLUMNS, NAMES, StepContext, held_to_contract


@dataclass
class Row:
    run: str
    seed: int
    step: int
    points: int
    start: str                # the variant's label: the start, and "@w" when relaxed
    iterations: int
    capped: bool
    residual: float
    error: float              # |l - l*| / |l*| over all rows of the step (impulses need not be unique)
    velocity_error: float     # max over bodies of |v - v*| after the solve, m/s (unique only without friction)
    predict_ms: float
    solve_ms: float
    history: np.ndarray       # the stopping measure after each sweep (index 0: before any)
    relaxation: float = 1.0
    fallback: bool = False    # over-relaxation (or acceleration) fell back to plain PGS in this solve
    accelerate: str = "none"
    reference_residual: float = 0.0     # what the step's reference solution reached
    reference_pivoted: bool = False     # the reference got there by a pivot (solver/reference.py)
    budget_ms: np.ndarray = None        # measured time of exactly BUDGETS[i] sweeps (no early stop)
    budget_residual: np.ndarray = None  # the residual after them
    factorizations: int = 0   # sparse systems a global method factorized or solved (newton, subspace)
    above: bool = False       # ended above the tolerance, judged by our residual (not by what the method said)
    solve_ms_again: float = None   # Box2D's warm start only: its A/A twin's solve (its own sandbox), never its time
    predict_ms_again: float = None   # and the twin's start
    transport_ms: float = 0.0  # the null contestant's least solve round trip over the run so far (subtracted)
    setup_ms: float = 0.0      # the variant's import and construction in its sandbox, and what it ran after its
                               # last call, charged (once, not per step)
    left_running: tuple = (0, 0)   # threads and processes the variant's process had running after a call


# Every variant's solve is asked once a step, its one call its time: with no other call of the same
# step, none can be answered from the memory of another (a memo gains nothing, at any threshold).
# Box2D's warm start (timed_twice) runs twice, in two sandboxes, each asked once a step in the
# step's shuffled order like every variant: the two are the noise floor (A/A). (Asking the same
# sandbox a second time after the round measured its second call 3-10% slower than its first on a
# quiet machine, and a plug-in handing back its values 3% slower than the first: an order of the
# calls, not the machine's noise.)

# Fixed sweep budgets for "what accuracy costs in time", each timed on its own.
BUDGETS = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024)


@dataclass
class Variant:
    """One column of the comparison: a start, and the over-relaxation w and acceleration its
    solves use."""
    label: str
    name: str                    # the start's name
    start: object
    relaxation: object = 1.0     # a float, "auto" until resolved, or None for a method that takes no w
    accelerate: str = "none"     # a solver method (solver.methods.SOLVERS)


def timed_twice(v):
    """Whether variant v is Box2D's warm start with plain PGS (w = 1): the yardstick, which runs a
    second time in a sandbox of its own for the A/A noise floor."""
    return v.name == "builtin" and v.relaxation in (1, 1.0) and v.accelerate == "none"


def with_twin(table):
    """(the table and, last, the yardstick's A/A twin (timed_twice): the same variant under its
    own label, in a sandbox of its own; the index of the yardstick, or None where there is none)."""
    yard = next((i for i, v in enumerate(table) if timed_twice(v)), None)
    if yard is None:
        return list(table), None
    # (a label no variant has: a library caller's start labelled "builtin (A/A)" must not share
    # the twin's sandbox, its own left unasked and open)
    labels, label = {v.label for v in table}, table[yard].label + " (A/A)"
    while label in labels:
        label += " (A/A)"
    return [*table, dataclasses.replace(table[yard], label=label)], yard


def variants(starts, relaxations=(1.0,), accelerations=("none",)):
    """Every start with every acceleration and every w; labels are the start names, with "+nncg"
    when accelerated and "@w" unless w is only 1."""
    starts = {name: held_to_contract(name, start) for name, start in starts.items()}
    plain = list(relaxations) == [1.0]
    out, used = [], set()
    for a in accelerations:
        # a plug-in method that takes no w runs once, with no w recorded for it
        for w in relaxations if takes_relaxation(a) else (None,):
            for name, start in starts.items():
                # each variant its own instance of a plug-in start: a stateful one cannot carry what it
                # saw in one variant into another (the built-ins keep no state of their own)
                own = copy.deepcopy(start) if name in used and _plugin(name) else start
                used.add(name)
                out.append(Variant(name + ("" if a == "none" else f"+{a}")
                                   + ("" if plain or w is None else f"@{w if w == 'auto' else _w_text(w)}"),
                                   name, own, w, a))
    labels = [v.label for v in out]
    twice = next((label for label in labels if labels.count(label) > 1), None)
    if twice is not None:   # (a library caller's start named "builtin+nncg" beside builtin with nncg)
        raise InputError(f"two variants would both be labelled {twice!r} (a start's name and another start with a "
                         f"method or a w): every variant's rows, sandbox and report line go by its label")
    return out


def _w_text(w):
    """w as its label gives it: six digits (1.7) where they give w back, else every digit it needs
    (1,1.0000001 read "@1" both, one label for two variants)."""
    short = format(w, "g")
    return short if float(short) == w else repr(float(w))


def _plugin(name):
    return name not in NAMES


def box2d_run(run_dir):
    """A finished run of Box2D's own solver (its warm start is the builtin start), with step files."""
    run = read_run(run_dir, solver="box2d", purpose="evaluate replays runs stepped by Box2D's own solver (its "
                   "warm start is the builtin start)")
    if not run.step_files:
        raise InputError("the run has no step files", run_dir)
    return run


def box2d_runs(runs):
    """Each run (a folder, or a Run already read) read once and checked (box2d_run); a run given
    twice is refused."""
    out, seen = [], set()
    for run in runs:
        read = run if isinstance(run, Run) else box2d_run(run)
        key = Path(read.path).resolve()
        if key in seen:
            raise InputError("this run is given twice", read.path)
        seen.add(key)
        out.append(read)
    return out


def _plan(runs):
    scenes, plan = {}, []
    for run in box2d_runs(runs):
        sims = run.simulations
        scenes[str(run.path)] = sims[0].scene
        for s in sims:
            plan.append((str(run.path), s.seed, s.files, (s.scene, s.engine)))
    if len(set(scenes.values())) > 1:
        raise InputError(f"the runs hold different scenes ({', '.join(sorted(map(str, set(scenes.values()))))}); "
                         f"evaluate one kind of scene at a time")
    return plan


def tune_relaxation(run_dirs, settings: SolveSettings):
    """The w `auto` picks for these runs (solving with `settings`): AutoRelaxation from builtin
    starts, on steps spread evenly over the first simulation (a replay knows the whole run; the
    loop only its past)."""
    tuner = AutoRelaxation(settings)
    _, _, files, _ = _plan(run_dirs)[0]
    stride = max(1, len(files) // (4 * tuner.trial_steps))
    for path in files[stride // 2::stride]:
        problem = StepProblem.from_step_file(path)
        if problem.points:
            tuner(problem, problem.start_normal, problem.start_tangent)
        if tuner.tuned:
            break
    return tuner.w


def previous_solution(before, index, settings: SolveSettings):
    """{contact key: (normal, tangent)} of the step before step `index`, solved from its builtin
    start to the same tolerance: the `prev` start's source. `before` is that step as read
    (header, bodies, contacts, path), or None; a step whose predecessor is not the step just before
    it (the first, or one after a skipped contactless step) gets {}."""
    if before is None or before[0]["index"] != index - 1 or len(before[2]["manifold"]) == 0:
        return {}
    header, bodies, contacts, path = before
    s = solve(StepProblem.from_step(header, bodies, contacts, path), settings=settings)
    return impulses_by_key(contact_keys(contacts), s.normal_impulse, s.tangent_impulse)


def _velocity_error(solution, reference):
    return float(np.sqrt(((solution.velocity - reference.velocity) ** 2).sum(axis=1)).max()) \
        if len(reference.velocity) else 0.0


def visible_context(ctx, traits, label):
    """ctx as a start with these traits may see it: the judge's one description of it
    (Contestant.traits, starts.described), never its process's word on what it asks for."""
    changes = {"variant": label, "cache": {}}
    if not traits["needs_reference"]:
        changes["reference"] = None
    if not traits["needs_recorded"]:
        changes["contacts"] = {k: v for k, v in ctx.contacts.items() if k not in ANSWER_COLUMNS}
        changes["problem"] = unanswered(ctx.problem)
    return dataclasses.replace(ctx, **changes)


def open_contestants(table, settings):
    """([Contestant] in the table's order, the null contestant): one sandbox per variant
    (deepcontact/contest), started side by side, and the null contestant that measures transport
    for all of them; each with the CPU no call can have used set apart (unasked), to be spread."""
    spec, checkpoint, networks = None, None, []
    for v in table:
        inner = getattr(v.start, "start", v.start)
        for obj in (inner, getattr(inner, "cnn", None), *getattr(inner, "candidates", {}).values()):
            predictor = getattr(obj, "predictor", None)
            checkpoint = checkpoint or getattr(predictor, "checkpoint", None)
            if getattr(predictor, "network", None) and not networks:
                networks = [] if predictor.network in NETWORKS.builtin() else [predictor.network]
            spec = spec or getattr(predictor, "spec", None) or getattr(obj, "spec", None)
    made = []
    try:
        for v in table:
            made.append(Contestant(v.label, v.name, v.start, v.accelerate, spec, checkpoint, protocol.threads_asked,
                                   networks, unasked=True))
        made.append(Contestant("(null)", "null", null=True, unasked=True))
    except BaseException:
        for c in made:
            c.close()
        raise
    start_all(made)
    return made[:-1], made[-1]


def evaluate_simulation(task):
    """The rows of one simulation: (run, seed, files, scene), the variants, the solver settings,
    every, seed, budgets. Every variant's calls go to its own sandbox (deepcontact/contest), in an
    order shuffled per step by a fixed seed, each charged here (its wall time or its sandbox's CPU,
    the larger) less the null contestant's round trip of the same request, and its answer judged
    here."""
    (run, sim_seed, files, (scene, engine)), table, settings, every, seed, budgets = task
    asked, yard = with_twin(table)
    made, null = open_contestants(asked, settings)
    contestants = {v.label: c for v, c in zip(asked, made)}
    rows, floors = [], NullFloors()
    try:
        for header, bodies, contacts, path, persisted, earlier in _steps_to_judge(files, scene, engine, sim_seed,
                                                                                   every):
            problem = StepProblem.from_step(header, bodies, contacts, path)
            reference = reference_solution(problem)
            ctx = StepContext(problem=problem, bodies=bodies, contacts=contacts, reference=reference,
                              persisted=persisted, seed=seed, index=int(header["index"]), trajectory="replay",
                              previous=previous_solution(earlier, header["index"], settings))
            order = np.random.default_rng([seed, sim_seed, int(header["index"])]).permutation(len(asked))
            step = _JudgedStep(problem, reference, settings, null, floors, yard, len(table))
            step.start(asked, contestants, ctx, order)
            step.solve(order)
            made_rows = [step.row(i, run, sim_seed, header["index"]) for i in range(len(table))]
            if budgets:
                # (every sandbox asked its budgets, the twin's too, in the step's order: the last one
                # busy before the next step measured quicker in it, so no variant may always be it;
                # the yardstick and its twin, the same start bit for bit, held to one trace)
                pair = {}
                for i in order:
                    measured = _budgets(step.variants[i][1], problem, step.requests[i], step.floor, asked[i].label,
                                        pair if yard is not None and i in (yard, len(table)) else {})
                    if i < len(table):
                        made_rows[i].budget_ms, made_rows[i].budget_residual = measured
            rows.extend(made_rows)
    finally:
        for c in (*contestants.values(), null):
            c.close()
    spread_unasked(rows, contestants, null, contestants[asked[-1].label] if yard is not None else None)
    for row in rows:   # (noticed after any call, ended with its process; the CPU it used after its last call charged)
        c = contestants[row.start]
        row.left_running = tuple(c.left_running)
        row.setup_ms += c.after_s * 1e3
    return rows


def spread_unasked(rows, contestants, null, twin=None):
    """Each variant's CPU that no call can have used (Contestant.outside_s: between its calls, or
    beyond what its granted threads could run in a call; less the null contestant's mean of the
    same as many times: charge.unasked_pool) spread evenly over its rows, with its start's time
    (predict_ms); the yardstick's A/A twin's (its own sandbox) with the twin's start
    (predict_ms_again). contestants: {label: Contestant}."""
    steps = collections.Counter(r.start for r in rows)

    def share(c, n):
        return unasked_pool(c, null) * 1e3 / n
    for row in rows:
        row.predict_ms += share(contestants[row.start], steps[row.start])
        if row.predict_ms_again is not None and twin is not None:
            row.predict_ms_again += share(twin, steps[row.start])


def _steps_to_judge(files, scene, engine, sim_seed, every):
    """(header, bodies, contacts, path, persisted, the step before) of every `every`-th step file
    with contacts, each checked as this simulation's; persisted: which contacts the step before had.
    Each `every`-th step counts one to the progress once judged (or found without contacts): the
    steps between are read for their contacts only, not evaluated."""
    previous, before = set(), None
    for k, path in enumerate(files):
        header, bodies, contacts = read_step(path)   # (held to the schema in the same pass)
        check_origin(header, scene, sim_seed, path, engine)
        keys = contact_keys(contacts)
        persisted = np.array([key in previous for key in keys], dtype=bool)
        previous, earlier, before = set(keys), before, (header, bodies, contacts, path)
        if k % every:
            continue
        if len(contacts["manifold"]):
            yield header, bodies, contacts, path, persisted, earlier
        workers.progress(1)   # (after the yield: the caller has judged the step)


class _JudgedStep:
    """One step put to every variant: each start asked, then every solve asked once, interleaved,
    and each answer judged by our residual."""

    def __init__(self, problem, reference, settings, null, floors, yard=None, twin=None):
        """yard: the index of the yardstick (timed_twice), twin: its A/A twin's (with_twin), or None."""
        self.problem, self.reference, self.settings, self.null = problem, reference, settings, null
        self.floors, self.yard, self.twin = floors, yard, (twin if yard is not None else None)
        self.deadline = deadline_for(problem.points)
        self.variants = {}   # i -> (variant, contestant, normal, tangent, prediction seconds)

    def start(self, table, contestants, ctx, order):
        """Each variant's start for the step, timed less the null contestant's round trip."""
        for i in order:
            v = table[i]
            c = contestants[v.label]
            request = packed({"op": "start", "ctx": visible_context(ctx, c.traits, v.label)})
            # (the null contestant's round trip of the same request, just before: a first touch
            # of the step's bytes, as the variant's call is; a repeat of it measured the
            # null 0.2 ms faster than any real start's call)
            self.null.call(request, self.deadline)
            floor = self.floors.seen("start", in_call(self.null))
            _, _, arrays = c.call(request, self.deadline)
            normal, tangent = checked_answer(v.label, arrays, self.problem.points)
            self.variants[i] = (v, c, normal, tangent, call_charge(*in_call(c), floor))

    def solve(self, order):
        """Every variant's solve from its start (the yardstick's twin's too), asked once, in the
        step's order, with the solve's transport measured before and after them (the least counts)."""
        settings, deadline = self.settings, self.deadline
        self.asked = {i: settings.but(relaxation=v.relaxation, accelerate=v.accelerate)
                      for i, (v, *_) in self.variants.items()}
        sent = pickle.dumps(unanswered(self.problem))
        self.requests = {i: {"op": "solve", "problem": sent, "normal": row[2], "tangent": row[3],
                             "settings": self.asked[i]} for i, row in self.variants.items()}
        wire = {i: packed(r) for i, r in self.requests.items()}
        self.answers = {i: [] for i in self.variants}
        first = next(iter(self.requests))
        self.null.call(wire[first], deadline)
        self.floors.seen("solve", in_call(self.null))
        took = {i: self._asked(i, wire[i]) for i in order}
        self.null.call(wire[first], deadline)
        self.floor = self.floors.seen("solve", in_call(self.null))
        for row in self.variants.values():
            row[1].status()
        self.times = {i: call_charge(*t, self.floor) * 1e3 for i, t in took.items()}

    def _asked(self, i, wire):
        """One solve call of variant i: its answer kept (to be judged) and its (wall, CPU) returned."""
        c = self.variants[i][1]
        _, head, arrays = c.call(wire, self.deadline)
        self.answers[i].append(self._kept(i, head, arrays))
        return in_call(c)

    def _kept(self, i, head, arrays):
        """An answer of variant i as the judge keeps it: its impulses and no other array
        (checked_answer), its claims held to its cap (wire.held_claims) and kept from a plug-in's
        first answer only, the one its history is read from (a built-in's history is the judge's
        own: traced)."""
        v = self.variants[i][0]
        checked_answer(v.label, arrays, self.problem.points, also=("claims",))
        held_claims(v.label, head, arrays, self.asked[i].max_iterations)
        if self.answers[i] or is_native(v.accelerate):
            arrays.pop("claims", None)
        return head, arrays

    def history(self, i, v, normal, tangent, head, arrays, judged):
        """(the stopping measure per iterate, the iterations) of variant i's solve: the judge's own
        solver traced here, untimed (the same iterates), or a plug-in's claims with our residual last."""
        if is_native(v.accelerate):
            traced = self.traced(i, v, normal, tangent)
            return traced.history[:, MEASURES.index(self.settings.stop_on)], traced.iterations
        hist, iterations = arrays.get("claims", np.zeros(0)).copy(), int(head.get("iterations", 0))
        if len(hist):
            hist[-1] = judged[0].residual   # (the last iterate's residual is ours, not its claim)
        return hist, iterations

    def traced(self, i, v, normal, tangent):
        """The judge's own run of variant i's built-in method from its start (untimed, with its
        history), every answer the variant's process gave held to it (same_as_traced)."""
        traced = solve(self.problem, normal, tangent, history=True, settings=self.asked[i])
        for head, arrays in self._all_answers(i):   # (the A/A twin's too: every answer is judged)
            same_as_traced(v.label, v.accelerate, head, arrays, traced)
        return traced

    def _twinned(self, i):
        """Whether variant i is the yardstick with an A/A twin."""
        return i == self.yard and self.twin is not None

    def _all_answers(self, i):
        """Variant i's answers, and for the yardstick its A/A twin's (the same start, bit for bit)."""
        if self._twinned(i):
            twin = self.variants[self.twin]
            row = self.variants[i]
            if not (np.array_equal(twin[2], row[2]) and np.array_equal(twin[3], row[3])):
                raise PluginError(f"the variant {row[0].label!r} made another start in its A/A twin's sandbox: the "
                                  f"yardstick runs twice for the noise floor, and must give the same start, bit for "
                                  f"bit, in either")
            return self.answers[i] + self.answers[self.twin]
        return self.answers[i]

    def row(self, i, run, sim_seed, index):
        """Variant i's Row: every timed answer judged by our residual, the worst of them its own."""
        problem, reference, s = self.problem, self.reference, self.settings
        v, c, normal, tangent, predict_s = self.variants[i]
        answers = self._all_answers(i)
        judged = [judge(problem, *checked_answer(v.label, arrays, problem.points, also=("claims",)))
                  for _, arrays in answers]
        if not is_native(v.accelerate):   # (a plug-in's answer: one a step could need at all?)
            for _, arrays in answers:
                check_plausible(v.accelerate, problem, arrays["normal"], arrays["tangent"])
        worst = max(judged, key=lambda x: x.residual)
        head, arrays = answers[0]
        hist, iterations = self.history(i, v, normal, tangent, head, arrays, judged)
        first = (solve(problem, normal, tangent, mode=s.mode, max_iterations=0).residual
                 if s.stop_on == "residual" else np.nan)
        capped = bool(iterations >= s.max_iterations and (len(hist) == 0 or hist[-1] >= s.tolerance))
        ref = np.concatenate([reference.normal_impulse, reference.tangent_impulse])
        got = np.concatenate([arrays["normal"], arrays["tangent"]])
        return Row(run=run, seed=sim_seed, step=index, points=problem.points, start=v.label,
                   iterations=iterations, capped=capped,
                   above=bool(worst.residual > s.tolerance) if s.stop_on == "residual" and s.tolerance > 0 else capped,
                   residual=worst.residual,
                   error=float(np.linalg.norm(got - ref) / max(np.linalg.norm(ref), 1e-300)),
                   velocity_error=_velocity_error(judged[0], reference),
                   predict_ms=predict_s * 1e3, solve_ms=self.times[i],
                   solve_ms_again=self.times[self.twin] if self._twinned(i) else None,
                   predict_ms_again=self.variants[self.twin][4] * 1e3 if self._twinned(i) else None,
                   history=np.concatenate([[first], hist]),
                   relaxation=None if v.relaxation is None else float(v.relaxation),
                   accelerate=v.accelerate, fallback=bool(head.get("fallback", 0)),
                   reference_residual=reference.residual, reference_pivoted=reference.pivoted,
                   factorizations=int(head.get("factorizations", 0)),
                   transport_ms=self.floor[0] * 1e3, setup_ms=max(c.setup_s - self.null.setup_s, 0.0) * 1e3)


def same_as_traced(label, method, head, arrays, traced):
    """A built-in method's answer from a contestant's process held to the judge's own run of it
    from the same start (traced): the native methods are deterministic, so the same start and
    settings give the same impulses bit for bit, after as many sweeps. One that differs (a start
    that swapped the method in its process for a faster one, whatever count it claims) is one
    line naming the variant, which no verdict then names."""
    differs = [what for what, same in (
        (f"{head.get('iterations', 0)} iterations, not {traced.iterations}",
         head.get("iterations", 0) == traced.iterations),
        ("other impulses", np.array_equal(arrays["normal"], traced.normal_impulse)
         and np.array_equal(arrays["tangent"], traced.tangent_impulse)),
        ("another fallback", head.get("fallback", 0) == int(traced.relaxation_fallback > 0)),
        ("other factorizations", head.get("factorizations", 0) == int(getattr(traced, "factorizations", 0))),
    ) if not same]
    if differs:
        raise PluginError(f"the variant {label!r} answered a solve of the built-in method {method!r} that the judge's "
                          f"own run of it from the same start does not give ({'; '.join(differs)}): a built-in "
                          f"method's answer is the built-in's, bit for bit")


def evaluate(run_dirs: list, starts: dict, *, settings: SolveSettings = SolveSettings(), every: int = 1, seed: int = 0,
             progress: Callable | None = None, relaxations: tuple = (1.0,), budgets: bool = False,
             accelerations: tuple = ("none",), jobs: int = 1) -> list:
    """Rows for every (step, variant): each start with each acceleration and w. Runs must hold
    one kind of scene. settings: what every solve is asked (its mode, tolerance, cap and
    measure; each variant's w and method replace its own).

    budgets: also time exactly BUDGETS[i] sweeps (no early stop) and record the residual reached.
    jobs > 1: simulations side by side in worker processes (the same rows, in the same order; the
    times are each worker's own). progress(n) is called as n more of the evaluated steps (each
    `every`-th step file) are done, in any worker."""
    arguments.starts(starts, "starts")
    every = arguments.whole(every, "every", 1)
    plan = _plan(arguments.paths(run_dirs, "run_dirs", also=Run))   # (folders, or runs already read)
    table = variants(starts, relaxations, accelerations)
    tuned = {}
    for v in table:
        if v.relaxation == "auto":
            if v.accelerate not in tuned:
                tuned[v.accelerate] = tune_relaxation(run_dirs, settings.but(accelerate=v.accelerate))
            v.relaxation = tuned[v.accelerate]
    tasks = [(sim, table, settings, every, seed, budgets) for sim in plan]
    rows = []
    with workers.for_jobs(jobs, tasks, progress) as pool:
        for simulation_rows in pool.imap(evaluate_simulation, tasks):
            rows.extend(simulation_rows)
    if not rows:
        raise InputError("no steps with contacts to evaluate")
    return rows


def _budgets(contestant, problem, request, null, label, traced):
    """Measured: the time of exactly b sweeps for every budget b (no early stop; a global method
    gets b sweeps and the Newton steps between them, a plug-in b iterations), each a call to the
    variant's process timed here less the solve's transport (null), and the residual its answer
    reaches, judged here. Each budget is asked once: a repeat of the same request (the first
    budget was once asked twice, the second call timed) is one a memo answers from its first (the
    tests' `Memo`: 0.42 ms for one sweep, 4.9 ms for two). traced: {budget: the judge's own run},
    filled here, shared by variants asked from the same start."""
    ms, residual = [], []
    for b in BUDGETS:
        asked = request["settings"].but(max_iterations=b, tolerance=0.0)
        _, head, arrays = contestant.call({**request, "settings": asked}, deadline_for(problem.points))
        took = in_call(contestant)
        judged = judge(problem, *checked_answer(label, arrays, problem.points, also=("claims",))).residual
        held_claims(label, head, arrays, b)
        if is_native(asked.accelerate):   # (the judge's own run of the same sweeps, off the clock)
            if b not in traced:
                traced[b] = solve(problem, request["normal"], request["tangent"], settings=asked, final_residual=False)
            same_as_traced(label, asked.accelerate, head, arrays, traced[b])
        ms.append(call_charge(*took, null) * 1e3)
        residual.append(judged)
    return np.array(ms), np.array(residual)
