"""Replay fidelity: re-solve every recorded step in Box2D-exact mode from the recorded start with
the recorded iteration count, and compare with the impulses Box2D produced."""
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..step.reader import check_origin, read_step
from ..step.run_folder import read_run
from .pgs import solve
from .problem import StepProblem


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
    run = read_run(run_dir, solver="box2d", purpose="--replay checks runs stepped by Box2D's own solver; this "
                   "run used --solver pgs", unfinished=True)
    if not run.step_files:
        raise InputError("no step files found (expected seed-*/step-*.xml)", run_dir)
    return run


def replay_run(run_dir, on_file=None) -> ReplayReport:
    report = ReplayReport(run=str(run_dir))
    for sim, path in ((s, f) for s in replayable_run(run_dir).simulations for f in s.files):
        header, bodies, contacts = read_step(path, validate=False)
        if sim.scene is not None:
            check_origin(header, sim.scene, sim.seed, path)
        problem = StepProblem.from_step(header, bodies, contacts, path)
        if on_file is not None:
            on_file(path)
        if problem.points == 0:
            continue
        s = solve(problem, mode="exact", final_residual=False)
        d = max(float(np.max(np.abs(s.normal_impulse - problem.normal_impulse))),
                float(np.max(np.abs(s.tangent_impulse - problem.tangent_impulse))))
        report.steps += 1
        report.points += problem.points
        if d > 0:
            report.inexact_steps += 1
        if d > report.max_difference or report.worst is None:
            report.max_difference = max(report.max_difference, d)
            report.worst = str(path)
    return report
