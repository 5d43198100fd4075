"""How sure a time comparison is: bootstrap intervals over the steps, and the noise floor.

A variant's time on a step is its start's whole call plus the median of its REPEATS interleaved
solves (replay.py). Two variants are compared by the ratio of their median times per step; the
interval resamples the steps (the same steps for both: a pair per step) with a fixed seed, so the
report repeats. The noise floor is Box2D's warm start against itself: its first timed solve of
each step against its second (A/A), which should be 1 and shows how far from 1 the machine moves
a ratio of two equal things. A verdict names a winner only when its interval excludes Box2D's warm
start's time and the runner-up's; else it says there is no clear winner within noise.
"""
import numpy as np

RESAMPLES = 2000
LEVEL = 0.95
SEED = 0   # (the intervals are a function of the rows: the same report twice is the same report)


def _totals(rows, name, repeat=None):
    """{step key: ms} of the variant `name`: prediction plus the median solve (or one repeat's)."""
    return {(r.run, r.seed, r.step): r.predict_ms + (r.solve_ms if repeat is None else r.solve_ms_repeats[repeat])
            for r in rows if r.start == name}


def ratio_interval(a, b, rng=None):
    """median(a) / median(b) over paired per-step times, with its bootstrap interval (LEVEL):
    (ratio, low, high)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    rng = np.random.default_rng(SEED) if rng is None else rng
    ratio = float(np.median(a) / max(np.median(b), 1e-12))
    if len(a) < 2:
        return ratio, ratio, ratio
    picks = rng.integers(0, len(a), size=(RESAMPLES, len(a)))
    boot = np.median(a[picks], axis=1) / np.maximum(np.median(b[picks], axis=1), 1e-12)
    tail = (1 - LEVEL) / 2
    return ratio, float(np.quantile(boot, tail)), float(np.quantile(boot, 1 - tail))


def _paired(x, y):
    keys = sorted(set(x) & set(y))
    return [x[k] for k in keys], [y[k] for k in keys]


def ranked(summary, is_oracle):
    """The variants a verdict may name, fastest first: no oracle, and none that ended a step above
    the tolerance by our residual; fewest steps at the cap, then the smallest median time."""
    return sorted((n for n, s in summary.items() if not is_oracle(n) and not s.get("above", 0)),
                  key=lambda n: (summary[n]["at_cap"], summary[n]["total_ms_median"]))


def judge(rows, summary, base, is_oracle):
    """What the verdict may say, measured: each variant's time against `base` with its interval,
    the A/A noise floor of `base`, and the best fair variant (not an oracle, never above the
    tolerance) against the runner-up. A dict for summary.json; None without a base."""
    if base is None or base not in summary:
        return None
    rng = np.random.default_rng(SEED)
    base_t = _totals(rows, base)
    against = {name: list(ratio_interval(*_paired(_totals(rows, name), base_t), rng)) for name in summary}
    first, second = _paired(_totals(rows, base, 0), _totals(rows, base, 1))
    out = {"base": base, "level": LEVEL, "resamples": RESAMPLES, "vs_base": against,
           "aa": list(ratio_interval(first, second, rng)), "best": None, "runner_up": None, "best_vs_runner_up": None,
           "clear": False}
    fair = ranked(summary, is_oracle)
    if not fair:
        return out
    best = fair[0]
    out["best"] = best
    # faster than the base beyond noise: its interval below 1, and below the A/A floor's (two equal
    # things measured that far apart)
    clear = best == base or (against[best][2] < 1.0 and against[best][2] < out["aa"][1])
    if len(fair) > 1:
        runner = fair[1]
        out["runner_up"] = runner
        out["best_vs_runner_up"] = list(ratio_interval(*_paired(_totals(rows, best), _totals(rows, runner)), rng))
        clear = clear and out["best_vs_runner_up"][2] < 1.0
    # and on the total (its setup included) as well as the median: a start that is slow on a few
    # steps (40 ms on 5% of them) wins the median while its whole run costs more
    totals = {name: sum(_totals(rows, name).values()) + float(summary[name].get("setup_ms", 0.0)) for name in summary}
    out["total_ms"] = totals
    beaten = [n for n in dict.fromkeys((base, out["runner_up"])) if n is not None and n != best
              and totals[n] < totals[best]]
    out["beaten_on_total_by"] = beaten
    out["clear"] = bool(clear and not beaten)
    return out
