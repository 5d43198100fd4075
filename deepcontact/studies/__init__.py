"""Studies: longer measurements built on every floor below, brought as plug-ins. The studies
themselves live outside the package (the repository's studies/ folder, its own distribution
`deepcontact-studies`, which `make setup` installs); each registers here through its package's
`deepcontact.studies` entry point, and `dc study` makes its commands from the registry.

    class Mine(Study):
        name, order, writes = "mine", 50, "text"
        summary = "what it measures, in a line"
        command = staticmethod(lambda: my_click_command)
"""
from ..plugins import PluginError, Registry, guest


class Study:
    """What a study is to `dc study`: a class with its command's `name`, a one-line `summary` (the
    help's list), what its -o `writes` (folder: tables, CSV and plots; file: its table; text: a
    report also echoed to stdout as it comes), its place in the list (`order`, smallest first) and
    `command()`, the click command `dc study NAME` runs (its options, help and Examples)."""
    name = None
    summary = ""
    writes = "text"
    order = 100

    @staticmethod
    def command():
        raise NotImplementedError


STUDIES = Registry("study", "deepcontact.studies")


def where_from(name):
    """Where a study's entry point comes from, for a line naming it: "distribution 1.0, entry
    point name = module:attr", or "registered in code"."""
    ep = STUDIES.installed().get(name) if name not in STUDIES.builtin() else None
    if ep is None:
        return "registered in code"
    dist = getattr(ep, "dist", None)
    return (f"{dist.name} {dist.version}, " if dist is not None else "") + f"entry point {name} = {ep.value}"


def _healthy(name):
    """The study named `name`, loaded and held to the contract (a Study whose command() makes a
    click command); PluginError, one line naming its distribution and entry point, otherwise."""
    import click
    where = where_from(name)
    try:
        found = STUDIES.load(name)
    except PluginError as e:
        raise PluginError(f"the study {name!r} ({where}) cannot be loaded: {str(e).split(': ', 1)[-1]}") from e
    if not (isinstance(found, type) and issubclass(found, Study)):
        raise PluginError(f"the study {name!r} ({where}) is not a deepcontact.studies.Study")
    with guest(f"the study {name!r} ({where}): its command()"):
        command = found.command()
    if not isinstance(command, click.Command):
        raise PluginError(f"the study {name!r} ({where}): its command() made {type(command).__name__}, "
                          f"not a click command")
    return found, command


def survey(names=None) -> tuple:
    """(the healthy studies, loaded in this process, in their order; {name: one line saying what
    is wrong} of the broken ones), of every study or of `names`. One broken package hides no other
    study. (`dc study` lists the installed ones from a sandbox: fence.survey.)"""
    healthy, broken = [], {}
    for name in STUDIES.names() if names is None else names:
        try:
            healthy.append(_healthy(name)[0])
        except PluginError as e:
            broken[name] = str(e)
    return sorted(healthy, key=lambda s: (s.order, s.name)), broken


def installed() -> list:
    """The healthy studies installed (every `deepcontact.studies` entry point and any registered
    in code), loaded, in their order (survey: the broken ones too)."""
    return survey()[0]


def command_of(name):
    """The click command of the study `name`; PluginError in one line naming its distribution and
    entry point if it is broken."""
    return _healthy(name)[1]
