"""Gravity's sweep order (SolveSettings.order): the manifolds swept from the highest to the lowest
along gravity. It changes the iterates, never the problem: the same answer to a tolerance, the
same step in one native call and in pieces, island order's bits where there is no gravity, and a
step file that says which order solved it."""
import dataclasses
import re

import numpy as np
import pytest

from deepcontact.errors import OptionError
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.simulate.engines import Box2D
from deepcontact.simulate.pgs_loop import PGSStepper
from deepcontact.simulate.problems import problems
from deepcontact.solver.methods import solve
from deepcontact.solver.settings import SolveSettings

from conftest import dc


def _settled(scene_name="pile", params=None, first=150):
    scene = generate(scene_name, 3, dict(params or dict(count=40, box=20.0, sigma=5.0), steps=first + 5))
    return next(iter(problems(scene, Box2D(), first=first, every=1)))[1]


def test_gravitys_order_reaches_the_answer_island_order_reaches():
    p = _settled()
    assert p.points > 30
    for order in ("island", "gravity"):
        s = solve(p, settings=SolveSettings(mode="float64", max_iterations=20_000, tolerance=1e-9, order=order))
        assert s.residual < 1e-9, (order, s.residual, s.iterations)


def test_gravitys_order_changes_the_iterates_but_not_without_gravity():
    p = _settled()
    few = dict(mode="float32", max_iterations=3, tolerance=0)
    island = solve(p, settings=SolveSettings(**few))
    down = solve(p, settings=SolveSettings(**few, order="gravity"))
    assert not np.array_equal(island.normal_impulse, down.normal_impulse)
    weightless = dataclasses.replace(p, gravity=(0.0, 0.0))
    a = solve(weightless, settings=SolveSettings(**few))
    b = solve(weightless, settings=SolveSettings(**few, order="gravity"))
    assert np.array_equal(a.normal_impulse, b.normal_impulse) and np.array_equal(a.tangent_impulse, b.tangent_impulse)


def _top_down(problem):
    """The problem with its manifolds posed from the highest to the lowest (their higher body's
    centre), each one's points together: (the problem, its rows' places in the original)."""
    c = problem.contacts
    first = np.flatnonzero(np.r_[True, c["manifold"][1:] != c["manifold"][:-1]])
    end = np.r_[first[1:], len(c["manifold"])]
    y = problem.bodies["center"][:, 1]
    order = np.argsort(-np.maximum(y[c["row_a"]], y[c["row_b"]])[first], kind="stable")
    rows = np.concatenate([np.arange(first[m], end[m]) for m in order])
    contacts = {k: v[rows] for k, v in c.items()}
    contacts["manifold"] = np.repeat(np.arange(len(order)), (end - first)[order]).astype(c["manifold"].dtype)
    return dataclasses.replace(problem, contacts=contacts, start_normal=problem.start_normal[rows],
                               start_tangent=problem.start_tangent[rows], keys=None), rows


@pytest.mark.parametrize("scene,params", [("pile", None), ("pyramid", dict(base=8))])
def test_gravitys_order_is_island_order_of_the_manifolds_posed_top_down(scene, params):
    # from rest (no start applied: applying one sums in the posed order) the sweeps of gravity's
    # order are those of island order on the same problem posed from the highest manifold down
    p = _settled(scene, params)
    rows = _as_posed_top_down(p)
    assert not np.array_equal(rows, np.arange(p.points))   # (posed top-down is another order here)


def _as_posed_top_down(problem):
    """Asserts that three sweeps from rest in gravity's order are island order's on the problem
    posed top-down (_top_down), bit for bit; the rows' places."""
    posed, rows = _top_down(problem)
    zero = np.zeros(problem.points)
    few = dict(mode="float32", max_iterations=3, tolerance=0)
    down = solve(problem, zero, zero, settings=SolveSettings(**few, order="gravity"))
    island = solve(posed, zero, zero, settings=SolveSettings(**few))
    assert np.array_equal(down.normal_impulse[rows], island.normal_impulse)
    assert np.array_equal(down.tangent_impulse[rows], island.tangent_impulse)
    return rows


@pytest.mark.parametrize("scene,mode", [("pile", "float32"), ("pyramid", "float64")])
def test_the_native_loop_sweeps_in_gravitys_order_as_the_step_in_pieces_does(scene, mode):
    s = generate(scene, 0, dict(count=30, box=16.0, sigma=4.0) if scene == "pile" else dict(base=6))
    settings = SolveSettings(mode=mode, max_iterations=4, tolerance=0, order="gravity")
    native, pieces = (PGSStepper(build_world(s), s, settings, "builtin", native=n) for n in (True, False))
    island = PGSStepper(build_world(s), s, settings.but(order="island"), "builtin")
    assert native.native and not pieces.native
    solved = 0
    for _ in range(80):
        a, b, c = native.step(), pieces.step(), island.step()
        assert (a.solution is None) == (b.solution is None)
        if a.solution is not None:
            solved += 1
            assert np.array_equal(a.solution.normal_impulse, b.solution.normal_impulse)
            assert np.array_equal(a.solution.tangent_impulse, b.solution.tangent_impulse)
    assert solved > 20
    assert np.array_equal(native.world.bodies()["position"], pieces.world.bodies()["position"])
    assert not np.array_equal(native.world.bodies()["position"], island.world.bodies()["position"])


def test_box2ds_exact_arithmetic_keeps_box2ds_order():
    with pytest.raises(OptionError, match="island order"):
        SolveSettings(mode="exact", order="gravity")
    with pytest.raises(OptionError, match="order must be one of island, gravity"):
        SolveSettings(order="down")
    with pytest.raises(OptionError, match="the plug-in method 'mine:Method' sweeps in its own"):
        SolveSettings(order="gravity", accelerate="mine:Method")


def test_a_step_file_says_which_order_solved_it(tmp_path):
    out = tmp_path / "run"
    r = dc("simulate", "pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=3", "--steps", "40",
           "--solver", "pgs", "--mode", "float32", "--order", "gravity", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    step = out / "seed-000000" / "step-000039.xml"
    assert ' order="gravity" ' in step.read_text()
    assert r'"order": "gravity"' in (out / "manifest.json").read_text()
    assert dc("validate", "-q", str(out)).returncode == 0
    step.write_text(step.read_text().replace(' order="gravity" ', " "))   # (island, by its default)
    r = dc("validate", "-q", str(out))   # (its findings are its report, on stdout)
    assert r.returncode == 1, r.stdout + r.stderr
    assert re.search(r"step-000039\.xml:\d+:\d+: the step file's <solve order> disagrees with its run's manifest "
                     r"\('gravity'\)", r.stdout), r.stdout


def test_the_order_is_a_pgs_option_and_not_box2ds_own_order(tmp_path):
    r = dc("simulate", "pile", "--order", "gravity", "-o", str(tmp_path / "a"))
    assert r.returncode == 2 and "--order only applies with --solver pgs" in r.stderr
    r = dc("simulate", "pile", "--solver", "pgs", "--mode", "exact", "--order", "gravity", "-o", str(tmp_path / "b"))
    assert r.returncode == 2 and re.search(r"--order.*island order", r.stderr), r.stderr
    assert not (tmp_path / "b").exists()


def test_a_float32_run_in_gravitys_order_is_replayed_in_its_order(tmp_path):
    # dc validate --residuals replays a float32 step that stopped at its cap: in island order it
    # gave other impulses, and every such step of a valid run was called invalid
    out = tmp_path / "run"
    r = dc("simulate", "pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4", "--steps", "80",
           "--solver", "pgs", "--mode", "float32", "--order", "gravity", "--tolerance", "1e-3", "--max-iterations",
           "12", "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    capped = [p for p in sorted(out.glob("seed-000000/step-*.xml")) if 'iterations="12"' in p.read_text()]
    assert capped, "no step stopped at its cap: the replay is not reached"
    r = dc("validate", "--residuals", str(out))
    assert r.returncode == 0 and " 0 invalid" in r.stdout + r.stderr, r.stdout + r.stderr


def test_exact_mode_in_gravitys_order_is_no_run_the_solver_makes(tmp_path):
    out = tmp_path / "run"
    assert dc("simulate", "pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=3", "--steps", "20",
              "--solver", "pgs", "--mode", "float32", "--order", "gravity", "-q", "-o", str(out)).returncode == 0
    for step in out.glob("seed-000000/step-*.xml"):
        step.write_text(step.read_text().replace('mode="float32"', 'mode="exact"'))
    manifest = out / "manifest.json"
    manifest.write_text(manifest.read_text().replace('"mode": "float32"', '"mode": "exact"'))
    r = dc("validate", str(out))
    assert r.returncode == 1 and "exact" in r.stdout + r.stderr and "order" in r.stdout + r.stderr, r.stdout + r.stderr


def test_ties_negative_heights_and_negative_zero_keep_the_posed_order_as_a_stable_sort_does():
    # the heights sorted natively (a radix sort of their bits) in the order numpy's stable sort
    # gives: the bodies' centres moved to heights with many ties, below zero, and -0.0
    p = _settled("pyramid", dict(base=8))
    centre = p.bodies["center"].copy()
    y = np.round(centre[:, 1] * 2) / 2 - 3.5            # (rows of boxes tie; the lowest below zero)
    y[np.abs(y) < 0.3] = -0.0
    centre[:, 1] = y.astype(centre.dtype)
    # (centres either side of x = 0: a height of -0.0 along gravity (0, -g) is then -0.0 or +0.0)
    centre[:, 0] -= np.median(centre[:, 0])
    moved = dataclasses.replace(p, bodies={**p.bodies, "center": centre})
    heights = np.maximum(centre[:, 1][p.contacts["row_a"]], centre[:, 1][p.contacts["row_b"]])
    assert len(np.unique(heights)) < len(heights) / 2 and (heights < 0).any()
    assert (np.signbit(heights) & (heights == 0)).any() and (heights > 0).any()
    _as_posed_top_down(moved)


def test_dc_evaluate_sweeps_every_variant_in_the_order_asked_and_says_so(tmp_path, monkeypatch):
    import json
    import sys
    from pathlib import Path
    run = tmp_path / "run"
    assert dc("simulate", "pile", "--param", "count=20", "--param", "box=14", "--param", "sigma=3", "--steps", "150",
              "-q", "-o", str(run)).returncode == 0
    reports = {}
    for order in ("island", "gravity"):
        r = dc("evaluate", str(run), "--starts", "builtin", "--max-iterations", "4", "--tolerance", "1e-9", "--every",
               "10", "--order", order, "--no-plots", "--no-budgets", "-q", "-o", str(tmp_path / order))
        assert r.returncode == 0, r.stderr
        reports[order] = json.loads((tmp_path / order / "summary.json").read_text())
    assert reports["gravity"]["settings"]["order"] == "gravity" and reports["island"]["settings"]["order"] == "island"
    assert "its sweeps in gravity's order" in (tmp_path / "gravity" / "report.md").read_text()
    assert "gravity" not in (tmp_path / "island" / "report.md").read_text()
    # (the same steps, each from the same start, in four sweeps: another order, other residuals)
    assert reports["gravity"]["starts"]["builtin"] != reports["island"]["starts"]["builtin"]
    r = dc("evaluate", str(run), "--starts", "builtin", "--closed-loop", "--steps", "15", "--order", "gravity",
           "--no-plots", "--no-budgets", "-q", "-o", str(tmp_path / "loop"))
    assert r.returncode == 0, r.stderr
    loop = json.loads((tmp_path / "loop" / "closed-loop.json").read_text())
    assert loop["order"] == "gravity" and {r["order"] for r in loop["results"]} == {"gravity"}
    assert "its sweeps in gravity's order" in (tmp_path / "loop" / "report.md").read_text()
    # a plug-in method sweeps in its own order: asked for gravity's, the command is refused before any work
    monkeypatch.syspath_prepend(str(Path(__file__).parent.parent / "examples" / "deepcontact-example-plugins"))
    try:
        r = dc("evaluate", str(run), "--accelerate", "none,dc_example_plugins.solvers:ProjectedJacobi", "--order",
               "gravity", "-o", str(tmp_path / "plugin"))
    finally:
        for name in [m for m in sys.modules if m.startswith("dc_example_plugins")]:
            del sys.modules[name]
    assert r.returncode == 2 and "sweeps in its own" in r.stderr and not (tmp_path / "plugin").exists(), r.stderr
