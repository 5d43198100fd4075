"""dc validate: step and scene files against schemas/."""
import click

from deepcontact.errors import count

from . import options, terminal


@click.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option("--replay", is_flag=True,
              help="PATHS are run folders: re-solve every step with the project's Box2D-exact PGS "
                   "and compare with the impulses Box2D produced (exit 1 unless identical).")
@click.option("--residuals", is_flag=True,
              help="Also judge every step a solver of ours stepped (--solver pgs): the residual of its recorded "
                   "impulses, recomputed in float64 from the file's own problem (never the residual the file "
                   "claims), must be within its run's tolerance (manifest.json), plus, in a float64 run, exactly "
                   "the most that the file's float32 rounding of the impulses can move it (a float32 run's step "
                   "above it is replayed: the run's solve must give it bit for bit, stopping below the tolerance); "
                   "a step at its cap need not meet the tolerance, but the residual it records must be the one "
                   "measured (to that rounding, or replayed); and each simulation's count of steps above it true; "
                   "else an error line (exit 1).")
@options.jobs
@options.verbosity
@options.command("validate")
def validate(paths, replay, residuals, jobs, verbose, quiet):
    """Check step and scene files against the XSD schemas in schemas/.

    Folders are searched for *.xml and *.xml.gz files. Every error is printed
    as path:line:col: message; the exit status is 1 if any file is invalid.
    Step files are streamed through libxml2 with the schema checked in the
    same pass; scene files are also checked for what the schema cannot see
    (convex polygons, effects used but not declared, overlapping bodies, ...).
    With -j, files are checked side by side; the output is the same.

    With --replay, each PATH is a run folder from `dc simulate`: every step is
    solved again from its recorded start, with its recorded iteration count, by
    the project's PGS in Box2D-exact mode; the largest difference to Box2D's
    impulses must be 0.

    \b
    Examples:
      dc validate runs/pile
      dc validate -j 2 runs/thesis
      dc validate runs/pile/seed-000000/step-000042.xml
      dc validate my-scene.xml
      dc validate --replay -j 2 runs/pile
      dc validate --residuals runs/psor
    """
    options.refuse_inapplicable([("residuals", not replay, "checks the step files' records; --replay re-solves")])
    if replay:
        return replay_runs(paths, quiet, jobs)
    from deepcontact.simulate.validate import validate as check

    bars = []

    def bar(total):
        bars.append(terminal.progress_bar(quiet, total, "file", "validate"))
        return bars[-1]
    try:
        files, invalid, above = check(paths, click.echo, jobs=jobs, progress=bar, residuals=residuals)
    finally:
        for b in bars:
            b.close()
    if not quiet:
        click.echo(f"{count(files, 'file')} checked, {invalid} invalid"
                   + (f"; {count(above, 'step')} with a residual above its tolerance (those that stopped at "
                      f"their cap with the residual they record are not invalid)" if residuals else ""), err=True)
    click.get_current_context().exit(1 if invalid else 0)


def replay_runs(paths, quiet, jobs):
    from deepcontact.evaluate.fidelity import replay_run, replayable_run

    failed = False
    for run_dir in paths:
        bar = terminal.progress_bar(quiet, len(replayable_run(run_dir).step_files), "step", f"replay {run_dir}")
        try:
            report = replay_run(run_dir, on_file=lambda _: bar.update(1), jobs=jobs)
        finally:
            bar.close()
        verdict = "exact" if report.exact else f"NOT exact in {report.inexact_steps} steps (worst: {report.worst})"
        click.echo(f"{run_dir}: {report.steps} steps, {report.points} contact points replayed; "
                   f"largest difference {report.max_difference:.9g}: {verdict}")
        failed |= not report.exact
    click.get_current_context().exit(1 if failed else 0)
