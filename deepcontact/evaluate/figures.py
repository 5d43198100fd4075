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

from .. import atomic
from ..grid.dataset import collect
from ..grid.spec import GridSpec
from .replay import evaluate, summarize
from .report import convergence_plot, summary_table
from .starts import SPH, make_starts

FIGURES = {
    "fig-5.4": [(f"h={h:g}", "poly6", 0.25, h) for h in (0.1, 0.2, 0.25, 0.5)],
    "fig-5.5": [(f"d=h={d:g}", "poly6", d, d) for d in (0.25, 0.5, 1.0)],
    "fig-5.6": [(k, k, 0.5, 0.5) for k in ("poly6", "spiky")],
}


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
        convergence_plot(rows, list(starts), out / fig, f"Thesis {fig[4:]}: the SPH start", args.tolerance,
                         args.stop_on)
        text += [f"## {fig}\n", summary_table(summarize(rows, starts, args.max_iterations)), ""]
    starts = make_starts(["zero", "builtin", "copy", "sph"], spec=GridSpec.over(window, 0.5, 0.5))
    rows = evaluate([args.run], starts, **kw)
    convergence_plot(rows, list(starts), out / "fig-5.7", "Thesis 5.7: all starts", args.tolerance, args.stop_on)
    text += ["## fig-5.7\n", summary_table(summarize(rows, starts, args.max_iterations)), ""]
    atomic.write_text(out / "figures.md", "\n".join(text) + "\n")
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
