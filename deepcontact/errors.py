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
