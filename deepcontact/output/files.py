"""Single files, written atomically: to a new temporary name in the same folder, then renamed.

An interrupted write leaves either the complete file or nothing. Under an output folder being
written (`hold_root`) every file is made from that folder's descriptor, one folder at a time and
no link followed: a folder swapped for a link during the run is never written through.
"""
import errno
import io
import os
import stat
from contextlib import contextmanager
from pathlib import Path

from .. import interrupts
from ..errors import InputError
from .names import short_name

# Output folders being written (a partial folder, or a folder written in place), by absolute path:
# a descriptor of the folder itself, opened without following a link.
_roots = {}

# Who is told of a temporary file before its bytes are written, so that a killed run's is known:
# the lock held on an output file, by the file's absolute path (lock.py), and the record of a
# folder written in place, by the folder's absolute path (record.py).
lock_notes = {}      # path -> note(tmp)
folder_notes = {}    # folder -> note(name, tmp)


def umask():
    """This process's umask (read by setting it, and set back at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def make_folder_for(path):
    """Makes the folder an output goes in (and its parents), as every output does. A folder
    named before a '..' must be there already: `-o x/../y` made a folder x only to go up out of
    it. InputError naming path for either."""
    parts = Path(path).parent.parts
    for k, part in enumerate(parts):
        if part == ".." and k and not Path(*parts[:k]).is_dir():
            raise InputError(f"the folder {Path(*parts[:k])} before '..' does not exist: give the output's path "
                             f"without going into a folder that is not there", path)
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot write there: {e.strerror or e}", path) from None


def check_replaceable(path, where=None, name=None):
    """Refuses (InputError) an output path that is there but is not a regular file: a folder, a
    device, a FIFO or a socket is never replaced by a file, and a symbolic link never followed.
    (where, name): path as `at` gives it."""
    try:
        st = os.stat(path if name is None else name, dir_fd=where, follow_symlinks=False)
    except FileNotFoundError:
        return
    except OSError as e:
        raise InputError(f"cannot write there: {e.strerror or e}", path) from None
    if stat.S_ISLNK(st.st_mode):
        raise InputError("is a symbolic link: refusing to write through it or replace it", path)
    if not stat.S_ISREG(st.st_mode):
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "a special file (device, FIFO or socket)"
        raise InputError(f"is {kind}, not a regular file: refusing to replace it", path)


def _notes(path, name):
    """note(tmp) for a temporary file made for path (None when nobody is to be told)."""
    a = os.path.abspath(path)
    lock = lock_notes.get(a) if lock_notes else None
    record = folder_notes.get(os.path.dirname(a)) if folder_notes else None
    if lock is None and record is None:
        return None

    def note(tmp):
        if lock is not None:
            lock(tmp)
        if record is not None:
            record(name, tmp)
    return note


def write_bytes(path, data: bytes):
    """data at path, atomically: complete or not there (an earlier file stays until replaced).
    Written to a new temporary file of ours (never one found there: a name planted there, a hard
    link to a user's file say, is never opened) and renamed over path."""
    # The hot path of `dc simulate` (one call per step): plain os calls, a temporary name
    # unique to this process (tempfile.mkstemp costs more than the write itself).
    path = os.fspath(path)
    with at(path) as (where, name):
        check_replaceable(path, where, name)
        fd, tmp = _new_temporary_in(where, name, path)
        try:
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
            finally:
                os.close(fd)
            os.replace(tmp, name, src_dir_fd=where, dst_dir_fd=where)
        except OSError as e:
            remove_quietly(tmp, where)
            raise type(e)(e.errno, e.strerror, path) from None   # the file asked for, not the temporary one
        except BaseException:
            remove_quietly(tmp, where)
            raise


def write_text(path, text: str):
    """text at path in UTF-8, atomically (write_bytes)."""
    write_bytes(path, text.encode("utf-8"))


def _new_temporary_in(where, name, path):
    """(fd, name) of a new temporary file for path, noted (_notes) before it is made; an OSError
    names path."""
    fd = tmp = None
    try:
        # held: a stop between making the file and knowing its name would leave it behind
        with interrupts.held():
            fd, tmp = _create_temporary(where, name, _notes(path, name))
    except OSError as e:
        raise type(e)(e.errno, e.strerror, path) from None
    except BaseException:
        if tmp is not None:
            os.close(fd)
            remove_quietly(tmp, where)
        raise
    return fd, tmp


def _create_temporary(where, name, note=None, mode=0o666):
    """A new file of ours beside name (in the folder `where`, a descriptor or None): (fd, its
    name), made with O_EXCL, so a name that is taken (a leftover, or a hard link planted there) is
    never opened, let alone truncated; the next free name is taken instead. note(tmp) is called
    before each name is made. The mode is less the umask, as any file's."""
    base = f".{short_name(name)}.{os.getpid()}"
    for k in range(1000):
        tmp = f"{base}.tmp" if k == 0 else f"{base}_{k}.tmp"
        if note is not None:
            note(tmp)
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode, dir_fd=where), tmp
        except FileExistsError:
            continue
    raise OSError(errno.EEXIST, "no free temporary name beside it", name)


@contextmanager
def at(path):
    """(folder, name): where path is made, folder a descriptor of its folder. Under an output
    folder being written (_roots), that folder is opened from the output's own, no link followed.
    OSError naming path where a folder on the way is not a real folder (a link put there during
    the run)."""
    a = os.path.abspath(path)
    root = max((r for r in _roots if a.startswith(r + os.sep)), key=len, default=None) if _roots else None
    if root is None:   # (the user's own folder: its path is theirs to give)
        head, name = os.path.split(a)
        try:
            where = os.open(head, os.O_RDONLY | os.O_DIRECTORY)
        except OSError as e:
            raise OSError(e.errno, e.strerror, os.fspath(path)) from None
        try:
            yield where, name
        finally:
            os.close(where)
        return
    parts = a[len(root) + 1:].split(os.sep)
    where, opened = _roots[root], []
    try:
        for part in parts[:-1]:
            where = _open_on_the_way(part, where, path)
            opened.append(where)
        yield where, parts[-1]
    finally:
        for fd in opened:
            os.close(fd)


def _open_on_the_way(part, where, path):
    """The folder `part` in the folder `where`, opened with no link followed; OSError naming path."""
    try:
        return os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=where)
    except OSError as e:
        if e.errno in (errno.ELOOP, errno.ENOTDIR):
            raise OSError(e.errno, f"the folder {part} on the way is not the one dc made (a link, or a "
                                   f"file, was put in its place during the run): not written through",
                          os.fspath(path)) from None
        raise OSError(e.errno, e.strerror, os.fspath(path)) from None


def hold_root(folder):
    """Registers folder (just made by this run, or an in-place output checked as a real folder) as
    an output being written: what is made under it is made from its descriptor (at). Returns the
    folder's identity."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    _roots[os.path.abspath(folder)] = fd
    st = os.fstat(fd)
    return [st.st_dev, st.st_ino]


def release_root(folder):
    """Ends hold_root."""
    fd = _roots.pop(os.path.abspath(folder), None)
    if fd is not None:
        os.close(fd)


def make_dir(path):
    """A new folder at path (made from the output's descriptor when under one: at)."""
    with at(path) as (where, name):
        try:
            os.mkdir(name, dir_fd=where)
        except OSError as e:
            raise OSError(e.errno, e.strerror, os.fspath(path)) from None


def open_fd(path, flags, mode=0o666):
    """os.open(path, flags) with no link followed in its last name, and under an output folder
    being written, in none on the way (at); an OSError names path."""
    with at(path) as (where, name):
        try:
            return os.open(name, flags | os.O_NOFOLLOW, mode, dir_fd=where)
        except OSError as e:
            raise OSError(e.errno, e.strerror, os.fspath(path)) from None


def open_new(path, mode="wb"):
    """A new file at path, opened for writing (O_EXCL: nothing found there is opened; open_fd):
    for a file written piece by piece inside an output folder being built, whose swap makes it
    appear whole."""
    fd = open_fd(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL)
    return os.fdopen(fd, mode, **({"newline": ""} if "b" not in mode else {}))


def new_temporary(path):
    """A new temporary file of ours beside the output path (noted in path's lock, if held): its
    path, for a program that writes it (ffmpeg) before it is renamed over path."""
    with at(path) as (where, name):
        fd, tmp = _new_temporary_in(where, name, path)
    os.close(fd)
    return Path(path).parent / tmp


def figure_bytes(fig, fmt, **savefig):
    """A matplotlib figure as the bytes of a picture (written with write_bytes, never in place)."""
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, **savefig)
    return buf.getvalue()


@contextmanager
def open_for_write(path, mode="wb"):
    """A file object whose content appears at ``path`` only if the block completes."""
    path = os.fspath(path)
    with at(path) as (where, name):
        check_replaceable(path, where, name)
        fd, tmp = _new_temporary_in(where, name, path)
        try:
            with os.fdopen(fd, mode) as f:
                yield f
            os.replace(tmp, name, src_dir_fd=where, dst_dir_fd=where)
        except BaseException:
            remove_quietly(tmp, where)
            raise


def remove_quietly(path, where=None):
    """Removes the file at path if it can; nothing said either way."""
    try:
        os.unlink(path, dir_fd=where)
    except OSError:
        pass
