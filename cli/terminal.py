"""What a command shows on the terminal: its logs and progress on stderr, the line naming its
output on stdout (none to a closed stdout)."""
import errno
import io
import logging
import os
import sys
import time

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
        staged, shown = os.environ.get("DC_OUTPUT_STAGED"), os.environ.get("DC_OUTPUT_SHOWN")
        if staged and shown and "DC_SANDBOX_BROKER" in os.environ:   # (a fenced job: the user's path, not its stage)
            text = text.replace(staged, shown)
        click.echo(text)


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
# in one line at least this often: what is done, the rate, about how long is left
# (DC_PROGRESS_EVERY=SECONDS sets another period).
PROGRESS_EVERY = 30.0   # seconds


def progress_every():
    try:
        value = float(os.environ.get("DC_PROGRESS_EVERY", PROGRESS_EVERY))
    except ValueError:
        return PROGRESS_EVERY
    return value if value >= 0 else PROGRESS_EVERY


def progress_bar(quiet, total, unit, desc):
    """A tqdm bar on stderr when it is a terminal; elsewhere a line every PROGRESS_EVERY seconds
    (LineBar); nothing when quiet (every bar takes update() and close(), so callers need not ask
    which). Neither off-terminal bar is tqdm's: a command in a pipeline need not import it."""
    if quiet:
        return SilentBar()
    if not _is_terminal(sys.stderr):
        return LineBar(total, unit, desc)
    from tqdm import tqdm
    return tqdm(total=total, unit=unit, desc=desc, file=sys.stderr, dynamic_ncols=True, leave=False)


def _is_terminal(stream):
    try:
        return stream is not None and stream.isatty()
    except (OSError, ValueError):   # closed
        return False


class SilentBar:
    """What progress_bar gives when nothing is shown: counts, says nothing."""

    def __init__(self):
        self.n = 0

    def update(self, n=1):
        self.n += n

    def close(self):
        pass


class LineBar(SilentBar):
    """Progress off a terminal: a line on stderr at the first update PROGRESS_EVERY seconds after
    the last line (what is done, the rate, what is left), and one at the end of a run that wrote
    any; a short run says nothing."""

    def __init__(self, total, unit, desc):
        super().__init__()
        self.total, self.unit, self.desc = total, unit, desc
        self.started = self.said = time.monotonic()
        self.lines, self.every = 0, progress_every()

    def update(self, n=1):
        self.n += n
        now = time.monotonic()
        if now - self.said >= self.every:
            self.said = now
            self._say(now, done=False)

    def close(self):
        if self.lines:
                self._say(time.monotonic(), done=True)

    def _say(self, now, done):
        took = max(now - self.started, 1e-9)
        rate = self.n / took
        of = f"/{self.total:,}" if self.total else ""
        share = f" ({100 * self.n / self.total:.0f}%)" if self.total else ""
        left = ""
        if not done and self.total and rate > 0 and self.n < self.total:
            left = f", about {duration((self.total - self.n) / rate)} left"
        what = "so far" if not done else "done" if not self.total or self.n >= self.total else "when it ended"
        sys.stderr.write(f"dc {self.desc}: {self.n:,}{of} {self.unit}s{share} {what} in {duration(took)}, "
                         f"{rate:.3g} {self.unit}s/s{left}\n")
        sys.stderr.flush()
        self.lines += 1


def duration(seconds):
    """A time for a progress line: 42s, 3m05s, 2h10m."""
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds // 60 % 60:02d}m"
