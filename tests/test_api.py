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
    finally:
        from deepcontact.warmstart import STARTS
        STARTS._builtin.pop("overshoot", None)   # (registered by the page; other tests see the built-ins)
    out = capsys.readouterr().out
    assert re.search(r"builtin\s+median\s+\d+ sweeps", out) and "mine" in out and "overshoot" in out, out


@pytest.fixture
def example_on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    yield
    for name in [m for m in sys.modules if m.startswith("dc_example_plugins")]:
        del sys.modules[name]


def test_a_start_by_module_path_runs_through_replay_and_the_closed_loop(run, tmp_path, example_on_path):
    start = "dc_example_plugins.starts:DampedBuiltin"
    r = invoke("evaluate", run, "--starts", f"builtin,{start}", "--every", "20", "--no-budgets", "-q",
               "-o", tmp_path / "replay")
    assert r.exit_code == 0, r.stderr
    summary = json.loads((tmp_path / "replay" / "summary.json").read_text())["starts"]
    assert set(summary) == {"builtin", start}
    assert summary[start]["iterations_median"] > 0 and summary[start]["predict_ms_median"] >= 0
    r = invoke("evaluate", run, "--starts", f"builtin,{start}", "--closed-loop", "--steps", "20", "--no-budgets",
               "-q", "-o", tmp_path / "loop")
    assert r.exit_code == 0, r.stderr
    assert start in (tmp_path / "loop" / "closed-loop.md").read_text()


def test_an_installed_plugin_is_found_by_its_entry_point(run, tmp_path):
    target = tmp_path / "site"
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                          "--target", str(target), str(EXAMPLE)], capture_output=True, text=True)
    assert pip.returncode == 0, pip.stderr
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-m", "deepcontact", "evaluate", str(run), "--starts", "builtin,damped-builtin",
                        "--every", "20", "--no-budgets", "-q", "-o", str(tmp_path / "r")],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    assert "damped-builtin" in json.loads((tmp_path / "r" / "summary.json").read_text())["starts"]
    r = subprocess.run([sys.executable, "-m", "deepcontact", "evaluate", "--help"], capture_output=True, text=True,
                       env=env)
    assert r.returncode == 0


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
    r = invoke("evaluate", run, "--starts", f"builtin,broken_starts:{name}", "--every", "20", "--no-budgets",
               "-o", tmp_path / "r")
    sys.modules.pop("broken_starts", None)
    assert r.exit_code == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"broken_starts:{name}" in lines[0] and needle in lines[0], lines
    assert not (tmp_path / "r").exists()
