"""An honest judge (issue 38, in part): contestants that lie about converging or about their cost
do not fool the verdict. The judge measures for itself: convergence by the project's residual
(never by what a method reports), time by the wall clock around the whole call."""
import json
import sys
import textwrap

import pytest

from conftest import dc

CONTESTANTS = textwrap.dedent("""
    import time
    import numpy as np
    from deepcontact.solver.methods import MethodResult
    from deepcontact.warmstart.starts import StartValue

    class Liar:
        '''Stops after one sweep's worth of nothing and claims it converged.'''
        def __call__(self, problem, normal, tangent, settings):
            return MethodResult(normal, tangent, np.array([1e-9]))

    class HidesItsCost:
        '''Box2D's warm start, 3 ms late, reporting no time spent.'''
        def __call__(self, ctx):
            time.sleep(0.003)
            return StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), {"net": 0.0})
    """)


@pytest.fixture
def contestants(tmp_path, monkeypatch):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "contestants.py").write_text(CONTESTANTS)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    yield "contestants"
    from deepcontact.solver import methods
    from deepcontact.warmstart.starts import STARTS
    sys.modules.pop("contestants", None)
    methods._instances.pop("contestants:Liar", None)
    methods.SOLVERS._loaded.pop("contestants:Liar", None)
    STARTS._loaded.pop("contestants:HidesItsCost", None)


def test_a_method_that_stops_early_is_never_the_winner(run, tmp_path, contestants):
    r = dc("evaluate", run, "--starts", "builtin", "--accelerate", "none,contestants:Liar", "--every", "20",
           "--no-budgets", "-q", "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())["starts"]
    liar = next(name for name in summary if "Liar" in name)
    assert summary[liar]["above"] > 0.5 and summary[liar]["residual_median"] > 1e-4
    assert summary["builtin"]["above"] == 0
    report = (tmp_path / "r" / "report.md").read_text()
    verdict = next(line for line in report.splitlines() if line.startswith("**Verdict**"))
    assert "is **builtin**" in verdict and "Left out" in verdict and "Liar" in verdict
    row = next(line for line in report.splitlines() if line.startswith("| ") and "Liar" in line)
    assert "(did not converge)" in row and "(Python)" in row


def test_a_loop_run_by_a_method_that_stops_early_says_so_and_validate_finds_it(tmp_path, contestants):
    r = dc("simulate", "pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5", "--steps", "150",
           "--solver", "pgs", "--tolerance", "1e-4", "--accelerate", "contestants:Liar", "-o", tmp_path / "run")
    assert r.returncode == 0 and "ended with a residual above the tolerance" in r.stderr, r.stderr
    above = json.loads((tmp_path / "run" / "manifest.json").read_text())["simulations"][0]["above_tolerance"]
    assert above > 0
    r = dc("validate", "--residuals", tmp_path / "run")
    assert r.returncode == 1 and f"{above} steps with a residual above its tolerance" in r.stderr
    assert r.stdout.count("is above its tolerance") == above


def test_a_start_that_hides_its_cost_is_timed_by_the_caller(run, tmp_path, contestants):
    r = dc("evaluate", run, "--starts", "builtin,contestants:HidesItsCost", "--every", "20", "--no-budgets", "-q",
           "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())["starts"]
    assert summary["contestants:HidesItsCost"]["predict_ms_median"] >= 3.0
    assert summary["builtin"]["predict_ms_median"] < 1.0
    report = (tmp_path / "r" / "report.md").read_text()
    assert "is **builtin**" in next(line for line in report.splitlines() if line.startswith("**Verdict**"))
