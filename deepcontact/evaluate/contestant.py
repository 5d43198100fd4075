"""Contestants out of the judge's reach: each variant's start and solver method run in a process
of their own, and the judge times and judges every call from its side.

A contestant process is forked from multiprocessing's fork server, a fresh interpreter started
before any run is read: it holds none of the judge's memory (no reference solution, no recorded
answer, no other variant's state), and nothing it does (patching the clock, walking the stack,
keeping a memo or a cache, starting threads) reaches the judge or another variant. Its start and
method are made there, from their names, and the time that takes (import, construction) is
reported beside the per-step times. The judge sends each request (pickled: the judge's own data)
and reads each answer as plain JSON and float64 arrays, never unpickled, so an answer is data,
not code. Every call is timed by the judge's clock around the request and its answer; the same
request answered by the process's null contestant (an echo of the same size) measures the
transport, which is subtracted and reported.
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
    """(start, method name, traits, import s, construct s) made from the setup's names."""
    from ..solver import methods
    from ..warmstart.starts import STARTS, asks, make_starts
    t0 = time.perf_counter()
    for name in setup["networks"]:   # (the checkpoint's plug-in network, which the user named with --arch)
        from ..model.arch import NETWORKS
        NETWORKS.load(name)
    kind, what = setup["start"]
    if kind == "name":
        factory = STARTS.load(what)
        if not methods.is_native(setup["method"]):
            methods.SOLVERS.load(setup["method"])
    t1 = time.perf_counter()
    if kind == "name":
        predictor = None
        if getattr(factory, "needs_model", False) or "predictor" in _parameters(factory):
            from ..model.inference import Predictor
            predictor = Predictor(setup["checkpoint"], threads=setup["threads"]) if setup["checkpoint"] else None
        start = make_starts([what], spec=setup["spec"], predictor=predictor)[what]
    else:
        start = pickle.loads(what)
    if not methods.is_native(setup["method"]):
        methods.method(setup["method"])
    t2 = time.perf_counter()
    traits = {k: bool(asks(setup["name"], start, k)) for k in TRAITS}
    return start, traits, t1 - t0, t2 - t1


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


def serve(conn, setup):
    """A contestant process: makes the start and method, then answers requests until "end"."""
    os.setsid()   # (its own group: whatever it starts is killed with it)
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # (the judge handles the user's stop, and ends it)
    sys.path[:0] = [p for p in setup["path"] if p not in sys.path]
    from .. import protocol
    from ..solver.methods import solve
    protocol.use_threads(setup["threads"])
    try:
        start, traits, imported, made = _make(setup)
        conn.send_bytes(pack({"import_s": imported, "construct_s": made, "traits": traits}))
    except BaseException as e:
        conn.send_bytes(pack({"error": _line(e)}))
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
                reply = pack({"seconds": {str(k): float(v) for k, v in dict(value.seconds).items()}},
                             {"normal": value.normal, "tangent": value.tangent})
            else:   # "solve"
                s = solve(pickle.loads(request["problem"]), request["normal"], request["tangent"],
                          settings=request["settings"], final_residual=False, history=request.get("history", False))
                claims = s.history[:, 0] if request.get("history") and len(s.history) else np.zeros(0)
                reply = pack({"iterations": int(s.iterations), "fallback": int(s.relaxation_fallback > 0),
                              "factorizations": int(getattr(s, "factorizations", 0))},
                             {"normal": s.normal_impulse, "tangent": s.tangent_impulse, "claims": claims})
            threads, processes = _left_running()
            if threads or processes:
                header, arrays = unpack(reply, "")
                reply = pack(dict(header, left_running=[threads, processes]), arrays)
        except BaseException as e:
            reply = pack({"error": _line(e)})
        conn.send_bytes(reply)


def _line(e):
    return str(e) if isinstance(e, InputError) else f"{type(e).__name__}: {e}"


# --- The judge's side -------------------------------------------------------------------------------

_context = None


def _server():
    """multiprocessing's fork server, started once per process with the solver imported."""
    global _context
    if _context is None:
        import multiprocessing
        _context = multiprocessing.get_context("forkserver")
        _context.set_forkserver_preload(["numpy", "deepcontact.evaluate.contestant", "deepcontact.solver.methods"])
    return _context


def stop_server():
    """Ends the fork server (and multiprocessing's resource tracker beside it), if started: the
    command's own helpers, not left for the end of the process to find."""
    global _context
    if _context is None:
        return
    import multiprocessing.forkserver as forkserver
    import multiprocessing.resource_tracker as resource_tracker
    for helper in (forkserver._forkserver, resource_tracker._resource_tracker):
        try:
            helper._stop()
        except Exception:   # (private in multiprocessing: a Python without it leaves it to the end of dc)
            pass
    _context = None


class Contestant:
    """One variant's start and method in a process of their own. `call` sends a request and
    returns (seconds, header, arrays), timed by the judge's clock around the whole exchange."""

    def __init__(self, label, name, start, method, spec=None, checkpoint=None, threads=1, networks=()):
        self.label = label
        made = _by_name(name, start)
        setup = {"name": name, "start": ("name", name) if made else ("object", pickle.dumps(start)),
                 "method": method, "spec": spec, "checkpoint": checkpoint, "threads": threads,
                 "path": list(sys.path), "networks": list(networks)}
        context = _server()
        self.conn, theirs = context.Pipe()
        self.process = context.Process(target=serve, args=(theirs, setup), daemon=True, name=f"dc contestant {label}")
        self.process.start()
        theirs.close()
        self.left_running = [0, 0]
        _, header, _ = self._answer()
        self.import_s, self.construct_s = float(header["import_s"]), float(header["construct_s"])
        self.traits = {k: bool(header["traits"].get(k)) for k in TRAITS}

    def call(self, request):
        data = pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL)
        t0 = time.perf_counter()
        self.conn.send_bytes(data)
        return self._answer(t0)

    def _answer(self, t0=None):
        try:
            data = self.conn.recv_bytes()
        except (EOFError, OSError):
            self.process.join(1.0)
            raise PluginError(f"the variant {self.label!r}: its process ended during a call (exit code "
                              f"{self.process.exitcode})") from None
        seconds = time.perf_counter() - t0 if t0 is not None else 0.0
        header, arrays = unpack(data, f"the variant {self.label!r}")
        if "error" in header:
            raise PluginError(f"the variant {self.label!r}: {header['error']}")
        if "left_running" in header:
            self.left_running = [max(a, int(b)) for a, b in zip(self.left_running, header["left_running"])]
        return seconds, header, arrays

    def close(self):
        """Ends the process and everything it started (its group)."""
        try:
            self.conn.send_bytes(pickle.dumps({"op": "end"}))
        except OSError:
            pass
        self.process.join(0.2)
        try:
            os.killpg(self.process.pid, signal.SIGKILL)
        except OSError:
            pass
        self.process.join(1.0)
        self.conn.close()


def _by_name(name, start):
    """Whether `start` is what make_starts makes for `name` (so the contestant makes it itself)."""
    from ..warmstart.starts import NAMES, STARTS, Checked
    if isinstance(start, Checked):
        return start.name == name and STARTS.resolved(name) is not None and \
            type(start.start).__module__ == getattr(STARTS.resolved(name), "__module__", None)
    return name in NAMES and type(start).__module__.startswith("deepcontact.")
