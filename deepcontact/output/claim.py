"""How a command claims its output: the one rule for a file and the one for a folder.

Both check the output before any work (a link is never followed, a folder never replaced by a
file, an existing output kept without --overwrite), lock it against a second command and write it
atomically. A folder is replaced only if its record says the same command wrote every entry in it.
"""
import os
import re
from contextlib import contextmanager
from pathlib import Path

from .. import interrupts
from ..errors import InputError, show_path
from . import files, swap
from .lock import locked
from .record import RECORD, InPlace, check_owned_folder


def check_file(path, overwrite):
    """Refuses (InputError) an output file path before any work: one that is there but is not a
    regular file (files.check_replaceable), a mount point, or one that is there without overwrite."""
    files.check_replaceable(path)
    _refuse_mounted_file(path)
    _refuse_existing(path, overwrite)


def mount_point(path):
    """Whether path is a mount point: of another file system (os.path.ismount), or a bind mount
    of a folder or file of the same one, which only the mount table names (/proc/self/mountinfo)."""
    if os.path.ismount(path):
        return True
    try:
        with open("/proc/self/mountinfo", "rb") as f:
            table = f.read()
    except OSError:   # (no /proc: what ismount sees is all that is known)
        return False
    where = os.fsencode(os.path.realpath(path))
    unescape = re.compile(rb"\\([0-7]{3})")   # (the table writes a space, tab, newline or \ as \ooo)
    return any(len(fields) > 4 and unescape.sub(lambda m: bytes([int(m.group(1), 8)]), fields[4]) == where
               for fields in (line.split(b" ") for line in table.splitlines()))


def _refuse_mounted_file(path):
    if os.path.isfile(path) and mount_point(path):
        raise InputError("is a mount point: an output file is replaced by renaming over it, which a mount point "
                         "refuses; give another name", path)


def _refuse_existing(path, overwrite):
    if os.path.lexists(path) and not overwrite:
        raise InputError("file exists; use --overwrite to replace it", path)


@contextmanager
def output_file(path, overwrite):
    """The one way a command claims its -o FILE: checked and locked before the block's work, the
    block writing it atomically (files.write_bytes). A file there is replaced only with overwrite;
    a link, folder, device or FIFO never."""
    files.check_replaceable(path)   # before the lock file: a device or a FIFO is never replaced
    _refuse_mounted_file(path)
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
    if not in_place and path.is_dir() and mount_point(path):
        raise InputError(f"is a mount point: an output is swapped in by renaming, which a mount point refuses; "
                         f"give a folder inside it (-o {show_path(path / 'out')})", path)
    if not in_place and path.is_dir() and not os.access(path, os.W_OK) and not any(path.iterdir()):
        # (an empty folder of the user's is filled, not replaced: it must take the output's entries)
        raise InputError("is a folder this user cannot write in (or on a read-only file system): the output "
                         "goes into it", path)
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
