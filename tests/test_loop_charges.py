"""The closed loop charged like replay: every call its wall time or its sandbox's CPU in it, the
larger, each less the null contestant's least over the run, and the CPU no call can have used
(between calls, or beyond what its CPUs could run in a call's wall time) spread over its steps; work
a contestant leaves running is charged to it, on its typical step too, and a net time at or below
zero is a measurement error stated, never a win."""
import csv
import json
import sys
import textwrap
from types import SimpleNamespace as Seen

import numpy as np
import pytest

from conftest import dc
from deepcontact import make_starts
from deepcontact.contest.charge import in_call, unasked_pool

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
    # (its process burns a core, or its share of one, while the others step: charged beyond
    # builtin's step; by how much is the machine's load's to say, so no factor is asked)
    assert attacker > builtin, (attacker, builtin)
    # and on its typical step, not only in total: that CPU reaches its control group in lumps, at
    # the kernel's ticks, which land on a few of its steps and which a median step once missed
    # (0.083 ms against builtin's 0.085); spread over its steps, most of it is in its median
    mean = float(np.mean(rows[busy]["ms_per_step"])) - float(np.mean(rows["builtin"]["ms_per_step"]))
    assert attacker - builtin > mean / 4, (attacker, builtin, mean)
    verdict = next(line for line in (tmp_path / "loop" / "report.md").read_text().splitlines()
                   if line.startswith("**Verdict**"))
    assert f"{busy}**" not in verdict and f"{busy} has the smallest" not in verdict, verdict


def loop_row(name, ms, again=None):
    from deepcontact.evaluate.closed_loop import LoopResult
    n = len(ms)
    return LoopResult(start=name, steps=n, iterations=np.full(n, 10), ms_per_step=np.asarray(ms, np.float64),
                      predict_ms=np.zeros(n), drift=np.zeros(n), penetration=0.0, finite=True,
                      residuals=np.full(n, 1e-5), ms_again=again)


def test_work_left_running_in_replay_is_charged_on_its_typical_step(stacked, tmp_path, busy):
    r = dc("evaluate", "--no-plots", stacked, "--starts", f"builtin,{busy}", "--every", "2", "--no-budgets", "-q",
           "-o", tmp_path / "replay")
    assert r.returncode == 0, r.stderr
    rows = [row for row in csv.DictReader((tmp_path / "replay" / "steps.csv").open())]
    ms = {n: np.array([float(row["predict_ms"]) + float(row["solve_ms"]) for row in rows if row["start"] == n])
          for n in ("builtin", busy)}
    excess = np.median(ms[busy]) - np.median(ms["builtin"])
    assert excess > (ms[busy].mean() - ms["builtin"].mean()) / 4, (np.median(ms[busy]), np.median(ms["builtin"]))
    summary = json.loads((tmp_path / "replay" / "summary.json").read_text())["starts"]
    assert summary[busy]["left_running"] == [0, 1]


def test_replay_spreads_what_its_own_contestants_used_between_calls(stacked, monkeypatch):
    from deepcontact.evaluate import replay
    seen, spread = [], replay.spread_unasked

    def spreads(rows, contestants, null, twin=None):   # (the real one, its arguments kept)
        before = {id(r): r.predict_ms for r in rows}
        spread(rows, contestants, null, twin)
        seen.append((rows, contestants, null, twin, before))
    monkeypatch.setattr(replay, "spread_unasked", spreads)
    rows = replay.evaluate([stacked], make_starts(["builtin", "zero"]), every=6)
    [(spread_rows, contestants, null, twin, before)] = seen
    assert spread_rows == rows and twin is not None and set(contestants) == {"builtin", "zero", twin.label}
    # every one of them read its CPU between calls apart, from the calls of this run
    for c in (*contestants.values(), null):
        assert c.unasked and c.calls >= len(rows) // 2 and c.outside_s >= 0, (c.label, c.calls)
        assert c.cpus == 1   # (the threads each is granted: one, whatever the machine's CPUs)
    for label, c in contestants.items():
        mine = [r for r in rows if r.start == label]
        share = unasked_pool(c, null) * 1e3 / max(len(mine), 1)
        assert all(r.predict_ms == pytest.approx(before[id(r)] + share) for r in mine), label


BURNS_BETWEEN = textwrap.dedent("""
    import os, time
    import numpy as np
    from deepcontact.solver.methods import MethodResult

    class Method:
        '''Answers with its start at once; its first call leaves a process that burns 0.2 s of CPU
        and ends, between its calls.'''
        calls = 0
        def __call__(self, problem, normal, tangent, settings):
            Method.calls += 1
            if Method.calls == 1 and os.fork() == 0:
                end = time.process_time() + 0.2
                while time.process_time() < end:
                    pass
                os._exit(0)
            return MethodResult(normal, tangent, np.zeros(1))
    """)


def test_a_studys_plugin_method_is_charged_the_cpu_it_used_beyond_its_calls(stacked, tmp_path, monkeypatch):
    # (the studies time a step by its wall time less its solves' round trips: work a method's
    # process did beside them, which that wall time does not hold, is added)
    import time
    from conftest import plugin_modules
    from deepcontact.contest import RemoteMethod
    from deepcontact.solver.problem import StepProblem
    from deepcontact.solver.settings import SolveSettings
    forget = plugin_modules(tmp_path, monkeypatch, {"burns_between": BURNS_BETWEEN})
    remote = RemoteMethod("burns_between:Method")
    try:
        problem = StepProblem.from_step_file(sorted(stacked.glob("seed-000000/step-*.xml"))[-1])
        settings = SolveSettings(accelerate="burns_between:Method")
        zeros = np.zeros(problem.points)
        remote.solve(problem, zeros, zeros, settings)
        first = remote.take_transport()
        burnt = remote.contestant.sandbox.cpu_seconds()
        for _ in range(200):   # (until the burner's CPU is in its group: it is once it has ended)
            if remote.contestant.sandbox.cpu_seconds() - burnt >= 0.15:
                break
            time.sleep(0.05)
        remote.solve(problem, zeros, zeros, settings)
        # its round trip less what its process used before it was asked (0.2 s in all, some of it
        # counted in the first call already): far below zero
        assert remote.take_transport() < min(first, 0.0) - 0.1, first
    finally:
        remote.close()
        forget()


def test_a_net_time_at_or_below_zero_is_a_measurement_error_never_a_win():
    from deepcontact.evaluate.loop_report import loop_table
    from deepcontact.evaluate.verdicts import loop_verdict
    rng = np.random.default_rng(7)
    builtin = rng.uniform(1.0, 1.2, 60)
    again = builtin * (1 + 0.01 * rng.standard_normal(60))
    under = builtin / 3
    under[::10] = -0.4   # (what the loop once reported for a start that slowed the null: -0.4 to -3.9 ms)
    fast = builtin / 2
    rows = [loop_row("builtin", builtin, again), loop_row("under", under), loop_row("fast", fast)]
    line = loop_verdict(rows, 1e-4)
    # (its median alone is a third of builtin's: named on it, were its steps believed)
    assert "**under**" not in line and "is **fast**" in line, line
    assert "Left out as a measurement error, a net time per step at or below zero" in line and "under (6 steps)" in line
    row = next(r for r in loop_table(rows, 1e-4).splitlines() if r.startswith("| under"))
    assert "measurement error: a net time at or below zero on 6 steps" in row
    zero = under.copy()
    zero[::10] = 0.0   # (zero is no faster than measured: an error too)
    assert "**under**" not in loop_verdict([rows[0], loop_row("under", zero)], 1e-4)
    broken = builtin.copy()
    broken[3] = -1.0
    line = loop_verdict([loop_row("builtin", broken, again), loop_row("fast", fast)], 1e-4)
    assert line.startswith("**Verdict**: none is named: Box2D's warm start's own time") and "**fast**" not in line


def test_a_start_slow_on_every_step_it_is_asked_has_no_smallest_median_from_steps_it_is_not():
    # (a pile that falls for 45 of its 60 steps touches nothing there: no start is asked, and each
    # variant's step is the engine's alone; a fork bomb slow on every step it was asked was said to
    # have the smallest median, 0.62x builtin's, from the engine's steps' noise)
    from deepcontact.evaluate.verdicts import loop_verdict
    rng = np.random.default_rng(3)
    falling = np.full(60, np.nan)
    falling[45:] = 1e-5
    builtin = np.concatenate([rng.uniform(0.045, 0.055, 45), rng.uniform(1.0, 1.2, 15)])
    again = builtin * (1 + 0.01 * rng.standard_normal(60))
    slow = np.concatenate([builtin[:45] * 0.6, builtin[45:] * 40])
    rows = [loop_row("builtin", builtin, again), loop_row("slow", slow)]
    for r in rows:
        r.residuals = falling
    line = loop_verdict(rows, 1e-4)
    assert "slow has the smallest median" not in line and "**slow**" not in line, line
    assert "intervals over the steps with contact points" in line, line
    from deepcontact.evaluate.loop_report import loop_table
    table = {r.split("|")[1].strip(): float(r.split("|")[8]) for r in loop_table(rows, 1e-4).splitlines()[2:]}
    assert table["slow"] > 10 * table["builtin"], table   # (the table's medians: the same steps)


class Answered:
    """What a Contestant's last call measured (Contestant.last: wall seconds, CPU seconds; outside:
    the part of that CPU its sandbox used before it was asked)."""

    def __init__(self, wall, cpu, outside=0.0):
        self.last, self.outside = (wall, cpu), outside


def test_cpu_used_between_calls_is_spread_over_the_steps_not_charged_where_it_lands():
    from deepcontact.contest.charge import StepCharges
    charges = StepCharges()
    null = Answered(0.5e-3, 0.1e-3)
    for k in range(8):   # (a lump of 4 ms, a tick's worth, reached the reads before every fourth call)
        lump = 4.0e-3 if k % 4 == 3 else 0.0
        charges.record("start", Answered(1.0e-3, 0.2e-3 + lump, outside=lump), null)
        charges.step_done()
    charges.step_done()   # (a step that asked nothing: charged nothing)
    # each step: its call's wall less the null's (0.5 ms), and 8 ms of CPU between calls over the 8
    # steps that asked it
    assert list(charges.charged()) == pytest.approx([0.5e-3] * 8 + [0.0])
    # (the contestant's own sums over the run, which its calls keep: Contestant.outside_s, calls)
    assert list(charges.unasked(unasked_pool(Seen(outside_s=8e-3, calls=8), Seen(outside_s=0.0, calls=8)))) \
        == pytest.approx([1.0e-3] * 8 + [0.0])
    assert list(charges.uncharged()) == pytest.approx([1.0e-3] * 8 + [0.0])   # (the round trips less the charges)
    # what the null used between its calls is no floor: the least CPU of its calls, once asked
    charges.record("start", Answered(1.0e-3, 0.2e-3), Answered(0.5e-3, 0.3e-3, outside=0.25e-3))
    assert charges.nulls["start"] == (0.5e-3, pytest.approx(0.05e-3))
    charges.step_done()
    # but its mean between calls (every guest's send and return, after the judge's read) is taken
    # off as many times: 8 ms less 9 calls x its mean (0.25 ms over its 9), over the 9 steps that asked
    pool = 8e-3 - 9 * 0.25e-3 / 9
    assert unasked_pool(Seen(outside_s=8e-3, calls=9), Seen(outside_s=0.25e-3, calls=9)) == pytest.approx(pool)
    assert list(charges.unasked(pool)) == pytest.approx([pool / 9] * 8 + [0.0] + [pool / 9])


def test_cpu_no_call_can_have_used_is_set_apart_and_a_calls_own_threads_are_not():
    from deepcontact.contest.charge import StepCharges, split_cpu
    # 1 ms of wall on 2 CPUs: at most 2 ms of CPU can be the call's; the 0.3 ms read before the
    # request was used between calls
    assert split_cpu(2.3e-3, 0.3e-3, 1.0e-3, 2) == pytest.approx((2.0e-3, 0.3e-3))
    # a lump the kernel accounted while the call was on (4 ms in a call of 1 ms) was run before it
    assert split_cpu(4.5e-3, 0.3e-3, 1.0e-3, 2) == pytest.approx((2.0e-3, 2.5e-3))
    assert split_cpu(0.2e-3, 0.0, 1.0e-3, 1) == (0.2e-3, 0.0)
    # so a start that works on two threads on every fourth step keeps that step's charge: its
    # steps keep their shape (its heavy steps spread over all would move its median)
    charges = StepCharges()
    null = Answered(0.5e-3, 0.1e-3)
    for k in range(8):
        charges.record("start", Answered(1.0e-3, 1.9e-3 if k % 4 == 3 else 0.2e-3), null)
        charges.step_done()
    assert list(charges.charged()) == pytest.approx([0.5e-3, 0.5e-3, 0.5e-3, 1.8e-3] * 2)
    assert list(charges.unasked(unasked_pool(Seen(outside_s=0.0, calls=8), Seen(outside_s=0.0, calls=8)))) \
        == pytest.approx([0.0] * 8)


class ScriptedGroup:
    """A sandbox whose control group's CPU reads are given in turn (None: a read that failed)."""

    def __init__(self, reads):
        self.reads = list(reads)

    def cpu_seconds(self):
        return self.reads.pop(0)


def test_a_contestants_call_sets_apart_what_no_call_can_have_used(monkeypatch):
    # (its group's reads, scripted: the real ones depend on the kernel's ticks; the call itself,
    # its line and its answer, is not what is tested here)
    from deepcontact.contest.client import Contestant

    def contestant(threads, reads):
        c = object.__new__(Contestant)
        c.unasked, c.cpus, c.cpu_last = True, threads, 1.0
        c.outside, c.outside_s, c.calls = 0.0, 0.0, 0
        c.sandbox, c.conn = ScriptedGroup(reads), Seen(send_bytes=lambda data: None)
        monkeypatch.setattr(c, "_receive", lambda deadline, doing: ({}, {}), raising=False)
        return c
    clock = iter([10.0, 10.001, 20.0, 20.001, 30.0, 30.001, 40.0, 40.001])   # (each call 1 ms of wall)
    monkeypatch.setattr("deepcontact.contest.client.time.perf_counter", lambda: next(clock))
    c = contestant(1, [1.0003, 1.0043])   # 0.3 ms between calls, then 4 ms in a 1 ms call on 1 thread
    assert c._timed(b"", 1.0, "answering")[0] == pytest.approx(4.3e-3)   # (what `call` returns: all of it)
    assert c.last == pytest.approx((1e-3, 4.3e-3)) and c.outside == pytest.approx(3.3e-3)
    assert in_call(c) == pytest.approx((1e-3, 1e-3))
    c = contestant(2, [1.0003, 1.0023])   # granted two threads: 2 ms in 1 ms of wall is the call's
    c._timed(b"", 1.0, "answering")
    assert c.outside == pytest.approx(0.3e-3) and c.outside_s == pytest.approx(0.3e-3) and c.calls == 1
    c = contestant(1, [None, 1.0043])   # the read before the request failed: the bound still holds
    c._timed(b"", 1.0, "answering")
    assert c.outside == pytest.approx(3.3e-3)
    c = contestant(1, [1.0003, None])   # the read after it failed: its CPU is charged to the next call
    c._timed(b"", 1.0, "answering")
    assert c.last[1] == 0.0 and c.outside == 0.0 and c.cpu_last == 1.0


def test_replay_spreads_each_sandboxs_cpu_between_calls_over_its_rows_starts():
    from deepcontact.evaluate.replay import spread_unasked
    rows = [Seen(start=name, predict_ms=0.1, predict_ms_again=0.1 if name == "builtin" else None)
            for _ in range(4) for name in ("builtin", "busy")]
    null = Seen(outside_s=10e-6, calls=10)   # (1 us a call: its guest's send and return)
    contestants = {"builtin": Seen(outside_s=5e-6, calls=5), "busy": Seen(outside_s=40e-3 + 5e-6, calls=5)}
    twin = Seen(outside_s=9e-6, calls=5)
    spread_unasked(rows, contestants, null, twin)
    busy = [r.predict_ms for r in rows if r.start == "busy"]
    assert busy == pytest.approx([0.1 + 40 / 4] * 4)   # (40 ms over its 4 rows, its 5 us of sends taken off)
    assert [r.predict_ms for r in rows if r.start == "builtin"] == pytest.approx([0.1] * 4)
    assert [r.predict_ms_again for r in rows if r.start == "builtin"] == pytest.approx([0.1 + 4e-3 / 4] * 4)


def test_a_null_slowed_by_a_contestant_does_not_enlarge_what_is_subtracted():
    from deepcontact.contest.charge import StepCharges, call_charge
    charges = StepCharges()
    # two steps: the same call (1.0 ms wall, 0.2 ms CPU), the null's round trip 0.5 ms, then 3 ms slowed
    for null_wall in (0.5e-3, 3.0e-3):
        charges.record("start", Answered(1.0e-3, 0.2e-3), Answered(null_wall, 0.1e-3))
        charges.step_done()
    assert charges.nulls == {"start": (0.5e-3, 0.1e-3)}   # (the least over the run)
    assert list(charges.charged()) == pytest.approx([0.5e-3, 0.5e-3])
    # the slowed null's own round trip is taken out of its step (it is not the contestant's), and no more
    assert charges.uncharged()[1] == pytest.approx(3.0e-3 + 1.0e-3 - 0.5e-3)
    # CPU its sandbox used in a call is charged beyond the wall time
    assert call_charge(1.0e-3, 9.0e-3, charges.nulls["start"]) == pytest.approx(8.9e-3)
    assert call_charge(0.2e-3, 0.0, charges.nulls["start"]) == 0.0   # (never below zero)


def test_every_answer_is_sent_after_its_threads_cpu_is_in_its_control_group(monkeypatch):
    # A task's CPU reaches its control group at a scheduling event, a tick or a read of its own
    # CPU clock; the judge reads the group as soon as an answer arrives. Without the read before
    # the answer, a call whose work was not yet there read as no CPU: the null's least, the floor
    # of every charge, read 0 (benchmarks/bench_charge_lag.py shows the race itself).
    from deepcontact.contest import guest
    order = []
    monkeypatch.setattr(guest.time, "thread_time_ns", lambda: order.append("clock read") or 0)

    class Line:
        def send_bytes(self, data):
            order.append("sent")
    guest._send(Line(), b"answer")
    assert order == ["clock read", "sent"]
    # and every answer goes through it: the contestant's loop, its setup and the engines' replies
    source = open(guest.__file__).read()
    assert source.count("conn.send_bytes(") == 1 and "_send(conn, reply)" in source
