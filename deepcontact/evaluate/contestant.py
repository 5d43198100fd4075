"""Contestants out of the judge's reach: each variant's start and solver method run in a process
of their own, and the judge times and judges every call from its side.

A contestant process is forked from a zygote, a fresh interpreter the judge starts as a new
program (never a fork of itself): it holds none of the judge's memory (no reference solution, no
recorded answer, no other variant's state), and nothing it does (patching the clock, walking the
stack, keeping a memo or a cache, starting threads) reaches the judge or another variant. Its
start and method are made there, from their names, and the time that takes (import,
construction) is reported beside the per-step times. The judge sends each request (pickled: the
judge's own data) and reads each answer as plain JSON and float64 arrays, never unpickled, so an
answer is data, not code. Every call is timed by the judge's clock around the request and its
answer; the same request answered by the process's null contestant (an echo of the same size)
measures the transport, which is subtracted and reported.
"""
import json
import os
import pickle
import signal
import struct
import sys
import time

import numpy as np

from ..errors import InputError
from ..plugins import PluginError

TRAITS = ("needs_reference", "needs_recorded", "needs_model", "oracle")
ANSWER_MAX = 1 << 28   # bytes an answer may take (three float64 arrays of 10 million contact points): no more is read


# --- Answers: JSON and float64 arrays, never pickle -------------------------------------------------

def pack(header, arrays=None):
    """An answer's bytes: its JSON header (naming each array and its length) and the arrays."""
    arrays = {k: np.ascontiguousarray(v, np.float64) for k, v in (arrays or {}).items()}
    header = dict(header, arrays=[[k, int(v.size)] for k, v in arrays.items()])
    head = json.dumps(header).encode()
    return struct.pack("<I", len(head)) + head + b"".join(v.tobytes() for v in arrays.values())


def unpack(data, who):
    """(header, arrays) of an answer; PluginError naming `who` for bytes that are not one."""
    try:
        (n,) = struct.unpack_from("<I", data)
        header = json.loads(data[4:4 + n])
        arrays, at = {}, 4 + n
        for name, size in header.pop("arrays"):
            if not (isinstance(name, str) and type(size) is int and 0 <= size):
                raise ValueError("bad array entry")
            arrays[name] = np.frombuffer(data, np.float64, size, at).copy()
            at += 8 * size
        if at != len(data) or not isinstance(header, dict):
            raise ValueError("trailing bytes")
    except (ValueError, TypeError, KeyError, struct.error) as e:
        raise PluginError(f"{who} answered with something that is not an answer ({e})") from None
    return header, arrays


# --- The contestant's side --------------------------------------------------------------------------

def _make(setup):
    """(start, traits) made from the setup's names (and the method made, where a plug-in)."""
    from ..plugins import guest
    from ..solver import methods
    from ..warmstart.starts import STARTS, Checked, asks, make_starts
    for name in setup["networks"]:   # (the checkpoint's plug-in network, which the user named with --arch)
        from ..model.arch import NETWORKS
        NETWORKS.load(name)
    kind, what = setup["start"]
    if kind == "name":
        factory = STARTS.load(what)
        if not methods.is_native(setup["method"]):
            methods.SOLVERS.load(setup["method"])
        predictor = None
        if getattr(factory, "needs_model", False) or "predictor" in _parameters(factory):
            from ..model.inference import Predictor
            predictor = Predictor(setup["checkpoint"], threads=setup["threads"]) if setup["checkpoint"] else None
        start = make_starts([what], spec=setup["spec"], predictor=predictor)[what]
    else:
        start = pickle.loads(what)
    if not methods.is_native(setup["method"]):
        methods.method(setup["method"])
    traits = {k: bool(asks(setup["name"], start, k)) for k in TRAITS}
    if isinstance(start, Checked):
        # (its step is its own already, unpickled for each call: no private copy; and its answer is
        # checked by the judge, off its clock, not here on it)
        name, inner = start.name, start.start

        def start(ctx):
            with guest(f"the start {name!r}"):
                return inner(ctx)
    return start, traits


def _describe(names):
    """What a judge may know of these plug-ins (starts and methods, by name), loaded here: each
    start's traits and origin, each method's origin and whether it takes a w."""
    from ..solver import methods
    from ..warmstart.starts import STARTS
    out = {"starts": {}, "methods": {}}
    for name in names["starts"]:
        factory = STARTS.load(name)
        traits = {k: bool(getattr(factory, k, False)) for k in TRAITS}
        traits["needs_model"] = traits["needs_model"] or "predictor" in _parameters(factory)
        out["starts"][name] = {"traits": traits, "origin": STARTS.origin(name)}
    for name in names["methods"]:
        factory = methods.SOLVERS.load(name)
        out["methods"][name] = {"origin": methods.method_origin(name),
                                "takes_relaxation": bool(getattr(factory, "takes_relaxation", False))}
    return out


def describe(starts=(), methods=()):
    """Describes the plug-in starts and methods among these names from a contestant process of
    their own (their code is imported there, never in this process): fills STARTS.described and
    SOLVERS.described. PluginError naming one that cannot be loaded."""
    from ..solver.methods import SOLVERS, is_native
    from ..warmstart.starts import NAMES, STARTS
    wanted = {"starts": [n for n in dict.fromkeys(starts) if n not in NAMES and n not in STARTS.described],
              "methods": [n for n in dict.fromkeys(methods) if not is_native(n) and n not in SOLVERS.described]}
    if not (wanted["starts"] or wanted["methods"]):
        return
    pid, conn = _fork()
    try:
        conn.send_bytes(pickle.dumps({"describe": wanted, "path": list(sys.path), "threads": 1}))
        try:
            data = conn.recv_bytes()
        except (EOFError, OSError):
            raise PluginError(f"the plug-ins {', '.join(wanted['starts'] + wanted['methods'])}: their process "
                              f"ended while they were loaded") from None
        header, _ = unpack(data, "a plug-in's description")
        if "error" in header:
            raise PluginError(header["error"]) from ContestantTraceback(str(header.get("traceback", "")))
        found = header.get("described")
        for registry, kind in ((STARTS, "starts"), (SOLVERS, "methods")):
            for name in wanted[kind]:
                info = (found or {}).get(kind, {}).get(name)
                if not isinstance(info, dict):
                    raise PluginError(f"the plug-in {name!r} was not described by its process")
                registry.described[name] = info
    finally:
        conn.close()
        try:
            os.killpg(pid, signal.SIGKILL)
        except OSError:
            pass


def _parameters(factory):
    import inspect
    try:
        return inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return {}


def _left_running():
    """Threads and processes the contestant left running after its call (noticed, and reported)."""
    import threading
    from ..leftovers import children
    return threading.active_count() - 1, len(children())


def serve(conn):
    """A contestant process: makes the start and method its setup names, then answers requests
    until "end"."""
    from .. import interrupts
    from ..workers import die_with_parent
    die_with_parent()
    os.setsid()   # (its own group: whatever it starts is killed with it)
    # dc's rules for guests hold here too (a KeyboardInterrupt a plug-in raises is its own: no
    # stop signal reaches a contestant, which the judge ends itself)
    interrupts.install("dc contestant")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from .. import plugins
    plugins.contained = True
    setup = pickle.loads(conn.recv_bytes())
    sys.path[:0] = [p for p in setup["path"] if p not in sys.path]
    from .. import protocol
    from ..solver.methods import call_plugin, is_native, solve
    protocol.use_threads(setup["threads"])
    if "describe" in setup:   # (a description of plug-ins, for a judge that must not import them)
        try:
            conn.send_bytes(pack({"described": _describe(setup["describe"])}))
        except BaseException as e:
            conn.send_bytes(pack({"error": _line(e), "traceback": _traceback(e)}))
        return
    try:
        start, traits = _make(setup)
        conn.send_bytes(pack({"traits": traits}))   # (its setup is timed by the judge's clock)
    except BaseException as e:
        conn.send_bytes(pack({"error": _line(e), "traceback": _traceback(e)}))
        return
    while True:
        try:
            request = pickle.loads(conn.recv_bytes())
        except EOFError:
            return
        op = request["op"]
        if op == "end":
            return
        try:
            if op == "echo":   # the null contestant: the same request, read as a call reads it, answered at once
                if "problem" in request:
                    pickle.loads(request["problem"])
                n = request["points"]
                reply = pack({}, {"normal": np.zeros(n), "tangent": np.zeros(n)})
            elif op == "start":
                value = start(request["ctx"])
                try:
                    reply = pack({"seconds": {str(k): float(v) for k, v in dict(value.seconds or {}).items()}},
                                 {"normal": value.normal, "tangent": value.tangent})
                except (AttributeError, TypeError, ValueError) as e:
                    raise PluginError(f"the start {setup['name']!r} must return a StartValue(normal, tangent, seconds): "
                                      f"{type(e).__name__}: {e}") from None
            elif op == "solve":
                # (a plug-in's claimed residuals come with every answer, alike on every call; a built-in's
                # trace the judge makes itself, from the same start, off the clock)
                problem, asked = pickle.loads(request["problem"]), request["settings"]
                if is_native(asked.accelerate):
                    s = solve(problem, request["normal"], request["tangent"], settings=asked, final_residual=False)
                    reply = pack({"iterations": int(s.iterations), "fallback": int(s.relaxation_fallback > 0),
                                  "factorizations": int(getattr(s, "factorizations", 0))},
                                 {"normal": s.normal_impulse, "tangent": s.tangent_impulse, "claims": np.zeros(0)})
                else:   # (its step is its own: no copy; the judge judges its answer from its own copy)
                    normal, tangent, claims = call_plugin(problem, request["normal"], request["tangent"], asked)
                    reply = pack({"iterations": len(claims), "fallback": 0, "factorizations": 0},
                                 {"normal": normal, "tangent": tangent, "claims": claims})
            elif op == "status":   # (asked off the clock: what its calls left running)
                reply = pack({"left_running": list(_left_running())})
            else:
                reply = pack({"error": f"no such request {op!r}"})
        except BaseException as e:
            reply = pack({"error": _line(e), "traceback": _traceback(e)})
        conn.send_bytes(reply)


def _line(e):
    return str(e) if isinstance(e, InputError) else f"{type(e).__name__}: {e}"


def _traceback(e):
    """The contestant's own traceback, chain and all, as text (shown by dc's -v)."""
    import traceback
    return "".join(traceback.format_exception(e))


class ContestantTraceback(Exception):
    """The traceback of an error in a contestant's process, as it printed it: the cause of the
    judge's PluginError, so that -v shows the plug-in's own file and line."""

    def __str__(self):
        return "\n\n" + self.args[0]


# --- The judge's side -------------------------------------------------------------------------------

# The zygote: a fresh interpreter, started once per process that judges (before any contestant is
# asked for), with the solver imported; it forks each contestant on request. Not multiprocessing's
# fork server, whose children re-run the caller's __main__ (a user's script, a notebook's stdin).
_zygote = None   # (Popen, socket, the pid that started it)
_zygote_torch = False   # whether the zygote has imported torch
_registered = []        # stop_server, once registered to run at the end of the process


def zygote(fd):
    """The zygote's loop: for each request on the socket fd (a socket end passed with it), forks a
    contestant serving that end, and answers its pid; ends when the judge's end closes."""
    import socket
    from multiprocessing.connection import Connection
    from ..workers import die_with_parent
    die_with_parent()
    import deepcontact.solver.methods  # noqa: F401 (imported once here, not in every contestant)
    import deepcontact.warmstart.starts  # noqa: F401
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)   # (contestants are reaped by the kernel)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    judge = socket.socket(fileno=fd)
    while True:
        try:
            message, fds, _, _ = socket.recv_fds(judge, 16, 1)
        except OSError:
            return
        if message == b"t" and not fds:   # (torch, imported once here rather than in every contestant)
            import deepcontact.model.inference  # noqa: F401
            judge.sendall(struct.pack("<q", 0))
            continue
        if not message or not fds:
            return
        pid = os.fork()
        if pid == 0:
            judge.close()
            signal.signal(signal.SIGCHLD, signal.SIG_DFL)
            code = 0
            try:
                serve(Connection(fds[0]))
            except BaseException:
                code = 1
            os._exit(code)
        os.close(fds[0])
        judge.sendall(struct.pack("<q", pid))


def _zygote_socket(torch=False):
    """The judge's socket to its zygote, started at the first call; torch: with torch imported in
    it (for contestants that load a trained model), asked once."""
    global _zygote, _zygote_torch
    import socket
    import subprocess
    if _zygote is not None and _zygote[2] != os.getpid():   # (a fork's: its socket is its parent's to use)
        _zygote = None
    if _zygote is None or _zygote[0].poll() is not None:
        _zygote_torch = False
        ours, theirs = socket.socketpair()
        process = subprocess.Popen(
            [sys.executable, "-c", f"from deepcontact.evaluate.contestant import zygote; zygote({theirs.fileno()})"],
            pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL, stdout=sys.stderr.fileno()
            if _has_fileno(sys.stderr) else subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": os.pathsep.join(
                p for p in sys.path if p)})
        theirs.close()
        _zygote = (process, ours, os.getpid())
        # kept for the process's later calls (it holds nothing of theirs: it was started fresh), and
        # ended with the process, or by dc before it looks for what plug-ins left
        from ..leftovers import at_end
        if stop_server not in _registered:
            import atexit
            at_end(stop_server)
            atexit.register(stop_server)
            _registered.append(stop_server)
    if torch and not _zygote_torch:
        _zygote[1].sendall(b"t")
        _receive_exactly(_zygote[1], 8)
        _zygote_torch = True
    return _zygote[1]


def _fork(torch=False):
    """(pid, connection) of a new process forked by the zygote, waiting for its setup."""
    import socket
    from multiprocessing.connection import Connection
    ours, theirs = socket.socketpair()
    zygote_socket = _zygote_socket(torch)
    socket.send_fds(zygote_socket, [b"c"], [theirs.fileno()])
    theirs.close()
    pid = struct.unpack("<q", _receive_exactly(zygote_socket, 8))[0]
    return pid, Connection(ours.detach())


def _has_fileno(stream):
    try:
        stream.fileno()
        return True
    except (AttributeError, OSError, ValueError):
        return False


def stop_server():
    """Ends the zygote, if started (the command's own helper, not left for the end of dc to find)."""
    global _zygote
    if _zygote is None or _zygote[2] != os.getpid():
        _zygote = None
        return
    process, sock, _ = _zygote
    _zygote = None
    sock.close()
    try:
        process.wait(2.0)
    except Exception:
        process.kill()
        process.wait()


class Contestant:
    """One variant's start and method in a process of their own. `call` sends a request and
    returns (seconds, header, arrays), timed by the judge's clock around the whole exchange."""

    def __init__(self, label, name, start, method, spec=None, checkpoint=None, threads=1, networks=()):
        self.label = label
        made = _by_name(name, start)
        setup = {"name": name, "start": ("name", name) if made else ("object", pickle.dumps(start)),
                 "method": method, "spec": spec, "checkpoint": checkpoint, "threads": threads,
                 "path": list(sys.path), "networks": list(networks)}
        self.pid, self.conn = _fork(torch=bool(checkpoint))
        t0 = time.perf_counter()
        self.conn.send_bytes(pickle.dumps(setup))
        self.left_running = [0, 0]
        took, header, _ = self._answer(t0)
        # the judge's clock, not the contestant's own (which a plug-in may have replaced): its
        # import and construction together, with the start of its process
        self.setup_s = took
        self.traits = {k: bool(header["traits"].get(k)) for k in TRAITS}

    def call(self, request):
        data = pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL)
        t0 = time.perf_counter()
        self.conn.send_bytes(data)
        return self._answer(t0)

    def _answer(self, t0=None):
        try:
            data = self.conn.recv_bytes(ANSWER_MAX)
        except EOFError:
            raise PluginError(f"the variant {self.label!r}: its process ended during a call") from None
        except OSError as e:   # (an answer over ANSWER_MAX: "bad message length")
            raise PluginError(f"the variant {self.label!r}: its answer could not be read ({e}; at most "
                              f"{ANSWER_MAX >> 20} MiB)") from None
        seconds = time.perf_counter() - t0 if t0 is not None else 0.0
        header, arrays = unpack(data, f"the variant {self.label!r}")
        if "error" in header:
            raise PluginError(f"the variant {self.label!r}: {header['error']}") \
                from ContestantTraceback(str(header.get("traceback", "")))
        if "left_running" in header:
            self.left_running = [max(a, int(b)) for a, b in zip(self.left_running, header["left_running"])]
        return seconds, header, arrays

    def echo(self, request, points):
        """The null contestant's round trip for this request: the same request, read as a call
        reads it, answered at once (the transport's fixed cost for a call of its kind and size)."""
        return self.call({**request, "op": "echo", "points": points})[0]

    def status(self):
        """Asks, off the clock, what the contestant's calls left running (threads, processes):
        noticed in left_running, and ended with its process."""
        self.call({"op": "status"})

    def close(self):
        """Ends the process and everything it started (its group)."""
        try:
            self.conn.send_bytes(pickle.dumps({"op": "end"}))
        except OSError:
            pass
        try:
            os.killpg(self.pid, signal.SIGKILL)
        except OSError:
            pass
        self.conn.close()


def _receive_exactly(sock, n):
    data = b""
    while len(data) < n:
        part = sock.recv(n - len(data))
        if not part:
            raise PluginError("the contestants' zygote process ended")
        data += part
    return data


def _by_name(name, start):
    """Whether `start` is what make_starts makes for `name` (so the contestant makes it itself)."""
    from ..warmstart.starts import NAMES, STARTS, Checked, Remote
    if isinstance(start, Checked) and isinstance(start.start, Remote):
        return True
    if isinstance(start, Remote):
        return True
    if isinstance(start, Checked):
        return start.name == name and STARTS.resolved(name) is not None and \
            type(start.start).__module__ == getattr(STARTS.resolved(name), "__module__", None)
    return name in NAMES and type(start).__module__.startswith("deepcontact.")


def unanswered(problem):
    """The step's problem without the impulses recorded for it (what a contestant is sent)."""
    import dataclasses
    return dataclasses.replace(problem, normal_impulse=None, tangent_impulse=None)


def checked_answer(label, arrays, points):
    """A contestant's impulses (normal, tangent), checked by the judge: one finite value per
    contact point, no pull; PluginError naming `label` otherwise."""
    out = []
    for what in ("normal", "tangent"):
        a = arrays.get(what)
        if a is None or a.shape != (points,):
            raise PluginError(f"the variant {label!r} answered {what} impulses of shape "
                              f"{None if a is None else a.shape}; the step has {points} contact points, so ({points},)")
        if not np.all(np.isfinite(a)):
            raise PluginError(f"the variant {label!r} answered a non-finite {what} impulse")
        out.append(a)
    if np.any(out[0] < 0):
        raise PluginError(f"the variant {label!r} answered a negative normal impulse (a contact only pushes)")
    return out


class RemoteMethod:
    """A plug-in solver method in a contestant process, as a loop's solve_fn (the closed loop's,
    in the variant's own contestant; the studies', in one of its own): each solve a call timed
    here, the round trips' fixed cost (the echo of the same request just before it, and the
    call's own) noted (take_transport) to be subtracted from the step's time, the answer checked
    and judged here."""

    def __init__(self, name, contestant=None):
        from ..warmstart.starts import Builtin
        self.name = name
        self.contestant = contestant or Contestant(name, "builtin", Builtin(), name)
        self.pending = 0.0

    def solve(self, problem, start_n, start_t, settings):
        import dataclasses
        from ..solver.methods import check_plausible, judge
        n = problem.points
        request = {"op": "solve", "problem": pickle.dumps(unanswered(problem)),
                   "normal": np.asarray(start_n, np.float64), "tangent": np.asarray(start_t, np.float64),
                   "settings": settings}
        null = self.contestant.echo(request, n)
        took, header, arrays = self.contestant.call(request)
        self.pending += null + min(null, took)   # (the echo and the call's own round trip: neither is the method's)
        normal, tangent = checked_answer(self.contestant.label, arrays, n)
        check_plausible(self.name, problem, normal, tangent)
        judged = judge(problem, normal, tangent)
        return dataclasses.replace(judged, iterations=int(header["iterations"]), relaxation=settings.relaxation)

    def take_transport(self):
        """Seconds of round trips since the last call (a step's), to subtract from its time."""
        out, self.pending = self.pending, 0.0
        return out

    def close(self):
        self.contestant.close()
