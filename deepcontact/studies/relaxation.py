"""Time to the same accuracy: Box2D's warm start against over-relaxation, conjugate directions
(NNCG) and the prev start.

For the settled half of a scene (steps 300-599, every 10th), each step is solved to a residual of
1e-4 (float64 PGS, cap 1000) from: builtin (Box2D's warm start), builtin with w = 1.7, prev (the
previous step's solution at the tolerance), prev with w = 1.7, builtin with the w `auto` picks,
with NNCG: builtin, builtin at w = 1.3, prev; and with Newton (sweeps, then semismooth Newton
steps): builtin, builtin at w = 1.7, prev at w = 1.7 (their sparse factorizations reported too);
with subspace minimization (Newton's systems solved by conjugate gradients): builtin, builtin at
w = 1.7, prev.
Reported: median sweeps and median measured solve time, each as a ratio to builtin at w = 1 in the
same run (best of --repeats timings per step); and the fixed cost of a solve (the same call with no
sweep: options, the arrays handed over and checked, the problem assembled, the answer handed back),
below which no start can bring a solve.

With --loop: our PGS drives the scene instead (600 steps, residual < 1e-4, cap 1000), where
Box2D's warm start is the previous step's solution at the tolerance; reported are median sweeps and
the median measured time of a whole step (collide, solve, Box2D's position step; one native call),
builtin with w = 1.7, with `auto`, with NNCG and with NNCG at w = 1.3 against builtin, runs
interleaved, best of --repeats per step (auto's trials, every w on the first 8 hard steps and then
one step in 50, included). --seeds 0,1,... pools several trajectories (default 0): the pile is
chaotic, and one trajectory's median says little about the next.

    dc study relaxation [--scene pile|pyramid] [--repeats N] [--loop [--seeds 0,1]]
"""
import statistics
import time

import numpy as np

from ..scene.generators import generate
from ..simulate.problems import problems as step_problems
from ..solver.methods import solve
from ..solver.problem import contact_keys, impulses_by_key
from ..solver.relaxation import AutoRelaxation
from ..solver.settings import SolveSettings
from .text import StudyText

SETTINGS = SolveSettings()   # (float64, to a residual of TOLERANCE within CAP sweeps)


def steps_of(name):
    scene = generate(name, 0, {})
    return [(done.index, problem, contact_keys(done.contacts))
            for done, problem in step_problems(scene, first=299, count=600)]


def timed(problem, n, t, w, repeats, accelerate="none", cap=SETTINGS.max_iterations):
    """(sweeps, best of `repeats` solve times, factorizations); cap=0 times a solve with no sweep."""
    best = float("inf")
    asked = SETTINGS.but(relaxation=w, accelerate=accelerate, max_iterations=cap)
    for _ in range(repeats):
        t0 = time.perf_counter()
        s = solve(problem, n, t, settings=asked, final_residual=False)
        best = min(best, time.perf_counter() - t0)
    return s.iterations, best, s.factorizations


LOOP_VARIANTS = (("builtin", 1.0, "none"), ("builtin@1.7", 1.7, "none"), ("builtin@auto", "auto", "none"),
                 ("builtin+nncg", 1.0, "nncg"), ("builtin+nncg@1.3", 1.3, "nncg"))


def loop(name, repeats, seeds=(0,), out=None):
    """Every variant in the loop on every seed; medians over all steps of all seeds (a pile is
    chaotic: one trajectory's median says little about the next)."""
    seconds, sweeps = {}, {}
    for seed in seeds:
        s, i = loop_one(name, repeats, seed)
        for label in s:
            seconds.setdefault(label, []).extend(s[label])
            sweeps.setdefault(label, []).extend(i[label])
    out(f"{name} seeds {','.join(map(str, seeds))}, our PGS in the loop: {len(seconds['builtin'])} steps, "
          f"residual < {SETTINGS.tolerance:g}, cap {SETTINGS.max_iterations}")
    out(f"{'start':<24} {'median sweeps':>14} {'ratio':>7} {'median ms/step':>15} {'ratio':>7}")
    base_it, base_ms = np.median(sweeps["builtin"]), np.median(seconds["builtin"])
    for label, _, _ in LOOP_VARIANTS:
        it, ms = np.median(sweeps[label]), np.median(seconds[label])
        out(f"{label:<24} {it:>14.0f} {it / base_it:>7.2f} {ms * 1e3:>15.3f} {ms / base_ms:>7.2f}")


def loop_one(name, repeats, seed):
    from deepcontact.simulate.engines import Box2D
    seconds, sweeps = {}, {}
    for _ in range(repeats):
        for label, w, accelerate in LOOP_VARIANTS:
            scene = generate(name, seed, {})
            engine = Box2D(solver=SETTINGS.but(relaxation=w, accelerate=accelerate))
            stepper = engine.stepper(engine.build(scene), scene, record=False)
            times, its = [], []
            for _ in range(scene.steps):
                t0 = time.perf_counter()
                solution = stepper().solution
                times.append(time.perf_counter() - t0)
                its.append(0 if solution is None else solution.iterations)
            seconds[label] = np.minimum(seconds[label], times) if label in seconds else np.array(times)
            sweeps[label] = its
    return {k: list(v) for k, v in seconds.items()}, sweeps


def run(scene="pile", repeats=3, loop_seeds=None, out=None) -> StudyText:
    """The study's table (a StudyText; `out` one to add to): replay of the scene's settled steps,
    or with loop_seeds (a list of seeds) our PGS driving the scene, pooled over those seeds."""
    out = StudyText() if out is None else out
    if loop_seeds:
        loop(scene, repeats, list(loop_seeds), out)
        return out
    steps = steps_of(scene)
    tuner = AutoRelaxation(SETTINGS)
    for _, p, _ in steps[::max(1, len(steps) // 32)]:
        if not tuner.tuned:
            tuner(p, p.start_normal, p.start_tangent)
    rows = {name: [] for name in ("builtin", "builtin@1.7", f"builtin@auto({tuner.w:g})", "prev", "prev@1.7",
                                  "builtin+nncg", "builtin+nncg@1.3", "prev+nncg",
                                  "builtin+newton", "builtin+newton@1.7", "prev+newton@1.7",
                                  "builtin+subspace", "builtin+subspace@1.7", "prev+subspace",
                                  "no sweep (fixed cost)")}
    for (k0, p0, keys0), (k, p, keys) in zip(steps, steps[1:]):
        if k != k0 + 1 or (k - 300) % 10:
            continue
        s0 = solve(p0, settings=SETTINGS)
        previous = impulses_by_key(keys0, s0.normal_impulse, s0.tangent_impulse)
        pn, pt = (np.array(v) for v in zip(*[previous.get(key, (0.0, 0.0)) for key in keys]))
        starts = {"builtin": (p.start_normal, p.start_tangent, 1.0, "none"),
                  "builtin@1.7": (p.start_normal, p.start_tangent, 1.7, "none"),
                  f"builtin@auto({tuner.w:g})": (p.start_normal, p.start_tangent, tuner.w, "none"),
                  "prev": (pn, pt, 1.0, "none"), "prev@1.7": (pn, pt, 1.7, "none"),
                  "builtin+nncg": (p.start_normal, p.start_tangent, 1.0, "nncg"),
                  "builtin+nncg@1.3": (p.start_normal, p.start_tangent, 1.3, "nncg"),
                  "prev+nncg": (pn, pt, 1.0, "nncg"),
                  "builtin+newton": (p.start_normal, p.start_tangent, 1.0, "newton"),
                  "builtin+newton@1.7": (p.start_normal, p.start_tangent, 1.7, "newton"),
                  "prev+newton@1.7": (pn, pt, 1.7, "newton"),
                  "builtin+subspace": (p.start_normal, p.start_tangent, 1.0, "subspace"),
                  "builtin+subspace@1.7": (p.start_normal, p.start_tangent, 1.7, "subspace"),
                  "prev+subspace": (pn, pt, 1.0, "subspace")}
        for name, (n, t, w, accelerate) in starts.items():
            rows[name].append(timed(p, n, t, w, repeats, accelerate))
        rows["no sweep (fixed cost)"].append(timed(p, None, None, 1.0, repeats, cap=0))
    base_it = statistics.median(i for i, _, _ in rows["builtin"])
    base_s = statistics.median(s for _, s, _ in rows["builtin"])
    out(f"{scene}: {len(rows['builtin'])} settled steps, residual < {SETTINGS.tolerance:g}, "
        f"cap {SETTINGS.max_iterations}")
    out(f"{'start':<24} {'median sweeps':>14} {'ratio':>7} {'median ms':>10} {'ratio':>7} {'factorizations':>15}")
    for name, r in rows.items():
        it = statistics.median(i for i, _, _ in r)
        ms = statistics.median(s for _, s, _ in r)
        fact = statistics.median(f for _, _, f in r)
        out(f"{name:<24} {it:>14.0f} {it / base_it:>7.2f} {ms * 1e3:>10.3f} {ms / base_s:>7.2f} {fact:>15.0f}")
    return out
