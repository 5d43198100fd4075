"""Folders removed whatever they hold, and private temporary folders that outlive no run.

`remove_tree` removes a folder of any depth: shutil.rmtree recurses (a fenced job's staging
folder 10,000 folders deep raised RecursionError, was left, and made every later run on that
output fail) and walks by path (past PATH_MAX it cannot name the entries). Here the walk holds one
descriptor at a time, opened without following a link, goes down by name and back up by "..",
and makes each folder writable before it empties it (a job may leave one mode 000).

`private_folder` makes a command's private temporary folder, holding a lock on a file in it
for as long as it lives; a run killed with SIGKILL leaves its folder (hundreds of MB of a
training's copies), and the next one made sweeps every such folder whose lock it can take. A lock
proves a run dead where a process number cannot: /proc answers for this PID namespace only, and
a run in another (a container sharing /tmp) had its live folder swept.
"""
import fcntl
import os
import stat
import tempfile
from contextlib import contextmanager

_DIRECTORY = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
ALIVE = ".dc-alive"   # the file a private folder's run holds locked while it lives


def remove_tree(path):
    """Removes path (a file, a link or a folder of any depth); OSError where it cannot."""
    path = os.fspath(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISDIR(st.st_mode):
        os.unlink(path)
        return
    names = []   # (the folders entered below path, by name: a string a level, no descriptor)
    fd = _enter(path)
    try:
        while True:
            sub = _empty_but_folders(fd)
            if sub is not None:
                child = _enter(sub, fd)
                os.close(fd)
                fd = child
                names.append(sub)
                continue
            if not names:
                break
            parent = os.open("..", _DIRECTORY, dir_fd=fd)
            os.close(fd)
            fd = parent
            os.rmdir(names.pop(), dir_fd=fd)
    finally:
        os.close(fd)
    os.rmdir(path)


def remove_tree_quietly(path):
    """remove_tree, whatever stops it (what is left is swept by the next run where it can be)."""
    try:
        remove_tree(path)
    except OSError:
        pass


def open_folder_under(top, parts):
    """A descriptor of the folder top/parts..., each step opened without following a link (one
    descriptor held at a time: a path past PATH_MAX is never named)."""
    fd = os.open(top, _DIRECTORY)
    for part in parts:
        try:
            child = os.open(part, _DIRECTORY, dir_fd=fd)
        finally:
            os.close(fd)
        fd = child
    return fd


def _enter(name, dir_fd=None):
    """A descriptor of the folder name (never through a link), made ours to empty."""
    fd = os.open(name, _DIRECTORY, dir_fd=dir_fd)
    try:
        os.fchmod(fd, 0o700)
    except OSError:
        pass
    return fd


def _empty_but_folders(fd):
    """Removes every entry of the folder fd but its folders; the name of one of those, or None."""
    sub = None
    with os.scandir(fd) as found:
        for entry in found:
            if entry.is_dir(follow_symlinks=False):
                sub = sub or entry.name
            else:
                os.unlink(entry.name, dir_fd=fd)
    return sub


# --- Private temporary folders --------------------------------------------------------------------------------

@contextmanager
def private_folder(kind):
    """A new private temporary folder "dc-KIND-PID-*" (in tempfile's folder) for the with block,
    removed after it, whatever it holds; made after sweeping the ones killed processes left."""
    base = tempfile.gettempdir()
    sweep(base, kind)
    folder = tempfile.mkdtemp(prefix=f"dc-{kind}-{os.getpid()}-", dir=base)
    # (the lock file locked under another name, then renamed: a concurrent sweep found it
    # unlocked between its creation and its lock, and removed a live run's folder)
    alive = os.open(os.path.join(folder, ALIVE + ".new"), os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(alive, fcntl.LOCK_EX)
        os.rename(os.path.join(folder, ALIVE + ".new"), os.path.join(folder, ALIVE))
        yield folder
    finally:
        os.close(alive)
        remove_tree_quietly(folder)


def sweep(base, kind):
    """Removes the "dc-KIND-*" folders in base that are this user's and whose run is over: the
    lock on their ALIVE file is free (its holder ended, however it ended). A folder without one
    is left: nothing proves it dead."""
    prefix = f"dc-{kind}-"
    try:
        found = [n for n in os.listdir(base) if n.startswith(prefix)]
    except OSError:
        return
    for name in found:
        full = os.path.join(base, name)
        try:
            if os.lstat(full).st_uid != os.getuid():
                continue
            fd = os.open(os.path.join(full, ALIVE), os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:   # (held: its run goes on)
            continue
        finally:
            os.close(fd)
        remove_tree_quietly(full)
