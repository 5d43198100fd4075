"""The lock beside an output: two commands never write one output at once.

``.NAME.lock`` is held with flock while a command works on NAME. It also lists the temporary files
the holder made beside NAME, so that the next holder removes those a killed run left.
"""
import errno
import fcntl
import json
import os
import stat
from contextlib import contextmanager
from pathlib import Path

from .. import interrupts, jsontext
from ..errors import InputError
from . import files
from .names import beside, own_name
from .record import remove_claimed

# Locks this process holds, by the absolute path of their output: the file descriptor, and the
# temporary files noted in it.
_locks = {}


def _open_lock(path, lock):
    """A descriptor of the lock file beside path, locked; InputError when it cannot be (held by
    another command, or not a plain file of its own)."""
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise InputError(f"the lock file {lock.name} beside it is a symbolic link: refusing to follow "
                                 "it; remove it", path) from None
            raise InputError(f"cannot write there: {e.strerror or e}", path) from None
        st = os.fstat(fd)
        problem = ("is not a regular file" if not stat.S_ISREG(st.st_mode) else
                   f"is a hard link to another file ({st.st_nlink} names): refusing to write to it"
                   if st.st_nlink != 1 else None)   # (truncating a hard link to a user's file would empty it)
        if problem:
            os.close(fd)
            raise InputError(f"the lock file {lock.name} beside it {problem}; remove it", path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError("another dc command is writing this output now; wait for it or choose another "
                             "output", path) from None
        try:   # the holder before us may have removed the file: then lock the new one
            if os.stat(lock, follow_symlinks=False).st_ino == os.fstat(fd).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)


@contextmanager
def locked(path):
    """Holds an exclusive lock on ``.NAME.lock`` beside path, or refuses at once. The folder path
    goes in is made first, as for every output (`dc render -o figures/x.png`)."""
    lock = beside(path, "lock")
    files.make_folder_for(path)
    key = os.path.abspath(path)
    fd, ours = None, False
    try:
        # (a stop between making the lock file and owning it left it behind: held to here)
        with interrupts.held():
            fd = _open_lock(path, lock)
            _clean_noted(path, lock, fd)
            _locks[key] = (fd, [])
            files.lock_notes[key] = lambda tmp: note_temporary(key, tmp)
            ours = True
        yield
    finally:
        # held too: a first stop as the block ended, raised half-way through, left the lock file;
        # one that comes as held() begins is raised before it holds: then let go here (a stop
        # raises once, a repeat nothing)
        gone = False
        try:
            with interrupts.held(check_first=False):
                _let_go(key if ours else None, lock, fd)
                gone = True
        except interrupts.Terminated:
            if not gone:
                _let_go(key if ours else None, lock, fd)
            raise


def _let_go(key, lock, fd):
    """Ends what locked() took: the lock's entries and its file where key is given (it was ours),
    and the descriptor where there is one."""
    if key is not None:
        files.lock_notes.pop(key, None)
        _locks.pop(key, None)
        files.remove_quietly(lock)
    if fd is not None:
        os.close(fd)


def _clean_noted(path, lock, fd):
    """Removes the temporary files that the lock's last holder noted and did not live to remove
    (ours now), then empties the lock. A noted name that is no file of ours is left alone, said in
    one warning line, and dropped with the rest (remove_claimed): the command goes on."""
    try:
        noted = jsontext.loads(os.pread(fd, 1 << 16, 0) or b"[]")
    except (OSError, ValueError, UnicodeDecodeError):
        noted = []
    for name in noted if isinstance(noted, list) else ():
        remove_claimed(Path(path).parent, name, own_name(path, "tmp", name),
                       f"the lock file {lock.name} lists it, but it is not a temporary file dc makes for "
                       f"{Path(path).name}")
    os.ftruncate(fd, 0)


def note_temporary(path, tmp):
    """Enters tmp, a temporary file beside the output path, in path's lock (held by this
    process), so that if the process is killed the next command on path removes it."""
    entry = _locks.get(os.path.abspath(path))
    if entry is None:
        return
    fd, names = entry
    name = os.path.basename(os.fspath(tmp))
    if name not in names:
        names.append(name)
        data = json.dumps(names).encode()
        os.pwrite(fd, data, 0)
        os.ftruncate(fd, len(data))


def abandon():
    """What unwinding would remove, removed at a hard stop: the temporary files noted in our
    locks, and the locks."""
    for key, (_, names) in list(_locks.items()):
        for name in names:
            files.remove_quietly(Path(key).parent / name)
        files.remove_quietly(beside(key, "lock"))
