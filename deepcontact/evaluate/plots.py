"""A report's plots: convergence, iterations to tolerance, what accuracy costs in time, and the
closed loop's drift against time. Every variant keeps one style (colour, line, marker) in every
plot of a report; oracles are dashed and kept off the main scale (deepcontact/plotstyle.py)."""
import warnings

import numpy as np

from .. import output
from ..escape import plot_text
from ..plotstyle import axis_floor, readable_log_ticks, show_bands, styles, with_markers
from .verdicts import oracle


def _axes():
    """A new figure and its axes, drawn off-screen."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt.subplots(figsize=(7, 4.5))


def _any_positive(ax, axis):
    """Whether any line on ax has a positive value on that axis (a log axis can show it)."""
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
    return {n for n in names if oracle(n)}


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
    """The replay report's plots into the folder out: convergence, iterations and (where the
    budgets ran) pareto, each PNG and SVG."""
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
