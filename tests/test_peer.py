"""Siconos as an independent peer: our step problems exported in FCLIB's format, solved by its
Lemke solver in Debian's own Python, and both answers judged by a residual Siconos's side
computes from the file alone."""
import numpy as np
import pytest

from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.exchange import fclib, peer
from deepcontact.solver import local
from deepcontact.solver.problem import StepProblem
from deepcontact.solver.reference import reference_solution

# (generator, parameters, steps): a fixed sample of the thesis pile, a pyramid and hard scenes
SAMPLE = [("pile", {}, (100, 150, 200, 250)), ("pyramid", dict(base=6), (60, 120)),
          ("stack", dict(count=8), (100, 200)), ("mass-ratio", dict(ratio=400.0), (100,)),
          ("card-house", dict(levels=2), (100,))]


def steps(generator, params, wanted):
    scene = generate(generator, 0, params)
    world = build_world(scene)
    out = []
    for k in range(max(wanted) + 1):
        bodies, contacts = world.step(scene.dt, scene.solver.velocity_iterations, scene.solver.position_iterations,
                                      record=True)
        if k in wanted:
            assert len(contacts["manifold"]), (generator, k)
            out.append(StepProblem.from_arrays(bodies, contacts, dt=scene.dt, index=k,
                                               gravity=scene.effects.gravity or (0.0, 0.0),
                                               block_solve=scene.solver.block_solve))
    return out


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    assert peer.available(), "Siconos for /usr/bin/python3 is missing: make setup installs python3-siconos"
    folder = tmp_path_factory.mktemp("fclib")
    out = []
    for generator, params, wanted in SAMPLE:
        for problem in steps(generator, params, wanted):
            ours = reference_solution(problem)
            path = fclib.write_problem(problem, folder / f"{generator}-{problem.index}.hdf5",
                                       solution=(ours.normal_impulse, ours.tangent_impulse))
            out.append((path, problem, ours))
    return out


@pytest.mark.process
def test_our_exact_solution_and_siconos_lemke_both_solve_the_exported_problems(exported):
    results = peer.run([path for path, _, _ in exported], solver="lemke")
    assert len(results) == len(exported)
    for (path, problem, ours), theirs in zip(exported, results):
        assert ours.residual < 1e-12, path.name
        # judged on the Siconos side, from the file alone
        assert theirs["stored_residual"] < 1e-12, path.name
        assert theirs["stored_residual"] == pytest.approx(ours.residual, rel=1e-3, abs=1e-12), path.name
        assert theirs["info"] == 0 and theirs["residual"] < 1e-9, path.name


@pytest.mark.process
def test_the_solve_in_body_space_is_judged_a_solution_on_the_siconos_side(exported, tmp_path):
    """Both its variants (bodyspace, lagged), their answers judged in one Siconos process."""
    from deepcontact.solver.methods import solve
    paths, ours = [], []
    for method in ("bodyspace", "lagged"):
        for path, problem, _ in exported:
            zero = np.zeros(problem.points)
            s = solve(problem, zero, zero, tolerance=1e-10, max_iterations=20_000, accelerate=method)
            ours.append(s.residual)
            paths.append(fclib.write_problem(problem, tmp_path / f"{method}-{path.name}",
                                             solution=(s.normal_impulse, s.tangent_impulse)))
    for path, residual, theirs in zip(paths, ours, peer.run(paths, solver="lemke")):
        assert residual < 1e-10, path.name
        assert theirs["stored_residual"] == pytest.approx(residual, rel=1e-3, abs=1e-12), path.name


def test_the_export_is_the_problem_our_solver_solves(exported):
    for path, problem, ours in exported:
        lp = fclib.read_problem(path)
        written = local.local_problem(problem)
        assert (abs(lp.W - written.W)).max() == 0 and np.array_equal(lp.q, written.q)
        # W is symmetric positive semidefinite (J M^-1 J^T) with the solver's k on its diagonal
        dense = lp.W.toarray()
        assert np.allclose(dense, dense.T, rtol=0, atol=1e-12 * np.abs(dense).max())
        assert np.linalg.eigvalsh(dense).min() > -1e-9 * np.abs(dense).max()
        r = written.reaction(ours.normal_impulse, ours.tangent_impulse)
        assert local.residual(lp, r) == pytest.approx(ours.residual, rel=1e-3, abs=1e-12)
        # a perturbed answer is not a solution: the check can fail
        assert local.residual(lp, r * 1.01 + 1e-3) > 1e-5


def test_dc_export_writes_every_nth_step_with_its_reference_and_replaces_only_its_own(pile_run, tmp_path):
    import json

    from conftest import dc, one_line_error, snapshot, written
    out = written(tmp_path / "fclib", "export", str(pile_run), "--every", "25")
    index = json.loads((out / "index.json").read_text())["problems"]
    assert index and all(p["step"] % 25 == 0 and p["contacts"] > 0 for p in index)
    assert all(p["residual"] < 1e-9 for p in index)    # the small pile's steps
    last = fclib.read_problem(out / index[-1]["file"])   # 2 rows per contact point the solver uses
    assert last.W.shape[0] == last.W.shape[1] == 2 * len(last.mu) and len(last.mu) <= index[-1]["contacts"]
    before = snapshot(out)
    one_line_error(dc("export", str(pile_run), "-o", str(out)), "not empty")
    (out / "notes.txt").write_text("mine")
    one_line_error(dc("export", str(pile_run), "-o", str(out), "--overwrite"), "notes.txt")
    assert snapshot(out) == dict(before, **{"notes.txt": b"mine"})
