"""What a command shows on the terminal: its logs and progress on stderr, the line naming its
output on stdout (none to a closed stdout)."""
import atexit
import errno
import io
import logging
import math
import os
import sys
import threading
import time
import weakref

import click


class ClosedStdout(io.TextIOBase):
    """What sys.stdout is when the shell closed it (`>&-`): writing data to it fails, in one line."""

    def writable(self):
        return True

    def write(self, text):
        raise OSError(errno.EBADF, "standard output is closed: nothing to write this command's output to")


def stdout_is_open():
    return not isinstance(sys.stdout, ClosedStdout)


def require_stdout(alternative):
    """Refuses, before any work, a command whose only output would go to a closed stdout."""
    if not stdout_is_open():
        raise click.UsageError(f"standard output is closed, and it is where this output goes: {alternative}")


def show_output(text, quiet):
    """The line naming what a command wrote (stdout): not shown with -q, nor to a closed stdout
    (the output itself is complete; the line only says where it is)."""
    if not quiet and stdout_is_open():
        click.echo(as_the_user_named_it(text))


def as_the_user_named_it(text):
    """text with a fenced job's staged output named as the user named it (its -o), not as the
    folder dc's process stages it in; text as it is outside a fenced job."""
    staged, shown = os.environ.get("DC_OUTPUT_STAGED"), os.environ.get("DC_OUTPUT_SHOWN")
    if staged and shown and "DC_SANDBOX_BROKER" in os.environ:
        return text.replace(staged, shown)
    return text


def log_level(verbose, quiet):
    return max(logging.DEBUG, min(logging.ERROR, logging.INFO - 10 * verbose + 10 * quiet))


def setup_logging(verbose, quiet):
    logging.basicConfig(level=log_level(verbose, quiet), stream=sys.stderr,
                        format="%(levelname)s: %(message)s", force=True)   # (force: each command its own stderr)
    for noisy in ("matplotlib", "PIL"):   # their debug output is not ours
        logging.getLogger(noisy).setLevel(max(logging.WARNING, log_level(verbose, quiet)))
    # Python warnings of the libraries (matplotlib, torch, numpy) are advice to us, not to the
    # user, and span lines: into the log, shown with -v only.
    logging.captureWarnings(True)
    logging.getLogger("py.warnings").setLevel(logging.WARNING if verbose else logging.ERROR)


# Off a terminal (a log file, Make, CI, nohup, a cluster's batch job), a long run says where it is
# in one line at least this often, on a clock (the first unit of work may take minutes): what is
# done of the total, the rate, about how long is left (DC_PROGRESS_EVERY=SECONDS sets another period).
PROGRESS_EVERY = 30.0   # seconds


_WARNED = set()   # the bad DC_PROGRESS_EVERY values already said (one line a process, not one a bar)


def progress_every():
    """DC_PROGRESS_EVERY's seconds (0: a line at every update; inf: none on the clock); a value
    that is not a number of seconds >= 0 is one warning line naming it, and the default used."""
    given = os.environ.get("DC_PROGRESS_EVERY")
    if given is None:
        return PROGRESS_EVERY
    try:
        value = float(given)
    except ValueError:
        value = math.nan
    if value >= 0:   # (False for nan)
        return value
    if given not in _WARNED:
        _WARNED.add(given)
        logging.getLogger(__name__).warning("DC_PROGRESS_EVERY=%s is not a number of seconds >= 0: a progress "
                                            "line every %gs (the default) instead", given, PROGRESS_EVERY)
    return PROGRESS_EVERY


def progress_bar(quiet, total, unit, desc, work=None, **line):
    """A tqdm bar on stderr when it is a terminal; elsewhere a line every PROGRESS_EVERY seconds
    (LineBar, which takes `line`); nothing when quiet. total: the units the run will count (always
    known: a bar that could pass it would lie). work: the units' total weight, where units differ
    in cost and each update(n, work) says its own (LineBar's time left then follows the work).
    Every bar takes update(n, work=None) and close(), so callers need not ask which. Neither
    off-terminal bar is tqdm's: a command in a pipeline need not import it."""
    if quiet:
        return SilentBar()
    if not _is_terminal(sys.stderr):
        return LineBar(total, unit, desc, work, **line)
    from tqdm import tqdm
    return TerminalBar(tqdm(total=total, unit=unit, desc=desc, file=sys.stderr, dynamic_ncols=True, leave=False))


def _is_terminal(stream):
    try:
        return stream is not None and stream.isatty()
    except (OSError, ValueError):   # closed
        return False


class SilentBar:
    """What progress_bar gives when nothing is shown: counts, says nothing."""

    def __init__(self):
        self.n = 0

    def update(self, n=1, work=None, kept=False):
        self.n += n

    def close(self):
        pass


class TerminalBar:
    """tqdm's bar on a terminal, taking what every bar takes (the work is tqdm's own rate's business)."""

    def __init__(self, bar):
        self.bar = bar

    def update(self, n=1, work=None, kept=False):
        self.bar.update(n)

    def close(self):
        self.bar.close()


# A clock thread writes while holding this lock, and a fork waits for it: a worker forked in the
# middle of a line would inherit stderr's buffer locked.
_SAYING = threading.Lock()
_LIVE = weakref.WeakSet()   # bars whose clock runs (stopped at exit: no thread writes while Python ends)


def _before_fork():
    _SAYING.acquire()


def _after_fork():
    _SAYING.release()


os.register_at_fork(before=_before_fork, after_in_parent=_after_fork, after_in_child=_after_fork)


@atexit.register
def _stop_clocks():
    for bar in list(_LIVE):
        bar.stop_clock()


class LineBar(SilentBar):
    """Progress off a terminal: a line on stderr every PROGRESS_EVERY seconds from a clock thread,
    whether or not a unit finished (what is done of the total, the rate, what is left), and one at
    the end of a run that wrote any; a short run says nothing. With a period of 0, a line at every
    update instead (no thread)."""

    def __init__(self, total, unit, desc, work=None, started=None, then=None, done=0):
        """started: when the work began (time.monotonic(); now by default), the first line one
        period after it. then(seconds left here): a clause on what follows this bar, or ''.
        done: units done before the bar began (a resumed run's), in the count, not in the rate."""
        super().__init__()
        self.total, self.unit, self.desc, self.then = total, unit, desc, then
        self.n = self.before = done
        self.total_work, self.work, self.work_before = work, 0.0, 0.0
        self.started = time.monotonic() if started is None else started
        self.lines, self.every = 0, progress_every()
        self._stop, self._clock, self.closed = threading.Event(), None, False
        if self.every > 0:
            self._clock = threading.Thread(target=self._tick, name=f"dc progress: {desc}", daemon=True)
            _LIVE.add(self)
            self._clock.start()

    def update(self, n=1, work=None, kept=False):
        """n more units done (weighing `work`); kept: done before this run (a resumed study's)."""
        self.n += n
        self.work += 0.0 if work is None else work
        if kept:
            self.before += n
            self.work_before += 0.0 if work is None else work
        if self.every == 0:
            self._say(time.monotonic(), done=False)

    def _tick(self):
        wait = max(0.0, self.every - (time.monotonic() - self.started))   # (the first: a period after the start)
        while not self._stop.wait(min(wait, threading.TIMEOUT_MAX)):
            wait = self.every
            with _SAYING:
                if self._stop.is_set():
                    return
                try:
                    self._say(time.monotonic(), done=False)
                except (OSError, ValueError):   # stderr closed or full: the run goes on unsaid
                    return

    def stop_clock(self):
        self._stop.set()
        if self._clock is not None and self._clock is not threading.current_thread():
            self._clock.join(timeout=5)   # (a line being written: stderr's own time)

    def close(self):
        if self.closed:
            return
        self.closed = True
        self.stop_clock()
        _LIVE.discard(self)
        if self.lines:
            self._say(time.monotonic(), done=True)

    def _say(self, now, done):
        sys.stderr.write(progress_line(self, now - self.started, done) + "\n")
        sys.stderr.flush()
        self.lines += 1


SURE = 0.01   # the share of the work a time left is estimated from, at least (and two units)


def progress_line(bar, took, done):
    """'dc DESC: 12/40 UNITs (30%) so far in 1m05s, 5.4 s a UNIT, about 2m31s left': the count never
    shown past its total, nor the share past 100% (a count that overran its total is a bug of the
    caller's; the line stays true meanwhile); the time left follows the work where the bar weighs it,
    once two units and SURE of the work are done (a study's first setting carries its scene's set-up)."""
    n = min(bar.n, bar.total) if bar.total is not None else bar.n
    of = f"/{bar.total:,}" if bar.total is not None else ""
    share = f" ({math.floor(100 * n / bar.total)}%)" if bar.total else ""
    finished = bar.total is None or bar.n >= bar.total
    what = "so far" if not done else "done" if finished else "when it ended"
    line = f"dc {bar.desc}: {n:,}{of} {bar.unit}s{share} {what} in {duration(took)}"
    counted = n - bar.before   # (what this bar saw done: the rate's)
    if counted <= 0:   # (nothing done, or only a resumed run's part: no rate yet)
        return line + ("" if done or n else f", the first {bar.unit} still running")
    line += f", {rate(counted, took, bar.unit)}"
    share = _share(bar)
    if done or share is None or counted < 2 or share[1] < SURE:   # (one unit, or 1% of the work, says little)
        return line
    left = took * (1 - share[0]) / share[1]
    if share[0] < 1:
        line += f", about {duration(left)} left"
    return line + (bar.then(left) if bar.then is not None else "")


def _share(bar):
    """(the share of the run done, the share this bar saw done): by weight where the bar weighs its
    units, else by count; None where no share is known."""
    if bar.total_work and bar.work > bar.work_before:
        return min(bar.work / bar.total_work, 1.0), (bar.work - bar.work_before) / bar.total_work
    if bar.total and bar.n > bar.before:
        return min(bar.n / bar.total, 1.0), (min(bar.n, bar.total) - bar.before) / bar.total
    return None


def rate(n, seconds, unit):
    """'250 steps/s', or for slow units the time each takes: '4m10s a setting'."""
    per_second = n / max(seconds, 1e-9)
    if per_second >= 1:
        return f"{per_second:.3g} {unit}s/s"
    return f"{duration(seconds / n)} a {unit}"


def duration(seconds):
    """A time for a progress line: 42s, 3m05s, 2h10m, 2d03h."""
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    if seconds < 86400:
        return f"{seconds // 3600}h{seconds // 60 % 60:02d}m"
    return f"{seconds // 86400}d{seconds // 3600 % 24:02d}h"
