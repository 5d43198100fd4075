"""Errors about the user's input: one line naming the file (and line) and what is wrong."""


class InputError(ValueError):
    """Bad input: the CLI prints ``path:line: message`` and exits non-zero, without a traceback.
    A ValueError, so that a library caller may catch what Python's own checks would raise."""

    def __init__(self, message: str, path: object = None, line: int | None = None):
        super().__init__(message)
        self.message = message
        self.path = None if path is None else str(path)
        self.line = line

    def __reduce__(self):   # across worker processes, with the path and line
        return (type(self), (self.message, self.path, self.line))

    def __str__(self):
        where = show_path(self.path) if self.path else ""
        if where and self.line:
            where += f":{self.line}"
        return f"{where}: {self.message}" if where else self.message


class Failure(Exception):
    """Work that could not finish for a reason outside the input (a worker killed, say): the CLI
    prints the message on one line and exits 1."""


class StudyFailed(Failure):
    """A study that ran to its end and whose verdict is a failure (a configuration that never met
    its criteria): its report is written; the CLI prints the line and exits 1."""


class OptionError(InputError):
    """Options that do not fit the input (or each other): the CLI exits 2, as for a bad option value."""

    def __init__(self, message, option):
        super().__init__(message)
        self.option = option

    def __reduce__(self):
        return (type(self), (self.message, self.option))

    def __str__(self):
        return f"Invalid value for {self.option!r}: {self.message}" if self.option else self.message


MAX_MESSAGE = 600   # characters: a message is one readable line, whatever a parser put in it


def one_line(text):
    """text on one line (white space folded), cut to MAX_MESSAGE characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 1] + "…"


def show_path(path):
    """A path as one line shows it: quoted when it holds a newline or other unprintable character."""
    path = str(path)
    return path if path.isprintable() else repr(path)


def count(n, word, plural=None):
    """'1 file', '2 files': a number with its noun in the right form."""
    return f"{n:,} {word if n == 1 else plural or word + 's'}"


# Modules a plain `pip install deepcontact` does not bring, and how to get each, as a line that
# works on any Linux machine (tests/test_install.py runs them): torch pinned to its CPU build,
# since PyPI's torch for Linux pulls multi-GB CUDA libraries; the studies are no published
# distribution, so they install from the repository's folder.
CPU_TORCH = "pip install torch==2.13.0+cpu --extra-index-url https://download.pytorch.org/whl/cpu"
STUDIES = "pip install ./studies in a clone of the repository (make setup installs them)"
OPTIONAL = {
    "torch": f"torch is not installed: {CPU_TORCH} (the CPU build; make setup installs it)",
    "pymunk": "pymunk is not installed: pip install pymunk==7.3.1 (make setup installs it)",
    "mujoco": "MuJoCo is not installed: pip install mujoco==4.0.1 (make setup installs it)",
    "dcstudies": f"the project's studies are not installed: {STUDIES}",
    "pyarrow": "pyarrow is not installed: pip install pyarrow",
}


def missing_module(error):
    """The InputError saying how to get an optional module that an ImportError says is missing,
    or None when it is not one of OPTIONAL."""
    name = (getattr(error, "name", None) or "").split(".")[0]
    return InputError(OPTIONAL[name]) if isinstance(error, ImportError) and name in OPTIONAL else None
