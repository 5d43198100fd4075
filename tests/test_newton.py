"""The global step: proximal semismooth Newton (accelerate="newton") and its inexact variant with
conjugate gradients (accelerate="subspace"), checked against the explicit LCP in Python."""
import numpy as np
import pytest

from conftest import dc, option_error
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.solver import lcp as L
from deepcontact.solver.pgs import solve
from deepcontact.solver.problem import StepProblem


def problems(generator, params, wanted):
    scene = generate(generator, 0, params)
    world = build_world(scene)
    out = []
    for k in range(max(wanted) + 1):
        bodies, contacts = world.step(scene.dt, 8, 3, record=True)
        if k in wanted and len(contacts["manifold"]):
            out.append(StepProblem.from_arrays(bodies, contacts, dt=scene.dt, index=k,
                                               gravity=scene.effects.gravity or (0.0, 0.0),
                                               block_solve=scene.solver.block_solve))
    return out


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
    option_error(dc("evaluate", str(tmp_path / "run"), "--mode", "float32", "--accelerate", "all",
                    "-o", str(tmp_path / "r")), "float64 only")


def test_lemke_solves_the_friction_lcp_of_a_step_to_machine_precision():
    from deepcontact.solver import fclib, pivoting
    for p in SAMPLE[:2] + SAMPLE[-1:]:
        lp = fclib.local_problem(p)
        M, q = pivoting.friction_lcp(lp)
        z = pivoting.lemke(M, q)
        assert z is not None
        w = M @ z + q
        assert z.min() >= 0 and w.min() >= -1e-9 * np.abs(q).max() and abs(z @ w) <= 1e-9 * np.abs(q).max() ** 2
        pair = pivoting.pivoted_impulses(p)
        assert fclib.residual(lp, lp.reaction(*pair)) < 1e-9
