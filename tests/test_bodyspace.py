"""The solve in body space (accelerate="bodyspace"): augmented-Lagrangian iterations on the
bodies' velocities after a few sweeps, checked against the explicit LCP in Python, its work
counted, in the loop and in a step file; and its lagged variant (accelerate="lagged"), each Newton
system preconditioned by a factor kept from an earlier one (in the native loop, an earlier step)."""
import numpy as np
import pytest

from conftest import dc, option_error, step_problems as problems
import reference_lcp as L
from deepcontact.solver.methods import judge, solve
from deepcontact.step.reader import read_step

# a settling pile (sliding and rolling contacts), a pyramid of boxes from its initial gaps (two-point
# manifolds, the block solver's redundant pairs), a stack, and the 400:1 mass ratio
SAMPLE = (problems("pile", dict(count=30, box=16.0, sigma=4.0), (100, 200)) + problems("pyramid", dict(base=8), (5, 100))
          + problems("stack", dict(count=8), (50,)) + problems("mass-ratio", dict(ratio=400.0), (100,)))


METHODS = ("bodyspace", "lagged")


def zero(p):
    return np.zeros(p.points)


@pytest.fixture(scope="module", params=METHODS)
def solved(request):
    """(the method, its answers on SAMPLE)"""
    return request.param, [solve(p, zero(p), zero(p), tolerance=1e-8, max_iterations=20_000, accelerate=request.param)
                           for p in SAMPLE]


def test_its_answers_are_judged_by_the_explicit_lcp_and_reach_the_tolerance(solved):
    for p, s in zip(SAMPLE, solved[1]):
        lcp = L.build_lcp(p)
        python = L.natural_residual(lcp, s.normal_impulse, s.tangent_impulse) / np.abs(lcp.b).max()
        assert python == pytest.approx(s.residual, rel=1e-3, abs=1e-12), p.index
        assert s.residual < 1e-8, p.index
        assert np.all(s.normal_impulse >= 0) and np.all(np.abs(s.tangent_impulse) <= p_friction(p) * s.normal_impulse + 1e-15)
        # the velocities reported are the ones the impulses give (not the inner iterate's)
        again = judge(p, s.normal_impulse, s.tangent_impulse)
        np.testing.assert_allclose(s.velocity, again.velocity, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s.omega, again.omega, rtol=0, atol=1e-9)


def p_friction(p):
    return np.asarray(p.contacts["friction"], np.float64)


def test_its_work_is_counted(solved):
    method, solved = solved
    global_work = 0
    for p, s in zip(SAMPLE, solved):
        # bodyspace: one factorization per Newton iteration; lagged: one at most (the factor
        # serves later systems); Newton iterations only inside outer ones
        if method == "bodyspace":
            assert s.factorizations == s.newton_iterations
        else:
            assert 1 <= s.factorizations <= s.newton_iterations or s.newton_iterations == 0
        assert s.newton_iterations == 0 or s.outer_iterations >= 1
        # an outer iteration is an iteration of the cap, as a sweep is
        assert s.iterations >= s.outer_iterations
        global_work += s.outer_iterations
    assert global_work > 0   # (the sample needs more than the first sweeps)
    if method == "lagged":   # the factor is kept: far fewer factorizations than systems
        assert sum(s.factorizations for s in solved) * 4 < sum(s.newton_iterations for s in solved)


@pytest.mark.parametrize("method", METHODS)
def test_without_a_tolerance_it_solves_to_1e_12_or_says_why_not(method):
    p = SAMPLE[4]   # the stack
    s = solve(p, zero(p), zero(p), max_iterations=20_000, accelerate=method)
    assert s.residual < 1e-12
    capped = solve(SAMPLE[2], zero(SAMPLE[2]), zero(SAMPLE[2]), tolerance=1e-12, max_iterations=6, accelerate=method)
    assert capped.iterations == 6 and capped.residual > 1e-12   # the cap holds, and the report says where it ended


@pytest.mark.parametrize("method", METHODS)
def test_from_an_exact_answer_it_does_no_work(method):
    p = SAMPLE[2]
    exact = solve(p, zero(p), zero(p), tolerance=1e-10, max_iterations=20_000, accelerate=method)
    again = solve(p, exact.normal_impulse, exact.tangent_impulse, tolerance=1e-8, max_iterations=100, accelerate=method)
    assert again.iterations == 0 and again.factorizations == 0 and again.residual == pytest.approx(exact.residual)


@pytest.mark.parametrize("method", METHODS)
def test_in_the_loop_its_step_files_validate_and_carry_its_work(tmp_path, method):
    out = tmp_path / "run"
    r = dc("simulate", "pyramid", "--param", "base=4", "--steps", "30", "--solver", "pgs", "--accelerate", method,
           "--start", "zero", "--tolerance", "1e-8", "--max-iterations", "2000", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert dc("validate", str(out)).returncode == 0
    solves = [read_step(f)[0]["solve"] for f in sorted((out / "seed-000000").glob("step-*.xml"))]
    assert all(s["accelerate"] == method for s in solves)
    assert all(float(s["residual"]) < 1e-8 for s in solves)
    assert sum(int(s["outer_iterations"]) for s in solves) > 0
    factorizations = [int(s["factorizations"]) for s in solves]
    newton = [int(s["newton_iterations"]) for s in solves]
    if method == "bodyspace":
        assert factorizations == newton
    else:   # the loop carries the factor from step to step: most steps make none
        assert 0 < sum(factorizations) < sum(n > 0 for n in newton) / 2
    option_error(dc("simulate", "pyramid", "--solver", "pgs", "--mode", "float32", "--accelerate", method,
                    "-o", str(tmp_path / "bad")), "float64 only")


def test_the_reference_ends_with_it_and_is_exact_on_a_settling_pyramid_step():
    """Step 8 of the base-20 pyramid: too wide to pivot, and Newton stalls on it (docs/results/);
    the reference's last stage, the solve in body space, is exact."""
    from deepcontact.solver.reference import reference_solution
    p, = problems("pyramid", dict(base=20), (8,))
    r = reference_solution(p)
    assert r.residual < 1e-12
    assert r.outer_iterations > 0 and not r.pivoted   # it was the solve in body space that got there
    lcp = L.build_lcp(p)
    assert L.natural_residual(lcp, r.normal_impulse, r.tangent_impulse) / np.abs(lcp.b).max() < 1e-11


def test_in_replay_each_step_reaches_the_tolerance_and_the_lagged_factor_serves(pile_run, tmp_path):
    """dc evaluate replays every 10th step with both methods (each step cold: replay carries nothing
    from one step to the next)."""
    import csv
    out = tmp_path / "report"
    r = dc("evaluate", "--no-plots", str(pile_run), "--starts", "builtin", "--accelerate", ",".join(METHODS),
           "--tolerance", "1e-6", "--max-iterations", "2000", "--every", "10", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(out / "summary.csv")))
    assert [row["accelerate"] for row in rows] == list(METHODS)
    for row in rows:
        assert float(row["above"]) == 0 and float(row["residual_p95"]) < 1e-6, row["accelerate"]
    bodyspace, lagged = (float(row["factorizations_median"]) for row in rows)
    assert lagged < bodyspace


def test_the_lagged_loop_steps_alike_from_a_python_start_and_from_the_native_one():
    """The same start values through the Python path (a start function: the closed loop's) and
    through the native step: the world's carried factor and penalty serve both, bit for bit."""
    import deepcontact as dcl
    scene = dcl.generate("pile", 0, {"count": "40", "box": "20", "sigma": "3"})

    def run(start_fn):
        settings = dcl.SolveSettings(accelerate="lagged", tolerance=1e-4, max_iterations=1000)
        world = dcl.World(scene, dcl.Box2D(solver=settings, start_fn=start_fn))
        steps = [world.step().solution for _ in range(150)]
        return [(s.iterations, s.normal_impulse.tobytes(), s.tangent_impulse.tobytes()) for s in steps if s is not None]
    native, python = run(None), run(lambda bodies, contacts, problem, n, t: (n, t))
    assert len(native) > 100 and native == python
