"""What a replay's rows say per variant: the summary its report and verdict read, the memos
found among its answers, and how far the reference solutions reached."""
import numpy as np

from ..solver.methods import is_native
from ..solver.reference import TOLERANCE as REFERENCE_TOLERANCE


# A memo's repeats answer in a lookup's time: the bar below which a variant's own repeats, against
# its own first calls, say it kept answers (the median over its steps of fastest repeat / first
# call, each a whole call, transport included: net of it, a 4-point step's honest repeats measure
# 0 and every ratio did), judged with at least MEMO_STEPS steps. The median over every step, not a
# chosen few: steps picked for a slow first call pick the machine's hiccups.
MEMO_BAR = 0.25
MEMO_STEPS = 3


def flag_memos(rows):
    """Marks the variants whose repeated solves answered far faster than their own first call of
    each step (a memo of answers by the problem's bytes): their rows are charged the first call
    (Row.memo). Each variant is held to a fixed bar on its own times (MEMO_BAR), so no other
    variant, colluding or slow, moves it."""
    ratios = {}
    for r in rows:
        if r.solve_ms_repeats is not None and len(r.solve_ms_repeats):
            whole = r.transport_ms + np.asarray(r.solve_ms_repeats, np.float64)
            ratios.setdefault(r.start, []).append(float(np.min(whole) / max(r.transport_ms + r.first_ms, 1e-9)))
    flagged = {name for name, v in ratios.items() if len(v) >= MEMO_STEPS and float(np.median(v)) < MEMO_BAR}
    for r in rows:
        if r.start in flagged:
            r.memo, r.solve_ms = True, float(r.first_ms)
    return rows


def summarize(rows, starts, max_iterations):
    """Per variant: the distribution of iterations, the share at the cap, times, residual, errors."""
    return {name: _summary([r for r in rows if r.start == name]) for name in dict.fromkeys(r.start for r in rows)}


def _summary(rs):
    """One variant's summary, from its rows."""
    it = np.array([r.iterations for r in rs])
    pred = np.array([r.predict_ms for r in rs])
    total = pred + np.array([r.solve_ms for r in rs])
    setup = float(max(r.setup_ms for r in rs))

    def median(field):
        return float(np.median([getattr(r, field) for r in rs]))

    def share(field):
        return float(np.mean([getattr(r, field) for r in rs]))
    return {
        "steps": len(rs),
        "relaxation": rs[0].relaxation,
        "accelerate": rs[0].accelerate,
        "iterations_median": float(np.median(it)), "iterations_p80": float(np.percentile(it, 80)),
        "iterations_p95": float(np.percentile(it, 95)),
        "at_cap": share("capped"),
        "predict_ms_median": float(np.median(pred)), "solve_ms_median": median("solve_ms"),
        "total_ms_median": float(np.median(total)),
        "residual_median": median("residual"),
        "residual_p95": float(np.percentile([r.residual for r in rs], 95)),
        "above": share("above"),
        "python": not is_native(rs[0].accelerate),
        "error_median": median("error"),
        "velocity_error_median": median("velocity_error"),
        "fallbacks": share("fallback"),
        "factorizations_median": median("factorizations"),
        "predict_ms_p90": float(np.percentile(pred, 90)), "total_ms_p90": float(np.percentile(total, 90)),
        "total_ms_sum": float(np.sum(total)) + setup,
        "transport_ms_median": median("transport_ms"),
        "setup_ms": setup,
        "memo": bool(any(r.memo for r in rs)),
        "left_running": [int(max(r.left_running[k] for r in rs)) for k in (0, 1)],
    }


def reference_summary(rows):
    """How many steps' reference solutions reached the 1e-12 target."""
    per_step = {(r.run, r.seed, r.step): (r.reference_residual, r.reference_pivoted) for r in rows}
    reached = sum(v < REFERENCE_TOLERANCE for v, _ in per_step.values())
    return {"steps": len(per_step), "reached": int(reached), "tolerance": REFERENCE_TOLERANCE,
            "pivoted": int(sum(pivoted for _, pivoted in per_step.values())),
            "worst_residual": float(max(v for v, _ in per_step.values()))}
