"""The contestant's side: a fresh interpreter in its sandbox (sandbox.py), started by the judge as
`python -m deepcontact.contest.guest FD`, serving one variant on the socket FD.

It imports the solver, says it is ready (the judge then reads its CPU clock), receives its setup,
makes the start and method the setup names (that is its setup, charged to it), and answers
requests until the judge closes the socket. It answers only the calls a contestant is charged
for ("start", "solve"); the judge measures transport and counts what is left running itself.
A setup of {"null": True} makes the null contestant: no plug-in code, a start of zeros and a
solve that hands its start back, the judge's measure of transport.
"""
import os
import pickle
import signal
import sys
import time

import numpy as np

from .. import interrupts, plugins, protocol
from ..errors import InputError
from ..model.arch import NETWORKS
from ..plugins import PluginError, guest
from ..simulate.engines import ENGINES, Engine
from ..solver import methods
from ..solver.methods import call_plugin, is_native, solve
from ..warmstart.starts import STARTS, TRAITS, Checked, declared, make_starts
from . import arena
from .shape import ERROR_MOST, TRACEBACK_MOST
from .wire import pack


def _parameters(factory):
    import inspect
    try:
        return inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return {}


def _make(setup):
    """The start made from the setup's names (and the method made, where a plug-in). What its ctx
    holds is the judge's to decide, from its own description (starts.described): nothing this
    process or its start says of itself is asked."""
    for name in setup["networks"]:   # (the checkpoint's plug-in network, which the user named with --arch)
        NETWORKS.load(name)
    kind, what = setup["start"]
    if kind == "name":
        factory = STARTS.load(what)
        if not methods.is_native(setup["method"]):
            methods.SOLVERS.load(setup["method"])
        predictor = None
        if getattr(factory, "needs_model", False) or "predictor" in _parameters(factory):
            from ..model.inference import Predictor   # (torch: paid only where a model is asked for)
            predictor = Predictor(setup["checkpoint"], threads=setup["threads"]) if setup["checkpoint"] else None
            if predictor is not None:
                predictor.build()   # (at setup, charged to it: not in its first call)
        start = make_starts([what], spec=setup["spec"], predictor=predictor)[what]
    else:
        start = pickle.loads(what)
    if not methods.is_native(setup["method"]):
        methods.method(setup["method"])
    # Every start, built-in or plug-in, is called through the same guard, so that a plug-in handing
    # back exactly a built-in's values costs what the built-in costs (the guard is about 9 us a
    # call). Its step is its own already, unpickled for each call: no private copy; its answer is
    # checked by the judge, off its clock, not here on it.
    inner = start.start if isinstance(start, Checked) else start
    what = f"the start {setup['name']!r}"

    def guarded(ctx):
        with guest(what):
            return inner(ctx)
    return guarded


def _describe(names):
    """What a judge may know of these plug-ins (starts and methods, by name), loaded here: each
    start's traits (as its factory declares them: True or False) and origin, each method's origin
    and whether it takes a w. The judge checks every field of it as it comes (client.describe)."""
    out = {"starts": {}, "methods": {}}
    for name in names["starts"]:
        factory = STARTS.load(name)
        traits = {k: declared(factory, k, f"the start {name!r}") for k in TRAITS}
        traits["needs_model"] = traits["needs_model"] or "predictor" in _parameters(factory)
        out["starts"][name] = {"traits": traits, "origin": STARTS.origin(name)}
    for name in names["methods"]:
        factory = methods.SOLVERS.load(name)
        out["methods"][name] = {"origin": methods.method_origin(name),
                                "takes_relaxation": bool(getattr(factory, "takes_relaxation", False))}
    return out


def _line(e):
    return str(e) if isinstance(e, InputError) else f"{type(e).__name__}: {e}"


def _traceback(e):
    """The contestant's own traceback, chain and all, as text (shown by dc's -v)."""
    import traceback
    return "".join(traceback.format_exception(e))


def _error(e):
    """An error's answer, its line and traceback cut to what the judge reads (shape.ANSWER: the
    line's start, the traceback's innermost frames)."""
    return pack({"error": _line(e)[:ERROR_MOST], "traceback": _traceback(e)[-TRACEBACK_MOST:]})


def _send(conn, data):
    """An answer sent, this thread's CPU clock read first: the read makes the kernel account the
    CPU the thread has run since it was scheduled (its time reaches its control group at a
    scheduling event, a tick or such a read; the process's clock does not, where a CPU timer is
    armed: a `ulimit -t`). The judge reads the group as soon as the answer arrives: a call whose
    work was not yet there read as no CPU, a floor of 0 that every charge of the run then paid.
    (Another thread's time, a plug-in's own, is accounted at its own events, and charged all the
    same: in the call it reaches the group in, between calls spread over the run's steps
    (contest/charge.py), or at the end.)"""
    time.thread_time_ns()
    conn.send_bytes(data)


def _step(request):
    """A loop step's answer names its sequence number (the judge refuses any other)."""
    return {"seq": request["seq"]} if "seq" in request else {}


def _answer(op, request, setup, start):
    if setup.get("null"):   # (the judge's measure of transport: the request read, nothing done)
        if op == "solve":
            pickle.loads(request["problem"])
            return pack({"iterations": 0, "fallback": 0, "factorizations": 0},
                        {"normal": request["normal"], "tangent": request["tangent"], "claims": np.zeros(0)})
        n = request["ctx"].problem.points
        return pack({"seconds": {}, **_step(request)}, {"normal": np.zeros(n), "tangent": np.zeros(n)})
    if op == "start":
        value = start(request["ctx"])
        try:
            return pack({"seconds": {str(k): float(v) for k, v in dict(value.seconds or {}).items()}, **_step(request)},
                        {"normal": value.normal, "tangent": value.tangent})
        except (AttributeError, TypeError, ValueError) as e:
            raise PluginError(f"the start {setup['name']!r} must return a StartValue(normal, tangent, seconds): "
                              f"{type(e).__name__}: {e}") from None
    if op == "solve":
        # (a plug-in's claimed residuals come with every answer, alike on every call; a built-in's
        # trace the judge makes itself, from the same start, off the clock)
        problem, asked = pickle.loads(request["problem"]), request["settings"]
        if is_native(asked.accelerate):
            s = solve(problem, request["normal"], request["tangent"], settings=asked, final_residual=False)
            return pack({"iterations": int(s.iterations), "fallback": int(s.relaxation_fallback > 0),
                         "factorizations": int(getattr(s, "factorizations", 0))},
                        {"normal": s.normal_impulse, "tangent": s.tangent_impulse, "claims": np.zeros(0)})
        normal, tangent, claims = call_plugin(problem, request["normal"], request["tangent"], asked)
        return pack({"iterations": len(claims), "fallback": 0, "factorizations": 0},
                    {"normal": normal, "tangent": tangent, "claims": claims})
    return pack({"error": f"no such request {op!r}"})


def _quiet(name):
    """What a plug-in's helper thread or finalizer raises is one line naming it on dc's standard
    error, never a traceback (its answers are judged either way)."""
    import threading

    def say(line):   # (dc's standard error, which the sandbox's is: no log handler runs here)
        sys.stderr.write(line + "\n")
        sys.stderr.flush()

    def thread_hook(args):
        if args.exc_type is not SystemExit:
            say(f"dc: warning: the variant {name!r}: a thread it started raised {args.exc_type.__name__}: "
                f"{args.exc_value}")

    def unraisable_hook(u):
        say(f"dc: warning: the variant {name!r}: {u.exc_type.__name__} raised and ignored in "
            f"{getattr(u.object, '__qualname__', type(u.object).__name__)}: {u.exc_value}")
    threading.excepthook = thread_hook
    sys.unraisablehook = unraisable_hook


def serve(conn):
    """A contestant: says it is ready, makes what its setup names, then answers requests until
    the judge closes the connection."""
    # dc's rules for guests hold here too (a KeyboardInterrupt a plug-in raises is its own: no
    # stop signal reaches a contestant, which the judge ends itself)
    interrupts.install("dc contestant")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    plugins.contained = True
    _send(conn, pack({"ready": 1}))   # (its imports accounted before the judge starts its clock)
    setup = pickle.loads(conn.recv_bytes())
    _quiet(setup.get("name", "?"))
    sys.path[:0] = [p for p in setup["path"] if p not in sys.path]
    protocol.use_threads(setup["threads"])
    if "describe" in setup:   # (a description of plug-ins, for a judge that must not import them)
        try:
            _send(conn, pack({"described": _describe(setup["describe"])}))
        except BaseException as e:
            _send(conn, _error(e))
        return
    if "engine" in setup:   # (a plug-in engine: its worlds built and stepped here)
        serve_engine(conn, setup)
        return
    start = None
    try:
        if not setup.get("null"):
            start = _make(setup)
        _send(conn, pack({"built": 1}))
    except BaseException as e:
        _send(conn, _error(e))
        return
    def answer(request):
        # (each call at the threads the report states: a plug-in that imported torch, at its
        # import or in a call, got torch's per-core default)
        protocol.keep_threads()
        return _answer(request["op"], request, setup, start)
    _requests(conn, answer, arena.Mapped())


def _requests(conn, answer, mapped=None):
    """Answers each request on conn with answer(request) (an error it raises as an error answer)
    until the judge closes the connection. mapped: the loop's channels (arena.Mapped), where its
    steps come through shared memory: a channel's setup is answered by the step that follows it."""
    failed = None
    while True:
        try:
            data = conn.recv_bytes()
        except EOFError:
            return
        try:
            if failed is not None:
                raise failed
            if mapped is not None and data[:1] == arena.STEP:
                seq, ctx = mapped.context(data)
                request = {"op": "start", "ctx": ctx, "seq": seq}
            else:
                request = pickle.loads(data)
                if mapped is not None and request.get("op") == "arena":
                    failed = _set_up(conn, mapped, request)
                    continue
            reply = answer(request)
        except BaseException as e:
            failed, reply = None, _error(e)
        _send(conn, reply)


def _set_up(conn, mapped, request):
    """A channel set up from its schema and the descriptors that follow it; None, or the error to
    answer the next request with."""
    import socket
    try:
        if mapped.socket is None:
            mapped.socket = socket.socket(fileno=os.dup(conn.fileno()))
        _, fds, _, _ = socket.recv_fds(mapped.socket, 1, 4)
        mapped.setup(request, fds)   # (which closes them)
    except BaseException as e:
        return e
    return None


def _engine_made(name, settings):
    """The plug-in engine `name` made from its settings, and its description for the judge."""
    import math
    cls = ENGINES.load(name)
    what = f"the engine {name!r}"
    if not (isinstance(cls, type) and issubclass(cls, Engine)):
        raise PluginError(f"{what} is not a deepcontact Engine (a subclass of deepcontact.simulate.engines.Engine)")
    with guest(what):
        engine = cls.from_settings(**settings)
        version, made = str(cls.version()), engine.settings()
    values = {}
    for k, v in dict(made).items():
        if not (isinstance(k, str) and (isinstance(v, (str, bool, int)) or (isinstance(v, float) and math.isfinite(v)))):
            raise PluginError(f"{what}'s settings hold {k!r}: {v!r}, not a name and a finite number or text")
        values[k] = v
    described = {"name": str(engine.name or ""), "label": str(engine.label or engine.name or ""), "rows": engine.rows,
                 "version": version, "settings": values,
                 "flags": {f: bool(getattr(engine, f, False)) for f in ("poses_box2d_problem", "continuous", "sleeps",
                                                                        "block_solve", "rests_in_skin")}}
    return engine, described


def _packed_step(what, done):
    """A step's arrays and account, as an answer (checked: tables of arrays, finite stats)."""
    import math
    bodies, contacts = getattr(done, "bodies", None), getattr(done, "contacts", None)
    if not (isinstance(bodies, dict) and isinstance(contacts, dict)):
        raise PluginError(f"{what} returned no bodies and contacts from a step (a LoopStep of both, as dicts of arrays)")
    arrays, layout = {}, {}
    for table, fields in (("bodies", bodies), ("contacts", contacts)):
        for field, a in fields.items():
            a = np.asarray(a)
            if a.dtype.kind not in "biuf":
                raise PluginError(f"{what} returned {table}.{field} of {a.dtype}, not numbers")
            arrays[f"{table}.{field}"] = a.astype(np.float64).ravel()
            layout[f"{table}.{field}"] = [a.dtype.name, list(a.shape)]
    stats = {}
    for k, v in dict(getattr(done, "engine_stats", None) or {}).items():
        if isinstance(v, float) and not math.isfinite(v):
            raise PluginError(f"{what}'s account of its step: {k}: the value {v!r} is not finite")
        stats[str(k)] = v if isinstance(v, (str, bool, int, float)) else str(v)
    deepest, ratio = float(getattr(done, "deepest", 0.0) or 0.0), getattr(done, "dt_ratio", None)
    header = {"layout": layout, "stats": stats, "deepest": deepest if math.isfinite(deepest) else 0.0}
    if ratio is not None:   # (none: the loop's own, 0 on the first step, as in a caller's process)
        header["dt_ratio"] = float(ratio) if math.isfinite(float(ratio)) else 1.0
    return pack(header, arrays)


def serve_engine(conn, setup):
    """A plug-in engine's sandbox: describes it, then builds one world and steps it on request."""
    name = setup["engine"]
    what = f"the engine {name!r}"
    try:
        engine, described = _engine_made(name, setup["settings"])
        _send(conn, pack({"engine": described}))
    except BaseException as e:
        _send(conn, _error(e))
        return
    state = {}   # (its world and step function, once built)

    def answer(request):
        with guest(what):
            if request["op"] == "build":
                scene = pickle.loads(request["scene"])
                engine.check(scene, request.get("source"))
                state["world"] = engine.build(scene, request.get("source"))
                state["step"] = engine.stepper(state["world"], scene, record=True)
                return pack({"built": 1})
            if request["op"] == "step":
                return _packed_step(what, state["step"]())
            if request["op"] == "remove":
                state["world"].remove_body(request["index"])
                return pack({"built": 1})
            return pack({"error": f"no such request {request['op']!r}"})
    _requests(conn, answer)


def main(argv):
    from multiprocessing.connection import Connection
    """The contestant's process: argv [_, FD] or [_, FD, "torch"] (torch imported before "ready")."""
    conn = Connection(int(argv[1]))
    if len(argv) > 2 and argv[2] == "torch":   # (a contestant that loads a trained model: torch imported before its clock)
        import deepcontact.model.inference  # noqa: F401
    code = 0
    try:
        serve(conn)
    except BaseException:
        code = 1
    sys.stdout.flush()
    os._exit(code)

