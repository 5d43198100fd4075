"""The closed loop's "of which prediction" is the start's share of "ms per step": both over the
same steps. The start's time was kept only for the steps that asked it (those with contact
points) and its median set beside the median over every step, so a slow start on a scene that
falls for most of its steps was reported predicting 5.28 ms of a 0.063 ms step."""
import textwrap

import numpy as np

import deepcontact as dc
from conftest import dc as invoke

SLOW = textwrap.dedent('''
    import time

    from deepcontact import StartValue


    class Slow:
        """Box2D's warm start, after 5 ms of prediction."""

        def __call__(self, ctx):
            t0 = time.perf_counter()
            time.sleep(0.005)
            return StartValue(ctx.problem.start_normal, ctx.problem.start_tangent, {"predict": time.perf_counter() - t0})
''')


def test_prediction_is_a_share_of_each_steps_time(tmp_path, monkeypatch):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "slow_starts.py").write_text(SLOW)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    scene = dc.generate("pile", 0, {"count": 6, "box": 20, "sigma": 2, "steps": 200})   # (falling: most steps touch nothing)
    results = dc.closed_loop(scene, dc.make_starts(["builtin", "slow_starts:Slow"]), steps=200)
    for r in results:
        if not r.ours:
            continue
        assert len(r.predict_ms) == len(r.ms_per_step) == r.steps, (r.start, len(r.predict_ms), r.steps)
        assert np.all(r.predict_ms <= r.ms_per_step + 1e-9), r.start
        assert np.median(r.predict_ms) <= np.median(r.ms_per_step), r.start
    slow = next(r for r in results if r.start == "slow_starts:Slow")
    touched = slow.predict_ms > 0
    assert 0 < touched.sum() < len(touched) / 2 and np.median(slow.predict_ms[touched]) > 2, touched.sum()


def test_the_loop_table_never_says_prediction_beyond_the_steps_time(tmp_path, monkeypatch):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "slow_loop_starts.py").write_text(SLOW)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    run = tmp_path / "tall"
    assert invoke("simulate", "pile", "--param", "count=6", "--param", "box=20", "--param", "sigma=2", "--steps", "200",
                  "-q", "-o", run).returncode == 0
    r = invoke("evaluate", run, "--closed-loop", "--starts", "builtin,slow_loop_starts:Slow", "--no-plots", "-q", "-o",
               tmp_path / "loop")
    assert r.returncode == 0, r.stderr
    lines = (tmp_path / "loop" / "report.md").read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if "of which prediction" in line)
    columns = [c.strip() for c in lines[head].strip("|").split("|")]
    total, share = columns.index("ms per step (median)"), columns.index("of which prediction")
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines[head + 2:] if line.startswith("|")]
    assert rows and all(float(row[share]) <= float(row[total]) for row in rows), rows
