"""Replay fidelity: re-solve every recorded step in Box2D-exact mode from the recorded start with
the recorded iteration count, and compare with the impulses Box2D produced."""
from dataclasses import dataclass, field

import numpy as np

from .. import workers
from ..errors import InputError
from ..step.reader import check_origin, read_step
from ..step.run_folder import read_run
from ..solver.pgs import solve
from ..solver.problem import StepProblem


@dataclass
class ReplayReport:
    run: str
    steps: int = 0
    points: int = 0
    max_difference: float = 0.0
    inexact_steps: int = 0
    worst: str = None
    skipped: list = field(default_factory=list)

    @property
    def exact(self):
        return self.max_difference == 0.0


def replayable_run(run_dir):
    """The run --replay checks: finished (its step files checked against the manifest) or not."""
    run = read_run(run_dir, solver="box2d", purpose="--replay checks runs stepped by Box2D's own solver",
                   unfinished=True)
    if not run.step_files:
        raise InputError("no step files found (expected seed-*/step-*.xml)", run_dir)
    return run


def replay_simulation(task):
    """(steps, points, [(difference, path)] of the steps replayed) for one simulation's files."""
    (scene, engine), seed, files = task
    steps = points = 0
    differences = []
    for path in files:
        header, bodies, contacts = read_step(path)
        if scene is not None:
            check_origin(header, scene, seed, path, engine)
        problem = StepProblem.from_step(header, bodies, contacts, path)
        if problem.points == 0:
            continue
        s = solve(problem, mode="exact", final_residual=False)
        d = max(float(np.max(np.abs(s.normal_impulse - problem.normal_impulse))),
                float(np.max(np.abs(s.tangent_impulse - problem.tangent_impulse))))
        steps += 1
        points += problem.points
        differences.append((d, str(path)))
    return steps, points, differences


def replay_run(run_dir, on_file=None, jobs=1) -> ReplayReport:
    """Every step of a run replayed; jobs > 1 replays simulations side by side (same report).
    on_file(path) is called for every step file read."""
    report = ReplayReport(run=str(run_dir))
    tasks = [((sim.scene, sim.engine), sim.seed, sim.files) for sim in replayable_run(run_dir).simulations]
    with workers.for_jobs(jobs, tasks) as pool:
        for task, (steps, points, differences) in zip(tasks, pool.imap(replay_simulation, tasks)):
            report.steps += steps
            report.points += points
            for d, path in differences:   # in step order: the first worst step is named
                if d > 0:
                    report.inexact_steps += 1
                if d > report.max_difference or report.worst is None:
                    report.max_difference = max(report.max_difference, d)
                    report.worst = path
            if on_file is not None:
                for path in task[2]:
                    on_file(path)
    return report
