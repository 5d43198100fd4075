"""Atomic output: write to a temporary name in the same folder, then rename.

An interrupted run leaves either the complete file or nothing (a stray ``.tmp`` file at most is
removed on the way out). Whole output folders go through `output_folder`: locked against a
second command, replaced only when every entry is the command's own, swapped in when complete.
"""
import glob
import logging
import os
import re
import tempfile
from contextlib import contextmanager
from pathlib import Path

log = logging.getLogger(__name__)


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


@contextmanager
def folder(path):
    """A temporary folder beside `path` that becomes `path` only if the block completes.

    An existing folder is moved aside first and removed after; on failure, Ctrl-C or a signal
    the temporary folder is removed and `path` is left as it was."""
    import shutil
    from .errors import InputError
    path = Path(path)
    tmp = path.parent / f".{path.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir(parents=True)
    except OSError as e:
        raise InputError(f"cannot write there: {e.strerror or e}", path) from None
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


# --- Output folders ----------------------------------------------------------------------------
# A command's output folder is replaced (--overwrite) only if everything in it is something that
# command writes: each writer keeps the list beside itself as an `Owned`. Two commands never write
# one output at once: each holds an exclusive lock on `.NAME.lock` beside it while it works.

# temporary names of write_bytes / open_for_write, anywhere in an output
_TEMPORARY = r"(?:.*/)?\.[^/]+\.tmp"


class Owned:
    """What one kind of output holds: regular expressions over paths relative to the output
    folder (``/``-separated); a pattern ending in ``/`` names a folder."""

    def __init__(self, what, patterns):
        self.what = what
        self._dirs = [re.compile(p[:-1]) for p in patterns if p.endswith("/")]
        self._files = [re.compile(p) for p in patterns if not p.endswith("/")] + [re.compile(_TEMPORARY)]

    def first_foreign(self, folder):
        """The first path under folder (in sorted order) that this kind of output does not hold,
        or None. Symbolic links are never followed, and never ours."""
        def walk(d, rel):
            with os.scandir(d) as it:
                entries = sorted(it, key=lambda e: e.name)
            for e in entries:
                r = f"{rel}{e.name}"
                if e.is_dir(follow_symlinks=False):
                    if not any(p.fullmatch(r) for p in self._dirs):
                        return e.path
                    bad = walk(e.path, r + "/")
                    if bad:
                        return bad
                elif not (e.is_file(follow_symlinks=False) and any(p.fullmatch(r) for p in self._files)):
                    return e.path
            return None
        return walk(folder, "")


@contextmanager
def locked(path):
    """Holds an exclusive lock on ``.NAME.lock`` beside path, or refuses at once."""
    import fcntl
    from .errors import InputError
    path = Path(path)
    lock = path.parent / f".{path.name}.lock"
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise InputError(f"cannot write there: {e.strerror or e}", path) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError("another dc command is writing this output now; wait for it or choose another "
                             "output", path) from None
        try:   # the holder before us may have removed the file: then lock the new one
            if os.stat(lock).st_ino == os.fstat(fd).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    try:
        yield
    finally:
        _remove_quietly(lock)
        os.close(fd)


def _remove_leftovers(path):
    """Folders an interrupted (killed) earlier command left beside path, under our own names.
    Called with the lock held, so no running command owns them."""
    import shutil
    for p in path.parent.glob(f".{glob.escape(path.name)}.*"):
        if re.fullmatch(rf"\.{re.escape(path.name)}\.(partial|old)-\d+", p.name) and not p.is_symlink():
            log.info("removing %s, left by an interrupted earlier run", p)
            shutil.rmtree(p, ignore_errors=True)


@contextmanager
def output_folder(path, owned, overwrite=False, *, command, in_place=False, existing_ok=False,
                  hint="use --overwrite to replace it"):
    """The folder a command writes its output in, checked, locked and atomic.

    A new or empty ``path`` is written; an existing output only with overwrite, and only if every
    entry in it is one `owned` lists (else the first foreign path is named). Normally the output is
    built in ``.NAME.partial-PID`` beside path and swapped in when complete, so a failed or
    interrupted command leaves path as it was. in_place: write into path itself (training, which
    resumes from what it wrote); a folder it created is removed again if it is still empty.
    existing_ok: an existing output is written into (resuming) without overwrite. hint: what
    the message for an output that is there already suggests."""
    from .errors import InputError
    path = Path(path)
    if path.is_symlink():
        raise InputError("is a symbolic link: refusing to write through it; give the folder itself", path)
    if path.exists() and not path.is_dir():
        raise InputError("exists and is not a folder", path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot write there: {e.strerror or e}", path) from None
    with locked(path):
        _remove_leftovers(path)
        existing = path.is_dir() and any(path.iterdir())
        if existing and not existing_ok:
            if not overwrite:
                raise InputError(f"output folder is not empty; {hint}", path)
            foreign = owned.first_foreign(path)
            if foreign is not None:
                raise InputError(f"not written by dc {command}: refusing to replace {path} (--overwrite only "
                                 f"replaces a folder holding nothing but a {owned.what})", foreign)
        if not in_place:
            with folder(path) as tmp, _named(path, tmp):
                yield tmp
            return
        created = not path.exists()
        path.mkdir(exist_ok=True)
        try:
            with _named(path, path):
                yield path
        except BaseException:
            if created and not any(path.iterdir()):
                path.rmdir()
            raise


@contextmanager
def _named(path, work):
    """An OSError names the file under its final name (not the partial folder's, which is gone),
    or the output itself when it names none (a plot, a full disk)."""
    try:
        yield
    except OSError as e:
        if e.errno is None:
            raise
        name = os.fspath(path) if e.filename is None else os.fspath(e.filename)
        if name.startswith(os.fspath(work)):
            name = os.fspath(path) + name[len(os.fspath(work)):]
        raise OSError(e.errno, e.strerror, name) from None
