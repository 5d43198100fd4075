"""What the closed loop's path through the contestants costs a step: the held-out thesis pile
(seed 1000, 100 circles) stepped by `closed_loop` with builtin, a plug-in start that gives back
exactly what builtin gives (`Same`, from a module of its own on the path) and builtin timed again
(the loop's A/A), each in a sandbox of its own, against the native loop (one call a step) in the
same run.

Per run: the native loop's median step, builtin's through the path, the path's cost a step
(`path_ms`: the median over the steps of builtin through the path less the native step), the
median charge of builtin's start in it (its calls' wall time less the null contestant's least round
trip over the run, or its CPU less the null's least CPU: contest/charge.py), the round trips a step
not charged (builtin's call and the null's: the transport taken out of its time), the judge's own
CPU a step over the native loop's (builtin alone stepped through the path, its two contestants
started and ended in it, against the native loop: the judge's side of the path alone, less noisy
than wall time on a shared machine), and the
ratios Same / builtin and builtin again / builtin of the median step (a start identical to builtin
should measure 1.00x). The reference trajectory is not what is measured: the native loop's own
trajectory stands in for it (the drift it gives is not read here).

--profile: the judge's side of one run under cProfile (its 25 largest by own time), after the table.
--doorbell N: the doorbell alone, N round trips between two bare processes, interleaved: a 16-byte
request and answer on a socket pair as the loop's path sends them (multiprocessing's Connection,
the judge polling before it reads) against an eventfd each way (the judge polling the eventfd);
the median and 90th percentile of each.

--pieces N: what the path's per-step work costs on one settled step of the pile (its step 250),
the way before (a Python tuple a contact key, the ctx pickled by the judge and unpickled by each
contestant) and the way now (keys matched as arrays, the ctx written into the arena and read out of
it), and the work both do (the world read out, the problem posed, the answer packed and checked),
each timed N times, interleaved, in this process: medians in microseconds. And the way an ordinary
start's steps after the first now take: the step written from the world (StepChannel.write_world:
the world read out, the problem posed, the keys matched, the visible ctx written, in one call).

--halves N: the judge's step alone, in this process, N rounds: the native loop (one call a step), a start
made in Python (an in-process start_fn handing back Box2D's warm start, no contestant) between the
native step's halves (pgs_pose, pgs_finish: what the closed loop takes), and the same start with the
step in pieces (PGSStepper's native=False: posed a second time in Python and in Box2D's own Step),
stepped in turn; each one's median CPU ms a step, and its median over the native step of the same round.

--instructions N: the judge's side counted in instructions, which the machine's load does not move
(valgrind's callgrind, its children not traced: the contestants' processes are not counted): this
script's own process stepping builtin through the path, then the native loop, each run twice, to
N and to 2N steps (at most the scene's); the difference over the N steps between, a step, and the
path's over the native loop's. Takes minutes (the judge runs about 50 times slower under valgrind).

--in-path N: the judge's pieces timed where they run, inside the path (builtin through it, as a run
above) and in the native loop, N runs of each: every piece's wall time at each call (a timer around
the function), the median over the steps from a third of the run on (the pile settled); then
the native halves in the path (pgs_pose + pgs_finish) against the native loop's one call
(pgs_step) over the same steps: what the path costs the native work itself. The pieces cost more
here than --pieces measures them alone (their data cold after the native step and the calls).

--calls N: builtin alone through the path, N runs, each call taken apart: its wall time and its
sandbox's CPU, builtin's and the null contestant's, and the two terms of its charge (the median of
each; the null's least over the run, the floors).

--pinned 1 (or any number but 0): the whole benchmark held to one CPU (the highest this process may use), its contestants'
sandboxes with it (they inherit it), as `taskset -c N` holds a command: each call to a contestant a
switch on one core, where unpinned the host's scheduler wakes it on the same core or the other, run
by run, and the call's time and CPU with it (docs/results/loop-path.md, "Held to one CPU"). The
protocol line says so.

Usage: python benchmarks/bench_loop_path.py [--steps 300] [--runs 3] [--seed 1000] [--count 100] [--profile 0]
       [--doorbell 0] [--pieces 0] [--halves 0] [--instructions 0] [--in-path 0] [--calls 0] [--pinned 0]
"""
import cProfile
import os
import pstats
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

from deepcontact.evaluate.closed_loop import _interleaved, closed_loop, run_loop
from deepcontact.evaluate.replay import variants, visible_context
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.simulate.pgs_loop import PGSStepper
from deepcontact.solver.settings import SolveSettings
from deepcontact.warmstart.starts import make_starts

sys.path.insert(0, str(Path(__file__).parent))
from common import arguments  # noqa: E402

SAME = textwrap.dedent("""
    from deepcontact.warmstart.starts import StartValue

    class Same:
        '''Box2D's warm start, given back from a plug-in: what builtin gives.'''
        def __call__(self, ctx):
            return StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), {})
    """)


def one_run(scene, steps, reference):
    """{start: LoopResult} of one closed loop of builtin and Same."""
    results = closed_loop(scene, make_starts(["builtin", "bench_same_start:Same"]), steps=steps, reference=reference)
    return {r.start: r for r in results}


def judge_cpu(scene, settings, steps):
    """The judge's CPU ms a step stepping builtin alone through the path (as closed_loop's
    _path_cost does: its contestant and the null contestant started, the steps, both ended)."""
    v = variants(make_starts(["builtin"]))[0]
    cpu = time.process_time()
    done = _interleaved(scene, [(v, settings, False)], steps)
    return (time.process_time() - cpu) / len(done[0][0].seconds) * 1e3


def calls(scene, settings, steps, runs):
    """--calls: builtin alone through the path, `runs` times; for each run the medians over the
    settled steps (from a third of the run on) of each call's wall time and its sandbox's CPU in it,
    builtin's and the null contestant's (the same request), the null's least of each over the run
    (the floors a call's charge is taken from: contest/charge.py), and the median charge's two
    terms, wall less the null's least wall and CPU less its least CPU (microseconds)."""
    from deepcontact.contest import charge
    seen, record = [], charge.StepCharges.record

    def recorded(self, kind, contestant, null):
        seen.append((*charge.in_call(contestant), *charge.in_call(null)))
        return record(self, kind, contestant, null)
    print(f"\neach call, builtin alone through the path, {runs} run(s) of {steps} steps (us; medians from a third "
          "of each run on)")
    print("| run | builtin wall | null wall | null's least wall | builtin CPU | null CPU | null's least CPU | "
          "charge's wall term | charge's CPU term |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    charge.StepCharges.record = recorded
    try:
        for k in range(runs):
            seen.clear()
            _interleaved(scene, [(variants(make_starts(["builtin"]))[0], settings, False)], steps)
            if not seen:
                print(f"| {k + 1} | (no calls: no step had a contact) |")
                continue
            a = np.array(seen) * 1e6
            wall, cpu, null_wall, null_cpu = (a[len(a) // 3:, i] for i in range(4))
            least_wall, least_cpu = a[:, 2].min(), a[:, 3].min()
            print(f"| {k + 1} | {np.median(wall):.0f} | {np.median(null_wall):.0f} | {least_wall:.0f} | "
                  f"{np.median(cpu):.0f} | {np.median(null_cpu):.0f} | {least_cpu:.0f} | "
                  f"{np.median(np.maximum(wall - least_wall, 0)):.0f} | {np.median(np.maximum(cpu - least_cpu, 0)):.0f} |",
                  flush=True)
    finally:
        charge.StepCharges.record = record


def native_run(scene, settings, steps):
    """(ms per step, the judge's CPU ms a step) of the native loop."""
    cpu = time.process_time()
    seconds = run_loop(scene, None, settings, steps, "builtin", report=False).seconds
    return seconds * 1e3, (time.process_time() - cpu) / len(seconds) * 1e3


def line(k, rows, judge, native, native_cpu):
    b, s = rows["builtin"], rows["bench_same_start:Same"]
    med = float(np.median(b.ms_per_step))
    again = float(np.median(b.ms_again)) if b.ms_again is not None else float("nan")
    charge, transport = float(np.median(b.predict_ms)), float(np.median(b.transport_ms))
    print(f"| {k} | {np.median(native):.3f} | {med:.3f} | {b.path_ms:.3f} | {charge:.3f} | {transport:.3f} | "
          f"{judge - native_cpu:.3f} | {float(np.median(s.ms_per_step)) / med:.3f} | {again / med:.3f} |", flush=True)


def doorbells(n):
    """{name: [round trip seconds]} of n round trips each way, interleaved in blocks of 100."""
    import select
    import socket
    import time
    from multiprocessing.connection import Connection
    ours, theirs = socket.socketpair()
    conn, their_conn = Connection(ours.detach()), Connection(theirs.detach())
    ring, back = os.eventfd(0), os.eventfd(0)
    child = os.fork()
    if child == 0:   # (the contestant: answers whichever bell rings)
        poller = select.poll()
        poller.register(their_conn.fileno(), select.POLLIN)
        poller.register(ring, select.POLLIN)
        while True:
            for fd, _ in poller.poll():
                if fd == ring:
                    os.eventfd_read(ring)
                    os.eventfd_write(back, 1)
                else:
                    data = their_conn.recv_bytes()
                    if data == b"end":
                        os._exit(0)
                    their_conn.send_bytes(data)
    times = {"socket pair": [], "eventfd": []}
    request = bytes(16)
    for _ in range(max(n // 100, 1)):
        for _ in range(100):
            t = time.perf_counter()
            conn.send_bytes(request)
            conn.poll(60)
            conn.recv_bytes()
            times["socket pair"].append(time.perf_counter() - t)
        for _ in range(100):
            t = time.perf_counter()
            os.eventfd_write(ring, 1)
            select.select([back], [], [], 60)
            os.eventfd_read(back)
            times["eventfd"].append(time.perf_counter() - t)
    conn.send_bytes(b"end")
    os.waitpid(child, 0)
    return times


def settled_step(scene, k):
    """(bodies, contacts, problem) of step k of the loop, as its start_fn is handed them, and the world."""
    from deepcontact.simulate import stepping
    from deepcontact.simulate.engines import Box2D
    from deepcontact.simulate.pgs_loop import PGSStepper
    caught = []

    def start_fn(bodies, contacts, problem, builtin_n, builtin_t):
        problem.start_normal, problem.start_tangent = builtin_n, builtin_t
        caught.append((bodies, contacts, problem))
        return builtin_n, builtin_t
    engine = Box2D(solver=SolveSettings(), start="builtin", start_fn=start_fn)
    world = engine.build(scene)
    stepper = PGSStepper(world, scene, engine.solver, "builtin", start_fn=start_fn, record=False)
    for _ in stepping.steps(world, scene, stepper.step, k):
        pass
    return (*caught[-1], world)


def pieces(scene, n):
    """{piece: [seconds]} of the path's per-step work, before and now, on one settled step."""
    import pickle

    from deepcontact.contest.arena import Mapped, StepChannel
    from deepcontact.contest.keyed import KeyedImpulses, KeySet
    from deepcontact.solver.problem import contact_keys, impulses_by_key
    from deepcontact.warmstart.starts import StepContext, described
    from deepcontact.contest.wire import checked_answer, pack, unpack
    from deepcontact.solver.problem import StepProblem
    bodies, contacts, problem, world = settled_step(scene, 250)
    traits = described("builtin")
    keys = contact_keys(contacts)
    known, keyset = set(keys), KeySet(problem.keys)
    normal, tangent = problem.start_normal.astype(np.float64), problem.start_tangent.astype(np.float64)

    def ctx(previous, persisted):
        return visible_context(StepContext(problem=problem, bodies=bodies, contacts=contacts, reference=None,
                                           persisted=persisted, previous=previous, index=250, variant="builtin",
                                           trajectory="loop"), traits, "builtin")
    persisted = np.zeros(problem.points, bool)
    before = ctx(impulses_by_key(keys, normal, tangent), persisted)
    now = ctx(KeyedImpulses(problem.keys, normal, tangent), persisted)
    channel, mapped = StepChannel(False), Mapped()
    channel.write(now)
    schema, fds = channel.setup_for("bench")
    mapped.setup(pickle.loads(schema), fds)

    def matched():
        keys = np.ascontiguousarray(problem.keys)
        return keyset.find(keys), KeySet(keys), KeyedImpulses(keys, normal, tangent)
    work = {
        "before: keys as tuples (persisted, previous by key)": lambda: (
            np.array([k in known for k in contact_keys(contacts)], bool), impulses_by_key(keys, normal, tangent)),
        "now: keys as arrays (persisted, previous by key)": matched,
        "before: the ctx pickled (judge)": lambda: pickle.dumps({"op": "start", "ctx": before},
                                                                protocol=pickle.HIGHEST_PROTOCOL),
        "now: the ctx written into the arena (judge)": lambda: channel.write(now),
    }
    previous = KeyedImpulses(problem.keys, normal, tangent)
    # (the bodies and contacts read out, the problem posed, the keys matched, the ctx made visible
    # and written: the steps after the first, in one call)
    work["now: the step written from the world (judge)"] = lambda: channel.write_world(world, np.float32(1.0), problem.keys, previous, (250, 0))
    data = work["before: the ctx pickled (judge)"]()
    work["before: the ctx unpickled (each contestant)"] = lambda: pickle.loads(data)
    work["now: the ctx read out of the arena (each contestant)"] = lambda: mapped.context(channel.write(now))
    answer = pack({"seconds": {}, "seq": 1}, {"normal": normal, "tangent": tangent})
    work.update({   # (the same both ways: what else the judge's side of a step does in Python)
        "both: the bodies read out of the world": world.bodies,
        "both: the contacts read out of the world": world.contacts,
        "both: the problem posed (as the loop poses it)": lambda: StepProblem._from_world(
            bodies, contacts, dt=scene.dt, gravity=scene.effects.gravity, block_solve=scene.solver.block_solve,
            velocity_iterations=8),
        "both: the ctx as the start may see it (visible_context)": lambda: ctx(None, None),
        "both: the answer packed (each contestant)": lambda: pack({"seconds": {}, "seq": 1},
                                                                  {"normal": normal, "tangent": tangent}),
        "both: the answer read and checked (judge)": lambda: checked_answer("b", unpack(answer, "b")[1],
                                                                            problem.points),
    })
    times = {name: [] for name in work}
    for _ in range(n):
        for name, fn in work.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    # (reading includes a write: the write's median taken out)
    reading = "now: the ctx read out of the arena (each contestant)"
    times[reading] = list(np.array(times[reading]) - np.median(times["now: the ctx written into the arena (judge)"]))
    channel.close()
    print(f"\none settled step (250) of the pile: {problem.points} contact points, {len(data):,} bytes pickled")
    for name, t in times.items():
        print(f"{name:56s} {np.median(t) * 1e6:8.1f} us")


def halves(scene, settings, rounds):
    """The judge's step alone, three ways, stepped in turn (see --halves)."""
    def builtin(bodies, contacts, problem, builtin_n, builtin_t):
        return builtin_n, builtin_t
    ways = {"the native loop": PGSStepper(build_world(scene), scene, settings, record=False, residual=True),
            "a start made between the halves": PGSStepper(build_world(scene), scene, settings, start_fn=builtin,
                                                          record=False, residual=True),
            "the same start, the step in pieces": PGSStepper(build_world(scene), scene, settings, start_fn=builtin,
                                                             record=False, residual=True, native=False)}
    times = {name: [] for name in ways}
    for _ in range(min(rounds, scene.steps)):
        for name, stepper in ways.items():
            t = time.thread_time()
            stepper.step()
            times[name].append(time.thread_time() - t)
    native = np.array(times["the native loop"])
    print(f"\nthe judge's step alone, {len(native)} rounds (CPU ms a step: median; median over the native step)")
    for name, t in times.items():
        print(f"{name:38s} {np.median(t) * 1e3:7.3f} {np.median(np.array(t) - native) * 1e3:7.3f}")


# The judge's pieces --in-path times: (module, attribute) of each function on the path's step
IN_PATH = (("deepcontact.simulate.pgs_loop", "pgs_pose"), ("deepcontact.simulate.pgs_loop", "pgs_finish"),
           ("deepcontact.simulate.pgs_loop", "pgs_step"), ("deepcontact.simulate.pgs_loop", "_builtin"),
           ("deepcontact.simulate.pgs_loop", "start_impulses"),
           ("deepcontact.simulate.pgs_loop", "PGSStepper._posed_step"),
           ("deepcontact.simulate.pgs_loop", "StepProblem._from_world"),
           ("deepcontact.evaluate.closed_loop", "_Adapter.__call__"),
           ("deepcontact.evaluate.closed_loop", "_Adapter.from_world"),
           ("deepcontact.contest.arena", "StepChannel.write_world"),
           ("deepcontact.evaluate.closed_loop", "visible_context"),
           ("deepcontact.evaluate.closed_loop", "checked_answer"),
           ("deepcontact.contest.arena", "StepChannel.write"), ("deepcontact.contest.client", "Contestant.call_step"),
           ("deepcontact.contest.keyed", "KeySet.find"))


def in_path(scene, settings, steps, runs):
    """({piece: [seconds at each call]}, [(the posed step, its native halves, its calls to
    contestants) in seconds, a step]) of the judge's pieces, in the path and in the native loop
    (IN_PATH's functions wrapped by a timer for the runs, then put back)."""
    import importlib
    times, put_back, per_step = {}, [], []
    inner = {"pgs_pose": "native", "pgs_finish": "native", "Contestant.call_step": "calls"}
    within = {"native": 0.0, "calls": 0.0}   # (the posed step's so far: it calls the others)

    def timed(owner, name, label):
        raw = vars(owner)[name]   # (what is put back: a classmethod as one)
        # (a classmethod's own function, its class passed on: a subclass's call stays the subclass's)
        call = raw.__func__ if isinstance(raw, classmethod) else getattr(owner, name)

        def wrapper(*args, **kw):
            t = time.perf_counter()
            try:
                return call(*args, **kw)
            finally:
                took = time.perf_counter() - t
                times.setdefault(label, []).append(took)
                if label in inner:
                    within[inner[label]] += took
                elif label == "PGSStepper._posed_step":
                    per_step.append((took, within["native"], within["calls"]))
                    within.update(native=0.0, calls=0.0)
        put_back.append((owner, name, raw))
        setattr(owner, name, classmethod(wrapper) if isinstance(raw, classmethod) else wrapper)

    try:
        for module, path in IN_PATH:
            owner = importlib.import_module(module)
            *outer, name = path.split(".")
            for part in outer:
                owner = getattr(owner, part)
            timed(owner, name, path)
        builtin = variants(make_starts(["builtin"]))[0]
        for _ in range(runs):
            _interleaved(scene, [(builtin, settings, False)], steps)
            run_loop(scene, None, settings, steps, "builtin", report=False)
    finally:
        for owner, name, raw in reversed(put_back):
            setattr(owner, name, raw)
    return times, per_step


def in_path_table(measured, steps, runs):
    """Prints --in-path's table: each piece's median a call over the settled steps, then the
    judge's own work a step (the posed step less its native halves and its calls, step by step)."""
    times, per_step = measured

    def settled(t):
        t = np.asarray(t)
        per_run = len(t) // runs if runs else 0
        if per_run == 0:
            return t[:0]
        return np.concatenate([t[k * per_run:][per_run // 3:per_run] for k in range(runs)])
    print(f"\nthe judge's pieces where they run, {runs} run(s) of {steps} steps each way (median us a call, "
          "from a third of each run on)")
    for label in sorted(times, key=lambda k: -np.median(settled(times[k])) if len(settled(times[k])) else 0):
        print(f"{label:40s} {np.median(settled(times[label])) * 1e6:9.1f}  ({len(times[label]):,} calls)")
    halves = settled(times.get("pgs_pose", []))[:len(settled(times.get("pgs_finish", [])))] + \
        settled(times.get("pgs_finish", []))
    native = settled(times.get("pgs_step", []))
    n = min(len(halves), len(native))
    if n:
        print(f"the native halves in the path {np.median(halves[:n]) * 1e6:.1f} us against the native loop's "
              f"step {np.median(native[:n]) * 1e6:.1f} us: {np.median(halves[:n]) / np.median(native[:n]):.3f}x")
    rows = settled(np.array(per_step).reshape(-1, 3))
    if len(rows):
        own = rows[:, 0] - rows[:, 1] - rows[:, 2]
        print(f"the judge's own work a step in the path (the posed step less its native halves and its calls, "
              f"step by step): median {np.median(own) * 1e6:.1f} us, quartiles {np.percentile(own, 25) * 1e6:.1f}-"
              f"{np.percentile(own, 75) * 1e6:.1f} us ({len(own)} steps)")


def instructions(seed, count, n):
    """{"path", "native"}: instructions a step of this process over its steps n to 2n (callgrind);
    None where valgrind is not installed."""
    import shutil
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        return None
    out = {}
    for way in ("path", "native"):
        counted = []
        for steps in (n, 2 * n):
            proc = subprocess.run([valgrind, "--tool=callgrind", "--callgrind-out-file=/dev/null",
                                   os.path.realpath(sys.executable), __file__, "--judge-only", way, str(seed), str(count),
                                   str(steps)], capture_output=True, text=True, env=dict(os.environ, PYTHONHASHSEED="0"))
            found = [line for line in proc.stderr.splitlines() if "Collected :" in line]
            if proc.returncode != 0 or not found:
                sys.exit(f"callgrind failed ({way}, {steps} steps):\n{proc.stderr[-2000:]}")
            counted.append(int(found[-1].split(":")[-1].strip()))
        out[way] = (counted[1] - counted[0]) / n
    return out


def judge_only(way, seed, count, steps):
    """The process --instructions counts: builtin through the path, or the native loop."""
    scene = generate("pile", seed, {"count": count} if count != 100 else None)
    if way == "path":
        _interleaved(scene, [(variants(make_starts(["builtin"]))[0], SolveSettings(), False)], steps)
    else:
        run_loop(scene, None, SolveSettings(), steps, "builtin", report=False)


def main():
    if sys.argv[1:2] == ["--judge-only"]:
        way, seed, count, steps = sys.argv[2], *map(int, sys.argv[3:6])
        return judge_only(way, seed, count, steps)
    args = arguments(__doc__, steps=300, runs=3, seed=1000, count=100, profile=0, doorbell=0, pieces=0, halves=0,
                     instructions=0, in_path=0, calls=0, pinned=0)
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    if args.doorbell:
        for name, t in doorbells(args.doorbell).items():
            us = np.array(t) * 1e6
            print(f"{name}: round trip median {np.median(us):.1f} us, p90 {np.percentile(us, 90):.1f} us ({len(us)})")
    folder = tempfile.mkdtemp(prefix="bench-loop-path-")
    Path(folder, "bench_same_start.py").write_text(SAME)
    sys.path.insert(0, folder)
    os.environ["PYTHONPATH"] = os.pathsep.join([folder, *filter(None, [os.environ.get("PYTHONPATH")])])
    scene = generate("pile", args.seed, {"count": args.count} if args.count != 100 else None)
    steps = min(args.steps, scene.steps)
    if args.pieces:
        pieces(scene, args.pieces)
    settings = SolveSettings()
    if args.halves:
        halves(scene, settings, args.halves)
    if args.in_path:
        in_path_table(in_path(scene, settings, steps, args.in_path), steps, args.in_path)
    if args.calls:
        calls(scene, settings, steps, args.calls)
    if args.instructions:
        n = min(args.instructions, scene.steps // 2)
        counts = instructions(args.seed, args.count, n)
        if counts is None:
            print("\n--instructions: not counted, no valgrind here (Debian's valgrind package)")
        else:
            print(f"\nthe judge's process, instructions a step over steps {n} to {2 * n} (callgrind): through the path "
                  f"{counts['path']:,.0f}, the native loop {counts['native']:,.0f}; the path's over the native loop's "
                  f"{counts['path'] - counts['native']:,.0f}")
    reference = run_loop(scene, None, settings, steps, "builtin", report=False)
    print(f"\nthe pile of seed {args.seed}, {args.count} circles, {steps} steps, {settings.tolerance:g} tolerance")
    print("| run | native ms/step | builtin through the path | path_ms | of which builtin's charge | round trips "
          "(ms a step) | judge's CPU over native (ms a step) | Same / builtin | builtin again / builtin |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for k in range(args.runs):
        native, native_cpu = native_run(scene, settings, steps)
        line(k + 1, one_run(scene, steps, reference), judge_cpu(scene, settings, steps), native, native_cpu)
    if args.profile:
        profiler = cProfile.Profile()
        profiler.enable()
        one_run(scene, steps, reference)
        profiler.disable()
        pstats.Stats(profiler).sort_stats("tottime").print_stats(25)
        pstats.Stats(profiler).sort_stats("cumulative").print_stats("pgs_loop|closed_loop|arena|client|methods|problem|world|replay|keyed|wire", 40)
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())


if __name__ == "__main__":
    main()
