"""Hard cases, exact answers: on every hard scene (the stability study's), stepped by Box2D's own
solver and by the project's, each step's reference answer is judged at the residual the
reference reported, and taken as a start it is accepted whole and solved at once. The start check
judges the whole answer (the velocities it gives), never one impulse alone: under a 400:1 mass
ratio, impulses that each would fling a light body balance each other."""
import numpy as np
import pytest

import deepcontact as dc
from conftest import written
from deepcontact.studies.stability import FAST

pytestmark = pytest.mark.study

EXACT = 1e-12
SOLVERS = {"box2d": [], "pgs": ["--solver", "pgs", "--tolerance", "1e-4"]}


# (the bullet's continuous collision is Box2D's own: the project's solver cannot step it)
RUNS = [(case, solver) for case in FAST for solver in sorted(SOLVERS)
        if not (case.generator == "bullet" and solver == "pgs")]


@pytest.mark.parametrize("case, solver", RUNS, ids=[f"{c.label}-{s}" for c, s in RUNS])
def test_the_reference_judge_start_round_trip_holds_on_every_hard_scene(tmp_path, case, solver):
    params = [a for k, v in case.params.items() if k != "steps" for a in ("--param", f"{k}={v}")]
    run = written(tmp_path / "run", "simulate", case.generator, *params, "--steps", "120", *SOLVERS[solver])
    exact = checked = 0
    for path in sorted(run.glob("seed-*/step-*.xml"))[::6]:
        problem = dc.StepProblem.from_step_file(path)
        if not problem.points:
            continue
        ref = dc.reference_solution(problem)
        judged = dc.judge(problem, ref.normal_impulse, ref.tangent_impulse)
        # one residual: the reference's own and the judge's of its answer (the judge applies the
        # impulses to the bodies at once, the solve sweep by sweep: they differ in rounding only)
        assert judged.residual == pytest.approx(ref.residual, rel=1e-6, abs=EXACT), path.name
        again = dc.solve(problem, ref.normal_impulse, ref.tangent_impulse, tolerance=EXACT, max_iterations=1000)
        assert again.sanitized["implausible"] == 0 and again.sanitized["negative"] == 0, (path.name, again.sanitized)
        if ref.residual <= EXACT:
            exact += 1
            assert again.residual <= EXACT and again.iterations <= 1, (path.name, again.residual, again.iterations)
        checked += 1
    assert checked and exact >= 0.9 * checked, (exact, checked)
