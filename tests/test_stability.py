"""The hard scenes stay numerically stable under Box2D's solver and ours (fast variants here;
`pytest -m slow` runs the full sizes). A case that fails at the default iteration count is
rerun with more iterations until it passes: the count is recorded, the criteria never loosened."""
import math

import pytest

from dcstudies.efforts import EFFORTS
from dcstudies import stability as S


@pytest.fixture(scope="module")
def fast_study():
    return {(d.case, d.solver, d.start): (d, f) for d, f in S.study(S.FAST, jobs=2)}   # (the same rows, tests/test_jobs.py)


def test_every_hard_scene_passes_at_a_recorded_iteration_count(fast_study):
    pgs = sum(solver == "pgs" for solver, *_ in S.CONFIGS)
    assert len(fast_study) == len(S.FAST) * len(S.CONFIGS) - pgs   # the bullet needs Box2D's own solver
    for key, (default, found) in fast_study.items():
        if key[1] not in ("box2d", "pgs"):
            continue   # (another engine's rows are measured, not required: test_box2d_v3_on_the_hard_scenes)
        assert found.passed, (key, found)
        assert found.finite and found.penetration <= S.PENETRATION_LIMIT
        assert found.energy_rise <= found.energy_allowed
        assert found.iterations >= default.iterations == 8


def test_box2d_at_its_default_count(fast_study):
    passes = {case for (case, solver, _), (d, _) in fast_study.items() if solver == "box2d" and d.passed}
    assert {"pyramid 6", "card house 2", "arch 5", "confined 64", "bullet"} <= passes
    # Known Box2D weaknesses at 8 iterations, passing with more: large mass ratios sink, and the
    # heavy top's overlap, pushed out after its removal, lifts the rest.
    for case in ("mass ratio 100:1", "mass ratio 400:1", "warm-start energy"):
        default, found = fast_study[(case, "box2d", "builtin")]
        assert not default.passed and found.passed and found.iterations > 8


def test_our_solver_from_box2d_warm_start_behaves_like_box2d(fast_study):
    for (case, solver, start), (default, found) in fast_study.items():
        if solver == "pgs" and start == "builtin":
            theirs = fast_study[(case, "box2d", "builtin")][1]
            assert found.iterations == theirs.iterations
            assert found.penetration == pytest.approx(theirs.penetration, abs=2e-4)


def test_garbage_starts_are_harmless(fast_study):
    for (case, solver, start), (default, found) in fast_study.items():
        if start == "garbage":
            zero = fast_study[(case, "pgs", "zero")][1]
            assert found.sanitized > 0 and found.finite
            assert found.iterations == zero.iterations
            assert found.penetration == zero.penetration


def test_over_relaxation_is_stable_on_every_hard_scene(fast_study):
    # PSOR at w = 1.7 keeps every criterion (finite, penetration at rest, energy) on every hard scene;
    # from Box2D's warm start it never needs more iterations than plain PGS (from zero it may: the
    # card house needs 32 instead of 8).
    for (case, solver, start), (default, found) in fast_study.items():
        if "@" in start:
            plain = fast_study[(case, solver, start.split("@")[0])][1]
            assert found.passed and found.finite, (case, start, found)
            if start.startswith("builtin"):
                assert found.iterations <= plain.iterations, (case, start, found.iterations, plain.iterations)


def test_conjugate_directions_are_stable_and_cost_no_iterations_from_the_warm_start(fast_study):
    # NNCG keeps every criterion on every hard scene; from Box2D's warm start it never needs more
    # iterations than plain PGS, and at w = 1.3 it passes everything at Box2D's default 8.
    for (case, solver, start), (default, found) in fast_study.items():
        if "+nncg" in start:
            assert found.passed and found.finite, (case, start, found)
            if start.startswith("builtin"):
                plain = fast_study[(case, solver, "builtin")][1]
                assert found.iterations <= plain.iterations, (case, start, found.iterations, plain.iterations)
            if start == "builtin+nncg@1.3":
                assert default.passed, (case, start)


def test_penetration_is_measured_at_rest_and_peaks_reported(fast_study):
    bullet = fast_study[("bullet", "box2d", "builtin")][1]
    assert bullet.peak_penetration > 0.1 > bullet.penetration     # the impact, then rest
    stack = fast_study[("stack 8", "box2d", "builtin")][1]
    assert not math.isnan(stack.top_drift) and stack.top_drift < S.TOP_DRIFT_LIMIT


def test_box2d_v3_on_the_hard_scenes(fast_study):
    """Box2D v3 under the same criteria, from its own rest: stable everywhere (finite; what rests
    comes to rest); it meets the criteria on the pyramid, card house, arch, confined circles and
    the bullet at its default 4 substeps. Its soft contacts give way under load at any substep
    count up to the cap: the stack's top sinks past 1 cm, the heavy circle of a large mass ratio
    past 1.5 cm, and the heavy top's sinking, released when it is removed, lifts the rest beyond
    the energy allowance. Bounded, not unstable."""
    v3 = {case: found for (case, solver, _), (_, found) in fast_study.items() if solver == "box2d3"}
    assert set(v3) == {c.label for c in S.FAST}
    for case, found in v3.items():
        assert found.finite, (case, found)
        if case not in ("confined 64", "bullet"):   # (no gravity, no friction: never rests; a shot flying off)
            assert found.final_speed < 0.05, (case, found)
    for case in ("pyramid 6", "card house 2", "arch 5", "confined 64", "bullet"):
        assert v3[case].passed and v3[case].iterations == EFFORTS['box2d3'].default, (case, v3[case])
    stack = v3["stack 8"]
    assert not stack.passed and stack.iterations == S.OWN_CAP * EFFORTS['box2d3'].default and S.TOP_DRIFT_LIMIT < stack.top_drift < 0.05
    for case in ("mass ratio 100:1", "mass ratio 400:1"):
        r = v3[case]
        assert not r.passed and r.iterations == S.OWN_CAP * EFFORTS['box2d3'].default and S.PENETRATION_LIMIT < r.penetration < 0.2, (case, r)
    removal = v3["warm-start energy"]
    assert not removal.passed and removal.penetration <= S.PENETRATION_LIMIT
    assert removal.energy_allowed < removal.energy_rise < 1.0


@pytest.mark.slow
def test_full_size_hard_scenes():
    rows = S.study(S.FULL)
    failed = [f for _, f in rows if not f.passed and f.solver in ("box2d", "pgs")]
    assert not failed, [S.format_row(d, f) for d, f in rows if not f.passed]


def test_pymunk_and_mujoco_on_the_hard_scenes(fast_study):
    """The peer engines are measured, not required: both stay finite everywhere and neither holds
    the 8-box stack's top within 1 cm at 16x its default effort. pymunk's stack leans and slides
    at any iteration count up to 160 (its order of contact features breaks the symmetry: built with
    pymunk's create_box vertex order the same stack stands); MuJoCo's soft contacts, engaging under
    the whole stack's weight from skins touching, let the top dip several cm in the first steps
    before it settles 3 mm low. MuJoCo rests every other stacked scene within 0.05 cm at its
    default 100 iterations; the heavy circle of 400:1 sinks 3.6 cm into its soft contacts."""
    peers = {(case, solver): found for (case, solver, _), (_, found) in fast_study.items()
             if solver in ("pymunk", "mujoco")}
    assert all(r.finite for r in peers.values())
    for solver in ("pymunk", "mujoco"):
        stack = peers["stack 8", solver]
        assert not stack.passed and stack.top_drift > S.TOP_DRIFT_LIMIT and stack.penetration <= S.PENETRATION_LIMIT
    for case in ("pyramid 6", "card house 2", "arch 5", "confined 64", "bullet"):
        r = peers[case, "mujoco"]
        assert r.passed and r.iterations == 100, (case, r)
    for case in ("pyramid 6", "card house 2", "arch 5"):
        assert peers[case, "mujoco"].penetration < 5e-4
    assert peers["mass ratio 400:1", "mujoco"].penetration > S.PENETRATION_LIMIT
    for case in ("pyramid 6", "mass ratio 100:1", "arch 5", "confined 64"):
        r = peers[case, "pymunk"]
        assert r.passed and r.iterations == 10, (case, r)
