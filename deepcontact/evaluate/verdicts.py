"""The verdict lines of a report, replay's and the closed loop's, by the contest's one rule
(contest/verdict.py): which variant is named the fastest, and why none is where none is."""
import numpy as np

from ..contest import missing_fences
from ..contest.verdict import MIN_STEPS, NOISE_LIMIT, decide
from ..errors import count
from ..escape import md_text
from ..solver.methods import is_native
from ..warmstart.starts import NAMES, is_oracle
from .noise import judge, ranked


def as_share(x):
    """A share as a percentage, where any at all shows and all shows only when it is all: "<1%" and
    ">99%", never a "0%" that hides a step or a "100%" that hides one that was not."""
    percent = 100 * x
    if 0 < percent < 1:
        return "<1%"
    if 99 < percent < 100:
        return ">99%"
    return f"{percent:.0f}%"


def not_converged_tag(above, steps):
    """A row's mark where it ended steps above the tolerance (above: their share of its steps),
    with their count, as the table's columns count them ("" where it ended none)."""
    if not above:
        return ""
    return f" (did not converge on {count(max(round(above * steps), 1), 'step')} of {steps:,})"


def base_start(label):
    """The start a variant label names: 'prev@1.7+nncg' -> 'prev'."""
    return label.split("@")[0].split("+")[0]


def baseline(summary):
    """The label of Box2D's own warm start with plain PGS (w = 1), the yardstick, or None: the
    variant the judge ran twice for the A/A where it did (replay.timed_twice), else by its label."""
    twinned = [name for name, s in summary.items() if s.get("yardstick")]
    if twinned:
        return twinned[0]
    for name, s in summary.items():
        if base_start(name) == "builtin" and s.get("relaxation") in (1, 1.0) and s.get("accelerate", "none") == "none":
            return name
    return None


def oracle(label):
    """Whether a variant label names a start that knows the answer."""
    return is_oracle(base_start(label))


def interval(triple):
    """A ratio and its interval: 0.95x [0.90, 1.01]; "did not converge" where the ratio is
    infinite (half the steps or more unfinished: contest/verdict.py), never "infx"."""
    ratio, lo, hi = triple
    if not np.isfinite(ratio):
        return "did not converge"
    return f"{ratio:.2f}x [{lo:.2f}, {hi:.2f}]"


def _fence_caveat():
    """What a verdict adds where this machine refused a contestant's fence (none: nothing)."""
    missing = missing_fences()
    return (f" Contestants' fences missing on this machine ({', '.join(missing)}): a contestant could reach "
            f"beyond its sandbox, so this verdict holds only for honest contestants." if missing else "")


def verdict(summary, noise=None):
    """The replay's verdict line (_verdict), with its power (power_words) and the fences this
    machine refused, if any."""
    line = _verdict(summary, noise)
    return None if line is None else line + power_words(noise) + _fence_caveat()


def plugin_variant(label):
    """Whether a variant label names a plug-in: its start or its method is not one of dc's own."""
    start, _, method = label.split("@")[0].partition("+")
    return start not in NAMES or not is_native(method or "none")


def power_words(noise):
    """The verdict's power, said of each plug-in variant that converged and is no oracle (contest/verdict.py,
    power_of): what its setup beyond the base's costs and the steps its saving a step needs to pay
    it back (or that it never does), and, where it is faster on the median but not named, that the
    run was too short to name it and about how many steps would be. "" where there is none to say."""
    if not noise or not noise.get("power"):
        return ""
    base, unfinished = noise["base"], noise.get("unfinished", {})
    named = noise["best"] if noise.get("clear") else None
    parts = [_power_part(n, p, base, noise["vs_base"][n][0], n == named) for n, p in noise["power"].items()
             if plugin_variant(n) and not oracle(n) and not unfinished.get(n, 0) and n in noise["vs_base"]]
    parts = [p for p in parts if p]
    return f" Power against {md_text(base)}: " + "; ".join(parts) + "." if parts else ""


def _power_part(name, power, base, ratio, named):
    """What power_words says of one plug-in variant (power: power_of's), or ""."""
    said = []
    if power["setup_ms"] > 0:
        said.append(payback_words(name, power, base))
    if ratio < 1 and not named:
        short = too_short_words(name, power)
        said += [short] if short else []
    return "; ".join(said)


def payback_words(name, power, base):
    """The steps a variant's saving a step needs to pay back its setup beyond the base's, or never."""
    setup = f"{power['setup_ms']:.3g} ms beyond {md_text(base)}'s"
    if power["payback_steps"] is None:
        return (f"{md_text(name)} saves nothing a step on the mean ({-power['saving_ms']:.3g} ms more), so its setup, "
                f"{setup}, never pays back")
    return (f"{md_text(name)}'s setup, {setup}, pays back after about {count(power['payback_steps'], 'step')} "
            f"(it saves {power['saving_ms']:.3g} ms a step on the mean)")


def too_short_words(name, power):
    """That a run was too short to name a variant faster on the median, and about how many steps
    would do, or that its saving is within this run's noise; "" where the run was long enough."""
    needed, steps = power["needed_steps"], power["steps"]
    if power.get("quiet_steps", 0) is None:   # (its A/A is off at any length: the verdict's noise clause says so)
        return ""
    if needed is None:
        return (f"too short to name {md_text(name)}: its saving a step is within the noise of this run's "
                f"{count(steps, 'step')}")
    if steps >= needed:
        return ""
    return f"too short to name {md_text(name)}: about {count(needed, 'step')} needed (this run: {steps:,})"


def _verdict(summary, noise=None):
    """One line: the start with the smallest median time per step to the tolerance (prediction
    included), named the fastest only where the contest's one rule (contest/verdict.py) finds a
    clear winner against Box2D's warm start, and else why none is. Left out: oracles, which know
    the answer; every variant that ended a step above the tolerance by our residual (it did not
    converge, whatever it said) is never named."""
    candidates = [n for n in summary if not oracle(n)]
    if not candidates:
        return None
    left_out = _unfinished_note({n: summary[n].get("above", 0) for n in candidates})
    base = baseline(summary)
    if not noise or noise.get("best") is None:
        return _unjudged(_unjudged_smallest(summary)) + left_out
    best = noise["best"]
    undecided = _no_winner(noise, best, base, candidates)
    if undecided:
        return undecided + left_out
    return _winner(summary, noise, best, base) + "." + left_out


def _unjudged_smallest(summary):
    """The non-oracle variant with the smallest median time per step that ended no step above the
    tolerance, or None where none did (one that did not converge is never named)."""
    done = [n for n in ranked(summary, oracle) if not summary[n].get("above", 0)]
    return done[0] if done else None


def _unjudged(best):
    """The verdict where no variant is Box2D's warm start at w = 1: no yardstick, no A/A, no winner
    (best: the smallest median of the variants that converged, or None)."""
    smallest = (f"{md_text(best)} has the smallest median time per step of the variants that converged "
                f"(prediction included; oracles left out)" if best is not None else
                "no variant converged on every step, and one that did not is never named")
    return (f"**Verdict**: no clear winner: {smallest}, but a winner is named only against Box2D's warm start at "
            f"w = 1 (builtin), timed against itself for the noise floor, and it is not among the variants.")


def too_noisy_words(base):
    """Why a verdict names no winner on a noisy machine (contest/verdict.py's NOISE_LIMIT)."""
    return (f"no clear winner: the machine was too noisy to time ({md_text(base)} timed against itself, A/A, "
            f"reached beyond [{1 / NOISE_LIMIT:.2f}, {NOISE_LIMIT:.2f}]x, where times name no winner: "
            f"contest/verdict.py)")


def converged_smallest(unfinished, vs_base, candidates):
    """The candidate with the smallest time against the base ({label: (ratio, low, high)}) of
    those that ended no step above the tolerance ({label: steps}), or None where none did."""
    done = [n for n in candidates if not unfinished.get(n, 0) and n in vs_base]
    return min(done, key=lambda n: vs_base[n][0], default=None)


def smallest_words(best, shown, base, vs_base, unfinished, what):
    """The clause on the smallest median: best's where it converged, else (best never named) the
    smallest of the variants that converged (shown) or that none did."""
    def against(n):
        return f", {interval(vs_base[n])} of {md_text(base)}'s" if n != base else ""
    if shown == best:
        return f"{md_text(best)} has the smallest {what}{against(best)}"
    lead = (f"The smallest {what} is that of a variant that ended {count(unfinished.get(best, 0), 'step')} above "
            f"the tolerance: a variant that did not converge is never named")
    if shown is None:
        return lead + "; no variant converged on every step"
    return lead + f"; of those that converged on every step, {md_text(shown)} has the smallest{against(shown)}"


def lost_the_run_words(best, beaten_by, totals, unfinished, setup_unpaid=False):
    """Why a verdict does not name best, whose whole run (setup included) cost more than beaten_by's
    (one that did not converge, by {label: steps} unfinished, is not named): its setup, where its
    steps took less than the base's (setup_unpaid), else a heavy tail of slow steps."""
    return ("but over the whole run, setup included, it took longer than "
            + " and ".join(f"{runner_name(n, unfinished)} ({totals[best]:.4g} ms against {totals[n]:.4g} ms)"
                           for n in beaten_by)
            + (": its setup, which its steps did not pay back in this run" if setup_unpaid
               else ": a heavy tail of slow steps"))


def setup_unpaid(v):
    """Whether a verdict's best lost the run to the base by its setup alone: its steps took less than
    the base's on the mean (v: the verdict's dict)."""
    mine = v.get("power", {}).get(v["best"])
    return bool(mine and v["base"] in v.get("beaten_on_total_by", ()) and mine["saving_ms"] > 0 and mine["setup_ms"] > 0)


def _no_winner(noise, best, base, candidates):
    """The verdict where the rule names no winner (too few steps, a machine too noisy to time, a
    fastest median that did not converge or lost the whole run, or one within noise), or None."""
    aa = f"{md_text(base)} timed against itself (A/A) measured {interval(noise['aa'])} " \
         f"({100 * noise['level']:.0f}% intervals over the steps)."
    unfinished = noise.get("unfinished", {})
    shown = best if not unfinished.get(best, 0) else converged_smallest(unfinished, noise["vs_base"], candidates)
    smallest = smallest_words(best, shown, base, noise["vs_base"], unfinished,
                              "median time per step (prediction included; oracles left out)")
    if noise.get("too_few_steps"):
        return (f"**Verdict**: no clear winner: {count(noise['steps'], 'step')} to judge on, and a winner is named "
                f"from at least {MIN_STEPS}.")
    if noise.get("noisy"):
        return f"**Verdict**: {too_noisy_words(base)}. {smallest}; {aa}"
    if noise.get("did_not_converge"):
        return f"**Verdict**: no clear winner. {smallest}; {aa}"
    if noise.get("beaten_on_total_by"):   # a heavy tail: the median's fastest lost the whole run
        return (f"**Verdict**: no clear winner. {smallest}, "
                f"{lost_the_run_words(best, noise['beaten_on_total_by'], noise['total_ms'], unfinished, setup_unpaid(noise))}"
                f"; {aa}")
    if noise["clear"]:
        return None
    runner = noise.get("runner_up")
    # (no winner, so none is called the fastest: the smallest median, with its intervals)
    return (f"**Verdict**: no clear winner within noise. {smallest}"
            + (f"; against the runner-up {runner_name(runner, unfinished)} it takes "
               f"{interval(noise['best_vs_runner_up'])}"
               if runner else "") + f"; {aa}")


def _winner(summary, noise, best, base):
    """The verdict naming best the fastest, with its ratios and the intervals the rule judged by."""
    b = summary[best]
    text = (f"**Verdict**: the fastest start to the tolerance (median time per step, prediction included; "
            f"oracles left out) is **{md_text(best)}**: {b['total_ms_median']:.3f} ms, "
            f"{count(round(b['iterations_median']), 'sweep')}")
    if base is not None and base != best:
        r = summary[base]
        text += (f", {b['total_ms_median'] / max(r['total_ms_median'], 1e-12):.2f}x the time and "
                 f"{b['iterations_median'] / max(r['iterations_median'], 1e-12):.2f}x the sweeps of {md_text(base)}")
    elif base == best:
        text += f"; nothing beats {md_text(base)}, Box2D's own warm start"
    if b["at_cap"] > 0:
        text += f" ({as_share(b['at_cap'])} of its steps stopped at the cap)"
    parts = ([f"time {interval(noise['vs_base'][best])} of {md_text(base)}'s"] if best != base else []) \
        + ([f"{interval(noise['best_vs_runner_up'])} of the runner-up "
            f"{runner_name(noise['runner_up'], noise.get('unfinished', {}))}'s"]
           if noise.get("runner_up") else []) + [f"A/A noise floor {interval(noise['aa'])}"]
    return text + f" ({'; '.join(parts)}; {100 * noise['level']:.0f}% intervals over the steps)"


def _unfinished_note(shares):
    """The rule for steps ended above the tolerance, said where a variant has any ({label: share})."""
    some = {n: share for n, share in shares.items() if share}
    if not some:
        return ""
    return (" Steps ended above the tolerance (by our residual) count as unfinished, slower than any finished "
            "step (contest/verdict.py): " + ", ".join(f"{md_text(n)} {as_share(share)}" for n, share in some.items())
            + ".")


def noise_of(rows, summary):
    """The intervals the verdict and the table state (noise.judge, with this report's baseline
    and oracles)."""
    return judge(rows, summary, baseline(summary), oracle)


def loop_residuals(r):
    """The residuals of a loop row's steps that had contacts (none for Box2D's own solver)."""
    res = np.asarray(r.residuals if r.residuals is not None else [], np.float64)
    return res[np.isfinite(res)]


def _asked(r):
    """The steps of a loop row on which its start was asked (those with contact points: a
    residual); every step where it has no residuals (Box2D's own solver)."""
    n = len(r.ms_per_step)
    if r.residuals is None:
        return np.arange(n)
    return np.flatnonzero(np.isfinite(np.asarray(r.residuals, np.float64)[:n]))


def on_asked_steps(r, values):
    """A loop row's per-step values on the steps its start was asked, as its iterations are taken;
    every step where none was."""
    v = np.asarray(values, np.float64)
    asked = _asked(r)
    return v[asked] if len(asked) else v


def loop_above(r, tolerance):
    """The share of a row's steps whose residual ended above the tolerance (None: not judged)."""
    res = loop_residuals(r)
    return None if tolerance is None or not len(res) else float(np.mean(res > tolerance))


def loop_verdict(results, tolerance):
    """The closed loop's verdict, by the contest's one rule (contest/verdict.py, as replay's): the
    fastest of the project's variants per step that stayed finite and never ended a step above the
    tolerance (oracles left out), against Box2D's warm start and the runner-up with 95% intervals
    over the steps, builtin timed against itself (A/A), and the run's totals (setup included); a
    winner is named only beyond noise, on a machine quiet enough to time, and none whose whole run
    cost more. None without Box2D's warm start."""
    base = next((r for r in results if r.ms_again is not None), None)
    if base is None:
        return None
    ours = [r for r in results if r.ours]
    errors = net_time_errors(ours)
    candidates = [r for r in ours if not r.oracle]
    fair = [r for r in candidates if r.finite and r.start not in errors]
    left_out = _loop_left_out(candidates, fair, tolerance, errors)
    if base.start in errors or not fair:
        return _none_left(base.start in errors) + left_out
    v = _judged(ours, fair, base, tolerance)
    said = v.as_dict()   # (the power of the variants it may name: one that stopped being finite is named at no length)
    said["power"] = {n: p for n, p in said["power"].items() if n in {r.start for r in fair}}
    power = power_words(said)
    if v.too_few_steps:
        return (f"**Verdict**: no clear winner: {count(v.steps, 'step')} to judge on, and a winner is named from at "
                f"least {MIN_STEPS}." + left_out + power + _fence_caveat())
    head = _loop_head(v, base.start, [r.start for r in fair])
    return (f"{head} ({'; '.join(_loop_intervals(v, base.start))}; 95% intervals over the steps with contact "
            "points)." + left_out + power + _fence_caveat())


def _none_left(base_in_error):
    """The loop verdict where nothing can be named: the baseline mismeasured, or no start left."""
    if base_in_error:
        return ("**Verdict**: none is named: Box2D's warm start's own time, which every ratio is taken to, is a "
                "measurement error.")
    return "**Verdict**: no start stayed finite, and measured, on every step of the loop, so none is named."


def _loop_left_out(candidates, fair, tolerance, errors):
    """What the loop verdict says of the variants it left out (not finite, a measurement error:
    errors, net_time_errors') or found unfinished."""
    left = [r.start for r in candidates if not r.finite]
    return (f" Left out, as they stopped being finite: {', '.join(md_text(n) for n in left)}." if left else "") \
        + measurement_error_words(errors) + _unfinished_note({r.start: loop_above(r, tolerance) or 0 for r in fair})


def net_time_errors(rows):
    """{label: its steps whose net time was at or below zero} of the loop rows that have any. A
    step holds at least the judge's own stepping, so such a step means more was subtracted than
    was measured: every step of that row is suspect (its median and total with it), a measurement
    error, never a win."""
    counts = {r.start: int(np.sum(np.asarray(r.ms_per_step, np.float64) <= 0.0)) for r in rows}
    return {name: n for name, n in counts.items() if n}


def measurement_error_words(errors):
    """The loop verdict's clause on the rows with a net time at or below zero (net_time_errors)."""
    named = ", ".join(f"{md_text(n)} ({count(k, 'step')})" for n, k in errors.items())
    return (f" Left out as a measurement error, a net time per step at or below zero (more subtracted than "
            f"measured): {named}." if errors else "")


def _loop_intervals(v, base):
    """The intervals the loop verdict states: best's against the base and the runner-up (only
    where best converged: else it is not named, nor are they its), and A/A."""
    mine = not v.unfinished.get(v.best, 0)
    return ([f"{interval(v.vs_base[v.best])} of {md_text(base)}'s time per step"] if mine and v.best != base else []) \
        + ([f"{interval(v.best_vs_runner_up)} of the runner-up {runner_name(v.runner_up, v.unfinished)}'s"]
           if mine and v.runner_up else []) + [f"A/A noise floor {interval(v.aa)}"]


def runner_name(runner, unfinished):
    """The runner-up as a verdict names it: by its label only where it converged."""
    return md_text(runner) if not unfinished.get(runner, 0) else "(a variant that did not converge)"


def _judged(ours, fair, base, tolerance):
    """contest.verdict.decide on the loop's rows, judged on the steps that asked some start: on a
    step with no contact point no start runs, and its time, the engine's alone, would be the median
    of a run mostly in free fall (every step where none was asked); each total stays its whole run's."""
    asked = sorted(set().union(*(_asked(r).tolist() for r in ours))) or range(len(base.ms_per_step))
    times = {r.start: {i: float(r.ms_per_step[i]) for i in asked if i < len(r.ms_per_step)} for r in ours}
    aa = [np.asarray(x, np.float64)[[i for i in asked if i < len(x)]] for x in (base.ms_per_step, base.ms_again)]
    return decide(times, [r.start for r in fair], base.start, aa, {r.start: r.setup_ms for r in ours},
                  {r.start: _loop_unfinished(r, tolerance) for r in ours},
                  totals={r.start: float(np.sum(r.ms_per_step)) for r in ours})


def _loop_unfinished(r, tolerance):
    """The steps of a loop row whose residual ended above the tolerance (none where not judged)."""
    if tolerance is None or r.residuals is None:
        return set()
    return set(np.flatnonzero(np.nan_to_num(np.asarray(r.residuals, np.float64), nan=0.0) > tolerance).tolist())


def _loop_head(v, base, candidates):
    """The loop verdict's first sentence, for the decision v against the baseline base (the
    reasons for no winner in replay's order: _no_winner; one that did not converge never named)."""
    shown = v.best if not v.unfinished.get(v.best, 0) else converged_smallest(v.unfinished, v.vs_base, candidates)
    smallest = smallest_words(v.best, shown, base, v.vs_base, v.unfinished, "median time per step of the loop") \
        if shown != v.best else f"{md_text(v.best)} has the smallest median time per step of the loop"
    if v.noisy:
        return f"**Verdict**: {too_noisy_words(base)}. {smallest}"
    if v.did_not_converge:
        return f"**Verdict**: no clear winner. {smallest}"
    if v.heavy_tail:
        lost = lost_the_run_words(v.best, v.beaten_on_total_by, v.totals, v.unfinished, setup_unpaid(v.as_dict()))
        return f"**Verdict**: no clear winner. {smallest}, {lost}"
    if v.clear:
        return ("**Verdict**: the fastest start per step of the loop (prediction included; oracles left out) is "
                f"**{md_text(v.best)}**")
    return f"**Verdict**: no clear winner within noise. {smallest}"
