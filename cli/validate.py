"""dc validate: step and scene files against schemas/."""
import sys
from pathlib import Path

import click

from deepcontact.errors import InputError

from . import options


def xml_files(paths):
    for p in map(Path, paths):
        if p.is_dir():
            yield from sorted(q for q in p.rglob("*.xml") if not q.name.startswith("."))
        elif p.exists():
            yield p
        else:
            raise InputError("no such file or folder", p)


@click.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@options.verbosity
@options.command("validate")
def validate(paths, verbose, quiet):
    """Check step and scene files against the XSD schemas in schemas/.

    Folders are searched for *.xml files. Every error is printed as
    path:line:col: message; the exit status is 1 if any file is invalid.
    Scene files are also checked for what the schema cannot see (convex
    polygons, effects used but not declared, overlapping bodies, ...).

    \b
    Examples:
      dc validate runs/pile
      dc validate runs/pile/seed-000000/step-000042.xml
      dc validate my-scene.xml
    """
    from deepcontact import schema
    from deepcontact.scene.xml import read_scene
    from deepcontact.simulate.build import check_overlaps

    files = list(xml_files(paths))
    bar = options.progress_bar(quiet or len(files) < 50, len(files), "file", "validate")
    invalid = 0
    for path in files:
        kind, tree, errors = schema.validate(path)
        if not errors and kind == "scene":
            try:
                check_overlaps(read_scene(path), path)
            except InputError as e:
                errors = [f"{e.path}:{e.line or 0}:0: {e.message}"]
        if errors:
            invalid += 1
            for line in errors:
                click.echo(line)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    if not quiet:
        click.echo(f"{len(files)} files checked, {invalid} invalid", err=True)
    sys.exit(1 if invalid else 0)
