"""How the project's plots draw: one style per variant, the same in every plot of a report, and
log axes a reader can read.

A style is a colour, a line style and a marker. Colours come from a 10-colour palette that stays
apart for colour-blind readers (matplotlib's tab10); line styles cycle through 4 and markers
through 7, so no two of the first 140 variants share all three (tested). Oracles (starts that know the
answer) are drawn thin, dashed and grey-toned, and kept off the main scale (axis_floor).
"""
import numpy as np

PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
           "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f")
LINES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "D", "v", "P", "X")
BAND_LIMIT = 4   # variants: more 10-90% bands than this merge into one smear


def styles(names, oracles=()) -> dict:
    """{name: matplotlib keyword arguments} for plot lines, in the order given; oracles dashed."""
    out = {}
    fair = [n for n in names if n not in oracles]
    for i, name in enumerate(fair):
        out[name] = dict(color=PALETTE[i % len(PALETTE)], linestyle=LINES[(i + i // len(PALETTE)) % len(LINES)],
                         marker=MARKERS[i % len(MARKERS)], linewidth=1.6)
    for j, name in enumerate(n for n in names if n in oracles):
        out[name] = dict(color=("#555555", "#999999", "#333333")[j % 3], linestyle=(0, (4, 2 + j)),
                         marker=None, linewidth=1.0)
    return out


def with_markers(style, points, every=None):
    """The style for a line of `points` values: markers thinned to about 8 along a long line."""
    s = dict(style)
    if s.get("marker") is not None and points > 8:
        s["markevery"] = every or max(1, points // 8)
    s["markersize"] = 4
    return s


def show_bands(names, asked=None) -> bool:
    """Whether to draw 10-90% bands: when asked, else only for a few variants."""
    return bool(asked) if asked is not None else len(names) <= BAND_LIMIT


def axis_floor(values_by_name, oracles):
    """The lower limit of a log axis that keeps the non-oracle values in view (an oracle's 1e-15
    would squeeze them into the top of the plot); None when no oracle reaches below them."""
    fair = [v for n, v in values_by_name.items() if n not in oracles]
    fair = np.concatenate([np.asarray(v, float).ravel() for v in fair]) if fair else np.zeros(0)
    fair = fair[np.isfinite(fair) & (fair > 0)]
    if not len(fair):
        return None
    low = float(fair.min())
    def lowest(v):   # an oracle's smallest positive value (an oracle without one reaches nothing)
        v = np.asarray(v, float).ravel()
        v = v[np.isfinite(v) & (v > 0)]
        return v.min() if len(v) else np.inf
    below = [n for n, v in values_by_name.items() if n in oracles and lowest(v) < low / 10]
    return low / 3 if below else None


def readable_log_ticks(axis):
    """Tick labels a reader can read on a log axis: plain numbers ("2", "0.05", "1e-06"); the
    ticks between the powers of ten labelled where the axis spans few decades (all of them under
    one decade, 2 and 5 under three), so that every axis has at least two labels."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    low, high = sorted(axis.get_view_interval())
    decades = np.log10(high / low) if low > 0 else np.inf
    shown = set(range(2, 10)) if decades < 1 else {2, 5} if decades < 3 else set()

    def plain(value, _):
        return f"{value:g}"

    def between(value, _):
        mantissa = round(value / 10 ** np.floor(np.log10(value) + 1e-9))
        return f"{value:g}" if mantissa in shown else ""

    axis.set_major_locator(LogLocator(base=10))
    axis.set_major_formatter(FuncFormatter(plain))
    axis.set_minor_locator(LogLocator(base=10, subs=np.arange(2, 10)))
    axis.set_minor_formatter(FuncFormatter(between) if shown else NullFormatter())
