"""dc study: the longer measurements (stability of the hard scenes, the thesis's figures, one map
or two)."""
import click

from . import options


@click.group()
def study():
    """Longer measurements built on the pipeline.

    \b
    stability  the hard scenes under Box2D's solver and ours: the iterations each needs
    figures    the thesis's convergence figures 5.4-5.7, regenerated with the SPH start
    maps       one network for both impulse maps, or one per map

    \b
    Examples:
      dc study stability --fast
      dc study stability -o runs/stability.md
      dc study figures runs/heldout -o reports/figures --every 10
      dc study maps data/thesis -o reports/maps --epochs 10
    """


@study.command()
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="Also write the table to this file.")
@click.option("--fast", is_flag=True, help="The small variants the test suite runs.")
@options.jobs
@options.overwrite
@options.verbosity
@options.command("study stability")
def stability(out, fast, jobs, overwrite, verbose, quiet):
    """Run every hard scene with Box2D's solver and ours until it meets its criteria.

    Criteria (deepcontact/studies/stability.py): finite, penetration at rest
    within 3 linear slops, no energy gained, a stack's top within 1 cm. Where
    a configuration fails at the scene's 8 iterations, the count is doubled
    until it passes; the table gives that count. Exit 1 if any configuration
    never passes.

    \b
    Examples:
      dc study stability --fast
      dc study stability -o runs/stability.md --overwrite -j 2
    """
    import os

    from deepcontact import atomic
    from deepcontact.errors import InputError
    from deepcontact.studies import stability as S

    from contextlib import nullcontext
    if out:   # checked (and locked) before the study, not after it
        atomic.check_replaceable(out)
    with atomic.locked(out) if out else nullcontext():
        if out and os.path.exists(out) and not overwrite:
            raise InputError("file exists; use --overwrite to replace it", out)
        from deepcontact.protocol import protocol, protocol_line
        measured = protocol(jobs=jobs)
        click.echo(S.HEADER)
        rows = S.study(S.FAST if fast else S.FULL, log=click.echo, jobs=jobs)
        if out:
            atomic.write_text(out, S.markdown(rows, fast, protocol_line(measured)))
    failed = sum(not f.passed for _, f in rows)
    if failed:
        raise InputError(f"{failed} of {len(rows)} configurations never met their criteria (see the table)")


@study.command()
@click.argument("run", metavar="RUN", type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False), help="Figures folder.")
@click.option("--every", type=options.count(min=1), default=10, show_default=True, help="Use every N-th step.")
@click.option("--tolerance", type=options.Finite(min=0, min_open=True), default=1e-4, show_default=True)
@click.option("--stop-on", type=click.Choice(["thesis", "velocity", "residual"]), default="residual", show_default=True,
              help="The stopping measure (residual, as everywhere; thesis: the thesis's largest change per sweep).")
@click.option("--max-iterations", type=options.count(min=1), default=1000, show_default=True)
@options.jobs
@options.overwrite
@options.verbosity
@options.command("study figures")
def figures(run, out, every, tolerance, stop_on, max_iterations, jobs, overwrite, verbose, quiet):
    """The thesis's figures 5.4-5.7 on RUN: h, d and the kernel of the SPH start, then every start.

    Writes fig-5.4 ... fig-5.7 (PNG and SVG) and figures.md with each
    figure's table.

    \b
    Examples:
      dc study figures runs/heldout -o reports/figures
      dc study figures runs/heldout -o reports/figures --stop-on thesis --every 5
      dc study figures runs/heldout -o reports/figures -j 2
    """
    from deepcontact import atomic
    from deepcontact.studies.figures import FIGURE_FILES, figures as make, step_files

    with atomic.output_folder(out, FIGURE_FILES, overwrite, command="study figures") as work:
        bar = options.progress_bar(quiet, step_files(run), "step", "study figures")
        try:
            text = make(run, work, every=every, tolerance=tolerance, stop_on=stop_on, max_iterations=max_iterations,
                        jobs=jobs, progress=bar.update)
        finally:
            bar.close()
        click.echo(text)


@study.command()
@click.argument("dataset", type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False), help="Comparison folder.")
@click.option("--epochs", type=options.count(min=1), default=10, show_default=True)
@click.option("--arch", "model", type=click.Choice(["thesis", "fcn"]), default="fcn", show_default=True,
              help="The network trained three times.")
@options.deprecated_alias("--model", "--arch", "model")
@click.option("--width", type=options.count(min=1, max=4096), default=16, show_default=True, help="[fcn] Channels.")
@click.option("--loss", type=click.Choice(["masked", "contacts", "mse", "solver"]), default="masked",
              show_default=True)
@click.option("--seed", type=options.count(), default=0, show_default=True)
@options.overwrite
@options.verbosity
@options.command("study maps")
def maps(dataset, out, epochs, model, width, loss, seed, overwrite, verbose, quiet):
    """One map or two: the same network trained on both impulse maps, and one per map.

    Trains three runs (joint, normal-only, tangent-only) into OUTPUT and
    compares them at the validation simulations' contact points
    (compare.md, compare.json).

    \b
    Examples:
      dc study maps data/thesis -o reports/maps --epochs 10
      dc study maps data/thesis -o reports/maps --arch thesis --loss contacts
    """
    from deepcontact import atomic
    from deepcontact.studies.maps import MAP_FILES, compare, write_comparison

    with atomic.output_folder(out, MAP_FILES, overwrite, command="study maps") as work:
        rows = compare(dataset, work, model=model, fcn_width=width, epochs=epochs, loss=loss, optimizer="adam",
                       lr=1e-3, batch_size=64, seed=seed)
        click.echo(write_comparison(work, rows))
