"""Reports that agree with themselves: a variant marked "did not converge" is never named the
fastest (replay and the closed loop alike), the columns "at the cap" and "above tolerance" count
one way (a step at all never shows as 0%), and an A/A interval that says the machine was too
noisy to time names no winner. Built from rows and results directly: the verdicts take data."""
import numpy as np
import pytest

from deepcontact.contest.verdict import NOISE_LIMIT
from deepcontact.evaluate.closed_loop import LoopResult
from deepcontact.evaluate.noise import judge
from deepcontact.evaluate.replay import Row
from deepcontact.evaluate.report import summary_table
from deepcontact.evaluate.summary import summarize
from deepcontact.evaluate.verdicts import as_share, loop_verdict, verdict
from deepcontact.evaluate.loop_report import loop_table

STEPS = 40


def rows(times, above=None, capped=None, first=None, seed=0):
    """Replay rows: per variant, per-step times (ms) with 2% noise, builtin's asked twice (its
    A/A); above and capped {variant: step indices}; first {variant: factor}: its A/A's first half
    against its second (the second call's time divided by it)."""
    rng = np.random.default_rng(seed)
    above, capped, first = above or {}, capped or {}, first or {}
    out = []
    for name, per_step in times.items():
        for step, t in enumerate(per_step):
            calls = t * (1 + 0.02 * rng.standard_normal(2))
            out.append(Row(run="r", seed=0, step=step, points=10, start=name, iterations=10,
                           capped=step in capped.get(name, ()), above=step in above.get(name, ()),
                           residual=1e-5, error=0.0, velocity_error=0.0, predict_ms=0.0,
                           solve_ms=float(calls[0]), history=np.zeros(1),
                           solve_ms_again=float(calls[1] / first.get(name, 1.0)) if name == "builtin" else None))
    return out


def replay_verdict(rs):
    summary = summarize(rs, None, 1000)
    return verdict(summary, judge(rs, summary, "builtin", lambda name: False))


def base_times(seed=1):
    return np.random.default_rng(seed).uniform(0.9, 1.1, STEPS)


def test_builtin_that_did_not_converge_on_a_step_is_never_called_the_fastest():
    """The report's own case: builtin fastest by far, one step of its 40 above the tolerance."""
    t = base_times()
    line = replay_verdict(rows({"builtin": t, "slow": 2 * t}, above={"builtin": {7}}))
    assert "**builtin**" not in line and "the fastest" not in line, line
    assert line.startswith("**Verdict**: no clear winner") and "did not converge is never named" in line, line
    assert "builtin has the smallest" not in line and "ended 1 step above the tolerance" in line, line
    assert "of those that converged on every step, slow has the smallest" in line, line


def test_a_faster_variant_that_did_not_converge_is_never_named_even_where_builtin_did_not_either():
    """Both left one step unfinished (so neither left more than the other): still neither named."""
    t = base_times()
    line = replay_verdict(rows({"builtin": t, "fast": t / 2}, above={"builtin": {3}, "fast": {5}}))
    assert "**fast**" not in line and "the fastest" not in line and "fast has the smallest" not in line, line
    assert "builtin has the smallest" not in line and "no variant converged on every step" in line, line


def test_a_converged_winner_is_still_named():
    t = base_times()
    line = replay_verdict(rows({"builtin": t, "fast": t / 2}))
    assert "is **fast**" in line and "A/A noise floor" in line, line


def test_without_builtin_no_winner_is_named():
    """No yardstick and no A/A: the smallest median is said, never "the fastest"."""
    t = base_times()
    rs = rows({"prev": t, "fast": t / 2})
    line = verdict(summarize(rs, None, 1000), None)
    assert line.startswith("**Verdict**: no clear winner") and "**fast**" not in line and "the fastest" not in line
    assert "fast has the smallest median time per step" in line, line


def test_a_noisy_a_a_names_no_winner_and_says_the_machine_was_too_noisy():
    """builtin against itself at 0.54x (as measured at load 8), fast at a quarter of builtin's time:
    beyond that floor, so the rule before named it; times this noisy name no winner."""
    t = base_times()
    rs = rows({"builtin": t, "fast": t / 4}, first={"builtin": 0.54})
    summary = summarize(rs, None, 1000)
    noise = judge(rs, summary, "builtin", lambda name: False)
    line = verdict(summary, noise)
    assert "**fast**" not in line and "the fastest" not in line, line
    assert line.startswith("**Verdict**: no clear winner: the machine was too noisy to time"), line
    assert "fast has the smallest median time per step" in line and "A/A" in line and "intervals over the steps" in line
    assert noise["aa"][2] < 1 / NOISE_LIMIT and noise["noisy"] and not noise["clear"], noise["aa"]


def test_a_wide_a_a_is_too_noisy_and_a_quiet_one_is_not():
    from deepcontact.contest.verdict import too_noisy
    assert too_noisy((1.0, 0.7, 1.4)) and too_noisy((0.54, 0.5, 0.58)) and too_noisy((1.0, float("nan"), 1.0))
    assert not too_noisy((1.02, 0.99, 1.04)) and not too_noisy((1.03, 0.94, 1.11))


def loop(name, ms, residuals=None, again=None):
    n = len(ms)
    return LoopResult(start=name, steps=n, iterations=np.full(n, 10), ms_per_step=np.asarray(ms, np.float64),
                      predict_ms=np.zeros(n), drift=np.zeros(n), penetration=0.0, finite=True,
                      residuals=np.full(n, 1e-5) if residuals is None else residuals,
                      ms_again=None if again is None else np.asarray(again, np.float64))


def test_the_closed_loop_never_names_a_variant_that_did_not_converge():
    t = base_times()
    res = np.full(STEPS, 1e-5)
    res[9] = 2e-4   # (one step of builtin's ended above the tolerance of 1e-4)
    line = loop_verdict([loop("builtin", t, res, again=t * 1.01), loop("slow", 2 * t)], 1e-4)
    assert "**builtin**" not in line and "the fastest" not in line and "did not converge is never named" in line, line
    table = loop_table([loop("builtin", t, res, again=t * 1.01)], 1e-4)
    assert "| builtin (did not converge on 1 step of 40) |" in table and "| 2% |" in table, table


def test_the_closed_loop_names_no_winner_on_a_noisy_machine():
    t = base_times()
    line = loop_verdict([loop("builtin", t, again=t / 0.54), loop("fast", t / 4)], 1e-4)
    assert line.startswith("**Verdict**: no clear winner: the machine was too noisy to time"), line
    assert "**fast**" not in line and "A/A noise floor" in line, line
    line = loop_verdict([loop("builtin", t, again=t * 1.01), loop("fast", t / 4)], 1e-4)
    assert "is **fast**" in line, line


@pytest.mark.parametrize("share,shown", [(1 / 1168, "<1%"), (0.005, "<1%"), (0.996, ">99%"), (0, "0%"), (1, "100%"),
                                         (0.02, "2%")])
def test_a_share_shows_a_step_at_all(share, shown):
    assert as_share(share) == shown


def test_one_capped_step_in_1168_shows_at_the_cap_as_it_shows_above_the_tolerance():
    """One step at the cap and above the tolerance: both columns "<1%", the row's mark counts it."""
    rs = rows({"builtin": np.random.default_rng(2).uniform(0.9, 1.1, 1168)}, above={"builtin": {100}},
              capped={"builtin": {100}})
    summary = summarize(rs, None, 1000)
    row = next(line for line in summary_table(summary).splitlines() if line.startswith("| builtin"))
    assert row.startswith("| builtin (did not converge on 1 step of 1,168) | 1168 |"), row
    assert "| <1% | <1% |" in row and "| 0% |" not in row, row


def zero_case(seed=3):
    """The hostile review's run: zero (no warm start) cheapest per step but above the tolerance on
    27 of 29 steps, builtin and prev above it on a few, builtin's A/A too noisy to time."""
    t = np.random.default_rng(seed).uniform(0.9, 1.1, 29)
    above = {"zero": set(range(27)), "builtin": {4}, "prev": {11}}
    return rows({"zero": t / 3, "builtin": t, "prev": 1.1 * t}, above=above, first={"builtin": 0.54})


@pytest.mark.parametrize("converged", [(), ("prev",)])
def test_a_variant_that_did_not_converge_is_named_in_no_clause_on_a_noisy_machine(converged):
    """zero did not converge: never "zero has the smallest median", noisy or not; the smallest of
    those that converged is named where there is one, else none is."""
    rs = zero_case()
    for r in rs:
        if r.start in converged:
            r.above = False
    line = replay_verdict(rs)
    assert line.startswith("**Verdict**: no clear winner: the machine was too noisy to time"), line
    assert "zero has" not in line and "builtin has" not in line and "the fastest" not in line, line
    assert "did not converge is never named" in line, line
    if converged:
        assert "of those that converged on every step, prev has the smallest" in line, line
    else:
        assert "no variant converged on every step" in line and "prev has" not in line, line


def test_a_ratio_over_an_unfinished_median_reads_did_not_converge_in_the_table():
    """zero's median step is unfinished: its time against builtin is infinite, shown as such, never "infx"."""
    rs = zero_case()
    summary = summarize(rs, None, 1000)
    table = summary_table(summary, judge(rs, summary, "builtin", lambda name: False))
    row = next(line for line in table.splitlines() if line.startswith("| zero"))
    assert "infx" not in table and "| did not converge |" in row, row


def test_the_closed_loop_names_no_variant_that_did_not_converge_on_a_noisy_machine():
    t = base_times()
    res = np.full(STEPS, 1e-5)
    res[:30] = 2e-4
    one = np.full(STEPS, 1e-5)
    one[2] = 2e-4
    line = loop_verdict([loop("builtin", t, one, again=t / 0.54), loop("zero", t / 3, res), loop("prev", 1.1 * t)],
                        1e-4)
    assert line.startswith("**Verdict**: no clear winner: the machine was too noisy to time"), line
    assert "zero" not in line.split(" Steps ended above")[0] and "the fastest" not in line, line
    assert "of those that converged on every step, prev has the smallest" in line, line
