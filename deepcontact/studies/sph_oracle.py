"""The SPH oracle: what the grid alone costs in accuracy, and in time.

Take each step's exact impulses (the reference solution, or the recorded impulses), splat them
onto the grid, interpolate back at the contact points, and compare with what went in. A network
predicting grids can at best reproduce this round trip, so its error is a floor for any learned
start built on the grid. Renormalised grids hold amounts (impulses) per node; plain SPH grids
hold densities, so their values are multiplied by the node area d^2 on the way back.
"""
import time
from dataclasses import dataclass

import numpy as np

from .. import atomic
from ..grid.interpolate import bilinear
from ..grid.splat import splat_points
from ..solver.problem import StepProblem
from ..solver.reference import reference_solution

# Everything an SPH study folder holds: what --overwrite may replace.
STUDY_FILES = atomic.Owned("SPH study", [r"sph-study\.(md|csv|png|svg)"])


@dataclass
class RoundTrip:
    label: str
    kernel: str
    cell: float
    h: float
    renormalize: bool
    steps: int
    points: int
    normal_rel_l2: float
    normal_max: float
    tangent_rel_l2: float
    tangent_max: float
    ms_per_step: float
    outside: int


def steps_of(runs, cell, smoothing, kernel, renormalize=True, window=None, impulses="reference", every=10,
             log=None):
    """The grid these settings give over the runs, and the exact answers (exact_impulses) of every
    `every`-th step file with contacts; log(path) per file read."""
    from ..errors import InputError
    from ..grid.dataset import collect, grid_for
    sims, _ = collect(runs)
    spec, _ = grid_for(sims, cell, smoothing, kernel, renormalize, window)
    files = [f for s in sims for f in s.files][::every]
    steps = exact_impulses(files, impulses, log=log)
    if not steps:
        raise InputError("no steps with contacts to push through the grid")
    return spec, steps, len(files)


SOURCES = ("reference", "recorded")   # the exact answers pushed through the grid


def exact_impulses(step_files, source="reference", log=None):
    """[(positions, normal, tangent)] per step: the reference solution or the recorded impulses."""
    from ..step.reader import read_step_for_grid
    out = []
    for path in step_files:
        if source == "reference":
            problem = StepProblem.from_step_file(path)
            if problem.points == 0:
                continue
            sol = reference_solution(problem)
            _, _, contacts = read_step_for_grid(path)
            out.append((contacts["position"], sol.normal_impulse, sol.tangent_impulse, sol.residual))
        else:
            _, _, contacts = read_step_for_grid(path)
            if len(contacts["position"]) == 0:
                continue
            out.append((contacts["position"], contacts["normal_impulse"].astype(np.float64),
                        contacts["tangent_impulse"].astype(np.float64), 0.0))
        if log:
            log(len(out))
    return out


def round_trip(steps, spec, label=""):
    """Errors of impulses → grid → bilinear back, over steps [(positions, normal, tangent, _)]."""
    err_n, err_t, ref_n, ref_t = [], [], [], []
    outside = 0
    scale = spec.impulse_scale
    t0 = time.perf_counter()
    backs = []
    for pos, n, t, _ in steps:
        grid = splat_points(spec, pos, np.stack([n, t], axis=1))
        back, out = bilinear(grid, spec, pos)
        backs.append(back * scale)
        outside += out
    elapsed = time.perf_counter() - t0
    for (pos, n, t, _), back in zip(steps, backs):
        err_n.append(back[0] - n)
        err_t.append(back[1] - t)
        ref_n.append(n)
        ref_t.append(t)
    en, et = np.concatenate(err_n), np.concatenate(err_t)
    rn, rt = np.concatenate(ref_n), np.concatenate(ref_t)
    return RoundTrip(label=label, kernel=spec.kernel, cell=spec.cell, h=spec.h, renormalize=spec.renormalize,
                     steps=len(steps), points=len(rn),
                     normal_rel_l2=float(np.linalg.norm(en) / max(np.linalg.norm(rn), 1e-300)),
                     normal_max=float(np.abs(en).max()),
                     tangent_rel_l2=float(np.linalg.norm(et) / max(np.linalg.norm(rt), 1e-300)),
                     tangent_max=float(np.abs(et).max()),
                     ms_per_step=elapsed / max(len(steps), 1) * 1e3, outside=outside)


# The thesis's figures 5.4-5.6, and the two other kernels at its chosen setting.
STUDY = (
    [("fig 5.4: h at d = 0.25", "poly6", 0.25, h) for h in (0.1, 0.2, 0.25, 0.5)]
    + [("fig 5.5: d at h = d", "poly6", d, d) for d in (0.25, 0.5, 1.0)]
    + [("fig 5.6: kernel at d = h = 0.5", k, 0.5, 0.5) for k in ("poly6", "spiky", "cubic", "gaussian")]
)


def study(steps, window, renormalize=True, log=None):
    from ..grid.spec import GridSpec
    rows = []
    warm = GridSpec.over(window, STUDY[0][2], STUDY[0][3], STUDY[0][1], renormalize)
    round_trip(steps[:3], warm)        # first calls pay for loading and caches: not timed
    for label, kernel, d, h in STUDY:
        spec = GridSpec.over(window, d, h, kernel, renormalize)
        rows.append(round_trip(steps, spec, label))
        if log:
            log(rows[-1])
    return rows


TABLE_HEADER = ("| study | kernel | d | h | normal rel. L2 | normal max | tangent rel. L2 | tangent max | "
                "ms / step |\n| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")


def table_row(r: RoundTrip):
    return (f"| {r.label} | {r.kernel} | {r.cell:g} | {r.h:g} | {r.normal_rel_l2:.3f} | {r.normal_max:.3g} | "
            f"{r.tangent_rel_l2:.3f} | {r.tangent_max:.3g} | {r.ms_per_step:.3f} |")


def plot(rows, path_stem):
    """Error against time per step, one point per setting: PNG and SVG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5))
    seen = set()
    for r in rows:
        if (r.kernel, r.cell, r.h) in seen:      # the same setting appears in two studies
            continue
        seen.add((r.kernel, r.cell, r.h))
        ax.scatter(r.ms_per_step, r.normal_rel_l2, marker="o", color="C0")
        ax.scatter(r.ms_per_step, r.tangent_rel_l2, marker="s", color="C1")
        ax.annotate(f"{r.kernel} d={r.cell:g} h={r.h:g}", (r.ms_per_step, r.normal_rel_l2), fontsize=7,
                    xytext=(3, 3), textcoords="offset points")
    ax.scatter([], [], marker="o", color="C0", label="normal impulse")
    ax.scatter([], [], marker="s", color="C1", label="tangent impulse")
    ax.set_xlabel("splat + interpolate, ms per step")
    ax.set_ylabel("relative L2 error of the round trip")
    ax.set_title("SPH oracle: what grid accuracy costs")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    for ext in ("png", "svg"):
        atomic.write_bytes(f"{path_stem}.{ext}", atomic.figure_bytes(fig, ext, dpi=120))
    plt.close(fig)


def write_study(out, steps, rows, impulses, renormalize):
    """sph-study.md (the table), .csv and the plot into the folder out; returns the table."""
    import io
    from ..escape import CsvWriter
    table = TABLE_HEADER + "\n" + "\n".join(table_row(r) for r in rows) + "\n"
    buf = io.StringIO()
    w = CsvWriter(buf)
    w.writerow(list(RoundTrip.__dataclass_fields__))
    for r in rows:
        w.writerow(list(r.__dict__.values()))
    atomic.write_text(out / "sph-study.md", f"{len(steps)} steps, {sum(len(s[0]) for s in steps)} contact points, "
                      f"{impulses} impulses, renormalised: {renormalize}\n\n" + table)
    atomic.write_text(out / "sph-study.csv", buf.getvalue())
    plot(rows, str(out / "sph-study"))
    return table
