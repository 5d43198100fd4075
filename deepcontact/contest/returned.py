"""What a fenced job hands back, opened once. A file dc's own process copies out of a job's
staging folder is whatever the job made it, and the job may swap one thing for another between
any two of dc's calls while it runs: a link to a file the fence hides (followed by dc, which has
no fence), a FIFO (a read that never ends), a sparse file of 64 GiB (read into dc's memory), a
hard link to a file of the user's elsewhere.

So a staging folder is opened once, before the job starts (a descriptor, no link followed); each
file in it is opened by name relative to that descriptor with O_NOFOLLOW (a link is refused by its
open) and O_NONBLOCK (a FIFO opens without waiting for a writer), checked on the opened file itself
(fstat: a regular file of this user with one name, not sparse, within the bound of its kind) and
read from that descriptor in bounded chunks. No path is looked up again after its check: what was
checked is what is read (rsync and git read the same way, through directory descriptors).
"""
import errno
import os
import stat

OPEN = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
CHUNK = 1 << 20        # bytes read at a time
SPARSE_FROM = 1 << 20  # bytes: a smaller file's blocks say little of holes (its last block, data kept inline)
SPARSE_RATIO = 8       # a file with under 1/8 of its size on disk, and a hole, is sparse (one written has it all)

# What an open refuses, in words, by errno (anything else: its strerror)
_OPEN_REFUSED = {errno.ELOOP: "a symbolic link (never followed)", errno.ENXIO: "a socket, not a regular file",
                 errno.EACCES: "a file dc may not read (its mode)", errno.EPERM: "a file dc may not read"}


class Refused(Exception):
    """A file handed back that is not read: str() says what it is ("a symbolic link ...")."""


class Staging:
    """A job's staging folder, opened once (a context manager): names() lists it, identity(name)
    tells a file's versions apart without opening it, read(name, limit) reads a file of it."""

    def __init__(self, path):
        self.fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        os.close(self.fd)
        return False

    def names(self):
        """The names in the folder, sorted."""
        return sorted(os.listdir(self.fd))

    def identity(self, name):
        """(type and mode, inode, modification and change times, size) of the entry `name`, its
        link itself if it is one; None where it is gone."""
        try:
            return _identity(os.stat(name, dir_fd=self.fd, follow_symlinks=False))
        except FileNotFoundError:
            return None

    def read(self, name, limit):
        """(its bytes, its identity) of `name`, a regular file of this user with one name, not
        sparse, of at most `limit` bytes; Refused for anything else, FileNotFoundError where it
        is gone."""
        try:
            fd = os.open(name, OPEN, dir_fd=self.fd)
        except FileNotFoundError:
            raise
        except OSError as e:
            raise Refused(_OPEN_REFUSED.get(e.errno) or f"a file that cannot be opened ({e.strerror})") from None
        try:
            st = os.fstat(fd)
            problem = file_problem(fd, st, limit)
            if problem:
                raise Refused(problem)
            return read_whole(fd, st.st_size), _identity(st)
        finally:
            os.close(fd)


def _identity(st):
    return (st.st_mode, st.st_ino, st.st_mtime_ns, st.st_ctime_ns, st.st_size)


def file_problem(fd, st, limit):
    """What makes the opened file fd (its fstat st) one not to read, or None."""
    if not stat.S_ISREG(st.st_mode):
        return f"{_kind(st.st_mode)}, not a regular file"
    if st.st_uid != os.geteuid():
        return f"a file of another user (uid {st.st_uid})"
    if st.st_nlink != 1:
        return f"a file with {st.st_nlink} names (a hard link to a file elsewhere)"
    if sparse(fd, st):
        return f"a sparse file ({st.st_size:,} bytes long, {st.st_blocks * 512:,} of them on disk)"
    if st.st_size > limit:
        return f"a file of {st.st_size:,} bytes, more than such a file may hold ({limit:,})"
    return None


def _kind(mode):
    for test, word in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISDIR, "a folder"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device")):
        if test(mode):
            return word
    return "a special file"


def sparse(fd, st):
    """Whether the regular file fd (its fstat st) is sparse: long, with little of it on disk, and
    a hole (where the file system can say; a compressing one keeps a written file small too)."""
    if st.st_size < SPARSE_FROM or st.st_blocks * 512 * SPARSE_RATIO >= st.st_size:
        return False
    try:
        return os.lseek(fd, 0, os.SEEK_HOLE) < st.st_size
    except OSError:   # (holes it cannot tell: its blocks said)
        return True


def read_whole(fd, size):
    """The `size` bytes of the regular file fd (its fstat's st_size, within its bound), read in
    chunks into one buffer of that size; Refused where it holds more or fewer by the end (a file
    changed as it was read: a training replaces its files whole, never writes one in place)."""
    buf = bytearray(size + 1)   # (one byte over: a file that grew fills it)
    view, total = memoryview(buf), 0
    try:
        while total < len(buf):
            n = os.preadv(fd, [view[total:total + CHUNK]], total)
            if not n:
                break
            total += n
    finally:
        view.release()
    if total != size:
        now = "more" if total > size else f"{total:,}"
        raise Refused(f"a file that changed size as it was read ({size:,} bytes, then {now})")
    del buf[size:]
    return buf
