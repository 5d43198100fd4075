"""The solve in body space (accelerate="bodyspace"): augmented-Lagrangian iterations on the
bodies' velocities after a few sweeps, checked against the explicit LCP in Python, its work
counted, in the loop and in a step file."""
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


def zero(p):
    return np.zeros(p.points)


@pytest.fixture(scope="module")
def solved():
    return [solve(p, zero(p), zero(p), tolerance=1e-8, max_iterations=20_000, accelerate="bodyspace") for p in SAMPLE]


def test_its_answers_are_judged_by_the_explicit_lcp_and_reach_the_tolerance(solved):
    for p, s in zip(SAMPLE, solved):
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
    global_work = 0
    for p, s in zip(SAMPLE, solved):
        # one factorization per Newton iteration, and Newton iterations only inside outer ones
        assert s.factorizations == s.newton_iterations
        assert s.newton_iterations == 0 or s.outer_iterations >= 1
        # an outer iteration is an iteration of the cap, as a sweep is
        assert s.iterations >= s.outer_iterations
        global_work += s.outer_iterations
    assert global_work > 0   # (the sample needs more than the first sweeps)


def test_without_a_tolerance_it_solves_to_1e_12_or_says_why_not():
    p = SAMPLE[4]   # the stack
    s = solve(p, zero(p), zero(p), max_iterations=20_000, accelerate="bodyspace")
    assert s.residual < 1e-12
    capped = solve(SAMPLE[2], zero(SAMPLE[2]), zero(SAMPLE[2]), tolerance=1e-12, max_iterations=6, accelerate="bodyspace")
    assert capped.iterations == 6 and capped.residual > 1e-12   # the cap holds, and the report says where it ended


def test_from_an_exact_answer_it_does_no_work():
    p = SAMPLE[2]
    exact = solve(p, zero(p), zero(p), tolerance=1e-10, max_iterations=20_000, accelerate="bodyspace")
    again = solve(p, exact.normal_impulse, exact.tangent_impulse, tolerance=1e-8, max_iterations=100, accelerate="bodyspace")
    assert again.iterations == 0 and again.factorizations == 0 and again.residual == pytest.approx(exact.residual)


def test_in_the_loop_its_step_files_validate_and_carry_its_work(tmp_path):
    out = tmp_path / "run"
    r = dc("simulate", "pyramid", "--param", "base=4", "--steps", "30", "--solver", "pgs", "--accelerate", "bodyspace",
           "--start", "zero", "--tolerance", "1e-8", "--max-iterations", "2000", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert dc("validate", str(out)).returncode == 0
    solves = [read_step(f)[0]["solve"] for f in sorted((out / "seed-000000").glob("step-*.xml"))]
    assert all(s["accelerate"] == "bodyspace" for s in solves)
    assert all(float(s["residual"]) < 1e-8 for s in solves)
    assert sum(int(s["outer_iterations"]) for s in solves) > 0
    assert all(int(s["factorizations"]) == int(s["newton_iterations"]) for s in solves)
    option_error(dc("simulate", "pyramid", "--solver", "pgs", "--mode", "float32", "--accelerate", "bodyspace",
                    "-o", str(tmp_path / "bad")), "float64 only")


def test_the_reference_ends_with_it_and_is_exact_on_a_settling_pyramid_step():
    """Step 8 of the base-20 pyramid: too wide to pivot, and Newton stalls on it (docs/results.md);
    the reference's last stage, the solve in body space, is exact."""
    from deepcontact.solver.reference import reference_solution
    p, = problems("pyramid", dict(base=20), (8,))
    r = reference_solution(p)
    assert r.residual < 1e-12
    assert r.outer_iterations > 0 and not r.pivoted   # it was the solve in body space that got there
    lcp = L.build_lcp(p)
    assert L.natural_residual(lcp, r.normal_impulse, r.tangent_impulse) / np.abs(lcp.b).max() < 1e-11
