"""The closed loop's report: report.md and .html, summary.csv, closed-loop.json and the plot."""
import io
import json

import numpy as np

from .. import output
from ..contest.client import deadline_rule
from ..errors import count
from ..escape import CsvWriter, md_text
from ..html import markdown_to_html
from ..protocol import protocol_line
from .plots import loop_plot
from .report import fenced_line, in_order
from .verdicts import (as_share, loop_above, loop_residuals, loop_verdict, net_time_errors, not_converged_tag,
                       on_asked_steps)


def _loop_path_line(results):
    """How the project's rows were measured in the loop: each variant's start (and plug-in method)
    in a process of its own, its calls charged (contest/charge.py), the path's own cost stated."""
    ours = [r for r in results if r.ours and getattr(r, "transport_ms", None) is not None and len(r.transport_ms)]
    if not ours:
        return ""
    transport = max(float(np.median(r.transport_ms)) for r in ours)
    path = max(getattr(r, "path_ms", 0.0) for r in ours)
    # (the path's cost is a difference of two runs' medians: at or below zero, it is within their noise)
    noise = ", at or below zero: within the two runs' noise" if path <= 0 else ""
    return (f"{fenced_line()} Every step went through Python; each call was charged less the null "
            f"contestant's least over the run, for every variant alike (the round trips left uncharged: at most "
            f"{transport:.3f} ms a step, median). "
            f"A net time per step at or below zero is a measurement error, never a win. Deadlines: "
            f"{deadline_rule()}. What that path costs over the project's native loop (one call a step), "
            f"{path:.3f} ms a step (builtin both ways, median{noise}), is in every row of the project's solver, alike; "
            f"Box2D's own rows are without it.\n\n")


def write_loop_report(out, results, what, settings, measured=None, simulations=1, plotted=None, plots=True):
    """report.md (and .html) and summary.csv as replay's, closed-loop.json and the plot closed-loop.png
    into the folder out; returns the table. settings: the SolveSettings every step was solved
    with (a variant's w and method aside). With several simulations, results hold the pooled rows first, then each simulation's;
    plotted: the rows the plot shows (default all); plots False: no plot."""
    stop_on, tolerance = settings.stop_on, settings.tolerance
    text = loop_table(results, tolerance if stop_on == "residual" else None)
    pooled = results[:len(results) // (simulations + 1)] if simulations > 1 else results   # (the verdict's rows)
    line = loop_verdict(pooled, tolerance if stop_on == "residual" else None)
    page = (f"# Closed loop: {md_text(what)}\n\n" + (line + "\n\n" if line else "") +
            f"Stopping: {stop_on} < {tolerance:g}, at most {settings.max_iterations} sweeps, {settings.mode}"
            f"{in_order(settings.order, box2d_rows=True)}. Drift: "
            f"largest distance of any surviving body from the trajectory stepped with reference solutions "
            f"(float64 PGS to 1e-12); energy error: largest |E - E_ref| over the steps, relative to "
            f"|E_ref| at the first step (E: kinetic plus gravitational energy of the dynamic bodies). "
            f"`@w`: over-relaxed PGS; `+nncg`: with conjugate directions. `box2d k iterations`: Box2D's own "
            f"solver. Iterations and times per step are medians over each row's steps with contact points, "
            f"where a start is asked (Box2D's own rows: every step). A pile is chaotic: a difference in the "
            f"last digits of one step's impulses changes which contacts form next, so every trajectory drifts from the reference, even one stepped by a converged "
            f"solver; compare the drifts of the rows with each other (and with Box2D at 256 iterations), and read "
            f"the iterations, energy error and penetration as the accuracy of each step."
            + (f" {simulations} simulations: the first rows pool them all (iterations and times over every step of "
               f"every simulation; the drift at each step the largest of any simulation's; the worst penetration "
               f"and energy error), the rows after them are each simulation's." if simulations > 1 else "")
            + "\n\n" + text + "\n\n" + _loop_path_line(pooled) + (protocol_line(measured) + "\n\n" if measured else "")
            + ("![closed loop](closed-loop.png)\n" if plots else ""))
    output.write_text(out / "report.md", page)
    if plots:
        loop_plot(results if plotted is None else plotted, out / "closed-loop")
    output.write_text(out / "report.html", markdown_to_html(page, out, f"Closed loop: {what}",
                                                            pictures=("closed-loop.png",) if plots else ()))
    _loop_summary_csv(out, results)
    output.write_text(out / "closed-loop.json", json.dumps({"protocol": measured, "order": settings.order, "results": [{
        "start": r.start, "steps": r.steps, "iterations": r.iterations.tolist(),
        "ms_per_step": r.ms_per_step.tolist(), "drift": r.drift.tolist(), "penetration": r.penetration,
        "energy_error": r.energy_error, "finite": r.finite,
        "transport_ms": None if getattr(r, "transport_ms", None) is None else r.transport_ms.tolist(),
        "path_ms": getattr(r, "path_ms", 0.0),
        "order": settings.order if r.ours else "island"} for r in results]}) + "\n")   # (Box2D's own: island)
    return text


def _loop_summary_csv(out, results):
    """summary.csv of a closed loop: a row per result."""
    buf = io.StringIO()
    w = CsvWriter(buf)
    w.writerow(["start", "steps", "iterations_median", "iterations_p80", "iterations_max", "ms_per_step_median",
                "predict_ms_median", "final_drift_m", "max_drift_m", "energy_error", "deepest_contact_m", "finite"])
    for r in results:
        it = r.iterations[r.iterations > 0] if np.any(r.iterations > 0) else r.iterations
        w.writerow([r.start, r.steps, float(np.median(it)), float(np.percentile(it, 80)), float(it.max()),
                    float(np.median(on_asked_steps(r, r.ms_per_step))),
                    float(np.median(on_asked_steps(r, r.predict_ms))) if len(r.predict_ms) else 0.0,
                    float(r.drift[-1]) if len(r.drift) else "", float(r.drift.max()) if len(r.drift) else "",
                    r.energy_error, r.penetration, r.finite])
    output.write_text(out / "summary.csv", buf.getvalue())


def loop_table(results, tolerance=None):
    """One row per start (and w) and per Box2D iteration count, with the project's residual of
    each (median / p95) and the share of steps above the tolerance where it is judged."""
    lines = ["| start | steps | median iterations | p80 | max | residual (median / p95) | above tolerance | "
             "ms per step (median) | of which prediction | "
             "final drift (m) | max drift (m) | energy error | deepest contact (cm) | finite |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    errors = net_time_errors(results)
    for r in results:
        it = r.iterations[r.iterations > 0] if np.any(r.iterations > 0) else r.iterations
        pred = float(np.median(on_asked_steps(r, r.predict_ms))) if len(r.predict_ms) else 0.0
        res = loop_residuals(r)
        above = loop_above(r, tolerance)
        judged = (f"{np.median(res):.2g} / {np.percentile(res, 95):.2g}" if len(res) else "-",
                  "-" if above is None else as_share(above))
        marks = (" (oracle)" if r.oracle else "") + not_converged_tag(above, len(res)) + (
            f" (measurement error: a net time at or below zero on {count(errors[r.start], 'step')})"
            if r.start in errors else "")
        lines.append(f"| {md_text(r.start)}{marks} | {r.steps} | {np.median(it):.0f} | {np.percentile(it, 80):.0f} | "
                     f"{it.max():.0f} | {judged[0]} | {judged[1]} | "
                     f"{np.median(on_asked_steps(r, r.ms_per_step)):.3f} | {pred:.2f} | {r.drift[-1] if len(r.drift) else float('nan'):.3g} | "
                     f"{r.drift.max() if len(r.drift) else float('nan'):.3g} | {r.energy_error:.2g} | "
                     f"{100 * r.penetration:.2f} | {'yes' if r.finite else 'NO'} |")
    return "\n".join(lines)
