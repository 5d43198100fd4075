"""The evaluation report: markdown, CSV/JSON tables and plots (PNG and SVG).

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
import warnings

import numpy as np

from .. import __version__, output
from ..errors import count
from ..escape import CsvWriter, md_text, plot_text
from ..html import markdown_to_html
from ..protocol import protocol_line
from ..contest.verdict import MIN_STEPS
from .noise import judge, ranked
from .replay import BUDGETS, reference_summary
from ..plotstyle import axis_floor, readable_log_ticks, show_bands, styles, with_markers

# Everything a report folder holds (replay and closed loop): what --overwrite may replace.
REPORT_FILES = output.Owned("report", [r"report\.(md|html)", r"(summary|steps)\.csv", r"(summary|pareto)\.json",
                                       r"(convergence|iterations|pareto)\.(png|svg)",
                                       r"closed-loop\.(md|html|json|png|svg)"])


def write_report(out, rows, summary, settings):
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


def _share(x):
    """A share as a percentage, where any at all shows ("<1%", never a "0%" that hides a step)."""
    return "<1%" if 0 < x < 0.005 else f"{100 * x:.0f}%"


def _csv_value(value):
    """A summary value as a CSV cell: text as it is, a record (an origin) as JSON, a number to 6 digits."""
    if isinstance(value, str):
        return value
    if isinstance(value, (dict, list)) or value is None:
        return json.dumps(value, sort_keys=True)
    return f"{value:.6g}"


def _base(label):
    """The start a variant label names: 'prev@1.7+nncg' -> 'prev'."""
    return label.split("@")[0].split("+")[0]


def baseline(summary):
    """The label of Box2D's own warm start with plain PGS (w = 1), the yardstick, or None."""
    for name, s in summary.items():
        if _base(name) == "builtin" and s.get("relaxation") in (1, 1.0) and s.get("accelerate", "none") == "none":
            return name
    return None


def _oracle(label):
    from ..warmstart.starts import is_oracle
    return is_oracle(_base(label))


def _interval(triple):
    ratio, lo, hi = triple
    return f"{ratio:.2f}x [{lo:.2f}, {hi:.2f}]"


def _fence_caveat():
    """What a verdict adds where this machine refused a contestant's fence (none: nothing)."""
    from ..contest import missing_fences
    missing = missing_fences()
    return (f" Contestants' fences missing on this machine ({', '.join(missing)}): a contestant could reach "
            f"beyond its sandbox, so this verdict holds only for honest contestants." if missing else "")


def verdict(summary, noise=None):
    """The replay's verdict line (_verdict), with the fences this machine refused, if any."""
    line = _verdict(summary, noise)
    return None if line is None else line + _fence_caveat()


def _verdict(summary, noise=None):
    """One line: the start with the smallest median time per step to the tolerance (prediction
    included), with its ratio to Box2D's warm start. Left out: oracles, which know the answer, and
    every variant that ended a step above the tolerance by our residual (it did not converge,
    whatever it said)."""
    candidates = [n for n in summary if not _oracle(n)]
    if not candidates:
        return None
    fair = ranked(summary, _oracle)
    left_out = _unfinished_note({n: summary[n].get("above", 0) for n in candidates})
    best = fair[0]
    b, base = summary[best], baseline(summary)
    if noise and noise.get("best") is not None:
        best = noise["best"]
        b = summary[best]
    if noise and noise.get("best") == best and noise.get("beaten_on_total_by"):
        # a heavy tail: the median's fastest lost the whole run; none is called the fastest
        beaten = noise["beaten_on_total_by"]
        text = (f"**Verdict**: no clear winner. {md_text(best)} has the smallest median time per step (prediction "
                f"included; oracles left out)" + (f", {_interval(noise['vs_base'][best])} of {md_text(base)}'s"
                                                   if best != base else "")
                + ", but over the whole run, setup included, it took longer than "
                + " and ".join(f"{md_text(n)} ({noise['total_ms'][best]:.4g} ms against {noise['total_ms'][n]:.4g} ms)"
                               for n in beaten)
                + f": a heavy tail of slow steps; {md_text(base)} timed against itself (A/A) measured "
                f"{_interval(noise['aa'])} ({100 * noise['level']:.0f}% intervals over the steps).")
        return text + left_out
    if noise and noise.get("best") == best and noise.get("gave_up_more"):
        return (f"**Verdict**: no clear winner. {md_text(best)} has the smallest median time per step, but it left "
                f"more steps above the tolerance than {md_text(base)} ({noise['unfinished'][best]} against "
                f"{noise['unfinished'][base]}): faster by not finishing is not faster." + left_out)
    if noise and noise.get("best") == best and noise.get("too_few_steps"):
        return (f"**Verdict**: no clear winner: {count(noise['steps'], 'step')} to judge on, and a winner is named "
                f"from at least {MIN_STEPS}." + left_out)
    if noise and noise.get("best") == best and not noise["clear"]:
        runner = noise.get("runner_up")
        # (no winner, so none is called the fastest: the smallest median, with its intervals)
        text = (f"**Verdict**: no clear winner within noise. {md_text(best)} has the smallest median time per step "
                f"to the tolerance (prediction included; oracles left out)"
                + (f", at {_interval(noise['vs_base'][best])} of {md_text(base)}'s time" if best != base else "")
                + (f"; against the runner-up {md_text(runner)} it takes {_interval(noise['best_vs_runner_up'])}"
                   if runner else "")
                + f"; {md_text(base)} timed against itself (A/A) measured {_interval(noise['aa'])} "
                f"({100 * noise['level']:.0f}% intervals over the steps).")
        return text + left_out
    text = (f"**Verdict**: the fastest start to the tolerance (median time per step, prediction included; "
            f"oracles left out) is **{md_text(best)}**: {b['total_ms_median']:.3f} ms, {count(round(b['iterations_median']), 'sweep')}")
    if base is not None and base != best:
        r = summary[base]
        text += (f", {b['total_ms_median'] / max(r['total_ms_median'], 1e-12):.2f}x the time and "
                 f"{b['iterations_median'] / max(r['iterations_median'], 1e-12):.2f}x the sweeps of {md_text(base)}")
    elif base == best:
        text += f"; nothing beats {md_text(base)}, Box2D's own warm start"
    if b["at_cap"] > 0:
        text += f" ({100 * b['at_cap']:.0f}% of its steps stopped at the cap)"
    if noise and noise.get("best") == best:
        parts = ([f"time {_interval(noise['vs_base'][best])} of {md_text(base)}'s"] if best != base else []) \
            + ([f"{_interval(noise['best_vs_runner_up'])} of the runner-up {md_text(noise['runner_up'])}'s"]
               if noise.get("runner_up") else []) + [f"A/A noise floor {_interval(noise['aa'])}"]
        text += f" ({'; '.join(parts)}; {100 * noise['level']:.0f}% intervals over the steps)"
    return text + "." + left_out


def _every(k):
    """"every step", "every 2nd step", "every 5th step"."""
    if k == 1:
        return "every step"
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"every {k}{suffix} step"


def _unfinished_note(shares):
    """The rule for steps ended above the tolerance, said where a variant has any ({label: share})."""
    some = {n: share for n, share in shares.items() if share}
    if not some:
        return ""
    return (" Steps ended above the tolerance (by our residual) count as unfinished, slower than any finished "
            "step (contest/verdict.py): " + ", ".join(f"{md_text(n)} {_share(share)}" for n, share in some.items())
            + ".")


def noise_of(rows, summary):
    """The intervals the verdict and the table state (noise.judge, with this report's baseline
    and oracles)."""
    return judge(rows, summary, baseline(summary), _oracle)


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
        marks = ([" (oracle)"] if _oracle(name) else []) + ([" (Python)"] if s.get("python") else []) \
            + ([" (did not converge)"] if s.get("above", 0) else [])
        cells = [md_text(name) + "".join(marks), f"{s['steps']}", f"{s['iterations_median']:.0f}",
                 f"{s['iterations_p80']:.0f}", f"{s['iterations_p95']:.0f}", f"{100 * s['at_cap']:.0f}%",
                 _share(s.get("above", 0)),
                 f"{s['residual_median']:.2g} / {s.get('residual_p95', s['residual_median']):.2g}"]
        if factor:
            cells.append(f"{s.get('factorizations_median', 0):.0f}")
        cells += [f"{s['predict_ms_median']:.3f}", f"{s['solve_ms_median']:.3f}", f"{s['total_ms_median']:.3f}"]
        if whole:   # (the distribution, not the median alone: a start slow on a few steps shows here)
            cells += [f"{s['total_ms_p90']:.3f}", f"{s['total_ms_sum']:.4g}"]
        if ref:
            timed = (_interval(noise["vs_base"][name]) if noise and name in noise.get("vs_base", {})
                     else f"{s['total_ms_median'] / max(ref['total_ms_median'], 1e-12):.2f}x")
            cells += [f"{s['iterations_median'] / max(ref['iterations_median'], 1e-12):.2f}x", timed]
        cells += [f"{s['error_median']:.3g}", f"{s['velocity_error_median']:.3g}"]
        if fell:
            cells.append(f"{100 * s['fallbacks']:.0f}%")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown(summary, settings, pareto):
    s = settings
    ref = s["reference"]
    line = verdict(summary, s.get("noise"))
    text = ["# Warm starts compared\n", *([line + "\n"] if line else []),
            f"Runs: {', '.join(md_text(r) for r in s['runs'])}; {s['steps']} steps, {_every(s['every'])}; solver {s['mode']} PGS stopped "
            f"when the {s['stop_on']} measure falls below {s['tolerance']:g}, at most {s['max_iterations']} sweeps. "
            f"Errors are against each step's reference solution (float64 from zero, PGS sweeps, Newton steps and, "
            f"where Newton stalls, Lemke's pivoting, to a residual of 1e-12; {ref['reached']} of {ref['steps']} steps reached it "
            f"({ref['pivoted']} by a pivot), the worst ended at "
            f"{ref['worst_residual']:.2g}). Exact solutions of a frictional step need not be unique, in impulses nor "
            f"in body velocities: the residual is the honest per-step measure, and the impulse and velocity errors "
            f"against one reference are informative, not ground truth.\n",
            summary_table(summary, s.get("noise")), "",
            *([protocol_line(s["protocol"]) + "\n"] if s.get("protocol") else []),
            f"Oracles (they ask for the step's answer, so they know it): "
            f"{', '.join(md_text(n) for n in summary if _oracle(n)) or 'none here'}. `@w`: over-relaxed (PSOR) with that w; "
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
    judge noticed (a memo, something left running)."""
    if not any("setup_ms" in s for s in summary.values()):
        return []
    from ..contest.client import deadline_rule
    setup = ", ".join(f"{md_text(n)} {s['setup_ms']:.1f} ms" for n, s in summary.items())
    transport = max(s["transport_ms_median"] for s in summary.values())
    out = [f"{_fenced_line()} Setting each up (import and construction, charged beyond the null contestant's, with what it ran after its last call; in "
           f"the totals, not in the times per step): {setup}. The transport, the null contestant's round trip of "
           f"the same request (the same sandbox and path, no plug-in code) measured per step and subtracted from "
           f"every variant alike, was at most {transport:.3f} ms (median per step); times below it are within its "
           f"noise. Deadlines: {deadline_rule()}.\n"]
    memo = [n for n, s in summary.items() if s.get("memo")]
    if memo:
        out.append(f"Answered repeats far faster than their own first calls (a memo of answers?), so charged their "
                   f"first calls: {', '.join(md_text(n) for n in memo)}.\n")
    left = [(n, s["left_running"]) for n, s in summary.items() if any(s.get("left_running") or ())]
    if left:
        out.append("Left threads or processes running after their calls (counted by the judge; their CPU charged to "
                   "the calls after them, and ended with their sandboxes): "
                   + ", ".join(f"{md_text(n)} ({t} thread{'s' if t != 1 else ''}, {p} "
                               f"process{'es' if p != 1 else ''})" for n, (t, p) in left) + ".\n")
    return out


def _fenced_line():
    """How every contestant was fenced and charged (contest/), the missing fences named."""
    from ..contest import describe_fences
    return (f"Each variant ran in a sandbox of its own ({describe_fences()}), made from its names there (the judge "
            f"holds none of its state, and it none of the judge's, no other variant's and no run folder), and every "
            f"call was charged here, the larger of its wall time and the CPU its sandbox used since its previous "
            f"call, and its answer judged here.")


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


def _axes():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt.subplots(figsize=(7, 4.5))


def _any_positive(ax, axis):
    values = [np.asarray(line.get_xdata() if axis == "x" else line.get_ydata(), dtype=float) for line in ax.lines]
    return any(np.any(np.isfinite(v) & (v > 0)) for v in values)


def _finish(fig, ax, stem, xlabel, ylabel, title, ylog=True, floor=None, xlog=True):
    # A log axis needs a positive value to show: when every value is 0 (a solve that starts at
    # the exact answer), the axis stays linear and the plot says so.
    if xlog and _any_positive(ax, "x"):
        ax.set_xscale("log")
        readable_log_ticks(ax.xaxis)
    if ylog and _any_positive(ax, "y"):
        ax.set_yscale("log")
        if floor is not None:
            ax.set_ylim(bottom=floor)
        readable_log_ticks(ax.yaxis)
    elif ylog:
        ax.text(0.5, 0.5, "every value is 0", transform=ax.transAxes, ha="center", va="center")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(plot_text(title))
    handles = len(ax.get_legend_handles_labels()[0])
    if handles > 6:   # (many variants: the legend beside the plot, not over the lines)
        fig.set_size_inches(9.5, 4.5)
        ax.legend(fontsize=8, handlelength=3.2, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    else:
        ax.legend(fontsize=8, handlelength=3.2)
    ax.grid(alpha=0.3, which="both")
    _save(fig, stem)


def _label(name, oracles, floor, values):
    """A legend label: the name, and for an oracle that says so (and that it runs off the scale)."""
    if name not in oracles:
        return plot_text(name)
    v = np.asarray(values, float)
    off = floor is not None and np.any(np.isfinite(v) & (v < floor))
    return plot_text(name) + (" (oracle, below the axis)" if off else " (oracle)")


def oracles_among(names):
    """The names of starts that know the answer (drawn dashed and off the main scale)."""
    return {n for n in names if _oracle(n)}


PLOT_POINTS = 2000   # sweeps drawn per curve at most: more than a figure's width in pixels


def plotted_sweeps(n):
    """The sweep indices 0 .. n-1 a curve draws: every one up to PLOT_POINTS, else PLOT_POINTS of
    them spread evenly (the first and last always)."""
    if n <= PLOT_POINTS:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, PLOT_POINTS).round().astype(np.int64))


def convergence_plot(rows, names, stem, title, tolerance, stop_on, cap=None, bands=None, style=None):
    """Median (and, for a few variants or when asked, the 10-90% band) of the stopping measure per
    sweep, one line per start in its own style; a step that stopped keeps its last value (it had
    converged, or hit the cap). Oracles are dashed and kept off the main scale."""
    fig, ax = _axes()
    oracles = oracles_among(names)
    style = style or styles(names, oracles)
    curves = {}
    for name in names:
        hs = [r.history for r in rows if r.start == name]
        n = max(len(h) for h in hs) if cap is None else min(cap + 1, max(len(h) for h in hs))
        # at most PLOT_POINTS sweeps drawn (a million-sweep history would be a matrix of steps x
        # sweeps, and a line no screen shows): each step's value at those sweeps, or its last
        x = plotted_sweeps(n)
        m = np.array([h[np.minimum(x, len(h) - 1)] for h in hs])
        with warnings.catch_warnings():   # column 0 is all NaN unless the residual is the measure
            warnings.simplefilter("ignore", RuntimeWarning)
            curves[name] = (x, np.nanmedian(m, axis=0), np.nanpercentile(m, 10, axis=0),
                            np.nanpercentile(m, 90, axis=0))
    floor = axis_floor({n: c[1][1:] for n, c in curves.items()}, oracles)
    band = show_bands([n for n in names if n not in oracles], bands)
    for name, (x, med, lo, hi) in curves.items():
        kw = with_markers(style[name], len(x) - 1)
        if len(x) <= 5 and kw.get("marker") is None:
            kw["marker"] = "o"   # (a start that needs one sweep is a point, not a line)
        ax.plot(x[1:], med[1:], label=_label(name, oracles, floor, med[1:]), **kw)
        if band and name not in oracles:
            ax.fill_between(x[1:], lo[1:], hi[1:], color=style[name]["color"], alpha=0.12, linewidth=0)
    ax.axhline(tolerance, color="k", lw=0.8, ls=(0, (1, 2)), label=f"tolerance {tolerance:g}")
    _finish(fig, ax, stem, "PGS sweep", f"{stop_on} measure (median" + (", 10-90%)" if band else ")"), title,
            floor=floor)


def plots(out, rows, summary, settings, pareto):
    names = list(summary)
    oracles = oracles_among(names)
    style = styles(names, oracles)   # (one style per variant in every plot of the report)
    convergence_plot(rows, names, out / "convergence", "Convergence by warm start", settings["tolerance"],
                     settings["stop_on"], cap=settings["max_iterations"], bands=settings.get("bands"), style=style)

    fig, ax = _axes()
    for name in names:
        it = np.sort([r.iterations for r in rows if r.start == name])
        kw = with_markers(style[name], len(it))
        kw["marker"] = None
        ax.step(np.maximum(it, 1), np.arange(1, len(it) + 1) / len(it), where="post",
                label=_label(name, oracles, None, []), **kw)
    _finish(fig, ax, out / "iterations", "iterations to tolerance", "share of steps", "Iterations to tolerance",
            ylog=False)

    if not pareto:
        return
    fig, ax = _axes()
    shown = {}
    for name, pts in pareto.items():
        shown[name] = [p for p in pts if p and np.isfinite(p["residual"]) and p["residual"] > 0]
    floor = axis_floor({n: [p["residual"] for p in pts] for n, pts in shown.items()}, oracles)
    for name, pts in shown.items():
        kw = dict(style.get(name, {}), markersize=4)
        values = [p["residual"] for p in pts]
        ax.plot([p["ms"] for p in pts], values, label=_label(name, oracles, floor, values), **kw)
    _finish(fig, ax, out / "pareto", "measured time per step, prediction + a fixed number of sweeps (ms, median)",
            "residual reached (median)", "What accuracy costs in time", floor=floor)


def _save(fig, stem):
    """PNG and SVG, the same bytes for the same figure (no date, fixed SVG ids): a report made
    with any -j is the same report."""
    import matplotlib
    import matplotlib.pyplot as plt
    fig.tight_layout()
    with matplotlib.rc_context({"svg.hashsalt": "deepcontact"}):
        output.write_bytes(f"{stem}.png", output.figure_bytes(fig, "png", dpi=110))
        output.write_bytes(f"{stem}.svg", output.figure_bytes(fig, "svg", dpi=110, metadata={"Date": None}))
    plt.close(fig)


def _loop_path_line(results):
    """How the project's rows were measured in the loop: each variant's start (and plug-in method)
    in a process of its own, the round trips subtracted, the path's own cost stated."""
    ours = [r for r in results if r.ours and getattr(r, "transport_ms", None) is not None and len(r.transport_ms)]
    if not ours:
        return ""
    transport = max(float(np.median(r.transport_ms)) for r in ours)
    path = max(getattr(r, "path_ms", 0.0) for r in ours)
    from ..contest.client import deadline_rule
    return (f"{_fenced_line()} Every step went through Python; the null contestant's round trip of the same "
            f"request (at most {transport:.3f} ms a step, median) was subtracted from every variant alike. Deadlines: "
            f"{deadline_rule()}. What that path costs over the project's native loop (one call a step), "
            f"{path:.3f} ms a step (builtin both ways, median), is in every row of the project's solver, alike; "
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
            f"Stopping: {stop_on} < {tolerance:g}, at most {settings.max_iterations} sweeps, {settings.mode}. Drift: "
            f"largest distance of any surviving body from the trajectory stepped with reference solutions "
            f"(float64 PGS to 1e-12); energy error: largest |E - E_ref| over the steps, relative to "
            f"|E_ref| at the first step (E: kinetic plus gravitational energy of the dynamic bodies). "
            f"`@w`: over-relaxed PGS; `+nncg`: with conjugate directions. `box2d k iterations`: Box2D's own "
            f"solver. A pile is chaotic: a difference in the last digits of one step's impulses changes which "
            f"contacts form next, so every trajectory drifts from the reference, even one stepped by a converged "
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
    output.write_text(out / "closed-loop.json", json.dumps({"protocol": measured, "results": [{
        "start": r.start, "steps": r.steps, "iterations": r.iterations.tolist(),
        "ms_per_step": r.ms_per_step.tolist(), "drift": r.drift.tolist(), "penetration": r.penetration,
        "energy_error": r.energy_error, "finite": r.finite,
        "transport_ms": None if getattr(r, "transport_ms", None) is None else r.transport_ms.tolist(),
        "path_ms": getattr(r, "path_ms", 0.0)} for r in results]}) + "\n")
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
                    float(np.median(r.ms_per_step)), float(np.median(r.predict_ms)) if len(r.predict_ms) else 0.0,
                    float(r.drift[-1]) if len(r.drift) else "", float(r.drift.max()) if len(r.drift) else "",
                    r.energy_error, r.penetration, r.finite])
    output.write_text(out / "summary.csv", buf.getvalue())


def _loop_residuals(r):
    """The residuals of a loop row's steps that had contacts (none for Box2D's own solver)."""
    res = np.asarray(r.residuals if r.residuals is not None else [], np.float64)
    return res[np.isfinite(res)]


def _loop_above(r, tolerance):
    """The share of a row's steps whose residual ended above the tolerance (None: not judged)."""
    res = _loop_residuals(r)
    return None if tolerance is None or not len(res) else float(np.mean(res > tolerance))


def loop_verdict(results, tolerance):
    """The closed loop's verdict, by the contest's one rule (contest/verdict.py, as replay's): the
    fastest of the project's variants per step that stayed finite and never ended a step above the
    tolerance (oracles left out), against Box2D's warm start and the runner-up with 95% intervals
    over the steps, builtin timed against itself (A/A), and the run's totals (setup included); a
    winner is named only beyond noise, and none whose whole run cost more. None without Box2D's
    warm start."""
    from ..contest.verdict import decide
    base = next((r for r in results if r.ms_again is not None), None)
    if base is None:
        return None
    candidates = [r for r in results if r.ours and not r.oracle]
    fair = [r for r in candidates if r.finite]
    left = [r.start for r in candidates if r not in fair]
    left_out = (f" Left out, as they stopped being finite: {', '.join(md_text(n) for n in left)}." if left else "") \
        + _unfinished_note({r.start: _loop_above(r, tolerance) or 0 for r in fair})
    if not fair:
        return "**Verdict**: no start stayed finite on every step of the loop, so none is named." + left_out
    ours = [r for r in results if r.ours]
    times = {r.start: dict(enumerate(np.asarray(r.ms_per_step, np.float64))) for r in ours}
    unfinished = {r.start: set(np.flatnonzero(np.nan_to_num(np.asarray(r.residuals, np.float64), nan=0.0) > tolerance)
                               .tolist()) if tolerance is not None and r.residuals is not None else set() for r in ours}
    v = decide(times, [r.start for r in fair], base.start, (base.ms_per_step, base.ms_again),
               {r.start: r.setup_ms for r in ours}, unfinished)
    parts = ([f"{_interval(v.vs_base[v.best])} of {md_text(base.start)}'s time per step"] if v.best != base.start else []) \
        + ([f"{_interval(v.best_vs_runner_up)} of the runner-up {md_text(v.runner_up)}'s"] if v.runner_up else []) \
        + [f"A/A noise floor {_interval(v.aa)}"]
    if v.too_few_steps:
        return (f"**Verdict**: no clear winner: {count(v.steps, 'step')} to judge on, and a winner is named from at "
                f"least {MIN_STEPS}." + left_out + _fence_caveat())
    if v.gave_up_more:
        head = (f"**Verdict**: no clear winner. {md_text(v.best)} has the smallest median time per step of the loop, "
                f"but it left more steps above the tolerance than {md_text(base.start)} ({v.unfinished[v.best]} "
                f"against {v.unfinished[base.start]}): faster by not finishing is not faster")
    elif v.heavy_tail:
        head = (f"**Verdict**: no clear winner. {md_text(v.best)} has the smallest median time per step of the loop, "
                f"but over the whole run, setup included, it took longer than "
                + " and ".join(f"{md_text(n)} ({v.totals[v.best]:.4g} ms against {v.totals[n]:.4g} ms)"
                               for n in v.beaten_on_total_by) + ": a heavy tail of slow steps")
    elif v.clear:
        head = ("**Verdict**: the fastest start per step of the loop (prediction included; oracles left out) is "
                f"**{md_text(v.best)}**")
    else:
        head = (f"**Verdict**: no clear winner within noise. {md_text(v.best)} has the smallest median time per step "
                f"of the loop")
    return f"{head} ({'; '.join(parts)}; 95% intervals over the steps)." + left_out + _fence_caveat()


def loop_table(results, tolerance=None):
    """One row per start (and w) and per Box2D iteration count, with the project's residual of
    each (median / p95) and the share of steps above the tolerance where it is judged."""
    lines = ["| start | steps | median iterations | p80 | max | residual (median / p95) | above tolerance | "
             "ms per step (median) | of which prediction | "
             "final drift (m) | max drift (m) | energy error | deepest contact (cm) | finite |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in results:
        it = r.iterations[r.iterations > 0] if np.any(r.iterations > 0) else r.iterations
        pred = float(np.median(r.predict_ms)) if len(r.predict_ms) else 0.0
        res = _loop_residuals(r)
        above = _loop_above(r, tolerance)
        judged = (f"{np.median(res):.2g} / {np.percentile(res, 95):.2g}" if len(res) else "-",
                  "-" if above is None else _share(above))
        marks = (" (oracle)" if r.oracle else "") + (" (did not converge)" if above else "")
        lines.append(f"| {md_text(r.start)}{marks} | {r.steps} | {np.median(it):.0f} | {np.percentile(it, 80):.0f} | "
                     f"{it.max():.0f} | {judged[0]} | {judged[1]} | "
                     f"{np.median(r.ms_per_step):.3f} | {pred:.2f} | {r.drift[-1] if len(r.drift) else float('nan'):.3g} | "
                     f"{r.drift.max() if len(r.drift) else float('nan'):.3g} | {r.energy_error:.2g} | "
                     f"{100 * r.penetration:.2f} | {'yes' if r.finite else 'NO'} |")
    return "\n".join(lines)


def loop_plot(results, stem):
    """What accuracy costs in time in the loop: the largest drift from the reference trajectory
    against the median measured time per step; Box2D's iteration counts joined by a line."""
    fig, ax = _axes()
    box2d = [r for r in results if r.start.startswith("box2d ")]
    ours = [r for r in results if not r.start.startswith("box2d ")]
    if box2d:
        ax.plot([np.median(r.ms_per_step) for r in box2d], [r.drift.max() for r in box2d], "k-o", ms=3,
                label="Box2D, 1 ... 256 iterations")
        for r in box2d:
            ax.annotate(str(int(r.iterations[0])), (np.median(r.ms_per_step), r.drift.max()), fontsize=7)
    style = styles([r.start for r in ours], oracles_among([r.start for r in ours]))
    for r in ours:
        kw = dict(style[r.start], linestyle="none", markersize=6)
        ax.plot([np.median(r.ms_per_step)], [r.drift.max()], label=plot_text(r.start), **kw)
    _finish(fig, ax, stem, "measured time per step (ms, median)", "largest drift from the reference trajectory (m)",
            "What accuracy costs in time, in the loop")
