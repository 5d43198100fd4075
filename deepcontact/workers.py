"""Worker processes that never outlive the command that started them.

A pool's workers ignore Ctrl-C (the parent handles it) and die with SIGTERM at once; the kernel
kills them if the parent dies, even by SIGKILL (PR_SET_PDEATHSIG). When the parent stops early
(an error, Ctrl-C, SIGTERM) the workers are terminated and waited for before the parent removes
its partial output, so no worker writes into a folder after it is gone.
"""
import ctypes
import multiprocessing
import os
import signal
from contextlib import contextmanager

_PR_SET_PDEATHSIG = 1


def _init_worker(parent):
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):   # not Linux: the terminate() below still applies
        pass
    if os.getppid() != parent:   # the parent died before prctl took effect
        os._exit(1)


@contextmanager
def pool(jobs):
    """A multiprocessing pool of `jobs` forked workers, terminated if the block fails."""
    p = multiprocessing.get_context("fork").Pool(jobs, initializer=_init_worker, initargs=(os.getpid(),))
    try:
        yield p
    except BaseException:
        # Killed first: Pool.terminate() alone can wait forever on a worker blocked writing a
        # result (seen once under load, after SIGTERM); these workers hold nothing to clean up.
        for worker in multiprocessing.active_children():
            worker.kill()
        p.terminate()
        p.join()
        raise
    p.close()
    p.join()
