"""dc evaluate: the starts, their orderings on a real run, the report, and the whole pipeline."""
import shutil

import numpy as np
import pytest

from conftest import dc
from deepcontact.errors import InputError
from deepcontact.evaluate.replay import evaluate
from deepcontact.evaluate.summary import summarize
from deepcontact.solver.settings import SolveSettings
from deepcontact.warmstart.starts import make_starts
from deepcontact.grid.spec import GridSpec



@pytest.fixture(scope="module")
def settled_pile(tmp_path_factory):
    """A small pile run long enough (300 steps) that most sampled steps are a resting pile."""
    out = tmp_path_factory.mktemp("eval") / "run"
    r = dc("simulate", "pile", "--param", "count=30", "--param", "box=16", "--param", "sigma=4", "--steps", "300",
           "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def rows_and_summary(settled_pile):
    starts = make_starts(["zero", "builtin", "copy", "copy2", "sph", "bad", "random"],
                         spec=GridSpec.over((0, 0, 16, 16), 0.5, 0.5))
    rows = evaluate([settled_pile], starts, settings=SolveSettings(tolerance=1e-4, max_iterations=3000), every=10)
    return rows, summarize(rows, starts, 3000)


def test_the_orderings_an_honest_comparison_must_show(rows_and_summary):
    _, s = rows_and_summary
    med = {k: v["iterations_median"] for k, v in s.items()}
    assert med["copy"] <= 3                                   # the answer converges at once
    assert med["copy2"] <= med["builtin"]
    assert med["builtin"] < med["zero"]                      # Box2D's warm start beats zero
    assert med["bad"] > med["zero"]                          # a bad start is worse than none
    assert s["copy"]["error_median"] < 1e-9
    assert all(v["residual_median"] < 1e-4 or v["at_cap"] > 0 for v in s.values())
    # (every start's whole call is timed by the caller: zero's is the call itself, sph's rasterizes)
    assert 0 <= s["zero"]["predict_ms_median"] < s["sph"]["predict_ms_median"]   # (net of transport)


def test_every_step_is_solved_from_every_start(rows_and_summary):
    rows, s = rows_and_summary
    steps = {(r.seed, r.step) for r in rows}
    assert len(rows) == len(steps) * len(s)
    for r in rows:
        assert r.iterations >= 1 and np.isfinite(r.residual) and np.isfinite(r.history[0])
        assert len(r.history) == r.iterations + 1
        assert r.capped or r.history[-1] < 1e-4            # converged to the tolerance, or hit the cap


def test_unknown_starts_and_missing_model_are_clear_errors(pile_run, tmp_path):
    with pytest.raises(InputError, match="unknown start"):
        make_starts(["zero", "lucky"])
    with pytest.raises(InputError, match="needs? a trained model"):
        make_starts(["cnn"])
    r = dc("evaluate", "--no-plots", str(pile_run), "--starts", "zero,nope", "-o", str(tmp_path / "r"))
    assert r.returncode == 2 and "nope" in r.stderr and not (tmp_path / "r").exists()   # a bad option value
    r = dc("evaluate", "--no-plots", str(tmp_path), "-o", str(tmp_path / "r2"))
    assert r.returncode == 1 and "manifest" in r.stderr


@pytest.mark.pipeline
def test_the_smoke_pipeline(request):
    """make smoke-pipeline (started when the run began: conftest.BACKGROUND) made a full report."""
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    from conftest import finished
    report = finished("smoke", request.config) / "smoke" / "report"
    for name in ("report.md", "summary.csv", "summary.json", "steps.csv", "pareto.json", "convergence.png",
                 "convergence.svg", "iterations.png", "pareto.png", "pareto.svg"):
        assert (report / name).exists(), name
    text = (report / "report.md").read_text()
    assert "| cnn |" in text and "| guarded |" in text and "What accuracy costs in time" in text


def test_evaluate_reads_each_run_once_and_takes_the_sph_window_from_the_manifest(tmp_path, monkeypatch):
    """The run folders are read once (the Run objects passed down), and the sph start's grid
    comes from the manifest's static box, the same grid the dataset writer draws, without
    reading the runs as a dataset."""
    from conftest import dc, simulate
    from deepcontact.evaluate import replay
    from deepcontact.grid import sources, window
    run = tmp_path / "run"
    simulate(run, seeds=(0, 1))
    sims, _ = sources.collect([run])
    expected, _ = window.grid_for(sims, 0.5, 0.5, "poly6", True)
    reads, real = [], replay.read_run
    monkeypatch.setattr(replay, "read_run", lambda path, **kw: reads.append(path) or real(path, **kw))
    monkeypatch.setattr(sources, "collect", lambda *a, **k: pytest.fail("read as a dataset"))
    grids = []
    from deepcontact.warmstart import starts
    real_make = starts.make_starts
    monkeypatch.setattr(starts, "make_starts", lambda names, spec=None, predictor=None:
                        grids.append(spec) or real_make(names, spec=spec, predictor=predictor))
    r = dc("evaluate", "--no-plots", run, "--starts", "builtin,sph", "--every", "10", "--no-budgets", "-q",
           "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    assert len(reads) == 1 and grids == [expected]


@pytest.mark.parametrize("changes,flag,words", [
    (dict(starts=["cnn"]), "--checkpoint", "need a trained model"),
    (dict(starts=["sph"], cell=0.5, smoothing=1e-30), "--cell", "cannot carry"),
    (dict(solve=SolveSettings(mode="float32"), accelerations=("newton",)), "--accelerate", "float64 only"),
    (dict(relaxations=(2.5,)), "--relaxation", "relaxation must be in (0, 2)"),
])
def test_evaluate_settings_check_their_own_rules_for_the_cli_and_a_library_caller(tmp_path, changes, flag, words):
    from conftest import dc
    from deepcontact.errors import OptionError
    from deepcontact.evaluate.command import EvaluateSettings
    with pytest.raises(OptionError) as e:
        EvaluateSettings(runs=[tmp_path], **{"starts": ["builtin"], **changes}).checked()
    assert words in str(e.value) and flag in str(e.value)
    args = {"starts": ",".join(changes.get("starts", ["builtin"]))}
    cli = ["--starts", args["starts"]]
    if "cell" in changes:
        cli += ["--cell", "0.5", "--smoothing", "1e-30"]
    if "solve" in changes:
        cli += ["--mode", "float32", "--accelerate", "newton"]
    if "relaxations" in changes:
        cli += ["--relaxation", "2.5"]
    r = dc("evaluate", "--no-plots", tmp_path, *cli, "-o", tmp_path / "r")
    assert r.returncode == 2 and words in r.stderr, r.stderr


@pytest.mark.parametrize("loop", [False, True])
def test_no_plots_writes_the_tables_alone(pile_run, tmp_path, loop):
    """--no-plots: the same tables, no picture, and no page that points at one."""
    extra = ["--closed-loop", "--steps", "20"] if loop else ["--every", "50"]
    for flag, out in (("--plots", tmp_path / "full"), ("--no-plots", tmp_path / "tables")):
        r = dc("evaluate", pile_run, "--starts", "zero,builtin", "--no-budgets", *extra, flag, "-q", "-o", out)
        assert r.returncode == 0, r.stderr
    drawn = {p.name for p in (tmp_path / "full").iterdir() if p.suffix in (".png", ".svg")}
    assert drawn and not any(p.suffix in (".png", ".svg") for p in (tmp_path / "tables").iterdir())
    for page in ("report.md", "report.html"):
        text = (tmp_path / "tables" / page).read_text()
        assert ".png" not in text and "<svg" not in text, page
    assert (tmp_path / "full" / "summary.csv").exists() and (tmp_path / "tables" / "summary.csv").exists()
    if not loop:
        r = dc("evaluate", pile_run, "--starts", "zero", "--bands", "--no-plots", "-o", tmp_path / "x")
        assert r.returncode == 2 and "--bands" in r.stderr and "--no-plots" in r.stderr
