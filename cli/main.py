"""`dc`: the deepcontact command-line suite."""
import click

from deepcontact import __version__

from .evaluate import evaluate
from .export import export
from .rasterize import rasterize
from .render import render
from .simulate import simulate
from .study import study
from .train import train
from .validate import validate


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="dc")
def cli():
    """Study Box2D's contact solver and warm-start it with learned impulses.

    The pipeline: simulate → validate → rasterize → train → evaluate; the
    longer measurements are under `dc study`; `dc export` hands a run's step
    problems to other solvers (FCLIB); `dc render` draws steps, runs and grid
    samples. Each subcommand has its own --help with examples.
    """


cli.add_command(simulate)
cli.add_command(validate)
cli.add_command(rasterize)
cli.add_command(train)
cli.add_command(evaluate)
cli.add_command(study)
cli.add_command(export)
cli.add_command(render)


def main():
    import shlex
    import sys
    from deepcontact import protocol
    protocol.command_line = shlex.join(["dc", *sys.argv[1:]])   # recorded in every report
    cli(prog_name="dc")


if __name__ == "__main__":
    main()
