"""A file of ours read back once, safely: opened without following a link and without blocking
(a FIFO planted in its place), checked on the opened descriptor (a regular file, within a size
bound), read whole from that descriptor. For the small records dc reads back from places a
plug-in could write (a fenced run's result record, a kept reference trajectory)."""
import os
import stat


def read_regular(path, limit):
    """The bytes of the regular file at path, at most `limit` of them; None where there is none,
    it is not a regular file (a link, a FIFO, a folder) or it is larger."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size > limit:
            return None
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(limit + 1)
    except OSError:
        return None
    finally:
        os.close(fd)
    return data if len(data) <= limit else None
