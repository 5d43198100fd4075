"""dc validate: step and scene files against schemas/."""
import sys
from itertools import groupby
from pathlib import Path

import click

from deepcontact import atomic
from deepcontact.errors import InputError, count

from . import options

CHUNK = 50   # files a worker checks per task


def is_xml(path):
    return path.name.endswith((".xml", ".xml.gz")) and not path.name.startswith(".")


def xml_files(paths):
    """Every *.xml and *.xml.gz file named or under a named folder. Anything by such a name that
    is not a regular file (a FIFO would block the parser forever) is refused."""
    for p in map(Path, paths):
        if p.is_dir():
            found = [q for q in (p / r for r in atomic.entries(p)) if is_xml(q)]   # (any depth, sorted)
        elif p.exists():
            found = [p]
        else:
            raise InputError("no such file or folder", p)
        for q in found:
            if not q.is_file():
                raise InputError("not a regular file", q)
        yield from found


def check_files(chunk):
    """[(path, error lines)] for [(path, origin)]: one worker's share of a simulation folder."""
    from deepcontact.scene.xml import read_scene
    from deepcontact.simulate.build import check_overlaps
    from deepcontact.step.check import check_file

    out = []
    for path, origin in chunk:
        kind, errors = check_file(path, origin)
        if not errors and kind == "scene":   # what the schema cannot see
            try:
                check_overlaps(read_scene(path), path)
            except InputError as e:
                errors = [f"{e.path}:{e.line or 0}:0: {e.message}"]
        out.append((path, errors))
    return out


def origins(paths):
    """step file -> (scene, seed) of the simulation it lies in, for the runs among paths; and the
    error lines of runs whose manifest does not match their folders."""
    from deepcontact.step.run_folder import MANIFEST, read_run

    origin, errors = {}, []
    for run in (Path(p) for p in paths):
        if (run / MANIFEST).is_file():
            try:
                r = read_run(run)
            except InputError as e:
                errors.append(f"{e.path}:{e.line or 0}:0: {e.message}")
                continue
            origin.update({f.resolve(): (r.manifest.get("scene"), s.seed) for s in r.simulations for f in s.files})
    return origin, errors


@click.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option("--replay", is_flag=True,
              help="PATHS are run folders: re-solve every step with the project's Box2D-exact PGS "
                   "and compare with the impulses Box2D produced (exit 1 unless identical).")
@options.jobs
@options.verbosity
@options.command("validate")
def validate(paths, replay, jobs, verbose, quiet):
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
    """
    if replay:
        return replay_runs(paths, quiet, jobs)
    from deepcontact import workers

    files = list(xml_files(paths))
    if not files:
        raise InputError(f"no XML files found in {', '.join(paths)}")
    origin, errors = origins(paths)
    invalid = len(errors)
    for line in errors:
        click.echo(line)
    # tasks of up to CHUNK files of one folder (a simulation), in file order: the report reads the
    # same with any -j
    chunks = [[(f, origin.get(f.resolve())) for f in group[i:i + CHUNK]]
              for group in (list(g) for _, g in groupby(files, key=lambda f: f.parent))
              for i in range(0, len(group), CHUNK)]
    bar = options.progress_bar(quiet or len(files) < 50, len(files), "file", "validate")
    with workers.pool(jobs) if jobs > 1 and len(chunks) > 1 else workers.serial() as pool:
        for checked in pool.imap(check_files, chunks):
            for _, lines in checked:
                invalid += bool(lines)
                for line in lines:
                    click.echo(line)
            bar.update(len(checked))
    bar.close()
    if not quiet:
        click.echo(f"{count(len(files), 'file')} checked, {invalid} invalid", err=True)
    sys.exit(1 if invalid else 0)


def replay_runs(paths, quiet, jobs):
    from deepcontact.evaluate.fidelity import replay_run, replayable_run

    failed = False
    for run_dir in paths:
        bar = options.progress_bar(quiet, len(replayable_run(run_dir).step_files), "step", f"replay {run_dir}")
        report = replay_run(run_dir, on_file=lambda _: bar.update(1), jobs=jobs)
        bar.close()
        verdict = "exact" if report.exact else f"NOT exact in {report.inexact_steps} steps (worst: {report.worst})"
        click.echo(f"{run_dir}: {report.steps} steps, {report.points} contact points replayed; "
                   f"largest difference {report.max_difference:.9g}: {verdict}")
        failed |= not report.exact
    sys.exit(1 if failed else 0)
