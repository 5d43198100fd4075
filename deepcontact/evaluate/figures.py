"""The thesis's convergence figures, regenerated with the SPH start:

  5.4  h in {0.1, 0.2, 0.25, 0.5} at d = 0.25 (Poly6)
  5.5  d in {0.25, 0.5, 1.0} at h = d (Poly6)
  5.6  Poly6 against Spiky at d = h = 0.5
  5.7  all starts (zero, builtin, copy, sph) at d = h = 0.5

Each is the median (and 10-90% band) of the stopping measure per PGS sweep over the run's steps.

    python -m deepcontact.evaluate.figures RUN -o OUTDIR [--every 10] [--tolerance 1e-4] [--stop-on thesis]
"""
import argparse
import sys
from pathlib import Path

import numpy as np

from .. import atomic
from ..grid.dataset import collect
from ..grid.spec import GridSpec
from .replay import evaluate, summarize
from .report import summary_table
from .starts import SPH, make_starts

FIGURES = {
    "fig-5.4": [(f"h={h:g}", "poly6", 0.25, h) for h in (0.1, 0.2, 0.25, 0.5)],
    "fig-5.5": [(f"d=h={d:g}", "poly6", d, d) for d in (0.25, 0.5, 1.0)],
    "fig-5.6": [(k, k, 0.5, 0.5) for k in ("poly6", "spiky")],
}


def plot_curves(rows, names, path, title, tolerance, stop_on):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, name in enumerate(names):
        hs = [r.history for r in rows if r.start == name]
        n = max(len(h) for h in hs)
        m = np.array([np.concatenate([h, np.full(n - len(h), h[-1])]) for h in hs])
        x = np.arange(1, n)
        ax.plot(x, np.median(m, axis=0)[1:], color=f"C{i}", label=name)
        ax.fill_between(x, np.percentile(m, 10, axis=0)[1:], np.percentile(m, 90, axis=0)[1:], color=f"C{i}", alpha=0.12)
    ax.axhline(tolerance, color="k", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("PGS sweep")
    ax.set_ylabel(f"{stop_on} measure (median, 10-90%)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    for ext in ("png", "svg"):
        fig.savefig(f"{path}.{ext}", dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--tolerance", type=float, default=1e-4)
    ap.add_argument("--stop-on", default="thesis")
    ap.add_argument("--max-iterations", type=int, default=1000)
    args = ap.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    sims, _ = collect([args.run])
    window = sims[0].box
    kw = dict(tolerance=args.tolerance, max_iterations=args.max_iterations, stop_on=args.stop_on, every=args.every)
    text = []
    for fig, settings in FIGURES.items():
        starts = {label: SPH(GridSpec.over(window, d, h, kernel)) for label, kernel, d, h in settings}
        rows = evaluate([args.run], starts, **kw)
        plot_curves(rows, list(starts), out / fig, f"Thesis {fig[4:]}: the SPH start", args.tolerance, args.stop_on)
        text += [f"## {fig}\n", summary_table(summarize(rows, starts, args.max_iterations)), ""]
    starts = make_starts(["zero", "builtin", "copy", "sph"], spec=GridSpec.over(window, 0.5, 0.5))
    rows = evaluate([args.run], starts, **kw)
    plot_curves(rows, list(starts), out / "fig-5.7", "Thesis 5.7: all starts", args.tolerance, args.stop_on)
    text += ["## fig-5.7\n", summary_table(summarize(rows, starts, args.max_iterations)), ""]
    atomic.write_text(out / "figures.md", "\n".join(text) + "\n")
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
