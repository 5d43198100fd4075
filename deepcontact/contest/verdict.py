"""One rule that names a winner, or says there is none, for replay rows and loop rows alike.

The candidates are the variants that may win (no oracle, none that left float32), ranked by their
median charged time per step. A step a variant ended above the tolerance is unfinished: it counts
as slower than any finished step (an infinite time in the medians and their intervals; what it
was charged stays in its total), so a variant that leaves a few steps unfinished is judged on the
rest, and one that leaves half of them has an infinite median. (Dropping such variants made a
verdict impossible wherever every variant leaves one step above the tolerance, as every one did
in the loop on the held-out pile, at any cap.) The fastest is named a clear winner only when,
with 95% bootstrap intervals over the steps (paired, the same steps for both):
- it is faster than Box2D's warm start (the base) beyond 1 and beyond the A/A floor (the base
  timed against itself: how far apart two equal things measure);
- it is faster than the runner-up beyond 1;
- it ended no step above the tolerance: a variant that did not converge is never named, whatever
  its times (its unfinished steps still rank it, so a faster variant that did not converge keeps
  a slower one that did from being called the fastest);
- the machine was quiet enough to time: the A/A interval lies within [1/NOISE_LIMIT, NOISE_LIMIT]
  (the base's two timings of the same solves that far apart make every ratio the machine's as
  much as the variants'; pyperf warns of an unstable benchmark the same way);
- and over the whole run, setup included, it cost no more than the base or the runner-up (a start
  slow on a few steps can win the median and lose the run: a heavy tail);
- on at least MIN_STEPS steps.
When one of these fails there is no clear winner, and a variant beaten on the total, or one that
did not converge, is never called the fastest.

The verdict's power is stated too (`power`): for each variant, its setup charged beyond the
base's, what it saves a step against the base on the mean (setup apart: what the totals add up),
the steps that saving needs to pay the setup back, and the steps a run needs to name it at the
noise measured: enough to pay its setup back, at least MIN_STEPS, enough for the A/A to come
within NOISE_LIMIT and for its interval against the base to clear 1 and the A/A floor, every
interval taken to narrow as one over the square root of the steps (a bootstrap interval of a
median does), the A/A's toward its own ratio (a bias of the machine's stays). A run shorter than that is too
short to name it; one that saves nothing a step, or is no faster on the median, is named at no length.
"""
import math
from dataclasses import dataclass, field

import numpy as np

RESAMPLES = 2000
LEVEL = 0.95
MIN_STEPS = 5   # a winner is never named from fewer steps (one step's interval is a point)
SEED = 0   # (the intervals are a function of the times: the same report twice is the same report)
RESOLUTION_MS = 1e-3   # the smallest time a ratio of medians takes as it is (1 microsecond)
# The A/A interval beyond which the machine is too noisy to time (module docstring): quiet reports
# measured A/A intervals within [0.90, 1.12], loaded ones [0.41, 2.81] (docs/results/measuring.md).
NOISE_LIMIT = 1.25
# How sure the steps a run needs to name a variant are (power_of): its saving a step taken Z standard
# errors below its mean, and over those steps clearing its extra setup by Z standard deviations of
# their sum (one-sided 95% each), at the noise measured.
Z = 1.645


def _median(x, axis=None):
    """numpy's median, but an infinite middle value gives inf, not nan (its interpolation of
    inf and inf is inf - inf)."""
    x = np.sort(np.asarray(x, np.float64), axis=-1 if axis is None else axis)
    if axis is None:
        x = x.ravel()
    n = x.shape[-1]
    lo, hi = np.take(x, (n - 1) // 2, axis=-1), np.take(x, n // 2, axis=-1)
    with np.errstate(invalid="ignore"):
        return np.where(np.isinf(hi), hi, (lo + hi) / 2)


def _ratio(ma, mb):
    """ma / mb of medians that may be infinite (unfinished) or 0 (a call no slower than the
    transport): equal medians are a tie (1: both infinite, both 0), one infinite is infinitely
    slower (or faster)."""
    # (a time is known to a microsecond at best: a median the transport's subtraction took to 0 is
    # that, not 0, else one such step put a ratio at 1e11)
    ma, mb = np.maximum(np.asarray(ma, np.float64), RESOLUTION_MS), np.maximum(np.asarray(mb, np.float64), RESOLUTION_MS)
    with np.errstate(invalid="ignore"):
        out = ma / mb
    return np.where(ma == mb, 1.0, out)


def ratio_interval(a, b, rng=None):
    """median(a) / median(b) over paired per-step times (inf: an unfinished step), with its
    bootstrap interval (LEVEL): (ratio, low, high)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    rng = np.random.default_rng(SEED) if rng is None else rng
    ratio = float(_ratio(_median(a), _median(b)))
    if len(a) < 2:
        return ratio, ratio, ratio
    picks = rng.integers(0, len(a), size=(RESAMPLES, len(a)))
    boot = _ratio(_median(a[picks], axis=1), _median(b[picks], axis=1))
    tail = (1 - LEVEL) / 2   # (quantiles taken, not interpolated: between inf and inf lies no number)
    return (ratio, float(np.quantile(boot, tail, method="inverted_cdf")),
            float(np.quantile(boot, 1 - tail, method="inverted_cdf")))


def paired(x, y):
    """The times of two variants on the steps both have, in the same order."""
    keys = sorted(set(x) & set(y))
    return [x[k] for k in keys], [y[k] for k in keys]


@dataclass
class Verdict:
    """What the rule found (module docstring): `best` is the fastest candidate on the median, a
    clear winner only when `clear`; `beaten_on_total_by` the variants whose whole run (setup
    included) cost less than best's."""
    base: str | None
    best: str | None = None
    runner_up: str | None = None
    clear: bool = False
    vs_base: dict = field(default_factory=dict)     # {label: (ratio, low, high)} against the base
    best_vs_runner_up: tuple | None = None
    aa: tuple = (1.0, 1.0, 1.0)
    totals: dict = field(default_factory=dict)      # {label: ms over the run, setup included}
    beaten_on_total_by: list = field(default_factory=list)
    level: float = LEVEL
    steps: int = 0                                  # the steps best and the base were paired on
    unfinished: dict = field(default_factory=dict)  # {label: steps it ended above the tolerance}
    power: dict = field(default_factory=dict)       # {label: what naming it needs (power_of)}, the base aside

    @property
    def heavy_tail(self):
        """Whether the median's fastest lost the run's total to the base or the runner-up."""
        return bool(self.beaten_on_total_by)

    def as_dict(self):
        """For summary.json."""
        return {"base": self.base, "level": self.level, "resamples": RESAMPLES,
                "vs_base": {k: list(v) for k, v in self.vs_base.items()}, "aa": list(self.aa), "best": self.best,
                "runner_up": self.runner_up,
                "best_vs_runner_up": None if self.best_vs_runner_up is None else list(self.best_vs_runner_up),
                "clear": self.clear, "total_ms": dict(self.totals), "beaten_on_total_by": list(self.beaten_on_total_by),
                "heavy_tail": self.heavy_tail, "steps": self.steps, "too_few_steps": self.too_few_steps,
                "unfinished": dict(self.unfinished), "did_not_converge": self.did_not_converge,
                "noisy": self.noisy, "noise_limit": NOISE_LIMIT, "power": {k: dict(v) for k, v in self.power.items()}}

    @property
    def did_not_converge(self):
        """Whether best ended a step above the tolerance (so it is never named)."""
        return self.best is not None and self.unfinished.get(self.best, 0) > 0

    @property
    def noisy(self):
        """Whether the A/A interval says the machine was too noisy to time (NOISE_LIMIT)."""
        return too_noisy(self.aa)

    @property
    def too_few_steps(self):
        """Whether there were too few steps to name a winner at all."""
        return self.best is not None and self.steps < MIN_STEPS


def too_noisy(aa):
    """Whether an A/A (ratio, low, high) reaches beyond NOISE_LIMIT either way (or is not a number)."""
    return not (1 / NOISE_LIMIT <= aa[1] and aa[2] <= NOISE_LIMIT)


def _ranked_times(times, unfinished):
    """The times with each label's unfinished steps infinite (slower than any finished step)."""
    return {name: {k: (np.inf if k in unfinished.get(name, ()) else ms) for k, ms in t.items()}
            for name, t in times.items()}


def _fastest_first(times, ranked_times, candidates):
    """The candidates with times, fastest median first (unfinished steps infinite; ties by the
    median of the times as charged)."""
    return sorted((n for n in candidates if n in times and times[n]),
                  key=lambda n: (float(_median(list(ranked_times[n].values()))), float(_median(list(times[n].values())))))


def decide(times, candidates, base, aa_pair, setup_ms=None, unfinished=None, totals=None):
    """The verdict on `times` ({label: {step key: charged ms}}): `candidates` the labels that may
    win, `base` Box2D's warm start's label, `aa_pair` (first, second) its paired A/A times,
    `setup_ms` {label: setup charged} added to each total, `unfinished` {label: step keys it ended
    above the tolerance} (infinite in the medians, module docstring), `totals` {label: ms of the
    whole run} where the times judged are not all its steps (else their sum). None without the base."""
    if base is None or base not in times:
        return None
    rng = np.random.default_rng(SEED)
    setup_ms, unfinished = setup_ms or {}, unfinished or {}
    ranked_times = _ranked_times(times, unfinished)
    v = Verdict(base=base, aa=ratio_interval(*aa_pair, rng))
    v.unfinished = {name: len(set(unfinished.get(name, ())) & set(t)) for name, t in times.items()}
    v.vs_base = {name: ratio_interval(*paired(t, ranked_times[base]), rng) for name, t in ranked_times.items()}
    totals = totals or {}
    v.totals = {name: float(totals.get(name, sum(t.values()))) + float(setup_ms.get(name, 0.0))
                for name, t in times.items()}
    quiet = aa_steps(len(aa_pair[0]), v.aa)
    v.power = {name: power_of(times[name], times[base], setup_ms.get(name, 0.0) - setup_ms.get(base, 0.0),
                              v.vs_base[name], v.aa, quiet) for name in times if name != base}
    fair = _fastest_first(times, ranked_times, candidates)
    if not fair:
        return v
    v.best = fair[0]
    v.steps = len(paired(times[v.best], times[base])[0])
    if len(fair) > 1:
        v.runner_up = fair[1]
        v.best_vs_runner_up = ratio_interval(*paired(ranked_times[v.best], ranked_times[v.runner_up]), rng)
    v.beaten_on_total_by = [n for n in dict.fromkeys((base, v.runner_up)) if n is not None and n != v.best
                            and v.totals[n] < v.totals[v.best]]
    v.clear = _beyond_noise(v) and not (v.beaten_on_total_by or v.too_few_steps or v.did_not_converge or v.noisy)
    return v


def _beyond_noise(v):
    """Whether best is faster than the base beyond the A/A noise (or is the base) and faster than
    the runner-up, both by their whole intervals."""
    upper = v.vs_base[v.best][2]
    faster = v.best == v.base or (upper < 1.0 and upper < v.aa[1])
    return bool(faster and (v.runner_up is None or v.best_vs_runner_up[2] < 1.0))


def power_of(mine, base, extra_setup_ms, vs_base, aa, quiet):
    """What naming a variant needs against the base (module docstring), from its per-step times
    `mine` and the base's ({step key: ms}), its setup beyond the base's, its (ratio, low, high)
    against the base, the A/A's and the steps the A/A needs to be quiet enough (aa_steps):
    {"setup_ms", "saving_ms", "payback_steps", "needed_steps", "quiet_steps", "steps"}, a count of
    steps None where no length of run does it."""
    a, b = paired(mine, base)
    saved = np.asarray(b, np.float64) - np.asarray(a, np.float64)   # (per step: what it saves)
    saving = float(np.mean(saved)) if len(saved) else 0.0
    needs = (total_steps(extra_setup_ms, saved), interval_steps(len(a), vs_base, aa), quiet)
    needed = None if None in needs else max(MIN_STEPS, *needs)
    return {"setup_ms": float(extra_setup_ms), "saving_ms": saving, "payback_steps": payback_steps(extra_setup_ms, saving),
            "needed_steps": needed, "quiet_steps": quiet, "steps": len(a)}


def payback_steps(extra_setup_ms, saving_ms):
    """The steps after which a variant saving `saving_ms` a step on the mean has paid back
    `extra_setup_ms` of setup beyond the base's (0 where it has nothing to pay), or None where it
    saves nothing a step (never)."""
    if saving_ms <= 0:
        return None
    return max(math.ceil(extra_setup_ms / saving_ms), 0)


def total_steps(extra_setup_ms, saved):
    """The steps after which a variant's total, setup included, lies below the base's at the noise
    measured: its saving a step (`saved`, per paired step; its mean taken Z standard errors low)
    summed over n steps, less Z of that sum's standard deviations (the steps' own spread), clears
    its extra setup. None where that saving is not above 0: no length can be told from this run."""
    if len(saved) < 2:
        return None
    spread = Z * float(np.std(saved, ddof=1))
    mean = float(np.mean(saved)) - spread / math.sqrt(len(saved))
    if mean <= 0:
        return None
    # n mean - spread sqrt(n) >= extra: a quadratic in sqrt(n)
    root = (spread + math.sqrt(spread ** 2 + 4 * mean * max(extra_setup_ms, 0.0))) / (2 * mean)
    return math.ceil(root ** 2)


def aa_steps(steps, aa):
    """The steps the base's A/A (ratio, low, high over `steps` steps) needs to lie within
    [1/NOISE_LIMIT, NOISE_LIMIT] (the machine quiet enough to time), its interval narrowing as one
    over the square root of the steps; None where its ratio itself lies beyond (no length helps)."""
    ratio, low, high = aa
    if not (np.all(np.isfinite(aa)) and 1 / NOISE_LIMIT < ratio < NOISE_LIMIT) or steps < 1:
        return None
    reach = max((high - ratio) / (NOISE_LIMIT - ratio), (ratio - low) / (ratio - 1 / NOISE_LIMIT))
    return math.floor(steps * reach ** 2) + 1


def interval_steps(steps, vs_base, aa):
    """The steps a run needs for a variant's interval against the base (ratio, low, high, measured
    on `steps` steps) to lie below 1 and below the A/A's low end, both half-widths narrowing as
    one over the square root of the steps: the A/A's low end narrows to the A/A's own ratio, not
    to 1 (a machine that times the base's first solve faster than its second keeps doing so at
    any length). None where its ratio is not below both (no length does)."""
    ratio, _, high = vs_base
    floor = min(1.0, aa[0])   # (where the bound it must clear settles)
    if not (np.isfinite(ratio) and ratio < floor and np.isfinite(high) and np.isfinite(aa[1])) or steps < 1:
        return None
    spread = (high - ratio) + max(floor - aa[1], 0.0)   # (its upper half-width, and how far the A/A's reaches below)
    return math.floor(steps * (spread / (floor - ratio)) ** 2) + 1
