"""Atomic output: write to a temporary name in the same folder, then rename.

An interrupted run leaves either the complete file or nothing (a stray ``.tmp`` file at most is
removed on the way out).
"""
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


def write_bytes(path, data: bytes):
    # The hot path of `dc simulate` (one call per step): plain os calls, a temporary name
    # unique to this process (tempfile.mkstemp costs more than the write itself).
    path = os.fspath(path)
    head, name = os.path.split(path)
    tmp = os.path.join(head, f".{name}.{os.getpid()}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as e:
        _remove_quietly(tmp)
        # name the file asked for, not the temporary one
        raise type(e)(e.errno, e.strerror, path) from None
    except BaseException:
        _remove_quietly(tmp)
        raise


def write_text(path, text: str):
    write_bytes(path, text.encode("utf-8"))


@contextmanager
def open_for_write(path, mode="wb"):
    """A file object whose content appears at ``path`` only if the block completes."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode) as f:
            yield f
        os.replace(tmp, path)
    except BaseException:
        _remove_quietly(tmp)
        raise


def _remove_quietly(path):
    try:
        os.unlink(path)
    except OSError:
        pass


def check_replaceable(path, overwrite, markers, what):
    """Refuse to write into `path` unless it is new, empty, or (with overwrite) an earlier output
    of the same kind: a folder holding one of `markers`. Anything else is the user's, not ours
    to replace."""
    from .errors import InputError
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError("exists and is not a folder", path)
    if not path.exists() or not any(path.iterdir()):
        return
    if not overwrite:
        raise InputError(f"{what} folder is not empty; use --overwrite to replace it", path)
    if not any((path / m).exists() for m in markers):
        raise InputError(f"refusing to replace a folder that holds no {what} (no {' or '.join(markers)})", path)


@contextmanager
def folder(path):
    """A temporary folder beside `path` that becomes `path` only if the block completes.

    An existing folder is swapped out first and removed after; on failure or Ctrl-C the
    temporary folder is removed and `path` is left as it was."""
    import shutil
    path = Path(path)
    tmp = path.parent / f".{path.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        yield tmp
        old = None
        if path.exists():
            old = path.parent / f".{path.name}.old-{os.getpid()}"
            os.replace(path, old)
        os.replace(tmp, path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
