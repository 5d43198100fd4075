"""dc study: the longer measurements (stability of the hard scenes, engines and the frontier, the
thesis's figures, the reference and its peer): every results table of docs/results.md that is not a
`dc evaluate` report comes from one of these. The studies are plug-ins registered in
deepcontact.studies.STUDIES; this group makes its commands from the registry."""
import click


# The studies of the project's own distribution (studies/): named when it is missing.
PROJECT_STUDIES = ("stability", "engines", "frontier", "figures", "exact", "peer", "scale")


class StudyGroup(click.Group):
    """`dc study`, built from the registry of studies: its commands in the studies' order, its
    help's list from their summaries; a study's module is imported only when it runs or is listed.
    A broken study (its package missing, raising on import, not a Study, its command() raising)
    is one line in the help and when run, and hides no other."""

    def list_commands(self, ctx):
        from deepcontact.studies import survey
        return [s.name for s in survey()[0]]

    def get_command(self, ctx, name):
        import sys
        from deepcontact.plugins import PluginError
        from deepcontact.studies import STUDIES, command_of
        if name not in STUDIES.names():
            if name in PROJECT_STUDIES:   # (the project's own, in its own distribution: say how to get it)
                from .options import one_line
                click.echo(one_line(f"dc study: error: the study {name!r} is in the project's studies distribution, "
                                    f"which is not installed: pip install -e studies/ from the repository (make "
                                    f"setup does)"), err=True)
                sys.exit(1)
            return None
        try:
            return command_of(name)
        except PluginError as e:   # (one line naming its distribution and entry point; -v: the traceback)
            if "-v" in sys.argv or "--verbose" in sys.argv:
                raise
            from .options import one_line
            click.echo(one_line(f"dc study: error: {e}"), err=True)
            sys.exit(1)

    def format_help_text(self, ctx, formatter):
        from deepcontact.studies import survey
        super().format_help_text(ctx, formatter)
        studies, broken = survey()
        with formatter.section("Studies"):
            if studies:
                formatter.write_dl([(s.name, s.summary) for s in studies])
            else:
                formatter.write_text("none installed: pip install -e studies/ (make setup does)")
        if broken:
            with formatter.section("Broken (not listed above)"):
                for line in broken.values():
                    formatter.write_text(line)

    def format_commands(self, ctx, formatter):
        pass   # (the list above says what each does)


@click.group(cls=StudyGroup)
def study():
    """Longer measurements built on the pipeline.

    Every results table of docs/results.md that is not a `dc evaluate` report
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
