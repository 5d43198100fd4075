"""dc rasterize: step files → grid datasets (SPH), and what the grid costs in accuracy."""
import click

from deepcontact.grid.kernels import KERNELS
from deepcontact.grid.splat import ALL_CHANNELS

from . import options, terminal, types

CHANNELS = types.CommaList(click.Choice(ALL_CHANNELS))


@click.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(file_okay=False))
@click.option("-o", "--output", "out", type=click.Path(), help="Dataset folder.")
@click.option("--kernel", type=types.choice(KERNELS), default="poly6",
              show_default=True, help="SPH kernel (2D-normalised).")
@click.option("--cell", type=types.Finite(min=0, min_open=True), default=0.5, show_default=True, help="Cell size d (node spacing).")
@click.option("--smoothing", type=types.Finite(min=0, min_open=True), default=0.5, show_default=True, help="Smoothing length h (support).")
@click.option("--renormalize/--no-renormalize", default=True, show_default=True,
              help="Scale each particle's weights to sum to 1 over its nodes (grids hold amounts).")
@click.option("--inputs", type=CHANNELS, help="Input channels, comma-separated (default mass,vx,vy,spin,nx,ny).")
@click.option("--labels", type=CHANNELS, help="Label channels (default normal_impulse,tangent_impulse).")
@click.option("--window", type=types.Window(),
              help="Grid window (default: the scenes' static box, or where the bodies went over the run).")
@click.option("--include-contactless", is_flag=True, help="Keep steps without contacts.")
@click.option("--validation", type=click.FloatRange(0, 1, max_open=True), default=0.2, show_default=True,
              help="Share of simulations held out for validation.")
@click.option("--seed", type=types.count(), default=0, show_default=True, help="Seed of the split.")
@options.jobs
@options.max_memory
@options.overwrite
@options.verbosity
@options.command("rasterize")
def rasterize(runs, out, kernel, cell, smoothing, renormalize, inputs, labels, window, include_contactless,
              validation, seed, jobs, max_memory, overwrite, verbose, quiet):
    """Turn the step files of RUNS into SPH grid images for training.

    Inputs (N, C_in, H, W) and labels (N, C_out, H, W) float32 are written as
    memory-mappable .npy files with metadata.json (see docs/formats.md);
    train and validation are split by simulation. The grid's nodes span the
    scenes' box at spacing d (61 x 61 for the thesis's 30 x 30 box at d = 0.5).

    \b
    Examples:
      dc rasterize runs/thesis -o data/thesis
      dc rasterize runs/a runs/b -o data/ab --kernel spiky --cell 0.25 --smoothing 0.25 -j 2
      dc rasterize runs/pile --inputs mass,vx,vy,spin,nx,ny --labels normal_impulse -o data/normal
    """
    from deepcontact.grid.dataset import DatasetSettings, write_dataset

    options.check_grid_options(kernel, cell, smoothing)
    win = window
    if not out:
        raise click.UsageError("missing -o/--output DATASET")
    bars = []

    def bar(total):
        bars.append(terminal.progress_bar(quiet, total, "step", "rasterize"))
        return bars[-1]
    try:
        settings = DatasetSettings(cell=cell, h=smoothing, kernel=kernel, renormalize=renormalize, inputs=inputs,
                                   labels=labels, window=win, include_contactless=include_contactless,
                                   validation_fraction=validation, seed=seed)
        meta = write_dataset(runs, out, settings, jobs=jobs, overwrite=overwrite, progress=bar, max_memory=max_memory)
    finally:
        for b in bars:
            b.close()
    g = meta["grid"]
    if not quiet and terminal.stdout_is_open():
        from deepcontact.grid.spec import GridSpec
        grid = GridSpec.from_dict(g)
        click.echo(f"{out}: {meta['samples']} samples, {g['nx']} x {g['ny']} grid over {g['x0']:g},{g['y0']:g},"
                   f"{grid.x1:g},{grid.y1:g} ({meta['window']}), inputs {','.join(meta['inputs'])}, "
                   f"labels {','.join(meta['labels'])}; {len(meta['split']['train'])} training and "
                   f"{len(meta['split']['validation'])} validation simulations", err=True)
