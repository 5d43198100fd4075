"""Stop signals as an exception, and the places where it must wait.

A command turns SIGINT, SIGTERM and SIGHUP into Terminated, raised in the main thread wherever it
is, so that the output being built unwinds like after Ctrl-C. Raised inside a lock that another
thread needs, it leaves that lock held: unwinding out of Future.result() left the future's
condition held, and the writer thread finishing that future waited for it while the command
waited for the writer thread, forever (`dc simulate` under load, SIGTERM ignored thereafter).
Code that waits on such locks runs inside held(): a signal that comes meanwhile is raised when
the block is left instead. Raised where Python cannot raise it (a weakref callback, a finalizer:
"Exception ignored in ..."), it is sent again, to be raised where the command is (_unraisable).
"""
import os
import signal
import sys
from contextlib import contextmanager

# Seconds a plug-in's code may go on after a stop signal before dc ends the process itself: a
# guest that swallows every stop (a loop around a bare except) would otherwise keep dc alive
# until SIGKILL. After a repeated signal the guest gets REPEAT_GRACE to unwind instead.
GUEST_DEADLINE = 2.0
REPEAT_GRACE = 0.5

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

# The process's own exit, kept before any plug-in runs: guest code finds os._exit replaced by a
# stand-in that raises (plugins.guest), and dc's own hard stop must still end the process.
real_exit = os._exit

_held = 0          # depth of held() blocks the main thread is in
_pending = None    # the signal that came while held
_received = None   # the first stop signal since install(), raised or not
_installed = False # whether install() has run in this process (dc's commands; not a library caller)
_guests = 0        # depth of plug-in calls in progress (plugins.guest)
_hook = None       # Python's unraisable hook, while install()'s is in place
_command = "dc"    # the command, for the line a hard stop prints
_replaced = []     # the handlers each install() replaced, put back by its uninstall()
_own_process = False   # dc's own process (own_process): its handlers stay to its end
_hard_stops = []   # clean-ups run before a hard stop ends the process (output.swap's: partial outputs, locks)
_watching = False  # whether a deadline thread is armed
_due = None        # when it ends the process (time.monotonic())


class Terminated(KeyboardInterrupt):
    """SIGTERM, SIGHUP or SIGINT: unwinds like Ctrl-C, so every partial output is removed."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


def _on_signal(signum, frame):
    global _pending, _received
    # The clean-up this starts must not itself be cut short by a second signal; only a plug-in
    # that swallowed the first (and goes on) is stopped again (_on_repeat).
    for s in STOP_SIGNALS:
        signal.signal(s, _on_repeat)
    _received = _received or signum
    if _guests:   # in a plug-in's code, which may swallow the stop: it gets a deadline
        _arm_deadline(GUEST_DEADLINE)
    if _held:
        _pending = signum
        return
    raise Terminated(signum)


def _on_repeat(signum, frame):
    """A stop after the first: ignored while the command cleans up, raised in a plug-in's code
    (which swallowed the first), and the process ended if the plug-in swallows this one too."""
    if _guests and not _held:
        _arm_deadline(REPEAT_GRACE)
        raise Terminated(_received or signum)


def at_hard_stop(clean_up):
    """Registers clean_up(), run (in another thread) before a hard stop ends the process."""
    _hard_stops.append(clean_up)


def _arm_deadline(seconds):
    """In `seconds` (or sooner, if a deadline is armed already), ends the process if plug-in code
    is still running then (it swallowed the stop). A thread, since the main thread is the
    plug-in's; it cleans up what the command was building (at_hard_stop) and exits 128 + the
    signal, as the unwinding would have."""
    global _watching, _due
    import time
    due = time.monotonic() + seconds
    _due = due if _due is None else min(_due, due)
    if _watching:
        return
    import threading
    _watching = True

    def watch():
        global _watching, _due
        while time.monotonic() < _due:
            time.sleep(0.05)
            if not _guests:   # the guest gave up: the command unwinds by itself
                _watching, _due = False, None
                return
        _hard_stop(_received or signal.SIGTERM)
    threading.Thread(target=watch, name="dc-stop-deadline", daemon=True).start()


def _hard_stop(signum):
    """Ends the process from the deadline thread: the clean-ups, one line, exit 128 + signum."""
    for clean_up in _hard_stops:
        try:
            clean_up()
        except BaseException:   # (whatever is left, the next command on the output finds and removes)
            pass
    try:
        sys.stderr.write(f"{_command}: interrupted ({signal.Signals(signum).name}); a plug-in went on after the "
                         f"stop, so dc ended it; no partial output was left, and output being replaced "
                         f"(--overwrite) is as it was\n")
        sys.stderr.flush()
    except BaseException:
        pass
    real_exit(128 + signum)


def _unraisable(unraisable):
    """A Terminated raised where Python can only print it (the signal came while a weakref callback
    or a finalizer ran, e.g. an import lock's): not printed, but sent again, so that it is raised in
    the command's own code, whose clean-up it starts."""
    if isinstance(unraisable.exc_value, Terminated):
        import _thread
        for s in STOP_SIGNALS:
            signal.signal(s, _on_signal)
        # From a new thread, which runs once this hook has returned and given up the GIL: a signal
        # handled in here would be unraisable too. (threading.Thread.start waits for the thread.)
        _thread.start_new_thread(os.kill, (os.getpid(), unraisable.exc_value.signum))
        return
    (_hook or sys.__unraisablehook__)(unraisable)


def install(command="dc"):
    """Stop signals raise Terminated from now on (in the main thread); command names the command
    in the line a hard stop prints. The handlers it replaces come back with uninstall."""
    global _pending, _received, _installed, _hook, _command
    _pending = _received = None
    _installed, _command = True, command
    _replaced.append({s: signal.getsignal(s) for s in STOP_SIGNALS})
    for s in STOP_SIGNALS:
        signal.signal(s, _on_signal)
    if sys.unraisablehook is not _unraisable:
        _hook, sys.unraisablehook = sys.unraisablehook, _unraisable


def uninstall():
    """The command is over: what it received is forgotten and, but in dc's own process
    (own_process), the handlers install replaced are back (a caller that ran a command in its own
    process, a notebook or a test, keeps its Ctrl-C: after a stop, dc's handler ignores a repeat)."""
    global _pending, _received, _installed, _hook
    _pending = _received = None
    _installed = False
    replaced = _replaced.pop() if _replaced else {}
    for s, handler in ({} if _own_process else replaced).items():
        if handler is not None:   # (None: not set from Python; left as it is)
            signal.signal(s, handler)
    if sys.unraisablehook is _unraisable:
        sys.unraisablehook, _hook = _hook or sys.__unraisablehook__, None


def own_process():
    """This process is dc's own (the `dc` entry point): its handlers stay after a command, so that
    a stop repeated during its last clean-up (ending what is left running) is ignored, as during
    the command's, not the end of the process."""
    global _own_process
    _own_process = True


def user_stopped():
    """Whether a KeyboardInterrupt now is the user's stop: a signal came (or dc's handlers are not
    installed, so Python's own raised it), not a plug-in raising it itself."""
    return _received is not None or not _installed


@contextmanager
def guest_code():
    """Marks a plug-in's call: the stop-signal handlers it changes are put back as it returns."""
    global _guests
    try:
        saved = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    except ValueError:   # not the main thread: no handlers to keep
        saved = {}
    _guests += 1
    try:
        yield
    finally:
        _guests -= 1
        for s, handler in saved.items():
            if signal.getsignal(s) not in (handler, _on_signal, _on_repeat):
                signal.signal(s, handler)


def check():
    """Raises Terminated if a stop signal came and its exception was swallowed on the way (a bare
    ``except:`` in a library's code, a plug-in's): called where the command must not go on past
    a stop, such as before an output is swapped in."""
    if _received is not None:
        raise Terminated(_received)


@contextmanager
def held(check_first=True):
    """A block that a stop signal does not interrupt: it is raised as the block is left. A stop
    that came before it (and was swallowed) is raised on entry (check), but with check_first=False:
    a clean-up (a finally) runs after a stop as well."""
    global _held, _pending
    if not _held and check_first:
        check()
    _held += 1
    try:
        yield
    finally:
        _held -= 1
        if not _held and _pending is not None:
            signum, _pending = _pending, None
            raise Terminated(signum)
