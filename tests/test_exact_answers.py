"""Hard cases, exact answers: on every hard scene (the stability study's), stepped by Box2D's own
solver and by the project's, each step's reference answer is judged at the residual the
reference reported, and taken as a start it is accepted whole and solved at once. The start check
judges the whole answer (the velocities it gives), never one impulse alone: under a 400:1 mass
ratio, impulses that each would fling a light body balance each other."""
import numpy as np
import pytest

import deepcontact as dc
from conftest import written
from dcstudies.stability import FAST

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


ORACLE_METHOD = """
import numpy as np
import deepcontact as dc
from deepcontact.solver.methods import MethodResult
class Oracle:
    def __call__(self, problem, normal, tangent, settings):
        r = dc.reference_solution(problem)
        return MethodResult(r.normal_impulse, r.tangent_impulse, np.array([r.residual]))
class Flinger:
    def __call__(self, problem, normal, tangent, settings):
        return MethodResult(np.full(problem.points, 1e30), np.zeros(problem.points), np.array([1.0]))
"""


def test_a_method_returning_the_exact_answer_is_accepted_and_one_flinging_bodies_is_not(tmp_path, monkeypatch):
    import sys
    from deepcontact.solver import methods
    (tmp_path / "exact_methods.py").write_text(ORACLE_METHOD)
    monkeypatch.syspath_prepend(str(tmp_path))
    run = written(tmp_path / "run", "simulate", "mass-ratio", "--param", "ratio=400", "--steps", "12")
    try:
        for path in sorted(run.glob("seed-*/step-*.xml"))[3:12]:   # (where the old check zeroed the answer)
            problem = dc.StepProblem.from_step_file(path)
            assert dc.solve(problem, accelerate="exact_methods:Oracle", tolerance=1e-4).residual <= EXACT
        with pytest.raises(dc.InputError, match="no step could need"):
            dc.solve(problem, accelerate="exact_methods:Flinger", tolerance=1e-4)
    finally:
        sys.modules.pop("exact_methods", None)
        methods.SOLVERS._loaded = {k: v for k, v in methods.SOLVERS._loaded.items() if "exact_methods" not in k}
        methods._instances = {k: v for k, v in methods._instances.items() if "exact_methods" not in k}


@pytest.mark.parametrize("column, value", [("inv_mass", 1e30), ("inv_inertia", np.nan), ("velocity", np.inf),
                                           ("inv_mass", -1.0)])
def test_degenerate_values_are_refused_by_every_solve_of_the_step(run, column, value):
    """An edited step's problem (inverse mass 1e30: the solve said 6.6e-7, judge 1) is refused in
    one line by each of solve, judge and the local problem, not solved to two answers."""
    header, bodies, contacts = dc.read_step(run / "seed-000000" / "step-000100.xml")
    bodies = {k: v.copy() for k, v in bodies.items()}
    bodies[column][1] = value
    problem = dc.StepProblem.from_step(header, bodies, contacts)
    zero = np.zeros(problem.points)
    for call in (lambda: dc.solve(problem), lambda: dc.judge(problem, zero, zero), lambda: dc.local_problem(problem)):
        with pytest.raises(dc.InputError, match=column):
            call()
