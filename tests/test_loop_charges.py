"""The closed loop charged like replay (issue 72 item 6): every call its wall time or its sandbox's
CPU since its previous call, the larger, each less the null contestant's least over the run; work a
contestant leaves running is charged to it, and a net time at or below zero is a measurement error
stated, never a win."""
import json
import sys
import textwrap

import numpy as np
import pytest

from conftest import dc

CONTESTANTS = textwrap.dedent("""
    import os
    from deepcontact.warmstart.starts import StartValue

    class LeavesWorkRunning:
        '''Box2D's warm start, with a busy process started on its first call and left running: it slows
        the null contestant and the rivals, and its own calls answer at once.'''
        def __init__(self):
            self.child = None

        def __call__(self, ctx):
            if self.child is None:
                self.child = os.fork()
                if self.child == 0:
                    while True:
                        pass
            return StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), {})
    """)


@pytest.fixture
def busy(tmp_path, monkeypatch):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "busy.py").write_text(CONTESTANTS)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    yield "busy:LeavesWorkRunning"
    from deepcontact.warmstart.starts import STARTS
    sys.modules.pop("busy", None)
    STARTS._loaded.pop("busy:LeavesWorkRunning", None)


@pytest.fixture(scope="module")
def stacked(tmp_path_factory):
    """A run whose every step has contacts (a stack at rest): every loop step calls the start."""
    out = tmp_path_factory.mktemp("stack") / "run"
    assert dc("simulate", "stack", "--param", "count=8", "--steps", "60", "-q", "-o", out).returncode == 0
    return out


def test_work_left_running_in_the_loop_is_charged_and_never_named_faster(stacked, tmp_path, busy):
    r = dc("evaluate", "--no-plots", stacked, "--closed-loop", "--starts", f"builtin,{busy}", "--steps", "60",
           "--no-budgets", "-q", "-o", tmp_path / "loop")
    assert r.returncode == 0, r.stderr
    rows = {row["start"]: row for row in json.loads((tmp_path / "loop" / "closed-loop.json").read_text())["results"]}
    builtin, attacker = (float(np.median(rows[n]["ms_per_step"])) for n in ("builtin", busy))
    # (its process burns a core, or its share of one, while the others step: far beyond builtin's step)
    assert attacker > 2 * builtin, (attacker, builtin)
    verdict = next(line for line in (tmp_path / "loop" / "report.md").read_text().splitlines()
                   if line.startswith("**Verdict**"))
    assert f"{busy}**" not in verdict and f"{busy} has the smallest" not in verdict, verdict
