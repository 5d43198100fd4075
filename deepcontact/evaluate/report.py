"""The replay report: markdown, CSV/JSON tables and plots (PNG and SVG); the verdict's words in
verdicts.py, the plots in plots.py, the closed loop's report in loop_report.py.

  convergence  median (and for up to 4 variants, or --bands, the 10-90% band) of the stopping
               measure per iteration, per start (the thesis's figures 3.7/3.8/5.7/5.9, with
               percentiles instead of a mean)

Every variant keeps one style (colour, line, marker) in every plot of a report; oracles are dashed
and kept off the main scale (deepcontact/plotstyle.py).
  iterations   the distribution of iterations to tolerance per start (empirical CDF)
  pareto       what accuracy costs in time, measured: for fixed sweep budgets run without early
               stopping, the median residual reached against the median measured time per step
               (prediction included), per start (written when the budgets were run)
  closed-loop  each start driving the simulation: iterations, time, drift and energy error
               against the reference trajectory, with Box2D's own solver at 1-256 iterations
"""
import io
import json

import numpy as np

from .. import __version__, output
from ..contest import describe_fences
from ..contest.client import deadline_rule
from ..escape import CsvWriter, md_text
from ..html import markdown_to_html
from ..protocol import protocol_line
from .plots import plots
from .replay import BUDGETS
from .summary import reference_summary
from .verdicts import as_share, baseline, interval, noise_of, not_converged_tag, oracle, verdict

# Everything a report folder holds (replay and closed loop): what --overwrite may replace.
REPORT_FILES = output.Owned("report", [r"report\.(md|html)", r"(summary|steps)\.csv", r"(summary|pareto)\.json",
                                       r"(convergence|iterations|pareto)\.(png|svg)",
                                       r"closed-loop\.(md|html|json|png|svg)"])


def write_report(out, rows, summary, settings):
    """The replay report into the folder out: steps.csv, summary.json/csv, pareto.json (where the
    budgets ran), the plots, report.md and report.html."""
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = CsvWriter(buf)
    w.writerow(["run", "seed", "step", "points", "start", "relaxation", "iterations", "capped", "fallback", "residual",
                "error", "velocity_error", "predict_ms", "solve_ms", "reference_residual", "reference_pivoted"])
    for r in rows:
        w.writerow([r.run, r.seed, r.step, r.points, r.start, "" if r.relaxation is None else f"{r.relaxation:g}", r.iterations, int(r.capped),
                    int(r.fallback), f"{r.residual:.6g}", f"{r.error:.6g}", f"{r.velocity_error:.6g}",
                    f"{r.predict_ms:.6g}", f"{r.solve_ms:.6g}", f"{r.reference_residual:.6g}",
                    int(r.reference_pivoted)])
    output.write_text(out / "steps.csv", buf.getvalue())
    settings = dict(settings, reference=reference_summary(rows))
    if "noise" not in settings:
        settings["noise"] = noise_of(rows, summary)
    output.write_text(out / "summary.json", json.dumps({"settings": settings, "starts": summary}, indent=2) + "\n")
    buf = io.StringIO()
    w = CsvWriter(buf)
    keys = list(next(iter(summary.values())))
    w.writerow(["start"] + keys)
    for name, s in summary.items():
        w.writerow([name] + [_csv_value(s[k]) for k in keys])
    output.write_text(out / "summary.csv", buf.getvalue())
    pareto = pareto_points(rows, summary)
    if pareto:
        output.write_text(out / "pareto.json", json.dumps(pareto, indent=1) + "\n")
    drawn = settings.get("plots", True)
    if drawn:
        plots(out, rows, summary, settings, pareto)
    text = markdown(summary, settings, pareto)
    output.write_text(out / "report.md", text)
    # the same tables and plots in one page that reads offline (SVG inline)
    output.write_text(out / "report.html", markdown_to_html(
        text, out, "Warm starts compared", pictures=("convergence.png", "iterations.png", "pareto.png") if drawn else ()))


def _csv_value(value):
    """A summary value as a CSV cell: text as it is, a record (an origin) as JSON, a number to 6 digits."""
    if isinstance(value, str):
        return value
    if isinstance(value, (dict, list)) or value is None:
        return json.dumps(value, sort_keys=True)
    return f"{value:.6g}"


def _every(k):
    """"every step", "every 2nd step", "every 5th step"."""
    if k == 1:
        return "every step"
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"every {k}{suffix} step"


def summary_table(summary, noise=None):
    """The replay table: one row per variant, ratios to Box2D's warm start (with their intervals
    where noise is given), no column of zeros."""
    base = baseline(summary)
    ref = summary.get(base)
    factor = any(s.get("factorizations_median", 0) for s in summary.values())
    fell = any(s.get("fallbacks", 0) for s in summary.values())
    head = ["start", "steps", "median iterations", "p80", "p95", "at the cap", "above tolerance",
            "residual (median / p95)"] + (["factorizations"] if factor else [])
    whole = all("total_ms_sum" in s for s in summary.values())
    head += ["predict ms", "solve ms", "total ms"] + (["total ms p90", "all steps ms"] if whole else []) \
        + (["sweeps vs builtin", "time vs builtin"] if ref else [])
    head += ["median impulse error", "median velocity error (m/s)"] + (["w fell back"] if fell else [])
    lines = ["| " + " | ".join(head) + " |", "| --- |" + " ---: |" * (len(head) - 1)]
    for name, s in summary.items():
        marks = ([" (oracle)"] if oracle(name) else []) + ([" (Python)"] if s.get("python") else []) \
            + [not_converged_tag(s.get("above", 0), s["steps"])]
        cells = [md_text(name) + "".join(marks), f"{s['steps']}", f"{s['iterations_median']:.0f}",
                 f"{s['iterations_p80']:.0f}", f"{s['iterations_p95']:.0f}", as_share(s["at_cap"]),
                 as_share(s.get("above", 0)),
                 f"{s['residual_median']:.2g} / {s.get('residual_p95', s['residual_median']):.2g}"]
        if factor:
            cells.append(f"{s.get('factorizations_median', 0):.0f}")
        cells += [f"{s['predict_ms_median']:.3f}", f"{s['solve_ms_median']:.3f}", f"{s['total_ms_median']:.3f}"]
        if whole:   # (the distribution, not the median alone: a start slow on a few steps shows here)
            cells += [f"{s['total_ms_p90']:.3f}", f"{s['total_ms_sum']:.4g}"]
        if ref:
            timed = (interval(noise["vs_base"][name]) if noise and name in noise.get("vs_base", {})
                     else f"{s['total_ms_median'] / max(ref['total_ms_median'], 1e-12):.2f}x")
            cells += [f"{s['iterations_median'] / max(ref['iterations_median'], 1e-12):.2f}x", timed]
        cells += [f"{s['error_median']:.3g}", f"{s['velocity_error_median']:.3g}"]
        if fell:
            cells.append(as_share(s["fallbacks"]))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def in_order(order, box2d_rows=False):
    """The sweep order as a report's line says it (replay's and the closed loop's): nothing for
    Box2D's island order; box2d_rows: the report also holds Box2D's own solver's rows."""
    if order == "island":
        return ""
    box2d = "; Box2D's own rows in its island order" if box2d_rows else ""
    return f", its sweeps in {order}'s order (the highest manifolds first{box2d})"


def markdown(summary, settings, pareto):
    """report.md's text: the verdict, the table, how it was measured, and the pareto table."""
    s = settings
    ref = s["reference"]
    line = verdict(summary, s.get("noise"))
    text = ["# Warm starts compared\n", *([line + "\n"] if line else []),
            f"Runs: {', '.join(md_text(r) for r in s['runs'])}; {s['steps']} steps, {_every(s['every'])}; solver {s['mode']} PGS stopped "
            f"when the {s['stop_on']} measure falls below {s['tolerance']:g}, at most {s['max_iterations']} sweeps"
            f"{in_order(s.get('order', 'island'))}. "
            f"Errors are against each step's reference solution (float64 from zero, PGS sweeps, Newton steps and, "
            f"where Newton stalls, Lemke's pivoting, to a residual of 1e-12; {ref['reached']} of {ref['steps']} steps reached it "
            f"({ref['pivoted']} by a pivot), the worst ended at "
            f"{ref['worst_residual']:.2g}). Exact solutions of a frictional step need not be unique, in impulses nor "
            f"in body velocities: the residual is the honest per-step measure, and the impulse and velocity errors "
            f"against one reference are informative, not ground truth.\n",
            summary_table(summary, s.get("noise")), "",
            *([protocol_line(s["protocol"]) + "\n"] if s.get("protocol") else []),
            f"Oracles (they ask for the step's answer, so they know it): "
            f"{', '.join(md_text(n) for n in summary if oracle(n)) or 'none here'}. `@w`: over-relaxed (PSOR) with that w; "
            "'w fell back': solves where the guard returned to w = 1. Times are medians per step (total: "
            "prediction plus solve of each step, then the median); prediction includes rasterizing, the network "
            "and interpolating where a start needs them. 'vs builtin': the median against Box2D's own warm start's.\n",
            *provenance(summary), *contestants_line(summary)]
    drawn = s.get("plots", True)
    if drawn:
        text += ["![convergence](convergence.png)\n", "![iterations](iterations.png)\n"]
    if pareto:
        text += [*(["![pareto](pareto.png)\n"] if drawn else []), "## What accuracy costs in time\n",
                 "Measured: each step solved with exactly that many sweeps (no early stop); the median residual "
                 "reached and the median measured time per step, prediction included:\n",
                 "| start | " + " | ".join(f"{b} sweeps" for b in BUDGETS) + " |",
                 "| --- |" + " ---: |" * len(BUDGETS)]
        for name, pts in pareto.items():
            cells = [f"{p['residual']:.2g} @ {p['ms']:.3f} ms" for p in pts]
            text.append(f"| {md_text(name)} | " + " | ".join(cells) + " |")
    return "\n".join(text) + "\n"


def contestants_line(summary):
    """How the contestants were measured: each in a process of its own, what setting it up cost
    (import and construction, not in the per-step times), the transport subtracted, and what the
    judge noticed (something left running)."""
    if not any("setup_ms" in s for s in summary.values()):
        return []
    setup = ", ".join(f"{md_text(n)} {s['setup_ms']:.1f} ms" for n, s in summary.items())
    transport = max(s["transport_ms_median"] for s in summary.values())
    out = [f"{fenced_line()} Setting each up (import and construction, charged beyond the null contestant's, with what it ran after its last call; in "
           f"the totals, not in the times per step): {setup}. The transport, the null contestant's round trip of "
           f"the same request (the same sandbox and path, no plug-in code) measured per step and subtracted from "
           f"every variant alike, was at most {transport:.3f} ms (median per step); times below it are within its "
           f"noise. Deadlines: {deadline_rule()}.\n"]
    left = [(n, s["left_running"]) for n, s in summary.items() if any(s.get("left_running") or ())]
    if left:
        out.append("Left threads or processes running after their calls (counted by the judge; their CPU charged, "
                   "what no call can have used spread evenly over the variant's steps, and ended with their "
                   "sandboxes): "
                   + ", ".join(f"{md_text(n)} ({t} thread{'s' if t != 1 else ''}, {p} "
                               f"process{'es' if p != 1 else ''})" for n, (t, p) in left) + ".\n")
    return out


def fenced_line():
    """How every contestant was fenced and charged (contest/), the missing fences named."""
    return (f"Each variant ran in a sandbox of its own ({describe_fences()}), made from its names there (the judge "
            f"holds none of its state, and it none of the judge's, no other variant's and no run folder), and every "
            f"call was charged here, the larger of its wall time and the CPU its sandbox used in it, with the CPU no "
            f"call can have used (between calls, or beyond what the threads it is granted could run in a call) "
            f"spread evenly over its steps, and its answer judged here.")


def provenance(summary):
    """A line naming where each plug-in in the report comes from (none: no line)."""
    seen = {}
    for s in summary.values():
        for key in ("start_origin", "method_origin"):
            o = s.get(key) or {}
            if o.get("origin") == "plug-in":
                where = (f"{o['distribution']} {o['version']}" if o.get("distribution")
                         else "not from an installed package")
                seen[o["name"]] = f"{md_text(o['name'])} ({md_text(o['target'])}; {md_text(where)})"
    return [f"Plug-ins: {'; '.join(seen.values())}. Built-ins are deepcontact {__version__}'s.\n"] if seen else []


def pareto_points(rows, summary):
    """Per start and budget, measured: the median residual after exactly that many sweeps and the
    median time of those sweeps plus the prediction. Empty when the budgets were not run."""
    out = {}
    for name in summary:
        rs = [r for r in rows if r.start == name and r.budget_ms is not None]
        if not rs:
            continue
        pred = np.array([r.predict_ms for r in rs])
        ms = np.array([r.budget_ms for r in rs]) + pred[:, None]
        res = np.array([r.budget_residual for r in rs])
        out[name] = [{"budget": b, "residual": float(np.median(res[:, i])), "ms": float(np.median(ms[:, i]))}
                     for i, b in enumerate(BUDGETS)]
    return out


