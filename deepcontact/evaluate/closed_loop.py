"""Closed loop: each start drives the simulation through the project's solver.

Unlike replay, errors feed back: a start that leaves the solver short of the answer changes the
next state. Every start runs the same scene from the same initial state under the same stopping
rule; the reference trajectory is the one stepped with each step's reference solution (float64
PGS to a residual of 1e-12). Reported per start: iterations per step, time per step (prediction
included), how far the bodies drift from the reference trajectory, the deepest contact, and
whether anything became non-finite.
"""
import time
from dataclasses import dataclass

import numpy as np

from ..simulate.build import build_world
from ..simulate.pgs_loop import LoopOptions, PGSStepper
from ..solver.problem import contact_keys
from ..solver.reference import reference_solution
from .starts import StepContext

NEEDS_REFERENCE = ("copy", "copy2", "copy0", "sph", "random")


@dataclass
class LoopResult:
    start: str
    steps: int
    iterations: np.ndarray
    ms_per_step: np.ndarray
    predict_ms: np.ndarray
    drift: np.ndarray          # max over bodies of |position - reference position|, per step
    penetration: float
    finite: bool


def _adapter(name, start, timing):
    previous = {"keys": set()}

    def start_fn(bodies, contacts, problem, builtin_n, builtin_t):
        problem.start_normal, problem.start_tangent = builtin_n, builtin_t
        keys = contact_keys(contacts)
        persisted = np.array([k in previous["keys"] for k in keys], dtype=bool)
        previous["keys"] = set(keys)
        reference = reference_solution(problem) if name in NEEDS_REFERENCE else None
        value = start(StepContext(problem=problem, bodies=bodies, contacts=contacts, reference=reference,
                                  persisted=persisted))
        timing.append(sum(value.seconds.values()))
        return value.normal, value.tangent
    return start_fn


def run_loop(scene, start_fn, options, steps):
    world = build_world(scene)
    stepper = PGSStepper(world, scene, options, start_fn=start_fn)
    removals = {e.step: e.body for e in scene.events}
    positions, iterations, seconds, deepest, finite = [], [], [], 0.0, True
    for k in range(steps):
        if k in removals:
            world.remove_body(removals[k])
        t0 = time.perf_counter()
        _, contacts, solution = stepper.step()
        seconds.append(time.perf_counter() - t0)
        iterations.append(0 if solution is None else solution.iterations)
        b = world.bodies()
        if not (np.all(np.isfinite(b["position"])) and np.all(np.isfinite(b["velocity"]))):
            finite = False
            break
        if len(contacts["separation"]):
            deepest = max(deepest, float(-contacts["separation"].min()))
        positions.append(b["position"].astype(np.float64).copy())
    return np.array(positions), np.array(iterations), np.array(seconds), deepest, finite


def closed_loop(scene, starts, *, tolerance=1e-4, max_iterations=1000, stop_on="residual", mode="float64",
                steps=None, progress=None):
    steps = steps or scene.steps
    options = LoopOptions(start="builtin", mode=mode, max_iterations=max_iterations, tolerance=tolerance,
                          stop_on=stop_on)
    exact = LoopOptions(start="builtin", mode="float64", max_iterations=100_000, tolerance=1e-12, stop_on="residual")

    def reference_fn(bodies, contacts, problem, builtin_n, builtin_t):
        problem.start_normal, problem.start_tangent = builtin_n, builtin_t
        r = reference_solution(problem)
        return r.normal_impulse, r.tangent_impulse
    ref_positions, *_ = run_loop(scene, reference_fn, exact, steps)
    if progress:
        progress(1)
    results = []
    for name, start in starts.items():
        timing = []
        pos, its, secs, deepest, finite = run_loop(scene, _adapter(name, start, timing), options, steps)
        n = min(len(pos), len(ref_positions))
        drift = np.array([np.abs(pos[k] - ref_positions[k]).max() for k in range(n)])
        results.append(LoopResult(start=name, steps=len(its), iterations=its, ms_per_step=secs * 1e3,
                                  predict_ms=np.array(timing) * 1e3, drift=drift, penetration=deepest, finite=finite))
        if progress:
            progress(1)
    return results


def loop_table(results):
    lines = ["| start | steps | median iterations | p80 | max | ms per step (median) | of which prediction | "
             "final drift (m) | max drift (m) | deepest contact (cm) | finite |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in results:
        it = r.iterations[r.iterations > 0] if np.any(r.iterations > 0) else r.iterations
        pred = float(np.median(r.predict_ms)) if len(r.predict_ms) else 0.0
        lines.append(f"| {r.start} | {r.steps} | {np.median(it):.0f} | {np.percentile(it, 80):.0f} | {it.max():.0f} | "
                     f"{np.median(r.ms_per_step):.2f} | {pred:.2f} | {r.drift[-1] if len(r.drift) else float('nan'):.3g} | "
                     f"{r.drift.max() if len(r.drift) else float('nan'):.3g} | {100 * r.penetration:.2f} | "
                     f"{'yes' if r.finite else 'NO'} |")
    return "\n".join(lines)
