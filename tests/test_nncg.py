"""Conjugate directions on top of the sweeps (NNCG): the same answer, fewer sweeps,
always a feasible iterate, refused where Box2D's exact arithmetic is asked for."""
import numpy as np
import pytest
from lxml import etree

from conftest import dc
from deepcontact.errors import InputError
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.simulate.pgs_loop import PGSStepper
from deepcontact.solver.settings import SolveSettings
from deepcontact.solver.pgs import solve
from deepcontact.solver.problem import StepProblem
from deepcontact.solver.reference import reference_solution

SMALL = ["pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4"]
SETTINGS = dict(mode="float64", max_iterations=100_000, tolerance=1e-6, stop_on="residual")


@pytest.fixture(scope="module")
def problems():
    """Settled steps of a small pile and of a pyramid (boxes: the 2x2 block solver)."""
    out = []
    for name, params in (("pile", dict(count=30, box=16.0, sigma=4.0)), ("pyramid", dict(base=6))):
        scene = generate(name, 0, params)
        world = build_world(scene)
        for k in range(240):
            b, c = world.step(scene.dt, 8, 3, record=True)
            if k >= 150 and k % 15 == 0 and len(c["manifold"]):
                out.append(StepProblem.from_arrays(b, c, dt=scene.dt, gravity=scene.effects.gravity))
    return out


def test_nncg_reaches_the_same_velocities(problems):
    # Impulses of redundant contacts are not unique, the velocities after the solve nearly so:
    # NNCG at the tolerance is as close to the reference's velocities as plain PGS there.
    for p in problems:
        s = solve(p, accelerate="nncg", **SETTINGS)
        plain = solve(p, **SETTINGS)
        assert s.residual < 1e-6
        exact = reference_solution(p)
        err, err_plain = (float(np.abs(x.velocity - exact.velocity).max()) for x in (s, plain))
        assert err <= 2 * err_plain + 1e-6, (err, err_plain)


def test_nncg_needs_fewer_sweeps_than_plain_pgs(problems):
    plain = [solve(p, **SETTINGS).iterations for p in problems]
    nncg = [solve(p, accelerate="nncg", **SETTINGS).iterations for p in problems]
    assert np.median(nncg) < 0.75 * np.median(plain), (plain, nncg)


@pytest.mark.parametrize("iterations", [1, 2, 7, 50])
def test_a_solve_ends_on_a_sweep_even_at_the_cap(problems, iterations):
    # The conjugate step may leave the cone (the next sweep projects it back): it never comes last,
    # so no normal impulse handed to Box2D is negative.
    for p in problems:
        for w in (1.0, 1.3):
            for tolerance in (0.0, 1e-12):
                s = solve(p, accelerate="nncg", relaxation=w, max_iterations=iterations, tolerance=tolerance)
                assert s.iterations == iterations
                assert np.all(np.isfinite(s.normal_impulse)) and np.all(s.normal_impulse >= 0)


def test_a_traced_solve_takes_the_same_iterates(problems):
    p = problems[-1]
    a = solve(p, accelerate="nncg", max_iterations=200, history=True)
    b = solve(p, accelerate="nncg", max_iterations=200, final_residual=False)
    assert np.array_equal(a.normal_impulse, b.normal_impulse)


def test_exact_mode_takes_no_acceleration(problems):
    with pytest.raises(ValueError, match="exact"):
        solve(problems[0], mode="exact", accelerate="nncg")
    with pytest.raises(ValueError, match="accelerate"):
        solve(problems[0], accelerate="anderson")
    scene = generate("pile", 0, dict(count=10))
    with pytest.raises(InputError, match="exact"):
        PGSStepper(build_world(scene), scene, SolveSettings(mode="exact", tolerance=0, accelerate="nncg"))


def test_simulate_and_evaluate_with_nncg(tmp_path):
    out = tmp_path / "cg"
    r = dc("simulate", *SMALL, "--steps", "60", "--solver", "pgs", "--tolerance", "1e-4", "--max-iterations", "500",
           "--accelerate", "nncg", "--relaxation", "1.3", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert dc("validate", "-q", str(out)).returncode == 0
    solved = etree.parse(str(sorted(out.glob("seed-*/step-*.xml"))[-1])).find("header/solve").attrib
    assert solved["accelerate"] == "nncg" and float(solved["relaxation"]) == 1.3
    r = dc("simulate", *SMALL, "--steps", "5", "--solver", "pgs", "--mode", "exact", "--accelerate", "nncg",
           "-o", str(tmp_path / "no"))
    assert r.returncode == 2 and "--accelerate" in r.stderr and "Traceback" not in r.stderr
    r = dc("simulate", *SMALL, "--steps", "5", "--accelerate", "nncg", "-o", str(tmp_path / "no"))
    assert r.returncode != 0 and "--solver pgs" in r.stderr
    run = tmp_path / "run"
    assert dc("simulate", *SMALL, "--steps", "120", "-q", "-o", str(run)).returncode == 0
    r = dc("evaluate", "--no-plots", str(run), "--starts", "builtin", "--accelerate", "none,nncg", "--every", "40",
           "--no-budgets", "-q", "-o", str(tmp_path / "rep"))
    assert r.returncode == 0, r.stderr
    assert "builtin+nncg" in r.stdout
    r = dc("evaluate", "--no-plots", str(run), "--starts", "builtin", "--accelerate", "nncg,anderson", "-o",
           str(tmp_path / "x"))
    assert r.returncode == 2 and "--accelerate" in r.stderr and "Traceback" not in r.stderr
