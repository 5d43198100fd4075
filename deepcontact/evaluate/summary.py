"""What a replay's rows say per variant: the summary its report and verdict read, and how far the
reference solutions reached."""
import numpy as np

from ..solver.methods import is_native
from ..solver.reference import TOLERANCE as REFERENCE_TOLERANCE


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
        "yardstick": any(getattr(r, "solve_ms_again", None) is not None for r in rs),   # (run twice: the A/A)
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
        "left_running": [int(max(r.left_running[k] for r in rs)) for k in (0, 1)],
    }


def reference_summary(rows):
    """How many steps' reference solutions reached the 1e-12 target."""
    per_step = {(r.run, r.seed, r.step): (r.reference_residual, r.reference_pivoted) for r in rows}
    reached = sum(v < REFERENCE_TOLERANCE for v, _ in per_step.values())
    return {"steps": len(per_step), "reached": int(reached), "tolerance": REFERENCE_TOLERANCE,
            "pivoted": int(sum(pivoted for _, pivoted in per_step.values())),
            "worst_residual": float(max(v for v, _ in per_step.values()))}
