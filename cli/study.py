"""dc study: the longer measurements (stability of the hard scenes, engines and the frontier, the
thesis's figures, the reference and its peer): every results table of docs/results/ that is not a
`dc evaluate` report comes from one of these. The studies are plug-ins registered in
deepcontact.studies.STUDIES; this group makes its commands from the registry."""
import os
import sys

import click

from . import options


# The studies of the project's own distribution (studies/): named when it is missing.
PROJECT_STUDIES = ("stability", "engines", "frontier", "figures", "exact", "peer", "scale")


class StudyGroup(click.Group):
    """`dc study`, built from the registry of studies: its commands in the studies' order, its
    help's list from their summaries. An installed study is listed and run fenced, in a sandbox of
    its own (deepcontact/studies/fence.py): its code never runs in this process. A broken study
    (its package missing, raising on import, not a Study, its command() raising) is one line in
    the help and when run, and hides no other."""

    def _listing(self):
        """([(order, name, summary)] of the healthy studies, {name: line} of the broken ones)."""
        from deepcontact.contest import machine, sandbox
        from deepcontact.contest.fence import inside
        from deepcontact.studies import STUDIES, fence, survey
        # (a study registered since is listed too; so is one a fence, or --unfenced, now lets run)
        key = (tuple(STUDIES.names()), os.environ.get(sandbox.UNFENCED_ENV), machine.bwrap())
        if getattr(self, "_listed", (None,))[0] != key:
            if inside():   # (the sandbox that lists or runs them: here, in place)
                healthy, broken = survey()
                rows = [(s.order, s.name, s.summary) for s in healthy]
            else:
                rows, broken = [], {}
                if any(n not in STUDIES.builtin() for n in STUDIES.names()):
                    found, broken = fence.survey()
                    rows = [(s["order"], s["name"], s["summary"]) for s in found]
                in_code, broken_here = survey(STUDIES.builtin())
                rows += [(s.order, s.name, s.summary) for s in in_code]
                broken.update(broken_here)
            self._listed = (key, (sorted(rows), broken))
        return self._listed[1]

    def list_commands(self, ctx):
        return [name for _, name, _ in self._listing()[0]]

    def get_command(self, ctx, name):
        from deepcontact.plugins import PluginError
        from deepcontact.studies import STUDIES, command_of, fence
        if name not in STUDIES.names():
            if name in PROJECT_STUDIES:   # (the project's own, in its own distribution: say how to get it)
                from deepcontact import errors
                click.echo(errors.one_line(f"dc study: error: the study {name!r} is in the project's studies "
                                           f"distribution, which is not installed: {errors.STUDIES}"), err=True)
                sys.exit(1)
            return None
        if fence.fenced(name):
            return _fenced_command(name)
        try:
            return _held(name, command_of(name))
        except PluginError as e:   # (one line naming its distribution and entry point; -v: the traceback)
            from deepcontact.contest import result
            from deepcontact.errors import one_line
            line = one_line(f"dc study: error: {e}")
            result.say(result.FAILED, 1, line)   # (the fence running it: its own line said why)
            if "-v" in sys.argv or "--verbose" in sys.argv:
                raise
            click.echo(line, err=True)
            sys.exit(1)

    def format_help_text(self, ctx, formatter):
        super().format_help_text(ctx, formatter)
        rows, broken = self._listing()
        with formatter.section("Studies"):
            if rows:
                formatter.write_dl([(name, summary) for _, name, summary in rows])
            else:
                from deepcontact import errors
                formatter.write_text(f"none installed: {errors.STUDIES}")
        if broken:
            with formatter.section("Broken (not listed above)"):
                for line in broken.values():
                    formatter.write_text(line)

    def format_commands(self, ctx, formatter):
        pass   # (the list above says what each does)


def _held(name, command):
    """A study's command as every dc command runs: whatever it raises one line (-v: the
    traceback), its end recorded for the fence that runs it (contest/result.py). The project's
    own commands are already (options.command); a plug-in's plain click command was a raw
    traceback, and its crash was published as its output."""

    if getattr(command.callback, "dc_command", False):
        return command
    invoke = command.invoke

    @options.command(f"study {name}")
    def held(ctx, verbose=0, quiet=0):
        from deepcontact.errors import Failure, InputError
        from deepcontact.plugins import PluginError
        from deepcontact.studies import where_from
        from deepcontact import interrupts
        try:
            return invoke(ctx)
        except (click.exceptions.ClickException, click.exceptions.Exit, click.exceptions.Abort, InputError, Failure,
                MemoryError):
            raise   # (its own words: a message, a verdict, click's usage)
        except KeyboardInterrupt:
            if interrupts.user_stopped():
                raise
            raise PluginError(f"the study {name!r} ({where_from(name)}) raised KeyboardInterrupt itself, with no "
                              f"stop signal") from None
        except SystemExit as e:
            raise PluginError(f"the study {name!r} ({where_from(name)}) called sys.exit({e.code!r})") from e
        except BaseException as e:   # (chained: -v shows its file and line)
            raise PluginError(f"the study {name!r} ({where_from(name)}) raised {type(e).__name__}: {e}") from e
    command.invoke = lambda ctx: held(ctx, verbose=sum(a in ("-v", "--verbose") for a in sys.argv))
    return command


def _fenced_command(name):
    """`dc study NAME ARGS`: the study run in its sandbox (its own --help and errors come from
    there); this process checks, stages and publishes its output."""


    @options.command(f"study {name}")
    def body(args, verbose=0, quiet=0):
        from deepcontact.contest import sandbox
        from deepcontact.studies import fence
        if sandbox.UNFENCED_OPTION in args:   # (dc's own option, wherever it stands: the study never sees it)
            args = [a for a in args if a != sandbox.UNFENCED_OPTION]
            options.allow_unfenced(click.get_current_context())
        raise click.exceptions.Exit(fence.run(name, args))

    @click.command(name, add_help_option=False,
                   context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
    @click.argument("args", nargs=-1, type=click.UNPROCESSED)
    def command(args):
        body(args, verbose=sum(a in ("-v", "--verbose") for a in args))
    return command


@click.group(cls=StudyGroup)
@options.unfenced
def study():
    """Longer measurements built on the pipeline.

    Every results table of docs/results/ that is not a `dc evaluate` report
    comes from one of these. The studies are plug-ins (the repository's
    studies/ folder, installed by make setup; docs/api.md, "Studies"). With -o, a study writes a folder (tables, CSV and plots), a file (its
    table) or a text report (also echoed to stdout as it comes); a study whose
    verdict is a failure says so in one line and exits 1.

    \b
    Examples:
      dc study stability --fast
      dc study stability -o runs/stability.md
      dc study figures runs/heldout -o reports/figures --every 10
      dc study engines --fast -o reports/engines-fast
    """
