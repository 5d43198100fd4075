"""Worker processes that never outlive the command that started them.

A small fork pool of our own: each worker has one pipe to the parent and shares no lock with it
or with the other workers. (multiprocessing.Pool shares a queue lock that an idle worker holds
while it waits for a task; Pool.terminate() waits for that lock, so a SIGTERM that arrived while
a worker sat idle hung the command.) Workers ignore Ctrl-C (the parent handles it) and die with
SIGTERM at once; the kernel kills them if the parent dies, even by SIGKILL (PR_SET_PDEATHSIG).
When the parent stops early (an error, Ctrl-C, SIGTERM) the workers are killed and waited for
before the parent removes its partial output, so no worker writes into a folder after it is gone.
"""
import ctypes
import os
import signal
from contextlib import contextmanager
from multiprocessing.connection import Pipe, wait

from .errors import Failure

_PR_SET_PDEATHSIG = 1


def _init_worker(parent):
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):   # not Linux: the kill on the way out still applies
        pass
    if os.getppid() != parent:   # the parent died before prctl took effect
        os._exit(1)


def _serve(conn):
    """A worker's loop: (fn, task) in, ("ok", result) or ("error", exception) out, until None."""
    while True:
        try:
            job = conn.recv()
        except EOFError:
            return
        if job is None:
            return
        fn, task = job
        try:
            reply = ("ok", fn(task))
        except BaseException as e:    # handed to the parent, which raises it
            reply = ("error", e)
        try:
            conn.send(reply)
        except Exception as e:        # an unpicklable result or exception
            conn.send(("error", RuntimeError(f"a worker's answer could not be sent back: {e!r}")))


class Pool:
    """`jobs` forked workers; imap and imap_unordered as multiprocessing.Pool's."""

    def __init__(self, jobs):
        self.workers = []   # (pid, connection)
        parent = os.getpid()
        for _ in range(jobs):
            ours, theirs = Pipe()
            pid = os.fork()
            if pid == 0:   # the worker: never returns into the parent's code
                code = 0
                try:
                    ours.close()
                    _init_worker(parent)
                    _serve(theirs)
                except BaseException:
                    code = 1
                os._exit(code)
            theirs.close()
            self.workers.append((pid, ours))

    def imap_unordered(self, fn, tasks):
        for _, result in self._run(fn, tasks):
            yield result

    def imap(self, fn, tasks):
        waiting, next_index = {}, 0
        for index, result in self._run(fn, tasks):
            waiting[index] = result
            while next_index in waiting:
                yield waiting.pop(next_index)
                next_index += 1

    def _run(self, fn, tasks):
        pending = iter(enumerate(tasks))
        busy = {}   # connection -> task index
        for _, conn in self.workers:
            if not self._give(conn, fn, pending, busy):
                break
        while busy:
            for conn in wait(list(busy)):
                index = busy.pop(conn)
                try:
                    status, value = conn.recv()
                except EOFError:
                    raise Failure("a worker process died (killed by a signal, or out of memory?); nothing of this "
                                  "command's output was kept") from None
                if status == "error":
                    raise value
                yield index, value
                self._give(conn, fn, pending, busy)

    @staticmethod
    def _give(conn, fn, pending, busy):
        job = next(pending, None)
        if job is None:
            return False
        conn.send((fn, job[1]))
        busy[conn] = job[0]
        return True

    def close(self):
        for _, conn in self.workers:
            try:
                conn.send(None)
            except OSError:
                pass
        self._reap()

    def kill(self):
        for pid, _ in self.workers:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self._reap()

    def _reap(self):
        for pid, conn in self.workers:
            conn.close()
            try:
                os.waitpid(pid, 0)
            except ChildProcessError:
                pass
        self.workers = []


@contextmanager
def pool(jobs):
    """A pool of `jobs` forked workers, killed and waited for if the block fails."""
    p = Pool(jobs)
    try:
        yield p
        p.close()
    except BaseException:
        p.kill()
        raise


class _Serial:
    """The pool's interface, run in this process (one job: no fork, nothing to kill)."""

    @staticmethod
    def imap(fn, tasks):
        return map(fn, tasks)

    imap_unordered = imap


@contextmanager
def serial():
    yield _Serial()
