"""`dc`: the deepcontact command-line suite.

Each subcommand's module is imported only when that subcommand runs (or shows its own help), so
`dc simulate` never pays for torch, scipy or matplotlib, and `dc --help` for none of them: the
listing below is written here, and tests/test_startup.py holds it equal to each command's own
first help line.
"""
import importlib

import click

from deepcontact import __version__

# name -> the short help `dc --help` lists, in the pipeline's order; each command lives in the
# module of its own name under deepcontact.cli
COMMANDS = {
    "simulate": "Simulate SCENE in Box2D 2.4.1 (or another --engine) and record every step as XML.",
    "validate": "Check step and scene files against the XSD schemas in schemas/.",
    "rasterize": "Turn the step files of RUNS into SPH grid images for training.",
    "train": "Train a network mapping the input images of DATASET to its impulse images.",
    "evaluate": "Solve every recorded step of RUNS from every start and compare.",
    "study": "Longer measurements built on the pipeline.",
    "export": "Write each step's contact problem as an FCLIB local problem (2D).",
    "render": "Draw INPUT: a step file, a run, or a sample of a grid dataset.",
}


class LazyGroup(click.Group):
    """A click group whose subcommands are imported when first asked for (click's documented
    lazy-loading pattern); its own --help lists them from COMMANDS without importing any."""

    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        if name not in COMMANDS:
            return None
        module = importlib.import_module(f"{__package__}.{name}")
        return getattr(module, name)

    def format_commands(self, ctx, formatter):
        limit = formatter.width - 6 - max(len(name) for name in COMMANDS)
        rows = [(name, click.utils.make_default_short_help(COMMANDS[name], limit))
                for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="dc")
def cli():
    """Study Box2D's contact solver and warm-start it with learned impulses.

    The pipeline: simulate → validate → rasterize → train → evaluate; the
    longer measurements are under `dc study`; `dc export` hands a run's step
    problems to other solvers (FCLIB); `dc render` draws steps, runs and grid
    samples. Each subcommand has its own --help with examples.
    """


def main():
    import os
    import shlex
    import sys
    from deepcontact import protocol
    from .terminal import ClosedStdout
    # A closed standard stream (`2>&-`, `>&-`): the logs go nowhere rather than fail the work, and
    # data meant for a closed stdout is an error (one line, exit 1), never silently dropped. Its
    # descriptor is held on /dev/null, so that no file or socket we open later takes its number
    # (and a child's standard output with it).
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            os.open(os.devnull, os.O_RDWR)   # (the lowest free number: this one, as those below are open)
    if sys.stderr is None:
        sys.stderr = open(os.devnull, "w")
    if sys.stdout is None or "DC_SANDBOX_BROKER" in os.environ and os.environ.get("DC_STDOUT_CLOSED"):
        sys.stdout = ClosedStdout()
    protocol.command_line = shlex.join(["dc", *sys.argv[1:]])   # recorded in every report
    if os.environ.get("DC_COMMAND_LINE") and "DC_SANDBOX_BROKER" in os.environ:
        protocol.command_line = os.environ["DC_COMMAND_LINE"]   # (a fenced job: the user's line, not the staged one)
    from deepcontact import interrupts, leftovers
    from deepcontact.contest import result   # (first: it takes its path from the environment before any plug-in runs)
    interrupts.own_process()
    leftovers.adopt_orphans()
    try:
        cli(prog_name="dc")
        code = 0
    except SystemExit as e:   # (click ends every command with one)
        code = e.code
    result.settle(code)   # (in a fence: how it ended, where its command said nothing)
    leftovers.end_process(code)


if __name__ == "__main__":
    main()
