"""How sure a time comparison is: bootstrap intervals over the steps, and the noise floor.

A variant's time on a step is its start's whole call plus its one solve call of the step, the
variants interleaved (replay.py). Two variants are compared by the ratio of their median times per step; the
interval resamples the steps (the same steps for both: a pair per step) with a fixed seed, so the
report repeats. The noise floor is Box2D's warm start against itself: its time on each step
against its twin's, the same variant run in a sandbox of its own and asked in the step's shuffled
order like every variant (A/A, replay.timed_twice), which should be 1 and shows how far from 1
the machine moves a ratio of two equal things. A verdict names a winner only when its interval excludes Box2D's warm
start's time and the runner-up's, and never where the A/A itself reaches beyond NOISE_LIMIT (the
machine too noisy to time); else it says there is no clear winner (contest/verdict.py).
"""
from ..contest.verdict import decide, paired as _paired


def _totals(rows, name, again=False):
    """{step key: ms} of the variant `name`: prediction plus its solve (or, again, its A/A twin's)."""
    def twin(r):
        return (r.predict_ms if r.predict_ms_again is None else r.predict_ms_again) + r.solve_ms_again
    return {(r.run, r.seed, r.step): twin(r) if again else r.predict_ms + r.solve_ms
            for r in rows if r.start == name and not (again and r.solve_ms_again is None)}


def ranked(summary, is_oracle):
    """The variants a verdict may name, fastest first: every one but the oracles; one that ended
    half its steps or more above the tolerance (unfinished: contest/verdict.py) after the rest,
    then the smallest median time."""
    return sorted((n for n in summary if not is_oracle(n)),
                  key=lambda n: (summary[n].get("above", 0) >= 0.5, summary[n]["total_ms_median"]))


def _unfinished(rows, name):
    """The step keys the variant `name` ended above the tolerance (by our residual)."""
    return {(r.run, r.seed, r.step) for r in rows if r.start == name and r.above}


def judge(rows, summary, base, is_oracle):
    """What the verdict may say, measured by the contest's one rule (contest/verdict.py) on the
    replay's rows: each variant's time against `base` with its interval, the A/A noise floor of
    `base`, the best fair variant against the runner-up, and the totals (setup included). A dict
    for summary.json; None without a base."""
    if base is None or base not in summary:
        return None
    times = {name: _totals(rows, name) for name in summary}
    aa = _paired(_totals(rows, base), _totals(rows, base, again=True))
    v = decide(times, ranked(summary, is_oracle), base, aa, {n: s.get("setup_ms", 0.0) for n, s in summary.items()},
               {name: _unfinished(rows, name) for name in summary})
    return v.as_dict()
