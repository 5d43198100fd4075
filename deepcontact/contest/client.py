"""The judge's side: a contestant in its sandbox, and one timed call that holds the charging rule.

A call costs the larger of its wall time (the judge's clock, around the request and its answer)
and the CPU time the contestant's sandbox used since its previous call ended (its control group:
every process and thread it runs, between calls too): what `call` returns (the studies' charge).
A contestant made with `unasked=True` (the loop's and replay's) has its group read once more just
before each request, so the CPU no call can have used (between calls: work left running; or
beyond what the threads it is granted could run in the call's wall time) is kept apart, `outside`,
to be spread over a run's steps (charge.py). Its setup (import and construction) is charged whole, from the moment it
said it was ready. Every call has a deadline; past it the
contestant is stopped and named. Transport is measured against the null contestant (the same
sandbox and path, no plug-in code: `Contestant.null()`), never by a contestant; what the
contestant left running is counted from its control group by the judge, never asked.
"""
import os
import pickle
import re
import select
import socket
import struct
import sys
import time

from ..plugins import PluginError
from ..solver.methods import SOLVERS, check_plausible, is_native, judge
from ..warmstart.starts import NAMES, STARTS, TRAITS, Builtin, Checked, Remote, described
from . import broker as _broker, grants, sandbox, shape
from .arena import FDS
from .charge import split_cpu
from .wire import ANSWER_MAX, checked_answer, held_claims, unanswered, unpack

SETUP_DEADLINE = 300.0   # seconds a contestant may take to start and make its start (torch, a model, on a busy machine)
CALL_FLOOR = 60.0        # seconds every call may take, at least
CALL_PER_POINT = 0.02    # and this many more per contact point of the step


def deadline_for(points):
    """The seconds a call on a step of `points` contact points may take before its contestant is
    stopped and named (stated in the report)."""
    return CALL_FLOOR + CALL_PER_POINT * max(int(points), 0)


def deadline_rule():
    """The deadline rule in words, for reports."""
    return f"{CALL_FLOOR:g} s + {1e3 * CALL_PER_POINT:g} ms per contact point a call; {SETUP_DEADLINE:g} s to set up"


def _path_for_guest():
    return [os.getcwd() if p == "" else os.path.abspath(p) for p in sys.path]


# --- One contestant -------------------------------------------------------------------------------

def packed(request):
    """A request's bytes, once, for every contestant it goes to (the variant's and the null's)."""
    return pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL)


class Contestant:
    """One variant's start and method in a sandbox of their own (sandbox.py). Made in two halves,
    so that several sandboxes start side by side: the constructor starts the sandbox, `begin()`
    sends the setup and charges it. `call` returns (charged seconds, header, arrays)."""

    def __init__(self, label, name, start=None, method="none", spec=None, checkpoint=None, threads=1, networks=(),
                 null=False, describe=None, engine=None, who=None, unasked=False):
        self.label, self.null_contestant = label, null
        self.who = who or f"the variant {label!r}"   # (how its errors name it)
        self.left_running = [0, 0]
        # unasked: the CPU of its last call's `last` that no call can have used (between calls:
        # work left running; or beyond what the threads it is granted could run in the call's wall
        # time), set apart, `outside` (charge.split_cpu); with its sum and the calls since its
        # setup. Only where it is spread: in a job, each read of its group asks the broker (tens
        # of microseconds)
        self.unasked = unasked
        self.outside, self.outside_s, self.calls = 0.0, 0.0, 0
        self.setup_s, self.setup_wall_s, self.start_s, self.after_s = 0.0, 0.0, 0.0, 0.0
        # what its ctx holds: the judge's one description of its start (starts.described), the same
        # that says whether it is an oracle; never what its process says of itself
        self.traits = dict.fromkeys(TRAITS, False)
        if engine is not None:   # (a plug-in engine: (its name, its settings); contest/engine.py)
            setup = {"engine": engine[0], "settings": engine[1], "name": engine[0], "path": _path_for_guest(),
                     "threads": 1}
            names, modules = [engine[0]], []
        elif describe is not None:
            setup = {"describe": describe, "path": _path_for_guest(), "threads": 1}
            names, modules = describe["starts"] + describe["methods"], []
        elif null:
            setup = {"null": True, "name": "null", "path": _path_for_guest(), "threads": 1}
            names, modules = [], []
        else:
            self.traits = described(name, start)
            made = _by_name(name, start)
            setup = {"name": name, "start": ("name", name) if made else ("object", pickle.dumps(start)),
                     "method": method, "spec": spec, "checkpoint": checkpoint, "threads": threads,
                     "path": _path_for_guest(), "networks": list(networks)}
            names = [name, method, *networks]
            modules = [] if made else [type(getattr(start, "start", start)).__module__]
        self._setup = setup
        # (the threads it is granted, on the CPUs it starts on: the judge's, which its sandbox inherits)
        self.cpus = max(min(len(os.sched_getaffinity(0)), int(setup["threads"])), 1)
        if grants.runs_plugin_code(names, modules):
            sandbox.refuse_bare(self.who, _broker.missing_fences())
        self.sandbox = _broker.new(grants.Grant(names, modules, [checkpoint] if checkpoint else []),
                                   threads=setup["threads"], name=self.who,
                                   profile="engine" if engine is not None else "contestant")
        from multiprocessing.connection import Connection
        ours, theirs = socket.socketpair()
        self._started = time.perf_counter()
        try:
            self.sandbox.start_guest(theirs.fileno(), torch=bool(checkpoint))
        except BaseException:
            ours.close()
            self.sandbox.kill()
            raise
        finally:
            theirs.close()
        self.conn = Connection(ours.detach())
        # (one poll object for its line: Connection.poll builds a selector each call, 7 us of
        # the loop's path twice a step)
        self._waiting = select.poll()
        self._waiting.register(self.conn.fileno(), select.POLLIN)
        self._begun = False

    @classmethod
    def null(cls):
        """The null contestant: the same sandbox and path, no plug-in code (the judge's measure of transport)."""
        return cls("(null)", "null", null=True).begin()

    def begin(self):
        """Waits for the sandbox, sends the setup and charges it; returns self."""
        if self._begun:
            return self
        self._begun = True
        try:
            self._receive(SETUP_DEADLINE, "starting")   # ("ready": the interpreter and the solver, before its clock)
            self.start_s = time.perf_counter() - self._started
            self.cpu_last = self.sandbox.cpu_seconds()
            self.baseline = self.sandbox.processes()
            self.setup_s, header, _ = self._timed(pickle.dumps(self._setup), SETUP_DEADLINE, "setting up")
            self.setup_wall_s = self._wall
            self.outside_s, self.calls = 0.0, 0   # (the setup's is in setup_s, charged whole)
        except BaseException:
            self.close()
            raise
        self.header = header
        return self

    def call(self, request, deadline=None):
        """Sends a request (a dict, or one already packed by `packed`); (seconds charged, header,
        arrays) of its answer, checked."""
        data = request if isinstance(request, bytes) else packed(request)
        return self._timed(data, deadline or CALL_FLOOR, "answering")

    def call_step(self, channel, request, deadline=None):
        """A loop step's start, its ctx written in `channel` (arena.StepChannel) and `request` the
        bytes its write returned: what this contestant lacks of the channel (its schema, its
        arenas' descriptors) sent first, in the call's time; (seconds charged, header, arrays) as
        `call`, the answer refused unless it names the step's sequence number."""
        schema, fds = channel.setup_for(self)
        took, header, arrays = self._timed(request, deadline or CALL_FLOOR, "answering", schema, fds)
        if header.get("seq") != channel.seq:
            self.close()
            raise PluginError(f"{self.who} answered step {header.get('seq')!r} of the loop when asked step "
                              f"{channel.seq} (it was stopped)")
        return took, header, arrays

    def _send_descriptors(self, fds):
        """Hands `fds` to the contestant over its socket (SCM_RIGHTS, with one byte)."""
        socket.send_fds(self._line(), [FDS], fds)

    def _timed(self, data, deadline, doing, before=None, fds=()):
        # (its CPU since its last answer, read before it is asked: work it did unasked, `outside`)
        sent = self.sandbox.cpu_seconds() if self.unasked else None
        t0 = time.perf_counter()
        try:
            if before is not None:   # (a step's arena set up: its schema, then its descriptors, maybe none)
                self.conn.send_bytes(before)
                self._send_descriptors(fds)
            self.conn.send_bytes(data)
        except OSError:
            self._ended(doing)
        finally:   # (ours to close, sent or not: the contestant holds its own copies)
            for fd in fds:
                os.close(fd)
        header, arrays = self._receive(deadline, doing)
        self._wall = time.perf_counter() - t0
        cpu = self.sandbox.cpu_seconds()
        used = 0.0 if cpu is None or self.cpu_last is None else cpu - self.cpu_last
        # (a read that failed before the request sets nothing apart as between calls; the bound holds)
        between = 0.0 if sent is None or cpu is None or self.cpu_last is None else \
            min(max(sent - self.cpu_last, 0.0), used)
        self.outside = split_cpu(used, between, self._wall, self.cpus)[1] if self.unasked else 0.0
        self.outside_s, self.calls = self.outside_s + self.outside, self.calls + 1
        if cpu is not None:   # (a read that failed: this call's CPU is charged to the next)
            self.cpu_last = cpu
        self.last = (self._wall, used)   # (both, for a loop's charge: charge.py)
        return max(self._wall, used), header, arrays

    def _receive(self, deadline, doing):
        try:
            data = self._message(time.monotonic() + max(deadline, 0))
        except TimeoutError:
            self.close()
            raise PluginError(f"{self.who} did not answer within {deadline:g} s while {doing} "
                              f"(its deadline: {deadline_rule()}); it was stopped") from None
        except (EOFError, ConnectionError):
            self._ended(doing)
        except OSError as e:   # (an answer over ANSWER_MAX: "bad message length")
            self.close()
            raise PluginError(f"{self.who}: its answer could not be read ({e}; at most "
                              f"{ANSWER_MAX >> 20} MiB)") from None
        header, arrays = unpack(data, self.who)
        if "error" in header:
            raise PluginError(said_by(self.who, self.label, header["error"])) \
                from ContestantTraceback(str(header.get("traceback", "")))
        return header, arrays

    def _message(self, end):
        """One message on its line, framed as Connection.send_bytes frames it (its length in 4
        bytes; -1 and then 8 where it is longer), whole by `end` (time.monotonic()), or
        TimeoutError: an answer begun and never finished is past its deadline too (recv_bytes
        would wait for its rest without end). OSError for a length over ANSWER_MAX."""
        self._wait(end)
        (size,) = struct.unpack("!i", self._read(4, end))
        if size == -1:
            (size,) = struct.unpack("!Q", self._read(8, end))
        if not 0 <= size <= ANSWER_MAX:
            raise OSError("bad message length")
        return self._read(size, end)

    def _wait(self, end):
        """Until its line is readable; TimeoutError where it is not by `end`."""
        if not self._waiting.poll(max(end - time.monotonic(), 0.0) * 1e3):
            raise TimeoutError

    def _read(self, n, end):
        """n bytes of its line, each part as it is there (never a read that blocks), the line
        waited for where none is, no later than `end`; EOFError where it ends first."""
        line, data = self._line(), bytearray(n)   # (read into: a large answer is not allocated again a part)
        view, at = memoryview(data), 0
        while at < n:
            try:
                got = line.recv_into(view[at:], n - at, socket.MSG_DONTWAIT)
            except BlockingIOError:
                self._wait(end)
                continue
            if not got:
                raise EOFError
            at += got
        return bytes(data)

    def _line(self):
        """Its line as a socket (a descriptor of its own: descriptors are sent on it, answers read)."""
        if getattr(self, "_socket", None) is None:
            self._socket = socket.socket(fileno=os.dup(self.conn.fileno()))
        return self._socket

    def _ended(self, doing):
        try:
            self.sandbox.process.wait(2)
        except Exception:
            pass
        how = self.sandbox.exit_description()
        self.close()
        raise PluginError(f"{self.who}: its process ended while {doing}"
                          + (f" ({how})" if how else "")) from None

    def status(self):
        """Counts, on the judge's side, what the contestant has running beyond what it had when
        ready (threads, processes): noticed in left_running, and ended with its sandbox."""
        now, base = self.sandbox.processes(), getattr(self, "baseline", None)
        if now is not None and base is not None:
            self.left_running = [max(a, b - c) for a, b, c in zip(self.left_running, now, base)]

    def close(self):
        """Ends the sandbox and everything in it; after_s: the CPU it used after its last call
        (work left running to the end), which its total is charged too."""
        cpu, last = self.sandbox.cpu_seconds(), getattr(self, "cpu_last", None)
        if cpu is not None and last is not None:
            self.after_s = max(self.after_s, cpu - last)
        # (killed before its line is closed: a guest that saw its line end first ended itself,
        # "exit status 0", where it was ended by the judge)
        self.sandbox.kill()
        for end in (self.conn, getattr(self, "_socket", None)):
            try:
                if end is not None:
                    end.close()
            except OSError:
                pass


def start_all(contestants):
    """Begins every contestant (their sandboxes started side by side); on a failure, closes them all."""
    try:
        for c in contestants:
            c.begin()
    except BaseException:
        for c in contestants:
            c.close()
        raise
    return contestants


# How dc's own lines in a contestant's process begin: "the start 'x' raised ...", "the solver method 'x' ..."
_NAMING = re.compile(r"the [a-z-]+(?: [a-z-]+){0,3} ")


def said_by(who, label, error):
    """A contestant's error line as the judge says it: its text (the contestant's own: what a
    terminal would act on, an escape sequence, shown escaped) after `who`, its name, unless the
    line begins by naming `label` (one of dc's own lines from its process, named once). A line
    that names it anywhere else (past the 600 characters a line shows, after blaming a rival) is
    the contestant's, and said as its."""
    text = "".join(c if c.isprintable() or c.isspace() else c.encode("unicode_escape").decode() for c in error)
    begins = _NAMING.match(text)
    return text if begins and text.startswith(repr(label), begins.end()) else f"{who}: {text}"


class ContestantTraceback(Exception):
    """The traceback of an error in a contestant's process, as it printed it: the cause of the
    judge's PluginError, so that -v shows the plug-in's own file and line."""

    def __str__(self):
        return "\n\n" + self.args[0]


def _by_name(name, start):
    """Whether `start` is what make_starts makes for `name` (so the contestant makes it itself)."""
    if isinstance(start, Checked) and isinstance(start.start, Remote):
        return True
    if isinstance(start, Remote):
        return True
    if isinstance(start, Checked):
        return start.name == name and STARTS.resolved(name) is not None and \
            type(start.start).__module__ == getattr(STARTS.resolved(name), "__module__", None)
    return name in NAMES and type(start).__module__.startswith("deepcontact.")


# What the judge decides from, as a plug-in's process describes it (guest._describe), every field
# typed before any of it is used: a start's traits are exactly the known names, each true or false
# (its ctx and whether it is an oracle follow from them: starts.described); an origin is text.
_ORIGIN = shape.Record({"origin": shape.Text(), "name": shape.Text(), "target": shape.Text(),
                        "distribution": shape.Maybe(shape.Text()), "version": shape.Maybe(shape.Text()),
                        "runs": shape.Text(choices=("native", "python"))}, required=("origin",))
_DESCRIBED = shape.Record({
    "starts": shape.Table(shape.Record({"traits": shape.Record({k: shape.Flag() for k in TRAITS}, required=TRAITS),
                                        "origin": _ORIGIN}, required=("traits", "origin")), most=shape.NAMES_MOST),
    "methods": shape.Table(shape.Record({"origin": _ORIGIN, "takes_relaxation": shape.Flag()},
                                        required=("origin", "takes_relaxation")), most=shape.NAMES_MOST),
}, required=("starts", "methods"))
shape.declare("plug-ins described", _DESCRIBED)


def describe(starts=(), methods=()):
    """Describes the plug-in starts and methods among these names from a sandbox of their own
    (their code is imported there, never in this process): fills STARTS.described and
    SOLVERS.described. PluginError naming one that cannot be loaded."""
    wanted = {"starts": [n for n in dict.fromkeys(starts) if n not in NAMES and n not in STARTS.described],
              "methods": [n for n in dict.fromkeys(methods) if not is_native(n) and n not in SOLVERS.described]}
    if not (wanted["starts"] or wanted["methods"]):
        return
    listed = ", ".join(wanted["starts"] + wanted["methods"])
    c = Contestant(listed, "describe", describe=wanted, who=f"the plug-ins {listed}")
    try:
        c.begin()
        found = c.header.get("described")
        for registry, kind in ((STARTS, "starts"), (SOLVERS, "methods")):
            for name in wanted[kind]:   # (every field typed as it came: _DESCRIBED, wire.unpack)
                if name not in (found or {}).get(kind, {}):
                    raise PluginError(f"the plug-in {name!r} was not described by its process")
                registry.described[name] = found[kind][name]
    finally:
        c.close()


class RemoteMethod:
    """A plug-in solver method in a contestant's sandbox, as a loop's solve_fn (the closed loop's,
    in the variant's own contestant; the studies', in one of its own): each solve a call charged
    here, the same request's round trip through the null contestant (take_transport) to be
    subtracted from the step's time, the answer checked and judged here. charges: the closed
    loop's StepCharges (charge.py), which then records each solve's round trips instead."""

    def __init__(self, name, contestant=None, null=None, charges=None):
        self.name = name
        self.contestant = contestant or Contestant(name, "builtin", Builtin(), name).begin()
        self.null, self._own_null = null, null is None
        if self.null is None:   # (started here, not in a step's time: its start would be the first step's)
            try:
                self.null = Contestant.null()
            except BaseException:
                if contestant is None:
                    self.contestant.close()
                raise
        self.pending, self.charges = 0.0, charges

    def solve(self, problem, start_n, start_t, settings):
        import dataclasses
        import numpy as np
        n = problem.points
        request = {"op": "solve", "problem": pickle.dumps(unanswered(problem)),
                   "normal": np.asarray(start_n, np.float64), "tangent": np.asarray(start_t, np.float64),
                   "settings": settings}
        took, header, arrays = self.contestant.call(request, deadline_for(n))
        null = self.null.call(request, deadline_for(n))[0]
        if self.charges is not None:
            self.charges.record("solve", self.contestant, self.null)
        else:   # (the CPU its call was charged beyond its wall time is added to the step: threads, or work
            # left running between calls, which the step's wall time does not hold)
            self.pending += min(null, took) - (took - self.contestant.last[0])
        normal, tangent = checked_answer(self.contestant.label, arrays, n, also=("claims",))
        held_claims(self.contestant.label, header, arrays, settings.max_iterations)   # (its iterations are recorded)
        check_plausible(self.name, problem, normal, tangent)
        judged = judge(problem, normal, tangent)
        return dataclasses.replace(judged, iterations=int(header.get("iterations", 0)), relaxation=settings.relaxation)

    def take_transport(self):
        """Seconds to subtract from a step's wall time since the last call: its solves' round trips
        (the null's), less the CPU they were charged beyond their wall times (negative where that
        is the more)."""
        out, self.pending = self.pending, 0.0
        return out

    def close(self):
        self.contestant.close()
        if self._own_null and self.null is not None:
            self.null.close()
