"""How a command claims its output: the one rule for a file and the one for a folder.

Both check the output before any work (a link is never followed, a folder never replaced by a
file, an existing output kept without --overwrite), lock it against a second command and write it
atomically. A folder is replaced only if its record says the same command wrote every entry in it.
"""
import os
from contextlib import contextmanager
from pathlib import Path

from .. import interrupts
from ..errors import InputError, show_path
from . import files, swap
from .lock import locked
from .record import RECORD, InPlace, check_owned_folder


def check_file(path, overwrite):
    """Refuses (InputError) an output file path before any work: one that is there but is not a
    regular file (files.check_replaceable), or one that is there without overwrite."""
    files.check_replaceable(path)
    _refuse_existing(path, overwrite)


def _refuse_existing(path, overwrite):
    if os.path.lexists(path) and not overwrite:
        raise InputError("file exists; use --overwrite to replace it", path)


@contextmanager
def output_file(path, overwrite):
    """The one way a command claims its -o FILE: checked and locked before the block's work, the
    block writing it atomically (files.write_bytes). A file there is replaced only with overwrite;
    a link, folder, device or FIFO never."""
    files.check_replaceable(path)   # before the lock file: a device or a FIFO is never replaced
    with locked(path):
        _refuse_existing(path, overwrite)   # (under the lock: a file another command just wrote counts)
        yield Path(path)


def check_folder(path, in_place=False):
    """Refuses (InputError) an output folder path that can never be one: a link, a file, a mount
    point (swapped in by renaming it aside, which a mount point refuses), the current folder or
    one above it."""
    path = Path(path)
    if path.is_symlink():
        raise InputError("is a symbolic link: refusing to write through it; give the folder itself", path)
    if os.path.lexists(path) and not path.is_dir():
        raise InputError("exists and is not a folder", path)
    if not in_place and path.is_dir() and os.path.ismount(path):
        raise InputError(f"is a mount point: an output is swapped in by renaming, which a mount point refuses; "
                         f"give a folder inside it (-o {show_path(path / 'out')})", path)
    here = Path.cwd().resolve()
    if path.resolve() == here or path.resolve() in here.parents:
        raise InputError("is the current folder or one above it: give the output a folder of its own "
                         "(e.g. -o out)", path)


@contextmanager
def output_folder(path, owned, overwrite=False, *, command, in_place=False, existing_ok=False,
                  hint="use --overwrite to replace it"):
    """The folder a command writes its output in, checked, locked and atomic.

    A new or empty ``path`` is written; an existing output only with overwrite, and only if its
    record says dc ``command`` wrote every entry in it (else the first foreign path is named).
    Normally the output is built in ``.NAME.partial-*`` beside path and swapped in when complete,
    so a failed or interrupted command leaves path as it was. in_place: write into path itself
    (training, which resumes from what it wrote), entering each file in the record before writing
    it; a folder it created is removed again if it holds nothing but the record. existing_ok: an
    existing output is written into (resuming) without overwrite. hint: what the message for an
    output that is there already suggests."""
    path = Path(path)
    check_folder(path, in_place)
    with locked(path):   # (which makes the folder the output goes in)
        swap.recover(path, command)
        if path.is_dir() and any(path.iterdir()) and not existing_ok:
            check_owned_folder(path, command, overwrite, owned.what, hint)
        if in_place:
            with _in_place(path, command):
                yield path
        else:
            with swap.folder(path, command) as tmp, _named(path, tmp):
                yield tmp


@contextmanager
def _in_place(path, command):
    """path written in place, every file entered in its record before its bytes; a folder this
    made is removed again if it holds nothing but the record."""
    created = not path.exists()
    record = None
    try:
        with interrupts.held():   # a stop between making the folder and owning it would leave it
            path.mkdir(exist_ok=True)
            files.hold_root(path)
            record = InPlace(path, command)
            record.watch()
        with _named(path, path):
            yield
    except BaseException:
        if created and path.is_dir() and set(os.listdir(path)) <= {RECORD}:
            if record is not None:
                record.forget()
                record = None
            files.remove_quietly(path / RECORD)
            path.rmdir()
        raise
    finally:
        if record is not None:
            record.unwatch()
        files.release_root(path)


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
