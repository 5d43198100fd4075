"""The thesis's convergence figures, regenerated with the SPH start:

  5.4  h in {0.1, 0.2, 0.25, 0.5} at d = 0.25 (Poly6)
  5.5  d in {0.25, 0.5, 1.0} at h = d (Poly6)
  5.6  Poly6 against Spiky at d = h = 0.5
  5.7  all starts (zero, builtin, copy, sph) at d = h = 0.5

Each is the median (and 10-90% band) of the stopping measure per PGS sweep over the run's steps.

    dc study figures RUN -o OUTDIR [--every 10] [--tolerance 1e-4] [--stop-on residual] [-j 2]
"""
from deepcontact import output, workers
from deepcontact.grid.sources import collect
from deepcontact.grid.spec import GridSpec
from deepcontact.protocol import protocol, protocol_line
from deepcontact.solver.settings import SolveSettings
from deepcontact.evaluate.replay import evaluate
from deepcontact.evaluate.summary import summarize
from deepcontact.evaluate.plots import convergence_plot
from deepcontact.evaluate.report import summary_table
from deepcontact.warmstart.starts import SPH, make_starts

FIGURES = {
    "fig-5.4": [(f"h={h:g}", "poly6", 0.25, h) for h in (0.1, 0.2, 0.25, 0.5)],
    "fig-5.5": [(f"d=h={d:g}", "poly6", d, d) for d in (0.25, 0.5, 1.0)],
    "fig-5.6": [(k, k, 0.5, 0.5) for k in ("poly6", "spiky")],
}


# Everything a figures folder holds: what --overwrite may replace.
FIGURE_FILES = output.Owned("figures folder", [r"figures\.md", r"fig-5\.[4-7]\.(png|svg)"])


def figures(run, out, every=10, settings=SolveSettings(), jobs=1, progress=None):
    """Figures 5.4-5.7 of the run into the folder out, each step solved as `settings` asks;
    returns the markdown text. jobs > 1: the
    four figures' replays side by side in worker processes (the same figures: sweeps do not
    depend on -j; the tables' times are each worker's own). progress(n): n more step files."""
    from deepcontact.errors import InputError
    sims, _ = collect([run])
    window = sims[0].box
    if window is None:
        raise InputError("the thesis's figures need a scene with a static box (the pile)", run)
    kw = dict(settings=settings, every=every)
    measured = protocol(jobs=jobs)
    names = [*FIGURES, "fig-5.7"]
    tasks = [(run, name, tuple(window), kw) for name in names]
    text = []
    with workers.for_jobs(jobs, tasks, progress) as pool:
        for name, (starts, rows) in zip(names, pool.imap(_figure_rows, tasks)):
            title = "Thesis 5.7: all starts" if name == "fig-5.7" else f"Thesis {name[4:]}: the SPH start"
            convergence_plot(rows, starts, out / name, title, settings.tolerance, settings.stop_on)
            text += [f"## {name}\n", summary_table(summarize(rows, starts, settings.max_iterations)), ""]
    text += [protocol_line(measured), ""]
    output.write_text(out / "figures.md", "\n".join(text) + "\n")
    return "\n".join(text)


def step_files(run):
    """How many step files the figures read (their progress bar's total): each figure reads the run once."""
    from deepcontact.step.run_folder import read_run
    return (len(FIGURES) + 1) * sum(len(s.files) for s in read_run(run).simulations)


def _figure_rows(task):
    """One figure's replay: (its start names, its rows); the starts are made here, in the worker."""
    run, name, window, kw = task
    if name == "fig-5.7":
        starts = make_starts(["zero", "builtin", "copy", "sph"], spec=GridSpec.over(window, 0.5, 0.5))
    else:
        starts = {label: SPH(GridSpec.over(window, d, h, kernel)) for label, kernel, d, h in FIGURES[name]}
    return list(starts), evaluate([run], starts, **kw)
