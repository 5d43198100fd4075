"""What the studies' tables and accuracy-against-time plots share: number cells, file-name slugs,
a CSV of dataclass rows, and the plot of families of settings (engines, frontier)."""
import io
import math
import re
from dataclasses import dataclass, fields
from pathlib import Path

from deepcontact import output
from deepcontact.escape import CsvWriter


@dataclass
class SettingRow:
    """What every accuracy-against-time study says of one setting on one scene (its own rows add
    their measures after these)."""
    scene: str
    family: str
    setting: str
    passed: bool         # met the scene's criteria (studies/stability.py)
    finite: bool
    ms_per_step: float   # mean over a run stepped without recording


def short_of_tolerance(row):
    """Whether a setting with a tolerance left steps above it, stopped by its cap (row.capped:
    the project's sweep cap, or an engine's own where it says so): such a setting is marked in
    the tables and never named the cheapest passing setting (it did not solve to its tolerance)."""
    return bool(getattr(row, "capped", None))


def setting_cell(row):
    """A row's setting as the tables show it, marked where its cap stopped steps above its tolerance."""
    if not short_of_tolerance(row):
        return row.setting
    return f"{row.setting} (cap hit on {row.capped:,} step{'s' if row.capped != 1 else ''}: not at its tolerance)"


def fmt(v, scale=1.0, digits=3):
    """A table cell: v * scale to `digits` significant digits; "" for None or nan, "inf"."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return f"{v * scale:.{digits}g}"


def slug(scene):
    """A scene's label as a file-name part: "pile 1000" -> "pile-1000"."""
    return re.sub(r"[^a-z0-9]+", "-", scene.lower()).strip("-")


def csv_text(rows, row_type):
    """The rows (dataclasses of row_type) as CSV text, a column per field."""
    out = io.StringIO()
    w = CsvWriter(out, lineterminator="\n")
    names = [f.name for f in fields(row_type)]
    w.writerow(names)
    for r in rows:
        w.writerow([getattr(r, n) for n in names])
    return out.getvalue()


def accuracy_plot(families, points, path, ylabel, title):
    """Time per step against a measure of accuracy, one line per family (log-log), a labelled
    marker per setting, hollow where the setting fails the criteria. points: {family: [(ms per
    step, accuracy, passed, label, ablation)]}, each family's in its sweep's order; an ablation is
    a star off the line."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from deepcontact.plotstyle import readable_log_ticks, styles
    style = styles(list(families))
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    plotted = False
    for family in families:
        mine = [p for p in points.get(family, []) if math.isfinite(p[0]) and math.isfinite(p[1]) and p[1] > 0]
        if not mine:
            continue
        s = style[family]
        sweep = [p for p in mine if not p[4]]
        ax.plot([p[0] for p in sweep], [p[1] for p in sweep], color=s["color"], linestyle=s["linestyle"],
                linewidth=s["linewidth"], label=family)
        for x, y, passed, label, ablation in mine:
            ax.plot(x, y, marker="*" if ablation else s["marker"], color=s["color"], markersize=8 if ablation else 6,
                    markerfacecolor=s["color"] if passed else "white", linestyle="none")
            ax.annotate(label, (x, y), textcoords="offset points", xytext=(4, 3), fontsize=6, color=s["color"])
        plotted = True
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per step (ms, one thread)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=8)
    if plotted:
        ax.legend(fontsize=8)
        readable_log_ticks(ax.xaxis)
        readable_log_ticks(ax.yaxis)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    output.write_bytes(path, output.figure_bytes(fig, Path(path).suffix[1:], dpi=110))
    plt.close(fig)


def markdown_table(columns, rows, left=3):
    """A markdown table: columns, a (title, cell function) each (the first `left` left-aligned
    text, the rest right-aligned numbers); a line per row."""
    lines = ["| " + " | ".join(title for title, _ in columns) + " |",
             "|" + "|".join(" --- " if i < left else " ---: " for i in range(len(columns))) + "|"]
    lines += ["| " + " | ".join(str(cell(r)) for _, cell in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"
