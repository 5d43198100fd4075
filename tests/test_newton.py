"""The global step: proximal semismooth Newton (accelerate="newton") and its inexact variant with
conjugate gradients (accelerate="subspace"), checked against the explicit LCP in Python."""
import numpy as np
import pytest

from conftest import dc, option_error, step_problems
import reference_lcp as L
from deepcontact.solver.pgs import solve


def problems(generator, params, wanted):
    return step_problems(generator, params, wanted)


def problems_of_seed(generator, seed, params, wanted):
    return step_problems(generator, params, wanted, seed)


SAMPLE = (problems("pile", dict(count=30, box=16.0, sigma=4.0), (100, 200, 300))
          + problems("pyramid", dict(base=8), (5, 100)) + problems("stack", dict(count=8), (50,)))


def zero(p):
    return np.zeros(p.points)


@pytest.fixture(scope="module")
def solved():
    return [solve(p, zero(p), zero(p), tolerance=1e-12, max_iterations=20_000, accelerate="newton") for p in SAMPLE]


def test_newton_is_exact_where_it_says_so_and_says_so_where_it_is_not(solved):
    exact = 0
    for p, s in zip(SAMPLE, solved):
        # the residual recomputed on the explicit LCP in Python, from the impulses alone
        lcp = L.build_lcp(p)
        python = L.natural_residual(lcp, s.normal_impulse, s.tangent_impulse) / np.abs(lcp.b).max()
        assert python == pytest.approx(s.residual, rel=1e-3, abs=1e-12), p.index
        if s.residual < 1e-12:
            exact += 1
            # plain PGS from zero needs far more sweeps to get there (or never does)
            plain = solve(p, zero(p), zero(p), tolerance=1e-12, max_iterations=20_000)
            assert s.iterations < plain.iterations and s.factorizations <= 60, p.index
        else:   # a stall near, not at, a solution: the sweeps ran to the cap, and the report says so
            assert s.iterations == 20_000 and s.newton_fallbacks > 0, p.index
    assert exact >= len(SAMPLE) - 1   # one small-pile step of six stalls (docs/solver.md)


def test_without_a_tolerance_newton_solves_to_1e_12_and_a_cap_is_reported_not_hidden():
    p = SAMPLE[2]
    assert solve(p, zero(p), zero(p), max_iterations=10_000, accelerate="newton").residual < 1e-12
    capped = solve(p, zero(p), zero(p), tolerance=1e-12, max_iterations=4, accelerate="newton")
    assert capped.iterations == 4
    assert capped.residual < 1e-12 or capped.newton_fallbacks > 0 or capped.factorizations > 0


def test_subspace_minimization_reaches_a_loose_tolerance_and_counts_its_work():
    for p in SAMPLE:
        s = solve(p, tolerance=1e-4, max_iterations=1000, accelerate="subspace")
        assert s.residual < 1e-4, p.index
        assert s.factorizations >= 1 or s.iterations <= 4, p.index   # systems solved, counted


def test_newton_in_the_loop_and_its_options(tmp_path):
    r = dc("simulate", "pyramid", "--param", "base=4", "--steps", "30", "--solver", "pgs", "--accelerate", "newton",
           "-q", "-o", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "run" / "seed-000000").glob("step-*.xml"))) == 30
    option_error(dc("simulate", "pyramid", "--solver", "pgs", "--mode", "float32", "--accelerate", "newton",
                    "-o", str(tmp_path / "bad")), "float64 only")
    option_error(dc("evaluate", "--no-plots", str(tmp_path / "run"), "--mode", "float32", "--accelerate", "all",
                    "-o", str(tmp_path / "r")), "float64 only")


def test_lemke_solves_the_friction_lcp_of_a_step_to_machine_precision():
    from deepcontact.solver import local as fclib, pivoting
    for p in SAMPLE[:2] + SAMPLE[-1:]:
        lp = fclib.local_problem(p)
        M, q = pivoting.friction_lcp(lp)
        z = pivoting.lemke(M, q)
        assert z is not None
        w = M @ z + q
        assert z.min() >= 0 and w.min() >= -1e-9 * np.abs(q).max() and abs(z @ w) <= 1e-9 * np.abs(q).max() ** 2
        pair = pivoting.StepPivots(p).whole()
        assert fclib.residual(lp, lp.reaction(*pair)) < 1e-9


def test_native_lemke_agrees_with_the_tableau_where_the_answer_is_unique():
    from deepcontact.solver import pivoting
    rng = np.random.default_rng(7)
    for n in (1, 5, 40):
        A = rng.standard_normal((n, n))
        M = A @ A.T + 0.1 * np.eye(n)          # positive definite: one solution
        q = rng.standard_normal(n)
        native, tableau = pivoting.lemke(M, q), pivoting.lemke_tableau(M, q)
        assert native is not None and tableau is not None
        w = M @ native + q
        assert native.min() >= 0 and w.min() >= -1e-9 and abs(native @ w) <= 1e-9
        np.testing.assert_allclose(native, tableau, atol=1e-9)
    assert pivoting.lemke(np.eye(3), np.ones(3)).tolist() == [0.0, 0.0, 0.0]   # q >= 0: z = 0
    z, pivots = pivoting.native_lemke(-np.eye(2), -np.ones(2), 100)   # w = -z - 1: no solution, a ray
    assert z is None and pivots >= 1
    with pytest.raises(ValueError, match="M must be 3 x 3"):
        pivoting.native_lemke(np.eye(2), np.ones(3), 10)


HELD_OUT = problems_of_seed("pile", 1000, {}, (245, 275))


def test_the_reference_pivots_where_newton_stalls_and_reaches_1e_12():
    """Held-out pile steps on which Newton alone settles at a residual of 1e-7 (docs/solver.md):
    Lemke on the neighbourhood of the contacts carrying that residual, then Newton, is exact (step
    245); on a step degenerate for Lemke (275: a ray on the whole step), with q perturbed."""
    from deepcontact.solver import pivoting, reference
    from deepcontact.solver.local import local_problem
    for p in HELD_OUT:
        newton = solve(p, zero(p), zero(p), tolerance=1e-12, max_iterations=reference.FIRST_SWEEPS,
                       accelerate="newton")
        assert newton.residual > 1e-9, p.index
        lp = local_problem(p)
        near = pivoting.StepPivots(p).neighbourhood(lp.reaction(newton.normal_impulse, newton.tangent_impulse), 1, 0.1)
        assert 0 < len(near) < p.points / 2, p.index    # a neighbourhood, not the step
        r = reference.reference_solution(p)
        assert r.residual < 1e-12 and r.pivoted, p.index
        assert r.iterations > newton.iterations and r.factorizations > newton.factorizations   # all the work counted


def test_a_neighbourhood_grows_through_dynamic_bodies_only():
    from deepcontact._box2d import contact_rows
    from deepcontact.solver import pivoting
    from deepcontact.solver.local import local_problem, point_residuals
    p = HELD_OUT[0]
    s = solve(p, zero(p), zero(p), tolerance=1e-12, max_iterations=300, accelerate="newton")
    lp = local_problem(p)
    r = lp.reaction(s.normal_impulse, s.tangent_impulse)
    f = point_residuals(lp, r)
    step = pivoting.StepPivots(p)
    worst = step.neighbourhood(r, rings=0, share=1.0)
    assert list(worst) == list(np.nonzero(f == f.max())[0])
    rows = contact_rows(p.bodies, p.contacts, p.settings(prune=False))
    a, b = rows["row_a"][lp.points], rows["row_b"][lp.points]
    dynamic = set(np.nonzero(p.bodies["type"] == 2)[0]) & (set(a[worst]) | set(b[worst]))
    ring = step.neighbourhood(r, rings=1, share=1.0)
    assert set(worst) < set(ring)
    assert set(ring) == set(np.nonzero(np.isin(a, list(dynamic)) | np.isin(b, list(dynamic)))[0]) | set(worst)


def test_a_perturbed_pivot_is_reproducible():
    from deepcontact.solver import pivoting
    p = HELD_OUT[1]
    first, second = pivoting.StepPivots(p).whole(perturb=1e-12), pivoting.StepPivots(p).whole(perturb=1e-12)
    assert first is not None
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1], second[1])
