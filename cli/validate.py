"""dc validate: step and scene files against schemas/."""
import sys
from pathlib import Path

import click

from deepcontact.errors import InputError

from . import options


def xml_files(paths):
    """Every *.xml file named or under a named folder. Anything by such a name that is not a
    regular file (a FIFO would block the parser forever) is refused."""
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(q for q in p.rglob("*.xml") if not q.name.startswith("."))
        elif p.exists():
            found = [p]
        else:
            raise InputError("no such file or folder", p)
        for q in found:
            if not q.is_file():
                raise InputError("not a regular file", q)
        yield from found


@click.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option("--replay", is_flag=True,
              help="PATHS are run folders: re-solve every step with the project's Box2D-exact PGS "
                   "and compare with the impulses Box2D produced (exit 1 unless identical).")
@options.verbosity
@options.command("validate")
def validate(paths, replay, verbose, quiet):
    """Check step and scene files against the XSD schemas in schemas/.

    Folders are searched for *.xml files. Every error is printed as
    path:line:col: message; the exit status is 1 if any file is invalid.
    Scene files are also checked for what the schema cannot see (convex
    polygons, effects used but not declared, overlapping bodies, ...).

    With --replay, each PATH is a run folder from `dc simulate`: every step is
    solved again from its recorded start, with its recorded iteration count, by
    the project's PGS in Box2D-exact mode; the largest difference to Box2D's
    impulses must be 0.

    \b
    Examples:
      dc validate runs/pile
      dc validate runs/pile/seed-000000/step-000042.xml
      dc validate my-scene.xml
      dc validate --replay runs/pile
    """
    if replay:
        return replay_runs(paths, quiet)
    from deepcontact import schema
    from deepcontact.scene.xml import read_scene
    from deepcontact.simulate.build import check_overlaps
    from deepcontact.step.reader import check_origin
    from deepcontact.step.run_folder import MANIFEST, read_run

    files = list(xml_files(paths))
    if not files:
        raise InputError(f"no XML files found in {', '.join(paths)}")
    invalid = 0
    origin = {}   # step file -> (scene, seed) of the simulation it lies in
    for run in (Path(p) for p in paths):
        if (run / MANIFEST).is_file():   # a run: its manifest must match its folders
            try:
                r = read_run(run)
            except InputError as e:
                invalid += 1
                click.echo(f"{e.path}:{e.line or 0}:0: {e.message}")
                continue
            origin.update({f.resolve(): (r.manifest.get("scene"), s.seed) for s in r.simulations for f in s.files})
    bar = options.progress_bar(quiet or len(files) < 50, len(files), "file", "validate")
    for path in files:
        kind, tree, errors = schema.validate(path)
        try:
            if not errors and kind == "scene":
                check_overlaps(read_scene(path), path)
            elif not errors and path.resolve() in origin:
                root = tree.getroot()
                check_origin({"scene": root.get("scene"), "seed": int(root.get("seed"))}, *origin[path.resolve()],
                             path)
        except InputError as e:
            errors = [f"{e.path}:{e.line or 0}:0: {e.message}"]
        if errors:
            invalid += 1
            for line in errors:
                click.echo(line)
        bar.update(1)
    bar.close()
    if not quiet:
        click.echo(f"{len(files)} files checked, {invalid} invalid", err=True)
    sys.exit(1 if invalid else 0)


def replay_runs(paths, quiet):
    from deepcontact.solver.fidelity import replay_run, replayable_run

    failed = False
    for run_dir in paths:
        bar = options.progress_bar(quiet, len(replayable_run(run_dir).step_files), "step", f"replay {run_dir}")
        report = replay_run(run_dir, on_file=lambda _: bar.update(1))
        bar.close()
        verdict = "exact" if report.exact else f"NOT exact in {report.inexact_steps} steps (worst: {report.worst})"
        click.echo(f"{run_dir}: {report.steps} steps, {report.points} contact points replayed; "
                   f"largest difference {report.max_difference:.9g}: {verdict}")
        failed |= not report.exact
    sys.exit(1 if failed else 0)
