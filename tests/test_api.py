"""docs/api.md runs as written, and a start brought as a plug-in runs through dc evaluate (replay
and closed loop) like a built-in, by module path and by entry point; a broken one is one line."""
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from test_mutations import invoke

ROOT = Path(__file__).parent.parent
EXAMPLE = ROOT / "examples" / "deepcontact-example-plugins"


def test_the_api_page_runs_as_written(capsys):
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), flags=re.S)
    assert len(blocks) >= 2
    namespace = {"__name__": "api_page"}
    try:
        for block in blocks:
            exec(compile(block, "docs/api.md", "exec"), namespace)
    finally:   # (registered by the page; other tests see the built-ins)
        from deepcontact.model.arch import NETWORKS
        from deepcontact.warmstart import STARTS
        STARTS._builtin.pop("overshoot", None)
        NETWORKS._builtin.pop("two-convs", None)
    out = capsys.readouterr().out
    assert re.search(r"builtin\s+median\s+\d+ sweeps", out) and "mine" in out and "overshoot" in out, out
    assert re.search(r"\d+ weights", out), out
    assert re.search(r"step 79: \d+ contact points, \d+ iterations", out) and "grids (2, 33, 33)" in out, out


@pytest.fixture
def example_on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    yield
    for name in [m for m in sys.modules if m.startswith("dc_example_plugins")]:
        del sys.modules[name]


def test_a_start_by_module_path_runs_through_replay_and_the_closed_loop(run, tmp_path, example_on_path):
    start = "dc_example_plugins.starts:DampedBuiltin"
    r = invoke("evaluate", "--no-plots", run, "--starts", f"builtin,{start}", "--every", "20", "--no-budgets", "-q",
               "-o", tmp_path / "replay")
    assert r.exit_code == 0, r.stderr
    summary = json.loads((tmp_path / "replay" / "summary.json").read_text())["starts"]
    assert set(summary) == {"builtin", start}
    assert summary[start]["iterations_median"] > 0 and summary[start]["predict_ms_median"] >= 0
    r = invoke("evaluate", "--no-plots", run, "--starts", f"builtin,{start}", "--closed-loop", "--steps", "20",
               "--no-budgets", "-q", "-o", tmp_path / "loop")
    assert r.exit_code == 0, r.stderr
    assert start in (tmp_path / "loop" / "report.md").read_text()


@pytest.mark.pipeline
def test_an_installed_plugin_is_found_by_its_entry_point(run, dataset, tmp_path, monkeypatch):
    target = tmp_path / "site"
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                          "--target", str(target), str(EXAMPLE)], capture_output=True, text=True)
    assert pip.returncode == 0, pip.stderr
    # Here, with the installed distribution on the path (entry points are read from sys.path when asked) ...
    from deepcontact.model.arch import NETWORKS
    monkeypatch.syspath_prepend(str(target))
    try:
        r = invoke("train", dataset, "--arch", "tiny-conv", "--epochs", "1", "--no-plots", "-q", "-o", tmp_path / "m")
    finally:
        NETWORKS._loaded.clear()
        for name in [m for m in sys.modules if m.startswith("dc_example_plugins")]:
            del sys.modules[name]
    assert r.exit_code == 0, r.stderr
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")]))
    def dc_there(*args):   # ... and in a process of its own, which has seen nothing but its own path
        return subprocess.run([sys.executable, "-m", "deepcontact", *map(str, args)], capture_output=True, text=True,
                              env=env)
    # one evaluation finds all three kinds: a start, a solver method and (for the checkpoint) a network
    r = dc_there("evaluate", "--no-plots", run, "--starts", "builtin,damped-builtin,cnn", "--checkpoint",
                 tmp_path / "m" / "best.pt", "--arch", "tiny-conv", "--accelerate", "none,damped-jacobi",
                 "--max-iterations", "100", "--every", "20", "--no-budgets", "-q", "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    assert {"damped-builtin", "damped-builtin+damped-jacobi", "cnn", "cnn+damped-jacobi"} <= set(
        json.loads((tmp_path / "r" / "summary.json").read_text())["starts"])


BROKEN = textwrap.dedent('''
    import numpy as np
    from deepcontact.warmstart import StartValue

    class Raises:
        def __call__(self, ctx):
            raise RuntimeError("no idea")

    class WrongShape:
        def __call__(self, ctx):
            return StartValue(np.zeros(ctx.problem.points + 1), np.zeros(ctx.problem.points), {})

    class NotFinite:
        def __call__(self, ctx):
            return StartValue(np.full(ctx.problem.points, np.nan), np.zeros(ctx.problem.points), {})

    class NoValue:
        def __call__(self, ctx):
            return (1, 2)

    class NeedsArgs:
        def __init__(self, colour):
            pass

    NOT_CALLABLE = 3
    ''')


@pytest.mark.parametrize("name,needle", [("Raises", "raised RuntimeError: no idea"), ("WrongShape", "shape"),
                                         ("NotFinite", "non-finite"), ("NoValue", "must return a StartValue"),
                                         ("NeedsArgs", "could not be made"), ("NOT_CALLABLE", "not a class"),
                                         ("Missing", "cannot be loaded")])
def test_a_broken_start_is_one_line_and_leaves_nothing(run, tmp_path, monkeypatch, name, needle):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "broken_starts.py").write_text(BROKEN)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    r = invoke("evaluate", "--no-plots", run, "--starts", f"builtin,broken_starts:{name}", "--every", "20",
               "--no-budgets", "-o", tmp_path / "r")
    sys.modules.pop("broken_starts", None)
    assert r.exit_code == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"broken_starts:{name}" in lines[0] and needle in lines[0], lines
    assert not (tmp_path / "r").exists()


def test_a_network_plugin_trains_evaluates_and_draws_and_is_never_loaded_by_a_checkpoint(
        run, dataset, tmp_path, example_on_path):
    net = "dc_example_plugins.networks:TinyConv"
    r = invoke("train", dataset, "--arch", net, "--epochs", "1", "--no-plots", "-q", "-o", tmp_path / "m")
    assert r.exit_code == 0, r.stderr
    ck = tmp_path / "m" / "best.pt"
    from deepcontact.model.arch import NETWORKS
    NETWORKS._loaded.clear()   # a fresh process: nothing loaded or chosen but what the user names
    NETWORKS._chosen.clear()   # (dc train chose the network it trained, to read its checkpoints)
    r = invoke("evaluate", run, "--starts", "cnn", "--checkpoint", ck, "--every", "30", "--no-budgets",
               "-o", tmp_path / "r")
    assert r.exit_code == 1 and "name it with --arch" in r.stderr and not (tmp_path / "r").exists(), r.stderr
    r = invoke("evaluate", "--no-plots", run, "--starts", "builtin,cnn", "--checkpoint", ck, "--arch", net, "--every", "30",
               "--no-budgets", "-q", "-o", tmp_path / "r")
    assert r.exit_code == 0, r.stderr
    r = invoke("evaluate", "--no-plots", run, "--starts", "cnn", "--checkpoint", ck, "--arch", net, "--closed-loop",
               "--steps", "15", "--no-budgets", "-q", "-o", tmp_path / "loop")
    assert r.exit_code == 0, r.stderr
    r = invoke("render", dataset, "--sample", "0", "--checkpoint", ck, "--arch", net, "-q", "-o", tmp_path / "s.png")
    assert r.exit_code == 0 and (tmp_path / "s.png").stat().st_size > 1000, r.stderr
    NETWORKS._loaded.clear()


BROKEN_NETS = textwrap.dedent('''
    import torch
    from torch import nn

    class WrongShape(nn.Module):
        def __init__(self, in_channels, out_channels, height, width):
            super().__init__()
            self.conv = nn.Conv2d(in_channels, out_channels + 1, 1)
        def forward(self, x):
            return self.conv(x)

    class Raises(nn.Module):
        def __init__(self, in_channels, out_channels, height, width):
            super().__init__()
            self.conv = nn.Conv2d(in_channels, out_channels, 1)
        def forward(self, x):
            raise ValueError("not today")

    def NoModule(in_channels, out_channels, height, width):
        raise RuntimeError("cannot build")
    ''')


@pytest.mark.parametrize("name,needle", [("WrongShape", "it must give"), ("Raises", "not today"),
                                         ("NoModule", "cannot build")])
def test_a_broken_network_is_one_line(dataset, tmp_path, monkeypatch, name, needle):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "broken_nets.py").write_text(BROKEN_NETS)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    r = invoke("train", "--no-plots", dataset, "--arch", f"broken_nets:{name}", "--epochs", "1", "-o", tmp_path / "m")
    sys.modules.pop("broken_nets", None)
    lines = r.stderr.strip().splitlines()
    assert r.exit_code == 1 and len(lines) == 1 and needle in lines[0] and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "m").exists()


def test_old_spellings_still_work_and_say_they_are_deprecated(run, model, tmp_path):
    r = invoke("evaluate", "--no-plots", run, "--starts", "cnn", "--model", model / "best.pt", "--every", "40",
               "--no-budgets", "-q", "-o", tmp_path / "r")
    assert r.exit_code == 0 and "--model is deprecated in dc evaluate: use --checkpoint" in r.stderr, r.stderr
    r = invoke("evaluate", "--no-plots", run, "--starts", "cnn", "--model", model / "best.pt", "--checkpoint",
               model / "best.pt", "-o", tmp_path / "r2")
    assert r.exit_code == 2 and "give one" in r.stderr


def test_the_public_api_is_small_documented_and_lazy():
    import deepcontact
    assert sorted(dir(deepcontact)) == sorted(deepcontact.__all__)
    for name in deepcontact.__all__[1:]:
        obj = getattr(deepcontact, name)
        doc = (obj.__doc__ or "").strip()
        assert doc and not doc.startswith(f"{name}("), f"{name} has no docstring of its own"
    with pytest.raises(AttributeError):
        deepcontact.no_such_name


def test_reading_and_solving_a_step_does_not_import_torch(run):
    step = sorted(run.glob("seed-000000/step-*.xml"))[-1]
    code = ("import sys, deepcontact as dc; h, b, c = dc.read_step(sys.argv[1]); "
            "s = dc.solve(dc.StepProblem.from_step(h, b, c), tolerance=1e-4, max_iterations=1000); "
            "print(s.iterations, 'torch' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code, str(step)], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.split()[-1] == "False", r.stdout + r.stderr


def test_every_public_function_has_type_hints():
    import inspect
    import deepcontact
    missing = []
    for name in deepcontact.__all__[1:]:
        obj = getattr(deepcontact, name)
        if hasattr(obj, "register"):   # a registry instance: its methods are documented in plugins.py
            continue
        f = obj.__init__ if inspect.isclass(obj) else obj
        sig = inspect.signature(f)
        missing += [f"{name}({p.name})" for p in sig.parameters.values()
                    if p.name != "self" and p.annotation is inspect.Parameter.empty
                    and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
        if not inspect.isclass(obj) and sig.return_annotation is inspect.Signature.empty:
            missing.append(f"{name} -> ?")
    assert missing == []


def test_a_solver_method_plugin_runs_through_replay_the_closed_loop_and_simulate(run, tmp_path, example_on_path):
    method = "dc_example_plugins.solvers:ProjectedJacobi"
    r = invoke("evaluate", "--no-plots", run, "--starts", "builtin", "--accelerate", f"none,{method}", "--every", "30",
               "--max-iterations", "200", "-q", "-o", tmp_path / "replay")
    assert r.exit_code == 0, r.stderr
    summary = json.loads((tmp_path / "replay" / "summary.json").read_text())["starts"]
    assert set(summary) == {"builtin", f"builtin+{method}"}
    jacobi, sweeps = summary[f"builtin+{method}"], summary["builtin"]
    # Jacobi moves every row from the same iterate: it needs more iterations than Gauss-Seidel's sweeps
    assert jacobi["iterations_median"] > sweeps["iterations_median"] and jacobi["solve_ms_median"] > 0
    r = invoke("evaluate", "--no-plots", run, "--starts", "builtin", "--accelerate", method, "--closed-loop",
               "--steps", "10", "--max-iterations", "100", "--no-budgets", "-q", "-o", tmp_path / "loop")
    assert r.exit_code == 0, r.stderr
    r = invoke("simulate", "pile", "--param", "count=6", "--steps", "12", "--solver", "pgs", "--accelerate", method,
               "--tolerance", "1e-3", "--max-iterations", "300", "-q", "-o", tmp_path / "sim")
    assert r.exit_code == 0, r.stderr
    assert f'accelerate="{method}"' in (tmp_path / "sim" / "seed-000000" / "step-000011.xml").read_text()


def test_a_solver_method_is_judged_by_the_projects_residual(run, example_on_path):
    import deepcontact as dc
    from deepcontact.step.run_folder import read_run
    files = read_run(run).simulations[0].files
    problem = dc.StepProblem.from_step_file(files[len(files) // 2])
    method = "dc_example_plugins.solvers:ProjectedJacobi"
    dc.SOLVERS.load(method)
    solution = dc.solve(problem, tolerance=1e-3, max_iterations=500, accelerate=method, history=True)
    assert solution.residual == dc.judge(problem, solution.normal_impulse, solution.tangent_impulse).residual
    assert solution.history.shape == (solution.iterations, 3) and solution.history[-1, 2] == solution.residual


BROKEN_SOLVERS = textwrap.dedent('''
    import numpy as np
    from deepcontact import MethodResult

    class Raises:
        def __call__(self, problem, normal, tangent, settings):
            raise ArithmeticError("diverged")

    class WrongShape:
        def __call__(self, problem, normal, tangent, settings):
            return MethodResult(normal[:-1], tangent, np.zeros(1))

    class NotFinite:
        def __call__(self, problem, normal, tangent, settings):
            return MethodResult(normal * np.inf, tangent, np.zeros(1))

    class Pulls:
        def __call__(self, problem, normal, tangent, settings):
            return MethodResult(-np.ones_like(normal), tangent, np.zeros(1))

    class NoResult:
        def __call__(self, problem, normal, tangent, settings):
            return normal, tangent
    ''')


@pytest.mark.parametrize("name,needle", [("Raises", "raised ArithmeticError: diverged"), ("WrongShape", "shape"),
                                         ("NotFinite", "non-finite"), ("Pulls", "cannot pull"),
                                         ("NoResult", "not a deepcontact.solver.methods.MethodResult"),
                                         ("Missing", "cannot be loaded")])
def test_a_broken_solver_method_is_one_line_and_leaves_nothing(run, tmp_path, monkeypatch, name, needle):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "broken_solvers.py").write_text(BROKEN_SOLVERS)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    r = invoke("evaluate", "--no-plots", run, "--starts", "builtin", "--accelerate", f"broken_solvers:{name}",
               "--every", "20", "--no-budgets", "-o", tmp_path / "r")
    sys.modules.pop("broken_solvers", None)
    from deepcontact.solver import methods
    methods._instances.pop(f"broken_solvers:{name}", None)
    assert r.exit_code == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"broken_solvers:{name}" in lines[0] and needle in lines[0], lines
    assert not (tmp_path / "r").exists()
