"""Studies: longer measurements built on every floor below, brought as plug-ins. The studies
themselves live outside the package (the repository's studies/ folder, its own distribution
`deepcontact-studies`, which `make setup` installs); each registers here through its package's
`deepcontact.studies` entry point, and `dc study` makes its commands from the registry.

    class Mine(Study):
        name, order, writes = "mine", 50, "text"
        summary = "what it measures, in a line"
        command = staticmethod(lambda: my_click_command)
"""
from ..plugins import Registry


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


def installed() -> list:
    """The studies installed (every `deepcontact.studies` entry point and any registered in code),
    loaded, in their order."""
    found = [STUDIES.load(name) for name in STUDIES.names()]
    return sorted(found, key=lambda s: (s.order, s.name))
