"""The names dc gives what it makes beside an output NAME, and how it recognises them.

``.NAME.lock`` (the lock), ``.NAME.partial-PID-XXXX`` (the output being built), ``.NAME.old-PID-XXXX``
(the output being replaced, only while the journal ``.NAME.swap`` names it), ``.NAME.PID.tmp`` (a
file being written). A NAME too long to take a suffix is shortened with a hash, so that every name
fits in 255 bytes. A control file's claim is acted on only for names this module would have made.
"""
import hashlib
import os
import re
import stat
from pathlib import Path

NAME_MAX = 255     # bytes in one file name (Linux, macOS)
_SPARE = 40        # room left for the longest suffix we add (".partial-PID-XXXXXXXX", ".PID.tmp")


def short_name(name):
    """name, or for one too long to take a suffix, its start and a hash of the whole (still unique)."""
    raw = name.encode("utf-8", "surrogateescape")
    if len(raw) <= NAME_MAX - _SPARE:
        return name
    head = raw[:NAME_MAX - _SPARE - 12].decode("utf-8", "ignore")
    return f"{head}~{hashlib.sha1(raw).hexdigest()[:10]}"


def beside(path, kind):
    """The path of our ``.NAME.KIND`` file or folder beside path."""
    path = Path(path)
    return path.parent / f".{short_name(path.name)}.{kind}"


def own_name(path, kind, name):
    """Whether name is one this module makes beside the output path: kind "partial" or "old" (a
    folder: ``.NAME.partial-PID-XXXX``), or "tmp" (a temporary file: ``.NAME.XXXX.tmp``)."""
    if not isinstance(name, str):
        return False
    stem = re.escape(f".{short_name(Path(path).name)}.")
    tail = r"[A-Za-z0-9_]+\.tmp" if kind == "tmp" else re.escape(kind) + r"-\d+-[A-Za-z0-9_]+"
    return re.fullmatch(stem + tail, name) is not None


def temporary_name(name):
    """A temporary file's name as write_bytes makes it inside a folder written in place."""
    return isinstance(name, str) and re.fullmatch(r"\.[^/\x00]+\.\d+(_\d+)?\.tmp", name) is not None


def kind(p):
    """What is at p, links not followed: "file", "folder", "other" (link, FIFO, device) or None."""
    try:
        mode = os.lstat(p).st_mode
    except OSError:
        return None
    return "file" if stat.S_ISREG(mode) else "folder" if stat.S_ISDIR(mode) else "other"
