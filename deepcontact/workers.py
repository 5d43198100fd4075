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

from . import interrupts
from .errors import Failure

_PR_SET_PDEATHSIG = 1
_report = None   # where progress() goes: a worker's pipe to its parent, or the serial run's callback


def progress(n=1, work=None, kept=False):
    """Counts n units of a task's work as done, from inside the task: a worker sends it to its
    parent, whose pool hands it to the command's progress callback; a serial run calls it at once.
    So a bar moves per step, not per task, with any -j. work: what those units weigh, where units
    differ (a setting of a 10,000-body scene against one of 40 bodies), so that a bar given the
    total weight estimates the time left from it; the callback then gets (n, work). kept: the
    units were done before this run (a resumed study's, read back), in the count, not the rate;
    the callback then gets (n, work, True)."""
    if _report is not None:
        if kept:
            _report(n, work, True)
        elif work is None:
            _report(n)
        else:
            _report(n, work)


def die_with_parent(parent=None):
    """This process is killed when its parent dies, even by SIGKILL (Linux: PR_SET_PDEATHSIG); if
    the parent (pid `parent`, where given) died already, it ends now."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):   # not Linux: the kill on the way out still applies
        pass
    if parent is not None and os.getppid() != parent:   # the parent died before prctl took effect
        interrupts.real_exit(1)


def _init_worker(parent):
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    die_with_parent(parent)


def _serve(conn):
    """A worker's loop: (fn, task) in, ("progress", n) as it goes, then ("ok", result) or
    ("error", exception) out, until None."""
    global _report
    _report = lambda *counted: conn.send(("progress", counted))   # noqa: E731 (one line, one job)
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
    """`jobs` forked workers; imap and imap_unordered as multiprocessing.Pool's; on_progress(n)
    receives what the tasks report through progress()."""

    def __init__(self, jobs, on_progress=None):
        self.workers = []   # (pid, connection)
        self.on_progress = on_progress
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
                interrupts.real_exit(code)   # (never a plug-in's stand-in: plugins.guest)
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
                try:
                    status, value = conn.recv()
                except EOFError:
                    raise Failure("a worker process died (killed by a signal, or out of memory?); nothing of this "
                                  "command's output was kept") from None
                if status == "progress":   # (the task goes on)
                    if self.on_progress is not None:
                        self.on_progress(*value)   # (n, and the work where the task weighed it)
                    continue
                index = busy.pop(conn)
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
def pool(jobs, progress=None):
    """A pool of `jobs` forked workers, killed and waited for if the block fails; progress(n)
    receives the tasks' progress() reports."""
    p = Pool(jobs, progress)
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
def serial(progress=None):
    """The pool's interface in this process; progress(n) receives the tasks' progress() reports."""
    global _report
    before = _report
    if progress is not None:   # (else a serial run inside a worker keeps reporting to the worker's parent)
        _report = progress
    try:
        yield _Serial()
    finally:
        _report = before


def for_jobs(jobs, tasks, progress=None):
    """A pool of `jobs` workers (no more than there are tasks: -j 100000 forks no more than the
    work needs) when there is more than one job and task, else a serial run."""
    jobs = min(jobs, len(tasks))
    return pool(jobs, progress) if jobs > 1 else serial(progress)
