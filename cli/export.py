"""dc export: a run's step problems in FCLIB's HDF5 format, for other contact solvers, or the run
as flat tables (CSV, Parquet)."""
import click

from deepcontact.exchange.fclib import SOLUTIONS

from . import options, terminal, types


@click.command()
@click.argument("run_dir", metavar="RUN", type=click.Path())
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False),
              help="Folder to write (seed-NNNNNN/step-NNNNNN.hdf5 and index.json; or bodies and contacts tables).")
@click.option("--every", type=types.count(min=1), default=1, show_default=True,
              help="Export every N-th step (steps without contacts are skipped).")
@click.option("--format", "fmt", type=click.Choice(["fclib", "csv", "parquet"]), default="fclib", show_default=True,
              help="fclib: each step's contact problem (HDF5); csv or parquet: the run as two flat tables, "
                   "bodies and contacts, one row per body (contact point) per step (Parquet needs pyarrow).")
@click.option("--solution", type=types.choice(SOLUTIONS), default="reference",
              show_default=True,
              help="Store as /solution: the exact reference (Newton, residual < 1e-12 where it gets "
                   "there), what the run's solver produced, or nothing.")
@options.jobs
@options.overwrite
@options.verbosity
@options.command("export")
def export(run_dir, out, fmt, every, solution, jobs, overwrite, verbose, quiet):
    """Write each step's contact problem as an FCLIB local problem (2D).

    Each file holds W (the Delassus matrix J M^-1 J^T of the contact points
    the solver uses, per point its normal row then its tangent row), q, mu,
    the step's recorded start as a guess and, by default, the reference
    solution; index.json lists the files with the stored solution's residual.
    The layout is fclib.c's, so FCLIB readers (Siconos among them) take the
    files as they are. docs/formats.md describes it.

    \b
    Examples:
      dc export runs/pile -o runs/pile-fclib --every 10
      dc export runs/thesis -o runs/thesis-fclib -j 2
      dc export runs/pyramid -o runs/pyramid-fclib --solution recorded
      /usr/bin/python3 -c "import h5py; print(list(h5py.File('runs/pile-fclib/seed-000000/step-000010.hdf5')))"
      dc export runs/pile -o runs/pile-table --format csv
      python -c "import pandas; print(pandas.read_csv('runs/pile-table/contacts.csv').describe())"
    """
    from deepcontact.exchange.fclib import export_run
    from deepcontact.step.run_folder import read_run

    options.refuse_inapplicable([("solution", fmt == "fclib", "only applies to --format fclib")])
    sims = read_run(run_dir).simulations
    total = sum(len(s.files) if fmt == "fclib" else len(s.files[::every]) for s in sims)
    bar = terminal.progress_bar(quiet, total, "step", "export")
    try:
        if fmt == "fclib":
            index = export_run(run_dir, out, every=every, solution=solution, overwrite=overwrite,
                               progress=bar.update, jobs=jobs)
        else:
            from deepcontact.step.table import export_tables
            rows = export_tables(run_dir, out, fmt=fmt, every=every, overwrite=overwrite, progress=bar.update,
                                 jobs=jobs)
    finally:
        bar.close()
    if quiet:
        return
    if fmt == "fclib":
        worst = max((p["residual"] for p in index if p["residual"] is not None), default=None)
        click.echo(f"{len(index)} problems in {out}" + ("" if worst is None else f"; worst stored residual {worst:.1e}"),
                   err=True)
    else:
        click.echo(f"{out}: bodies.{fmt} ({rows['bodies']:,} rows), contacts.{fmt} ({rows['contacts']:,} rows)",
                   err=True)
