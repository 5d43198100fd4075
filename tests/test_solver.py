"""The project's PGS: Box2D-exact, checked against a slow Python reference, honest measures."""
import numpy as np
import pytest

from deepcontact import _box2d
from deepcontact.scene.generators import generate
from deepcontact.scene.xml import read_scene
from deepcontact.simulate.build import build_world
import reference_lcp as L
from deepcontact.solver.pgs import solve
from deepcontact.solver.problem import StepProblem
from pathlib import Path

SCENES = Path(__file__).parent.parent / "datasets" / "scenes"


def scenes():
    return {
        "pile": generate("pile", 0, dict(count=30, box=16.0, sigma=4.0)),
        "boxes-and-circles": read_scene(SCENES / "boxes-and-circles.xml"),
        "bouncing": read_scene(SCENES / "bouncing.xml"),
        "frictionless": generate("confined", 0, dict(count=64)),
        "pyramid": generate("pyramid", 0, dict(base=6)),
    }


def recorded_steps(scene, steps=None, iterations=8, every=1):
    """(problem, Box2D's contacts) for steps of a live world."""
    world = build_world(scene)
    out = []
    for k in range(steps or scene.steps):
        bodies, contacts = world.step(scene.dt, iterations, 3, record=True)
        if len(contacts["manifold"]) and k % every == 0:
            out.append((StepProblem.from_arrays(bodies, contacts, dt=scene.dt,
                                                gravity=scene.effects.gravity or (0.0, 0.0),
                                                block_solve=scene.solver.block_solve,
                                                velocity_iterations=iterations), contacts))
    return out


@pytest.mark.parametrize("name", ["pile", "boxes-and-circles", "bouncing", "frictionless", "pyramid"])
@pytest.mark.parametrize("iterations", [8, 100])
def test_exact_mode_is_box2d_bit_for_bit(name, iterations):
    scene = scenes()[name]
    steps = recorded_steps(scene, steps=min(scene.steps, 200), iterations=iterations)
    assert len(steps) > 20
    for problem, c in steps:
        s = solve(problem, mode="exact")
        assert np.array_equal(s.normal_impulse, c["normal_impulse"]), problem.index
        assert np.array_equal(s.tangent_impulse, c["tangent_impulse"]), problem.index


def test_exact_mode_without_block_solver():
    scene = read_scene(SCENES / "boxes-and-circles.xml")
    scene.solver.block_solve = False
    for problem, c in recorded_steps(scene, steps=120):
        s = solve(problem, mode="exact")
        assert np.array_equal(s.normal_impulse, c["normal_impulse"])


def test_island_order_matters():
    # The same contacts, manifolds in reverse order: not Box2D's answer.
    problem, c = recorded_steps(generate("pile", 0, dict(count=30, box=16.0, sigma=4.0)), steps=150)[-1]
    m = problem.contacts["manifold"]
    order = np.concatenate([np.nonzero(m == k)[0] for k in np.unique(m)[::-1]])
    reversed_ = StepProblem(bodies=problem.bodies,
                            contacts={k: np.ascontiguousarray(v[order]) for k, v in problem.contacts.items()},
                            dt=problem.dt, gravity=problem.gravity, start_normal=problem.start_normal[order],
                            start_tangent=problem.start_tangent[order])
    s = solve(reversed_, mode="exact")
    assert not np.array_equal(s.normal_impulse, c["normal_impulse"][order])
    assert np.array_equal(solve(problem, mode="exact").normal_impulse, c["normal_impulse"])


@pytest.mark.parametrize("name", ["pile", "boxes-and-circles", "bouncing"])
def test_native_float64_matches_the_python_reference(name):
    scene = scenes()[name]
    for problem, _ in recorded_steps(scene, steps=150, every=40)[-2:]:
        problem.block_solve = False   # the textbook PGS has no 2x2 blocks
        lcp = L.build_lcp(problem)
        # the native solver projects starts onto the friction cone first (Box2D's own warm
        # start can lie just outside it); give the reference the same start
        n0 = problem.start_normal.astype(np.float64)
        bound = problem.contacts["friction"].astype(np.float64) * n0
        t0 = np.clip(problem.start_tangent.astype(np.float64), -bound, bound)
        n, t = L.pgs(lcp, n0, t0, 25)
        s = solve(problem, mode="float64", max_iterations=25)
        scale = max(1.0, np.abs(n).max())
        assert np.allclose(s.normal_impulse, n, rtol=0, atol=1e-9 * scale)
        assert np.allclose(s.tangent_impulse, t, rtol=0, atol=1e-9 * scale)
        # the same residual, normalised by the largest free velocity |b|
        free = np.abs(lcp.b).max()
        assert s.residual == pytest.approx(L.natural_residual(lcp, n, t) / free, rel=1e-6, abs=1e-12)


def test_float64_differs_from_float32_only_by_rounding():
    worst = 0.0
    for problem, c in recorded_steps(scenes()["pile"], steps=150, every=30):
        single = solve(problem, mode="float32")
        double = solve(problem, mode="float64")
        scale = max(1e-3, np.abs(single.normal_impulse).max())
        worst = max(worst, np.abs(double.normal_impulse - single.normal_impulse).max() / scale)
    assert 0 < worst < 1e-4


@pytest.mark.parametrize("name", ["pile", "boxes-and-circles", "frictionless"])
def test_the_rounding_bound_holds_everywhere_float32_rounding_can_reach(name):
    """solver.rounding: no impulses within half a float32 spacing of stored ones (the box a float64
    answer lies in once written) have a residual further from theirs than the bound, at the box's
    corners (the worst signs) and inside it; and the bound is the rounding's size, not a blanket."""
    from deepcontact.solver.rounding import half_spacing, rounding_bound
    rng = np.random.default_rng(0)
    widest = 0.0
    for problem, _ in recorded_steps(scenes()[name], steps=150, every=30):
        answer = solve(problem, mode="float64", max_iterations=200)
        stored = [v.astype(np.float32).astype(np.float64) for v in (answer.normal_impulse, answer.tangent_impulse)]
        bound = rounding_bound(problem, *stored)
        at_stored = solve(problem, *stored, max_iterations=0, cone=False).residual
        for k in range(40):
            signs = rng.choice([-1.0, 1.0], 2 * problem.points)
            draw = signs if k % 2 else signs * rng.uniform(size=2 * problem.points)   # (a corner, or inside)
            moved = [v + d * half_spacing(v) for v, d in zip(stored, np.split(draw, 2))]
            moved_residual = solve(problem, *moved, max_iterations=0, cone=False).residual
            widest = max(widest, abs(moved_residual - at_stored) / bound)
            # (the bound is reached, to float64's own rounding of the two residuals: frictionless rows)
            assert abs(moved_residual - at_stored) <= bound * (1 + 1e-6), (bound, moved_residual, at_stored)
        assert bound < 1e-5
    assert widest > 0.5   # (the rounding moves the residual by most of the bound: it is no blanket)


def test_reference_solution_solves_the_lcp():
    problem, _ = recorded_steps(scenes()["boxes-and-circles"], steps=150)[-1]
    from deepcontact.solver.reference import reference_solution
    r = reference_solution(problem)
    assert r.residual < 1e-12 and r.iterations < 100_000
    lcp = L.build_lcp(problem)
    assert L.natural_residual(lcp, r.normal_impulse, r.tangent_impulse) < 1e-10
    # complementarity and feasibility, in the LCP's own terms
    lam = np.where(lcp.kind == 0, r.normal_impulse[lcp.point], r.tangent_impulse[lcp.point])
    w = lcp.A @ lam + lcp.b
    nrm = lcp.kind == 0
    assert np.all(lam[nrm] >= 0) and np.all(w[nrm] > -1e-9)
    assert np.abs(lam[nrm] * w[nrm]).max() < 1e-9


def test_measures_are_what_the_readme_says():
    problem, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    k = 6
    before = solve(problem, mode="float64", max_iterations=k)
    after = solve(problem, mode="float64", max_iterations=k + 1, history=True)
    dn = after.normal_impulse - before.normal_impulse
    dt = after.tangent_impulse - before.tangent_impulse
    assert after.history.shape == (k + 1, 3)
    assert after.measure("thesis")[k] == pytest.approx(np.sqrt(dn ** 2 + dt ** 2).max(), rel=1e-12)
    lcp = L.build_lcp(problem)
    kn = np.zeros(problem.points)
    kt = np.zeros(problem.points)
    kn[lcp.point[lcp.kind == 0]] = np.diag(lcp.A)[lcp.kind == 0]
    kt[lcp.point[lcp.kind == 1]] = np.diag(lcp.A)[lcp.kind == 1]
    expected = max((np.abs(dn) * kn).max(), (np.abs(dt) * kt).max())
    assert after.measure("velocity")[k] == pytest.approx(expected, rel=1e-6)
    assert after.measure("residual")[k] == pytest.approx(after.residual, rel=1e-12)


def test_tolerance_stops_early_and_the_cap_holds():
    problem, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    s = solve(problem, mode="float64", max_iterations=5000, tolerance=1e-4, stop_on="velocity", history=True)
    assert s.iterations < 5000 and s.measure("velocity")[-1] < 1e-4 <= s.measure("velocity")[-2]
    capped = solve(problem, mode="float64", max_iterations=3, tolerance=1e-14, stop_on="residual")
    assert capped.iterations == 3


@pytest.mark.parametrize("bad", [np.nan, np.inf, -1.0, 1e30])
def test_garbage_starts_are_sanitised_and_reported(bad):
    problem, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    n = np.full(problem.points, bad)
    t = np.full(problem.points, bad)
    s = solve(problem, n, t, mode="float32", max_iterations=200)
    assert np.all(np.isfinite(s.normal_impulse)) and np.all(s.normal_impulse >= 0)
    report = s.sanitized
    assert sum(report.values()) >= problem.points
    key = {True: "nonfinite"}.get(not np.isfinite(bad), "negative" if bad < 0 else "implausible")
    assert report[key] == problem.points
    zero = solve(problem, np.zeros(problem.points), np.zeros(problem.points), mode="float32", max_iterations=200)
    assert np.array_equal(s.normal_impulse, zero.normal_impulse)


def test_a_residual_that_is_not_a_number_says_so():
    # exact mode uses a start as given: a NaN start leaves the velocities NaN whatever the clamps
    # make of the impulses, and the residual is NaN (a max that dropped NaN terms read 0)
    problem, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    n = np.full(problem.points, np.nan)
    s = solve(problem, n, n, mode="exact", max_iterations=8)
    assert np.isnan(s.residual), s.residual
    finite = solve(problem, mode="exact", max_iterations=8)
    assert np.isfinite(finite.residual) and finite.residual > 0


def test_pivoting_finishes_an_answer_whose_residual_is_not_a_number():
    # each attempt was kept only if below the best so far: below NaN nothing is, and the
    # reference handed back the NaN answer it started from
    from deepcontact.solver.reference import TOLERANCE, finish_by_pivoting
    problem, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    n = np.full(problem.points, np.nan)
    lost = solve(problem, n, n, mode="exact", max_iterations=8)
    assert np.isnan(lost.residual)
    assert finish_by_pivoting(problem, lost).residual < TOLERANCE


def test_only_the_effects_a_scene_calls_for():
    # frictionless: no tangent rows at all, and the answer equals the full problem's
    problem, _ = recorded_steps(scenes()["frictionless"], steps=200)[-1]
    lean = solve(problem, mode="float64", max_iterations=30)
    full = solve(problem, mode="float64", max_iterations=30, prune=False)
    assert lean.stats["tangent_rows"] == 0 and full.stats["tangent_rows"] == full.stats["normal_rows"] > 0
    assert np.array_equal(lean.normal_impulse, full.normal_impulse)
    assert not np.any(lean.tangent_impulse) and not np.any(full.tangent_impulse)
    # no restitution declared: no bias rows; with restitution, some
    pile, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    assert solve(pile, mode="float64").stats["bias_rows"] == 0
    bouncing = [solve(p, mode="float64").stats["bias_rows"] for p, _ in recorded_steps(scenes()["bouncing"])]
    assert max(bouncing) > 0
    # no rotation: fixed-rotation bodies and edges only give linear manifolds
    scene = generate("confined", 0, dict(count=16))
    for b in scene.bodies:
        b.fixed_rotation = True
    problem, _ = recorded_steps(scene, steps=200)[-1]
    assert solve(problem, mode="float64").stats["angular_manifolds"] == 0
    assert solve(problem, mode="float64", prune=False).stats["angular_manifolds"] > 0


def test_bad_problem_arrays_are_refused():
    problem, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    with pytest.raises(ValueError, match="one value per contact point"):
        solve(problem, np.zeros(3), np.zeros(3))
    broken = dict(problem.contacts, point=problem.contacts["point"][::-1].copy())
    bad = StepProblem(bodies=problem.bodies, contacts=broken, dt=problem.dt, gravity=problem.gravity,
                      start_normal=problem.start_normal, start_tangent=problem.start_tangent)
    if (problem.contacts["point_count"] == 2).any():
        with pytest.raises(ValueError, match="consecutive"):
            solve(bad)
    with pytest.raises(ValueError, match="relaxation"):
        solve(problem, relaxation=2.5)


def test_bad_options_are_refused_once_natively_naming_the_option():
    problem, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    for kwargs, message in [(dict(mode="float16"), "mode must be one of exact, float32, float64, not 'float16'"),
                            (dict(accelerate="apgd"), "accelerate must be one of none, nncg, newton, subspace, bodyspace, lagged, not 'apgd'"),
                            (dict(mode="float32", accelerate="newton"), "float64 only"),
                            (dict(mode="float32", accelerate="bodyspace"), "float64 only"),
                            (dict(tolerance=1e-3, stop_on="energy"), "stop_on must be one of none, thesis"),
                            (dict(mode="exact", relaxation=1.3), "exact is Box2D's PGS"),
                            (dict(mode="exact", accelerate="nncg"), "exact is Box2D's PGS"),
                            (dict(max_iterations=-1), "max_iterations must be >= 0"),
                            (dict(tolerance=float("nan")), "tolerance must be finite")]:
        with pytest.raises(ValueError, match=message):
            solve(problem, **kwargs)
    with pytest.raises(TypeError, match="SolveOptions has no field 'relax'"):
        _box2d.SolveOptions(relax=1.5)
    with pytest.raises(ValueError, match="dt must be positive"):
        _box2d.StepSettings(dt=0.0, gravity=(0.0, -10.0))
    settings = problem.settings()
    with pytest.raises(ValueError, match="position_iterations must be >= 0"):
        _box2d.PGSStepSettings(step=settings, solve=_box2d.SolveOptions(), position_iterations=-1)
    with pytest.raises(ValueError, match="start must be one of zero, builtin"):
        _box2d.PGSStepSettings(step=settings, start="garbage")
    # options set after construction are checked again where they are used
    options = _box2d.SolveOptions()
    options.relaxation = 3.0
    with pytest.raises(ValueError, match="relaxation must be in"):
        _box2d.solve_contacts(problem.bodies, problem.contacts, problem.start_normal, problem.start_tangent,
                              settings, options)


def test_the_solver_reads_exactly_its_columns_of_the_record_tables():
    problem, _ = recorded_steps(scenes()["pile"], steps=150)[-1]
    assert set(problem.bodies) == set(_box2d.SOLVER_BODY_FIELDS)
    assert set(problem.contacts) == set(_box2d.SOLVER_CONTACT_FIELDS) | {"row_a", "row_b"}
    for key in _box2d.SOLVER_BODY_FIELDS:
        with pytest.raises(KeyError, match=f"missing array '{key}'"):
            _box2d.contact_rows({k: v for k, v in problem.bodies.items() if k != key}, problem.contacts,
                                problem.settings())
    for key in _box2d.SOLVER_CONTACT_FIELDS + ("row_a", "row_b"):
        with pytest.raises(KeyError, match=f"missing array '{key}'"):
            _box2d.contact_rows(problem.bodies, {k: v for k, v in problem.contacts.items() if k != key},
                                problem.settings())


@pytest.mark.parametrize("name", ["pile", "boxes-and-circles", "pyramid"])
def test_the_body_rows_are_the_python_references_jacobian(name):
    """native/body_rows.hpp, which Newton, the body-space solve and solver.local.jacobian read,
    against the slow reference's J, derived in Python from the recorded contacts."""
    from deepcontact.solver.local import jacobian
    for problem, _ in recorded_steps(scenes()[name], steps=60, every=20):
        lcp = L.build_lcp(problem, prune=False)
        J, _, _, rows, points = jacobian(problem)
        for kind, offset in ((0, 0), (1, 1)):   # normal rows, tangent rows
            ours = J.toarray()[offset::2]
            ref = lcp.J[lcp.kind == kind]
            assert np.array_equal(lcp.point[lcp.kind == kind], points)
            assert np.allclose(ours, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max())), (name, kind)
