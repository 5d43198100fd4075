"""The end of a `dc` process: nothing a plug-in started outlives the command's decision.

A plug-in's non-daemon thread kept dc alive 20 s after its report; a process it started held dc's
standard output open, so a pipe ended 30 s late; its atexit handlers and finalizers printed
tracebacks after exit 0. So `dc` ends its process itself once the command has decided: the
streams flushed, every process still running under it killed (with dc made the reaper of
orphans, those of its children's children too) and said in one line, then os._exit with the
command's status, which neither waits for threads nor runs exit handlers. A library caller's
process is the caller's own: none of this runs there.
"""
import os
import signal
import sys
import threading

from . import interrupts

_PR_SET_CHILD_SUBREAPER = 36
_own = []   # clean-ups of dc's own helper processes (the contestants' zygote), run before the search


def at_end(clean_up):
    """Registers clean_up(): ends a helper process of dc's own before end_process looks for what
    plug-ins left (which it would otherwise count among them)."""
    if clean_up not in _own:
        _own.append(clean_up)


_inherited = set()   # the children this process had when dc began (the user's, kept across exec): never signalled
_ours = []           # checks naming processes of dc's own sandboxes: ended at the end, never blamed on a plug-in


def own_processes(check):
    """Registers check(pid) -> bool: whether a process under dc is one of dc's own (a sandbox's
    bubblewrap, or a process of a sandbox's namespace, still ending as dc ends it), which
    end_process kills like any other but never counts among what plug-ins left."""
    if check not in _ours:
        _ours.append(check)


def adopt_orphans():
    """Makes this process the reaper of the processes its descendants leave (Linux): a plug-in's
    daemon that forks twice still ends up under dc, where end_process finds it. The children it
    already has (`sh -c 'job & exec dc ...'`: the user's job, inherited across exec) are noted,
    and never signalled nor waited for: dc ends only what it started."""
    _inherited.update(children())
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def children(pid=None):
    """The processes whose parent is pid (this process by default), from /proc (Linux; else none)."""
    pid = os.getpid() if pid is None else pid
    out = []
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for task in tasks:
        try:
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out += [int(c) for c in f.read().split()]
        except OSError:
            pass
    return out


def kill_descendants():
    """SIGKILLs every process still running under this one, reaped as they go (each round adopts
    the orphans the last made); one that has ended already is only reaped. Returns how many were
    killed that were not dc's own (own_processes)."""
    killed = set()
    for _ in range(100):
        found = [c for c in children() if c not in _inherited]
        if not found:
            break
        for c in found:
            if not _ended(c):
                ours = any(check(c) for check in _ours)   # (asked before the kill: /proc then says nothing)
                try:
                    os.kill(c, signal.SIGKILL)
                    if not ours:
                        killed.add(c)
                except OSError:
                    pass
        for c in found:
            try:
                os.waitpid(c, 0)
            except OSError:
                pass
    return len(killed)


def _ended(pid):
    """Whether pid has ended and waits only to be reaped (a zombie)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] == "Z"
    except OSError:
        return True


def end_process(code):
    """Ends the process with the command's status (click's SystemExit code): what is left running
    (threads, processes) said in one line each on stderr and not waited for."""
    if code is None:
        code = 0
    elif not isinstance(code, int):   # (a message: printed, as Python's exit would)
        sys.stderr.write(f"{code}\n")
        code = 1
    for clean_up in _own:
        try:
            clean_up()
        except Exception:
            pass
    threads = [t for t in threading.enumerate() if t is not threading.main_thread() and t.is_alive()
               and not t.daemon]
    killed = kill_descendants()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:   # (a closed pipe: what was for it is lost, as with any program)
            pass
    try:
        if threads:
            sys.stderr.write(f"dc: {len(threads)} thread{'s' if len(threads) != 1 else ''} a plug-in started "
                             f"{'were' if len(threads) != 1 else 'was'} still running; ended with the command\n")
        if killed:
            sys.stderr.write(f"dc: {killed} process{'es' if killed != 1 else ''} started under the command "
                             f"(by a plug-in?) {'were' if killed != 1 else 'was'} still running; killed\n")
        sys.stderr.flush()
    except Exception:
        pass
    interrupts.real_exit(code)
