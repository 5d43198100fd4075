"""dc evaluate: every warm start compared on the recorded steps, with reports."""
import click

from deepcontact.grid.kernels import KERNELS
from deepcontact.solver.methods import BUILTIN as BUILTIN_SOLVERS, SOLVERS, methods_help
from deepcontact.solver.pgs import MODES, ORDERS
from deepcontact.warmstart.starts import NAMES as START_NAMES, STARTS

from . import options, terminal, types


@click.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False), help="Report folder.")
@click.option("--starts", type=types.CommaList(types.PluginName(STARTS), "START[,...]"),
              default="zero,builtin,copy,sph", show_default=True,
              help=f"Comma-separated: {', '.join(START_NAMES)}, an installed plug-in's name, or "
                   f"package.module:Name (docs/api.md).")
@options.checkpoint("A checkpoint from dc train (the starts cnn, guarded, cnn-new).",
                    "Load this network plug-in for a checkpoint that needs it (a checkpoint never imports code).")
@options.solve_to_tolerance
@click.option("--mode", type=types.choice(MODES, leave_out=("exact",)), default="float64", show_default=True)
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True, help="Use every N-th step.")
@click.option("--cell", type=types.Finite(min=0, min_open=True), default=0.5, show_default=True, help="[sph without --checkpoint] Cell size d.")
@click.option("--smoothing", type=types.Finite(min=0, min_open=True), default=0.5, show_default=True, help="[sph without --checkpoint] h.")
@click.option("--kernel", type=types.choice(KERNELS), default="poly6",
              show_default=True, help="[sph without --checkpoint] SPH kernel.")
@click.option("--seed", type=types.count(), default=0, show_default=True, help="Seed of the random start.")
@click.option("--closed-loop", is_flag=True,
              help="Let each start drive the simulation (the run's scene, from its first state) instead of "
                   "replaying the recorded steps.")
@click.option("--steps", type=types.count(min=1), help="[--closed-loop] Steps to simulate (default: the scene's).")
@click.option("--relaxation", "relaxation", type=types.CommaList(types.Relaxation(), "W[,W...]"), default="1",
              show_default=True,
              help="Over-relaxation (PSOR) w in (0, 2) for every start, or auto (the w with the fewest sweeps on "
                   "the first 8 hard steps); several, comma-separated, compare them.")
@click.option("--accelerate", type=types.CommaList(types.PluginName(SOLVERS, extra=("all",)), "METHOD[,...]|all"),
              default="none", show_default=True,
              help=f"The solver method: {methods_help()}. Several, comma-separated, or all (every built-in), "
                   f"compare them (each with every w).")
@click.option("--order", type=types.choice(ORDERS), default="island", show_default=True,
              help="The order every built-in method's sweep visits the contacts in: island (Box2D's) or gravity "
                   "(from the highest to the lowest along gravity; docs/solver.md, \"Sweep order\"). Not with a "
                   "plug-in method, which sweeps in its own.")
@click.option("--budgets/--no-budgets", default=True, show_default=True,
              help="What accuracy costs in time, measured: solve every step with exactly 1, 2, 4, ... 1024 sweeps "
                   "and time each; with --closed-loop, also Box2D's own solver at 1, 2, 4, ... 256 iterations.")
@click.option("--bands/--no-bands", default=None,
              help="Draw the 10-90% band of every variant in convergence.png (default: only for up to 4 variants).")
@options.plots("Draw the report's pictures (PNG and SVG); --no-plots writes its tables alone (on a small run, "
               "a tenth of the time: docs/results/).")
@options.jobs
@options.threads
@options.max_memory
@options.overwrite
@options.verbosity
@options.unfenced
@options.command("evaluate")
def evaluate(runs, out, starts, model, arch, tolerance, max_iterations, stop_on, mode, every, cell, smoothing, kernel,
             seed, closed_loop, steps, relaxation, accelerate, order, budgets, bands, plots, jobs, threads,
             max_memory, overwrite, verbose, quiet):
    """Solve every recorded step of RUNS from every start and compare.

    Each step's reference solution (float64 from zero to a residual of 1e-12:
    PGS sweeps, Newton steps and, where Newton stalls, Lemke's pivoting; where
    it stops short the report says so) is
    the oracle "copy" and the ground truth for errors, in impulses and in body
    velocities after the solve (exact solutions of a frictional step need not
    agree in either: the residual is the honest measure). Per step and start: sweeps
    to tolerance, the convergence history, the final error, and time split
    into prediction and solving. OUTPUT gets report.md, summary.csv/json,
    steps.csv, pareto.json and convergence, iterations and pareto plots
    (PNG and SVG). With -j, simulations are replayed side by side in worker
    processes (the same rows; each solve is still timed on its own core).

    \b
    Examples:
      dc evaluate runs/pile -o reports/starts
      dc evaluate runs/pile --starts zero,builtin,copy,copy2,copy0,sph,random,bad -o reports/all
      dc evaluate runs/val --starts zero,builtin,copy,sph,cnn,guarded,cnn-new --checkpoint models/fcn/best.pt -o r/cnn
      dc evaluate runs/pile --tolerance 1e-4 --stop-on thesis --max-iterations 5000 --every 10 -o r/thesis
      dc evaluate runs/pile --closed-loop --starts zero,builtin,copy,bad --steps 200 -o r/loop
      dc evaluate runs/pile --starts builtin,prev --relaxation 1,1.5,1.7,auto --every 5 -o r/psor
      dc evaluate runs/pile --starts builtin --accelerate none,nncg --relaxation 1,1.3 --closed-loop -o r/nncg
      dc evaluate runs/pile --starts builtin,prev --order gravity --closed-loop -o r/down
      dc evaluate runs/pile --starts builtin,prev --accelerate all --tolerance 1e-4 --every 5 -o r/global
      dc evaluate runs/heldout --starts zero,builtin,prev -j 2 -o r/fast
      dc evaluate runs/pile --starts builtin,prev --no-plots --no-budgets -o r/tables
    """
    if "all" in accelerate:
        accelerate = list(dict.fromkeys([a for a in accelerate if a != "all"] + list(BUILTIN_SOLVERS)))
    # the plug-ins, described from a process of their own: the judge never runs their code
    from deepcontact.contest import describe
    describe(starts, accelerate)
    _refuse_inapplicable(starts, model, closed_loop, plots)
    if arch is not None:   # (the user's explicit choice; its code is loaded in the contestants' sandboxes only)
        from deepcontact.model.arch import NETWORKS
        NETWORKS.choose(arch)

    from deepcontact.evaluate.command import EvaluateSettings, history_bytes
    from deepcontact.solver.settings import SolveSettings
    settings = EvaluateSettings(
        runs=list(runs), starts=list(starts), checkpoint=model,
        solve=SolveSettings(mode=mode, max_iterations=max_iterations, tolerance=tolerance, stop_on=stop_on,
                            order=order),
        every=every, cell=cell, smoothing=smoothing, kernel=kernel, seed=seed,
        closed_loop=closed_loop, steps=steps, relaxations=tuple(relaxation), accelerations=tuple(accelerate),
        budgets=budgets, bands=bands, plots=plots, jobs=jobs,
        threads=threads).checked()   # (the library's rules: exit 2)
    if not closed_loop:   # each solve keeps its convergence history, up to a value per sweep
        from deepcontact.resources import check_memory
        needed, what = history_bytes(settings)
        check_memory(needed, max_memory, what)
    table = _report(settings, out, overwrite, quiet)
    if terminal.stdout_is_open():   # (the table is report.md's: a closed stdout loses nothing)
        click.echo(table)


def _refuse_inapplicable(starts, model, closed_loop, plots):
    """The options that do not apply to the starts and the mode given, refused (exit 2)."""
    from deepcontact.warmstart.starts import trait
    learned = [n for n in starts if trait(n, "needs_model")]
    sph_grid = "sph" in starts and not model
    options.refuse_inapplicable([
        ("steps", closed_loop, "only applies with --closed-loop (replay solves the recorded steps)"),
        ("every", not closed_loop, "applies to replay; --closed-loop steps every step"),
        ("max_memory", not closed_loop, "applies to replay's convergence histories, not --closed-loop"),
        ("model", bool(learned), "only applies to the starts that use a model (cnn, guarded, cnn-new)"),
        ("arch", bool(model), "only applies with --checkpoint"),
        *((name, sph_grid, "only applies to the sph start without --checkpoint (a model brings its own grid)")
          for name in ("cell", "smoothing", "kernel")),
        ("seed", "random" in starts, "only applies to the random start"),
        ("bands", plots and not closed_loop, "applies to replay's convergence plot, which --closed-loop and "
                                             "--no-plots leave out"),
    ])


def _report(settings, out, overwrite, quiet):
    """The evaluation run into the report folder out (computed inside the output's lock; the
    report appears only when complete), with a progress bar per stage; its table."""
    from deepcontact import output
    from deepcontact.evaluate.command import run_evaluation
    from deepcontact.evaluate.report import REPORT_FILES
    bars = []

    def bar(total, unit):
        bars.append(terminal.progress_bar(quiet, total, unit, "closed loop" if settings.closed_loop else "evaluate"))
        return bars[-1].update
    with output.output_folder(out, REPORT_FILES, overwrite, command="evaluate") as work:
        try:
            return run_evaluation(settings, work, bar)
        finally:
            for b in bars:
                b.close()
