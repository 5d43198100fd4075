"""A judge no contestant can reach, II: each trick a contestant in a process of its own (same user,
same machine) used to move `dc evaluate`'s verdict, written here as a contestant, and what the
judge says of it now that each contestant runs in a sandbox the judge owns and is charged for
all the CPU it uses (deepcontact/contest)."""
import json
import re
import sys
import textwrap

import numpy as np
import pytest

from conftest import dc, plugin_modules
from deepcontact.contest import fences
from test_judge_reach import TRICKS   # (its Memo: solves each problem once, 4 ms late, then answers from a memo)

pytestmark = pytest.mark.skipif(not all(fences().values()),
                                reason=f"a contestant's fence is missing here: {fences()}")

HOSTILE = textwrap.dedent("""
    import json, os, signal, struct, time
    RUN = {run!r}
    import numpy as np
    from deepcontact.warmstart.starts import StartValue

    def box2d(ctx):
        return StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), {})

    class WorksInSetup:
        '''Burns 0.4 s of CPU while it is made (where it would solve the run ahead of the clock).'''
        def __init__(self):
            end = time.process_time() + 0.4
            while time.process_time() < end:
                pass
        def __call__(self, ctx):
            return box2d(ctx)

    class Detached:
        '''Answers at once, and leaves a process of its own session (double-forked: no longer its
        child) to burn 0.3 s of CPU in the background, where it would solve the next steps.'''
        started = False
        def __call__(self, ctx):
            if not Detached.started:
                Detached.started = True
                if os.fork() == 0:
                    os.setsid()
                    if os.fork() == 0:
                        end = time.process_time() + 0.3
                        while time.process_time() < end:
                            pass
                    os._exit(0)
                os.wait()
            return box2d(ctx)

    class Reacher:
        '''Looks for every process it could stop, renice or kill (a rival, the judge), and for the
        judge's memory; raises what it reached.'''
        def __call__(self, ctx):
            me, reached = os.getpid(), []
            for entry in os.listdir('/proc'):
                if entry.isdigit() and int(entry) not in (me, 1):   # (1: its sandbox's own first process)
                    try:
                        os.kill(int(entry), 0)          # (signal 0: only asks whether it could)
                        reached.append(f'could signal {entry}')
                    except OSError:
                        pass
            for pid in {os.getppid(), 1}:
                try:
                    with open(f'/proc/{pid}/mem', 'rb') as f:
                        f.read(1)
                    reached.append(f'read the memory of {pid}')
                except OSError:
                    pass
            try:
                os.setpriority(os.PRIO_USER, 0, 19)     # (renice every process of its user)
            except OSError:
                pass
            for path in (RUN + '/manifest.json', RUN, os.path.dirname(RUN)):   # (the run being judged, named here)
                if os.path.exists(path):
                    reached.append(f'found {path}')
            import ctypes, socket   # (a socket of its own reaches every listening one on the machine)
            try:
                socket.socket(socket.AF_UNIX).close()
                reached.append('made an AF_UNIX socket')
            except OSError:
                pass
            libc = ctypes.CDLL(None, use_errno=True)
            libc.syscall.restype = ctypes.c_long
            fd = libc.syscall(ctypes.c_long(41), ctypes.c_long((1 << 32) | 1), ctypes.c_long(1), ctypes.c_long(0))
            if fd >= 0:
                reached.append('made an AF_UNIX socket with the high bits of its family set')
            if reached:
                raise RuntimeError('reached: ' + ', '.join(reached))
            return box2d(ctx)

    class Shares:
        '''Leaves its answer in a shared folder for its other variants, and raises if it finds a
        rival's there (two variants of one plug-in passing answers).'''
        def __call__(self, ctx):
            folder = '/tmp/dc-shared'
            os.makedirs(folder, exist_ok=True)
            mine = os.path.join(folder, f'{ctx.index}-{ctx.variant}')
            rivals = [f for f in os.listdir(folder) if f.startswith(f'{ctx.index}-') and f != os.path.basename(mine)]
            if rivals:
                raise RuntimeError(f'found a rival answer: {rivals}')
            np.save(mine + '.npy', ctx.problem.start_normal)
            os.rename(mine + '.npy', mine)
            return box2d(ctx)

    class Untidy:
        '''Leaves a helper thread that raises, and objects whose finalizer raises.'''
        def __call__(self, ctx):
            import threading
            class Leaky:
                def __del__(self):
                    raise ValueError('from a finalizer')
            Leaky()
            t = threading.Thread(target=lambda: 1 / 0)
            t.start()
            t.join()
            return box2d(ctx)

    class EndsItself:
        '''Ends its own process mid-run, past every guard (a signal to itself).'''
        def __call__(self, ctx):
            os.kill(os.getpid(), signal.SIGKILL)

    class ExitsThree:
        '''Calls os._exit(3) in a call.'''
        def __call__(self, ctx):
            os._exit(3)

    class KillsItsParent:
        '''Sends SIGKILL to its parent and to its process group (once the judge's helper and group).'''
        def __call__(self, ctx):
            for target in (os.getppid(), 1):
                try:
                    os.kill(target, signal.SIGKILL)
                except OSError:
                    pass
            return box2d(ctx)

    class Hangs:
        '''Never answers its second call.'''
        calls = 0
        def __call__(self, ctx):
            Hangs.calls += 1
            while Hangs.calls > 1:
                time.sleep(1)
            return box2d(ctx)

    class Stalls:
        '''Begins its second answer on its line (the length of one) and never sends the rest.'''
        calls = 0
        def __call__(self, ctx):
            import gc
            from multiprocessing.connection import Connection
            Stalls.calls += 1
            if Stalls.calls > 1:
                for line in [o for o in gc.get_objects() if isinstance(o, Connection)]:
                    os.write(line.fileno(), struct.pack("!i", 1000))
                while True:
                    time.sleep(1)
            return box2d(ctx)

    class Forges:
        '''From its second answer on, replaces the answer's framing with a header holding NaN.'''
        def __call__(self, ctx):
            import deepcontact.contest.guest as g
            def forged(header, arrays=None):
                head = json.dumps({"iterations": float("nan"), "arrays": []}).encode()
                return struct.pack("<I", len(head)) + head
            g.pack = forged
            return box2d(ctx)

    """)


@pytest.fixture
def hostile(run, tmp_path, monkeypatch):
    forget = plugin_modules(tmp_path, monkeypatch, {"hostile": HOSTILE.replace("{run!r}", repr(str(run))),
                                                    "tricks": TRICKS})
    yield
    forget()


def evaluate(run, out, *args, every=20):
    return dc("evaluate", "--no-plots", "--no-budgets", run, "--every", str(every), "-q", "-o", out, *args)


def summary_of(r, out):
    assert r.returncode == 0, r.stderr
    return json.loads((out / "summary.json").read_text())


def test_work_done_while_it_is_made_is_charged_to_its_total(run, tmp_path, hostile):
    out = tmp_path / "r"
    s = summary_of(evaluate(run, out, "--starts", "builtin,hostile:WorksInSetup"), out)
    setup = s["starts"]["hostile:WorksInSetup"]["setup_ms"]
    assert setup >= 300 and s["starts"]["builtin"]["setup_ms"] < 100, (setup, s["starts"]["builtin"]["setup_ms"])
    totals = s["settings"]["noise"]["total_ms"]
    assert totals["hostile:WorksInSetup"] >= 300 + totals["builtin"] - s["starts"]["builtin"]["setup_ms"]
    assert s["starts"]["hostile:WorksInSetup"]["total_ms_sum"] >= 300
    report = (out / "report.md").read_text()
    assert "hostile:WorksInSetup" not in report.split("**Verdict**")[1].split("(")[0] or "no clear winner" in report


def test_a_process_working_in_the_background_is_charged_to_the_calls(run, tmp_path, hostile):
    out = tmp_path / "r"
    s = summary_of(evaluate(run, out, "--starts", "builtin,hostile:Detached", every=3), out)["starts"]
    detached, builtin = s["hostile:Detached"], s["builtin"]
    # 0.3 s of CPU burnt between its calls: what reaches the judge's reads between calls spread over
    # its steps, what reaches them during a call charged to that call, and what falls after its
    # last call to its total (it slows every variant on two cores, but it alone pays for its CPU).
    # At least 60 ms of it: the run may end the burner early, and a call is charged the larger of
    # its wall time and its CPU, so CPU counted under a call's own wall time does not add (0.1 s of
    # burning once showed as 51 ms, in an idle CI run)
    assert detached["total_ms_sum"] > builtin["total_ms_sum"] + 60.0, (detached, builtin)


def test_a_contestant_reaches_no_other_process_nor_the_users_files(run, tmp_path, hostile):
    # (it raises what it reached: signalling a rival or the judge, reading their memory, listing the user's folders)
    out = tmp_path / "r"
    s = summary_of(evaluate(run, out, "--starts", "builtin,hostile:Reacher,zero"), out)
    assert {"builtin", "hostile:Reacher", "zero"} <= set(s["starts"])


def test_what_a_contestants_thread_or_finalizer_raises_is_a_line_not_a_traceback(run, tmp_path, hostile):
    import os
    from conftest import dc_process
    # (a real process: the contestant writes to dc's own standard error, which CliRunner does not hold)
    r = dc_process("evaluate", "--no-plots", "--no-budgets", str(run), "--every", "20", "-q", "-o", str(tmp_path / "r"),
                   "--starts", "builtin,hostile:Untidy",
                   env={**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "mods"), *sys.path])})
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "the variant 'hostile:Untidy': a thread it started raised ZeroDivisionError" in r.stderr
    assert "the variant 'hostile:Untidy': ValueError raised and ignored in" in r.stderr


@pytest.mark.parametrize("start, needle", [("EndsItself", "its process ended while answering (killed by SIGKILL)"),
                                           ("ExitsThree", "called os._exit(3)")])
def test_a_contestant_that_ends_its_own_process_is_named(run, tmp_path, hostile, start, needle):
    r = evaluate(run, tmp_path / "r", "--starts", f"builtin,hostile:{start}")
    assert r.returncode == 1 and f"hostile:{start}" in r.stderr and needle in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "r").exists()


def test_two_variants_of_one_plugin_share_no_folder(run, tmp_path, hostile):
    # (each raises if it finds the other's answer in /tmp: each /tmp is its sandbox's own)
    out = tmp_path / "r"
    s = summary_of(evaluate(run, out, "--starts", "hostile:Shares", "--relaxation", "1,1.7"), out)
    assert set(s["starts"]) == {"hostile:Shares@1", "hostile:Shares@1.7"}


def test_a_contestant_that_kills_its_parent_kills_only_its_own_sandbox(run, tmp_path, hostile):
    out = tmp_path / "r"
    r = evaluate(run, out, "--starts", "builtin,hostile:KillsItsParent")
    if r.returncode == 0:   # (its sandbox's first process shrugs off a signal from inside)
        assert "hostile:KillsItsParent" in json.loads((out / "summary.json").read_text())["starts"]
    else:                   # (or it ended its own sandbox: it is named, never builtin)
        assert r.returncode == 1 and "hostile:KillsItsParent" in r.stderr and "'builtin'" not in r.stderr, r.stderr


def test_a_call_that_never_returns_is_stopped_at_its_deadline_and_named(run, tmp_path, hostile, monkeypatch):
    import time
    from deepcontact.contest import client
    monkeypatch.setattr(client, "CALL_FLOOR", 3.0)
    monkeypatch.setattr(client, "CALL_PER_POINT", 0.0)
    t0 = time.monotonic()
    r = evaluate(run, tmp_path / "r", "--starts", "builtin,hostile:Hangs")
    assert r.returncode == 1 and "hostile:Hangs" in r.stderr and "did not answer within 3 s" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and time.monotonic() - t0 < 30
    assert not (tmp_path / "r").exists()


def test_an_answer_begun_and_never_finished_is_stopped_at_its_deadline_and_named(run, tmp_path, hostile,
                                                                                  monkeypatch):
    """Its line readable (the first bytes of an answer), the rest never sent: the judge waited for
    that rest without end (Connection.recv_bytes after a poll); now the whole answer has the deadline.
    (An alarm at 60 s ends the wait, should it come back, with an error instead of a hung suite.)"""
    import signal
    import time
    from deepcontact.contest import client

    def hung(signum, frame):
        raise RuntimeError("the judge still waits for the rest of an answer, past its deadline")
    monkeypatch.setattr(client, "CALL_FLOOR", 3.0)
    monkeypatch.setattr(client, "CALL_PER_POINT", 0.0)
    t0 = time.monotonic()
    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(60)
    try:
        r = evaluate(run, tmp_path / "r", "--starts", "builtin,hostile:Stalls")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert r.returncode == 1 and "hostile:Stalls" in r.stderr and "did not answer within 3 s" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and time.monotonic() - t0 < 30
    assert not (tmp_path / "r").exists()


def test_a_forged_answer_is_one_line_naming_its_contestant(run, tmp_path, hostile):
    r = evaluate(run, tmp_path / "r", "--starts", "builtin,hostile:Forges")
    assert r.returncode == 1 and "hostile:Forges" in r.stderr and "not an answer" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_colluding_memos_are_each_charged_the_problem_they_have_not_seen(run, tmp_path, hostile):
    # three variants of one memoizing method, and no honest one: each asked each step's problem once
    out = tmp_path / "r"
    s = summary_of(evaluate(run, out, "--starts", "builtin,zero,prev", "--accelerate", "tricks:Memo"), out)["starts"]
    charged = {name: v["solve_ms_median"] for name, v in s.items()}
    assert len(charged) == 3 and all(ms >= 3.5 for ms in charged.values()), charged   # (its 4 ms, each step)


def test_the_noise_floor_is_builtin_asked_again_and_no_variant_is_flagged(run, tmp_path, hostile):
    """builtin's solve is asked a second time a step for the A/A (its time stays its first call);
    no variant carries a memo flag, for no threshold is left to set one."""
    out = tmp_path / "r"
    data = summary_of(evaluate(run, out, "--starts", "zero,builtin,prev"), out)
    aa = data["settings"]["noise"]["aa"]
    assert all(np.isfinite(aa)) and aa[1] <= aa[0] <= aa[2], aa
    assert not any("memo" in v for v in data["starts"].values())
    assert not re.search(r"\bmemos?\b", (out / "report.md").read_text())


def test_a_heavy_tail_is_never_called_the_fastest():
    """The median's fastest that loses the whole run: no clear winner, and not "the fastest"."""
    from deepcontact.contest.verdict import decide
    from deepcontact.evaluate.verdicts import verdict
    steps = range(40)
    times = {"builtin": {k: 1.0 + 0.01 * (k % 3) for k in steps},
             "tailed": {k: (0.5 if k % 10 else 40.0) for k in steps}}   # half the time, but 40 ms on a step in ten
    aa = ([1.0 + 0.01 * (k % 3) for k in steps], [1.0 + 0.01 * ((k + 1) % 3) for k in steps])
    v = decide(times, ["tailed", "builtin"], "builtin", aa)
    assert v.best == "tailed" and v.heavy_tail and not v.clear and v.beaten_on_total_by == ["builtin"]
    summary = {name: {"total_ms_median": float(np.median(list(t.values()))), "iterations_median": 10.0,
                      "at_cap": 0.0, "above": 0.0, "relaxation": 1.0, "accelerate": "none"}
               for name, t in times.items()}
    line = verdict(summary, v.as_dict())
    assert "no clear winner" in line and "fastest" not in line and "heavy tail" in line, line
    # without the tail, the same median wins clearly
    times["tailed"] = {k: 0.5 for k in steps}
    v = decide(times, ["tailed", "builtin"], "builtin", aa)
    assert v.clear and not v.heavy_tail


def test_where_the_machine_refuses_a_fence_the_report_says_which(run, tmp_path, monkeypatch):
    """No bubblewrap, no control group: the contestants still run, as bare processes, and the
    protocol line and the verdict name the missing fences (nothing dropped silently)."""
    from deepcontact.contest import machine
    monkeypatch.setattr(machine, "bwrap", lambda: None)
    monkeypatch.setattr(machine, "cgroup_roots", lambda: {})
    out = tmp_path / "r"
    s = summary_of(evaluate(run, out, "--starts", "builtin,zero"), out)
    assert {"builtin", "zero"} <= set(s["starts"])
    report = (out / "report.md").read_text()
    verdict = next(line for line in report.splitlines() if line.startswith("**Verdict**"))
    assert "fences missing on this machine (namespaces, read-only view, seccomp, cpu accounting, process limit)" \
        in verdict, verdict
    assert "Contestants' fences MISSING on this machine: namespaces" in report


def test_no_winner_is_named_from_a_single_step():
    from deepcontact.contest.verdict import MIN_STEPS, decide
    times = {"builtin": {0: 1.0}, "fast": {0: 0.1}}
    v = decide(times, ["fast", "builtin"], "builtin", ([1.0], [1.0]))
    assert v.best == "fast" and v.too_few_steps and not v.clear and v.steps == 1
    steps = range(MIN_STEPS)
    times = {"builtin": {k: 1.0 + 0.01 * k for k in steps}, "fast": {k: 0.1 for k in steps}}
    v = decide(times, ["fast", "builtin"], "builtin", ([1.0 + 0.01 * k for k in steps],) * 2)
    assert v.clear and not v.too_few_steps


def test_a_variant_timed_against_itself_is_1_whatever_its_times():
    """Equal medians are a tie: both infinite (unfinished) or both 0 (calls no slower than the
    transport; the interval of builtin against itself read [0.00, 1.00] in CI)."""
    from deepcontact.contest.verdict import ratio_interval
    for times in ([0.0, 0.0, 0.0, 0.2, 0.3, 0.0], [float("inf")] * 4 + [1.0, 2.0], [1.0, 2.0, 3.0]):
        assert ratio_interval(times, times) == (1.0, 1.0, 1.0), times
    # a median the transport's subtraction took to 0 counts as a microsecond: no ratio of 1e11
    ratio, low, high = ratio_interval([0.2, 0.0, 0.0, 0.3, 0.0, 0.4], [0.0, 0.2, 0.3, 0.0, 0.4, 0.0])
    assert high <= 0.4 / 1e-3 and low >= 1e-3 / 0.4, (ratio, low, high)
