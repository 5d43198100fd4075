"""Replay: every recorded step solved from every start, on the same problem.

For each step and start: the start is made (its prediction time measured by stage), then the
project's PGS runs from it until the stopping measure falls below the tolerance or the cap, once
with the convergence history recorded and once without, for honest timing. Recorded per step
and start: iterations, whether the cap was hit, the history, the final residual, the error
against the reference solution (relative, in impulses), prediction and solve time.
"""
import time
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..step.run_folder import read_run
from ..solver.pgs import MEASURES, solve
from ..solver.problem import StepProblem, contact_keys
from ..solver.reference import reference_solution
from ..step.reader import read_step
from .starts import StepContext


@dataclass
class Row:
    run: str
    seed: int
    step: int
    points: int
    start: str
    iterations: int
    capped: bool
    residual: float
    error: float              # |l - l*| / |l*| over all rows of the step
    predict_ms: float
    solve_ms: float
    history: np.ndarray       # the stopping measure after each sweep (index 0: before any)


def step_files(run_dir):
    """(manifest, [(seed, step files)]) of a finished run of Box2D's own solver."""
    run = read_run(run_dir, solver="box2d", purpose="evaluate replays runs stepped by Box2D's own solver (its "
                   "warm start is the builtin start)")
    if not run.step_files:
        raise InputError("the run has no step files", run_dir)
    return run.manifest, [(s.seed, s.files) for s in run.simulations]


def evaluate(run_dirs, starts, *, tolerance=1e-4, max_iterations=1000, stop_on="residual", mode="float64",
             every=1, seed=0, progress=None):
    """Rows for every (step, start). Runs must all come from one kind of scene."""
    scenes = {}
    plan = []
    for run in run_dirs:
        manifest, sims = step_files(run)
        scenes[str(run)] = manifest.get("scene")
        for s, files in sims:
            plan.append((str(run), s, files))
    if len(set(scenes.values())) > 1:
        raise InputError(f"the runs hold different scenes ({', '.join(sorted(map(str, set(scenes.values()))))}); "
                         f"evaluate one kind of scene at a time")
    measure = MEASURES.index(stop_on)
    rows = []
    for run, sim_seed, files in plan:
        previous = set()
        for k, path in enumerate(files):
            header, bodies, contacts = read_step(path, validate=False)
            keys = contact_keys(contacts)
            persisted = np.array([key in previous for key in keys], dtype=bool)
            previous = set(keys)
            if k % every or len(contacts["manifold"]) == 0:
                continue
            problem = StepProblem.from_step(header, bodies, contacts, path)
            reference = reference_solution(problem)
            ctx = StepContext(problem=problem, bodies=bodies, contacts=contacts, reference=reference,
                              persisted=persisted, seed=seed)
            ref = np.concatenate([reference.normal_impulse, reference.tangent_impulse])
            for name, start in starts.items():
                value = start(ctx)
                kw = dict(mode=mode, max_iterations=max_iterations, tolerance=tolerance, stop_on=stop_on)
                traced = solve(problem, value.normal, value.tangent, history=True, **kw)
                t0 = time.perf_counter()
                solve(problem, value.normal, value.tangent, final_residual=False, **kw)
                solve_s = time.perf_counter() - t0
                got = np.concatenate([traced.normal_impulse, traced.tangent_impulse])
                hist = traced.history[:, measure]
                # the measure before any sweep exists only for the residual (the others are changes)
                first = (solve(problem, value.normal, value.tangent, mode=mode, max_iterations=0).residual
                         if stop_on == "residual" else np.nan)
                rows.append(Row(run=run, seed=sim_seed, step=header["index"], points=problem.points, start=name,
                                iterations=traced.iterations,
                                capped=bool(traced.iterations >= max_iterations and (len(hist) == 0 or hist[-1] >= tolerance)),
                                residual=traced.residual,
                                error=float(np.linalg.norm(got - ref) / max(np.linalg.norm(ref), 1e-300)),
                                predict_ms=sum(value.seconds.values()) * 1e3, solve_ms=solve_s * 1e3,
                                history=np.concatenate([[first], hist])))
            if progress is not None:
                progress(1)
    if not rows:
        raise InputError("no steps with contacts to evaluate")
    return rows


def summarize(rows, starts, max_iterations):
    """Per start: the distribution of iterations, the share at the cap, times, residual, error."""
    out = {}
    for name in starts:
        rs = [r for r in rows if r.start == name]
        it = np.array([r.iterations for r in rs])
        pred = np.array([r.predict_ms for r in rs])
        sol = np.array([r.solve_ms for r in rs])
        out[name] = {
            "steps": len(rs),
            "iterations_median": float(np.median(it)), "iterations_p80": float(np.percentile(it, 80)),
            "iterations_p95": float(np.percentile(it, 95)),
            "at_cap": float(np.mean([r.capped for r in rs])),
            "predict_ms_median": float(np.median(pred)), "solve_ms_median": float(np.median(sol)),
            "total_ms_median": float(np.median(pred + sol)),
            "residual_median": float(np.median([r.residual for r in rs])),
            "error_median": float(np.median([r.error for r in rs])),
        }
    return out
