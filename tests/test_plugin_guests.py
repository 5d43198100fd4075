"""Plug-ins are guests: whatever a start, a solver method or a network does (sys.exit,
a KeyboardInterrupt of its own, an exception at import or at call, editing the problem it is
handed, moving the working folder, swallowing a stop signal, taking over the signal handlers), the
command ends in one line naming it (exit 1), or goes on unharmed; the user's own Ctrl-C stays 130.

The misbehaviours are generated: each one in each kind of plug-in, at import and at call."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import dc, forget_plugins, plugin_modules, wait_for

pytestmark = pytest.mark.audit

# What a plug-in may do wrong, as the body of the call (or of the module, at import).
MISDEEDS = {
    "exit0": "sys.exit(0)",
    "exit3": "sys.exit(3)",
    "interrupt": "raise KeyboardInterrupt",
    "error": "raise RuntimeError('broken')",
    "base": "raise GeneratorExit",
    # would end dc at once: its partial output and lock left behind, exit 0
    "os_exit": "os._exit(0)",
}

START = """
import os, sys, signal
import numpy as np
from deepcontact.warmstart.starts import StartValue
{at_import}
class Start:
    def __call__(self, ctx):
        {at_call}
        return StartValue(np.zeros(ctx.problem.points), np.zeros(ctx.problem.points), {{}})
"""

METHOD = """
import os, sys, signal
import numpy as np
from deepcontact.solver.methods import MethodResult
{at_import}
class Method:
    def __call__(self, problem, normal, tangent, settings):
        {at_call}
        return MethodResult(normal, tangent, np.zeros(1))
"""

NETWORK = """
import os, sys, signal
import torch
from torch import nn
{at_import}
calls = [0]
class Net(nn.Module):
    def __init__(self, in_channels, out_channels, height, width):
        super().__init__()
        self.conv = nn.Conv2d(in_channels, out_channels, 1)
    def forward(self, x):
        calls[0] += 1
        if calls[0] > 2:   # (past the contract's check: in training)
            {at_call}
        return self.conv(x)
"""


def write_module(tmp_path, monkeypatch, name, template, at_import="", at_call="pass"):
    plugin_modules(tmp_path, monkeypatch, {name: template.format(at_import=at_import, at_call=at_call)})


def forget(name):
    forget_plugins((name,))


def one_line_naming(r, name):
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert len(lines) == 1 and "Traceback" not in r.stderr and name in lines[0], r.stderr
    return lines[0]


@pytest.mark.parametrize("when", ["import", "call"])
@pytest.mark.parametrize("misdeed", sorted(MISDEEDS))
def test_a_start_that_misbehaves_is_one_line_naming_it(run, tmp_path, monkeypatch, misdeed, when):
    name = f"guest_start_{misdeed}_{when}"
    code = MISDEEDS[misdeed]
    write_module(tmp_path, monkeypatch, name, START, **{"at_import" if when == "import" else "at_call": code})
    try:
        r = dc("evaluate", "--no-plots", run, "--starts", f"builtin,{name}:Start", "--every", "40", "--no-budgets",
               "-q", "-o", tmp_path / "r")
    finally:
        forget(name)
    line = one_line_naming(r, f"{name}:Start")
    assert not (tmp_path / "r").exists()
    if misdeed.startswith("exit"):
        assert "sys.exit" in line


@pytest.mark.parametrize("misdeed", sorted(MISDEEDS))
def test_a_solver_method_that_misbehaves_is_one_line_naming_it(run, tmp_path, monkeypatch, misdeed):
    name = f"guest_method_{misdeed}"
    write_module(tmp_path, monkeypatch, name, METHOD, at_call=MISDEEDS[misdeed])
    try:
        r = dc("evaluate", "--no-plots", run, "--starts", "builtin", "--accelerate", f"{name}:Method", "--every", "40",
               "--no-budgets", "-q", "-o", tmp_path / "r")
        one_line_naming(r, f"{name}:Method")
        r = dc("simulate", "pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5", "--steps",
               "150", "--solver", "pgs", "--accelerate", f"{name}:Method", "-q", "-o", tmp_path / "s")
        one_line_naming(r, f"{name}:Method")
    finally:
        forget(name)
    assert not (tmp_path / "r").exists() and not (tmp_path / "s").exists()


@pytest.mark.parametrize("misdeed", sorted(MISDEEDS))
def test_a_network_that_misbehaves_in_training_is_one_line_naming_it(dataset, tmp_path, monkeypatch, misdeed):
    name = f"guest_net_{misdeed}"
    write_module(tmp_path, monkeypatch, name, NETWORK, at_call=MISDEEDS[misdeed])
    try:
        r = dc("train", "--no-plots", dataset, "--arch", f"{name}:Net", "--epochs", "1", "-q", "-o", tmp_path / "m")
    finally:
        forget(name)
    one_line_naming(r, f"{name}:Net")
    assert not (tmp_path / "m").exists()


EDITS = ["problem.contacts['local_normal'][:] = 0.5", "problem.bodies['velocity'][:] = 99.0",
         "problem.start_normal[:] = 1e3", "problem.dt = 1.0", "problem.bodies.clear()"]


@pytest.fixture(scope="module")
def clean(run, tmp_path_factory):
    """The built-in rows with no guest beside them: a report folder."""
    out = tmp_path_factory.mktemp("clean") / "report"
    r = dc("evaluate", "--no-plots", run, "--starts", "builtin,zero", "--every", "40", "--no-budgets", "-q", "-o", out)
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.parametrize("kind", ["start", "method"])
def test_what_a_method_does_to_its_problem_no_other_row_sees(run, clean, tmp_path, monkeypatch, kind):
    """A method (or start) that edits the problem in place changes no built-in row after it: every
    edit a plug-in of its own, all of them in one run (each a contestant of its own)."""
    names = [f"guest_{kind}_editor_{k}" for k in range(len(EDITS))]
    for name, edit in zip(names, EDITS):
        if kind == "start":
            write_module(tmp_path, monkeypatch, name, START, at_call=edit.replace("problem.", "ctx.problem."))
        else:
            write_module(tmp_path, monkeypatch, name, METHOD, at_call=edit)
    guests = ",".join(f"{name}:{kind.title()}" for name in names)
    asked = (["--starts", f"{guests},builtin,zero"] if kind == "start"
             else ["--starts", "builtin,zero", "--accelerate", f"{guests},none"])
    try:
        r = dc("evaluate", "--no-plots", run, *asked, "--every", "40", "--no-budgets", "-q", "-o", tmp_path / "dirty")
    finally:
        for name in names:
            forget(name)
    assert r.returncode == 0, r.stderr
    rows = lambda folder: json.loads((folder / "summary.json").read_text())["starts"]   # noqa: E731
    before, after = rows(clean), rows(tmp_path / "dirty")
    assert set(before) <= set(after) and len(after) == len(before) + len(EDITS) * (1 if kind == "start" else 2)
    for key in before:   # the built-in rows computed beside the plug-ins: the same answers
        for measure in ("iterations_median", "residual_median", "error_median", "velocity_error_median"):
            assert after[key][measure] == before[key][measure], (key, measure)


def test_a_start_that_moves_the_working_folder_moves_no_output(run, tmp_path, monkeypatch):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    # (a contestant's sandbox holds no folder of the user's: it moves to one of its own)
    write_module(tmp_path, monkeypatch, "guest_mover", START, at_call="import tempfile; os.chdir(tempfile.mkdtemp())")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    try:
        r = dc("evaluate", "--no-plots", run, "--starts", "builtin,guest_mover:Start", "--every", "40", "--no-budgets",
               "-q", "-o", "report")
    finally:
        forget("guest_mover")
    assert r.returncode == 0, r.stderr
    assert (work / "report" / "report.md").exists() and list(elsewhere.iterdir()) == []
    assert Path.cwd() == work


# The cue a guest gives the test that it is running: a line on dc's standard error (a contestant's
# sandbox can write no file the test could see).
CUE = "dc-test: the guest was called"


class Watch:
    """A process's standard error, read as it comes (a thread), for the guest's cue."""

    def __init__(self, proc):
        import threading
        self.proc, self.lines = proc, []
        self.thread = threading.Thread(target=lambda: self.lines.extend(proc.stderr), daemon=True)
        self.thread.start()

    def cued(self):
        return any(CUE in line for line in list(self.lines)) or self.proc.poll() is not None

    def finish(self, timeout=30):
        """The process's standard error once it has ended (less the cue)."""
        self.proc.wait(timeout)
        self.thread.join(timeout)
        return "".join(line for line in self.lines if CUE not in line)


SWALLOWER = """
import pathlib, signal, sys, time
CUE = {cue!r}
import numpy as np
from deepcontact.warmstart.starts import StartValue
class Start:
    def __call__(self, ctx):
        {body}
        print(CUE, file=sys.stderr, flush=True)   # (the test's cue: one call is done)
        return StartValue(np.zeros(ctx.problem.points), np.zeros(ctx.problem.points), {{}})
"""
SWALLOWS = {
    # catches the stop and goes on: stopped when it returns
    "catches": "try:\n            time.sleep(0.2)\n        except BaseException:\n            pass",
    # takes the handlers over for good: put back when it returns
    "ignores": "time.sleep(0.05); signal.signal(signal.SIGTERM, signal.SIG_IGN); "
               "signal.signal(signal.SIGINT, signal.SIG_IGN)",
    # catches the first and then never returns on its own: the second stop ends it
    "loops": "try:\n            time.sleep(0.2)\n        except BaseException:\n            while True: time.sleep(0.01)",
}


def evaluating_with(run, tmp_path, name, body, starts):
    """dc evaluate in a process of its own, with the start `name` (SWALLOWER with `body`), once
    the start has returned from its first call."""
    import os
    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / f"{name}.py").write_text(SWALLOWER.format(body=body, cue=CUE))
    proc = subprocess.Popen([sys.executable, "-m", "deepcontact.cli.main", "evaluate", "--no-plots", str(run),
                             "--starts", starts,
                             "--no-budgets", "-q", "-o", str(tmp_path / "r")], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(mods)},
                            cwd=tmp_path)
    proc.watch = Watch(proc)
    wait_for(proc.watch.cued)
    return proc


@pytest.mark.parametrize("kind", sorted(SWALLOWS))
def test_a_start_that_swallows_a_stop_signal_still_stops(run, tmp_path, kind):
    proc = evaluating_with(run, tmp_path, "guest_swallow", SWALLOWS[kind], "builtin,guest_swallow:Start")
    proc.send_signal(signal.SIGTERM)
    if kind == "loops":
        time.sleep(1)
        proc.send_signal(signal.SIGTERM)
    try:
        err = proc.watch.finish()
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "interrupted" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mods"]


def test_the_users_own_ctrl_c_in_a_plugin_is_130(run, tmp_path):
    proc = evaluating_with(run, tmp_path, "guest_slow", "time.sleep(0.05)", "guest_slow:Start")
    proc.send_signal(signal.SIGINT)
    err = proc.watch.finish()
    assert proc.returncode == 130 and "interrupted (SIGINT)" in err, err


def test_the_plugins_error_is_chained_to_its_own(tmp_path, monkeypatch):
    """-v shows the plug-in's traceback: the PluginError is chained to what it raised, and names it."""
    from deepcontact.plugins import PluginError, guest
    from deepcontact.solver.methods import SOLVERS
    write_module(tmp_path, monkeypatch, "guest_chain", METHOD, at_call="raise ValueError('deep inside')")
    try:
        method = SOLVERS.load("guest_chain:Method")()
        with pytest.raises(PluginError) as info, guest("the solver method 'guest_chain:Method'"):
            method(None, np.zeros(1), np.zeros(1), None)
    finally:
        forget("guest_chain")
    assert isinstance(info.value.__cause__, ValueError)
    assert "guest_chain:Method" in str(info.value) and "deep inside" in str(info.value)
    assert info.value.__cause__.__traceback__.tb_next is not None   # (its own frames: file and line)


@pytest.mark.parametrize("misdeed", ["exit0", "interrupt"])
def test_a_start_that_misbehaves_in_a_worker_is_one_line_naming_it(run, tmp_path, monkeypatch, misdeed):
    """With -j 2 the start runs in worker processes: the same one line, from the parent."""
    name = f"guest_worker_{misdeed}"
    write_module(tmp_path, monkeypatch, name, START, at_call=MISDEEDS[misdeed])
    try:
        r = dc("evaluate", "--no-plots", run, "--starts", f"builtin,{name}:Start", "--every", "40", "--no-budgets",
               "-j", "2", "-q", "-o", tmp_path / "r")
    finally:
        forget(name)
    one_line_naming(r, f"{name}:Start")
    assert not (tmp_path / "r").exists()


def test_a_network_that_reads_values_on_the_meta_device_is_one_line_naming_it(dataset, tmp_path, monkeypatch):
    """Its memory is estimated on torch's meta device, where .item() has no value to read."""
    name = "guest_net_item"
    write_module(tmp_path, monkeypatch, name, NETWORK.replace("calls[0] += 1", "calls[0] += 1\n        "
                                                                "float(x.sum().item())"))
    try:
        r = dc("train", "--no-plots", dataset, "--arch", f"{name}:Net", "--epochs", "1", "-q", "-o", tmp_path / "m")
    finally:
        forget(name)
    assert "meta device" in one_line_naming(r, f"{name}:Net")


def test_a_checkpoint_records_where_its_network_comes_from(dataset, tmp_path, monkeypatch):
    from deepcontact.model.checkpoint import load_checkpoint
    write_module(tmp_path, monkeypatch, "guest_net_fine", NETWORK)
    try:
        r = dc("train", "--no-plots", dataset, "--arch", "guest_net_fine:Net", "--epochs", "1", "-q", "-o",
               tmp_path / "m")
        assert r.returncode == 0, r.stderr
        from deepcontact.model.arch import NETWORKS
        NETWORKS.choose("guest_net_fine:Net")   # (read here as --arch names it: trained fenced, never loaded here)
        origin = load_checkpoint(tmp_path / "m" / "last.pt")["network_origin"]
    finally:
        forget("guest_net_fine")
    assert origin["origin"] == "plug-in" and origin["target"] == "guest_net_fine:Net"


# --- A guest that swallows every stop: a second signal, or the deadline, ends dc, leaving nothing ---

STUBBORN = f"""
import pathlib, sys, time
CUE = {CUE!r}
import numpy as np
from deepcontact.solver.methods import MethodResult
from deepcontact.warmstart.starts import StartValue
def stubborn():
    print(CUE, file=sys.stderr, flush=True)   # (the test's cue: the guest is running)
    while True:
        try:
            time.sleep(0.01)
        except BaseException:   # every stop, every time
            pass
class Start:
    def __call__(self, ctx):
        stubborn()
class Method:
    def __call__(self, problem, normal, tangent, settings):
        stubborn()
"""
# each stop-signal path a plug-in's code runs in: the command line around the guest `guest_stubborn`
GUEST_PATHS = {
    "replay start": lambda run, out: ["evaluate", "--no-plots", run, "--starts", "builtin,guest_stubborn:Start",
                                      "--no-budgets", "-o", out],
    "closed-loop start": lambda run, out: ["evaluate", "--no-plots", run, "--closed-loop", "--steps", "60",
                                           "--starts", "guest_stubborn:Start", "-o", out],
    "simulate method": lambda run, out: ["simulate", "pile", "--steps", "60", "--solver", "pgs", "--tolerance",
                                         "1e-4", "--accelerate", "guest_stubborn:Method", "-o", out],
}
SIGNALS = {"TERM, TERM": (signal.SIGTERM, signal.SIGTERM), "TERM, INT": (signal.SIGTERM, signal.SIGINT),
           "INT, INT": (signal.SIGINT, signal.SIGINT), "TERM alone": (signal.SIGTERM,)}


@pytest.mark.parametrize("path, signals", [("replay start", k) for k in SIGNALS]
                         + [("closed-loop start", "TERM, TERM"), ("simulate method", "INT, INT")])
def test_a_guest_that_swallows_every_stop_cannot_keep_dc_alive(run, tmp_path, path, signals):
    from deepcontact import interrupts
    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / "guest_stubborn.py").write_text(STUBBORN)
    proc = subprocess.Popen([sys.executable, "-m", "deepcontact.cli.main", *map(str, GUEST_PATHS[path](run, tmp_path / "out"))],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(mods)})
    watch = Watch(proc)
    try:
        wait_for(watch.cued)
        first, *then = SIGNALS[signals]
        proc.send_signal(first)
        sent = time.monotonic() + interrupts.GUEST_DEADLINE   # (one signal: from the deadline on)
        for s in then:
            time.sleep(0.3)
            sent = time.monotonic()
            proc.send_signal(s)
        err = watch.finish()
        took = time.monotonic() - sent
    finally:
        proc.kill()
    assert proc.returncode == 128 + first, err
    # after the second signal (its grace; the first's deadline alone would be later) or the deadline
    assert took < (interrupts.REPEAT_GRACE + 1 if then else 2), took
    assert "interrupted" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mods"]


class _Editor:
    """A start object handed to the library directly (not by name): it edits what it is given."""

    def __init__(self, edit):
        self.edit = edit

    def __call__(self, ctx):
        from deepcontact.warmstart.starts import StartValue
        exec(self.edit, {"problem": ctx.problem, "ctx": ctx})
        return StartValue(np.zeros(ctx.problem.points), np.zeros(ctx.problem.points), {})


def _library_rows(path, run, starts):
    import deepcontact as dcl
    if path == "evaluate_starts":
        rows = dcl.evaluate_starts([run], starts, every=20)
        return sorted((r.start, r.seed, r.step, r.iterations, r.residual) for r in rows
                      if not r.start.startswith("editor"))
    scene = dcl.read_scene(Path(run) / "seed-000000" / "scene.xml")
    return [(r.start, r.iterations.tolist(), r.drift.tolist()) for r in dcl.closed_loop(scene, starts, steps=40)
            if not r.start.startswith("editor")]


@pytest.mark.parametrize("path", ["evaluate_starts", "closed_loop"])
def test_what_a_start_handed_to_the_library_does_to_its_problem_no_other_start_sees(run, path):
    """Every editor beside the built-ins in one run (each start is a contestant of its own, so
    one run holds them apart as well as one run each would)."""
    import deepcontact as dcl
    clean = _library_rows(path, run, dcl.make_starts(["builtin", "prev", "zero"]))
    edits = EDITS + ["ctx.bodies['velocity'][:] = 99.0", "ctx.previous.clear()"]
    editors = {f"editor-{k}": _Editor(edit) for k, edit in enumerate(edits)}
    dirty = _library_rows(path, run, {**editors, **dcl.make_starts(["builtin", "prev", "zero"])})
    assert dirty == clean


@pytest.mark.parametrize("change", ["os.umask(0)", "__import__('torch').set_num_threads(7)"])
def test_what_a_start_changes_in_the_process_is_put_back_as_it_returns(run, tmp_path, monkeypatch, change):
    """The umask the outputs' modes come from and torch's thread count (--threads) are the
    command's, whatever a plug-in's call sets."""
    import stat
    import torch
    name = "guest_process_state"
    write_module(tmp_path, monkeypatch, name, START, at_call=change)
    old = os.umask(0o022)
    try:
        r = dc("evaluate", "--no-plots", run, "--starts", f"{name}:Start,builtin", "--every", "40", "--no-budgets",
               "-q", "-o", tmp_path / "report")
        assert r.returncode == 0, r.stderr
        modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in (tmp_path / "report").iterdir()}
        assert modes and all(not mode & stat.S_IWOTH for mode in modes.values()), modes
        assert os.umask(0o022) == 0o022 and torch.get_num_threads() == 1
    finally:
        os.umask(old)
        forget(name)


# --- What a plug-in starts does not outlive the command -------------------------------------------

OUTLIVES = {
    # a thread that is no daemon: Python would wait for it at exit
    "thread": "import threading; threading.Thread(target=time.sleep, args=(60,)).start()",
    # a process holding dc's standard output: a pipe would end only when it does
    "process": "import subprocess; subprocess.Popen(['sleep', '60'])",
    # its child's child, orphaned at once: adopted by dc, and killed as well
    "orphan": "import subprocess; subprocess.Popen(['sh', '-c', 'sleep 60 & exit 0']).wait()",
    # an exit handler and a finalizer that raise: tracebacks after the command's status
    "atexit": "import atexit; atexit.register(lambda: 1 / 0); Start.kept = Finalizer()",
    # a fork whose child comes back out of the start: it must not run the rest of dc evaluate
    "fork": "os.fork()",
}

LEAVER = """
import os, pathlib, time
import numpy as np
{imports}
class Finalizer:
    def __del__(self):
        raise RuntimeError("finalizer")
class Start:
    done = False
    def __call__(self, {arguments}):
        if not Start.done:
            Start.done = True
            {body}
        return {value}
"""
# the same leaver as a start and as a solver method
AS_START = dict(imports="from deepcontact.warmstart.starts import StartValue", arguments="ctx",
                value="StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), {})")
AS_METHOD = dict(imports="from deepcontact.solver.methods import MethodResult",
                 arguments="problem, normal, tangent, settings", value="MethodResult(normal, tangent, np.zeros(1))")


@pytest.mark.parametrize("kind", sorted(OUTLIVES))
def test_nothing_a_plugin_starts_outlives_the_command(run, tmp_path, kind):
    import os
    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / "guest_leaves.py").write_text(LEAVER.format(body=OUTLIVES[kind], **AS_START))
    proc = subprocess.run([sys.executable, "-m", "deepcontact.cli.main", "evaluate", "--no-plots", str(run),
                           "--starts", "builtin,guest_leaves:Start", "--every", "20", "--no-budgets", "-q", "-o",
                           str(tmp_path / "r")], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(mods)}, cwd=tmp_path)
    assert proc.returncode == 0, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr and "finalizer" not in proc.stderr, proc.stderr
    # the start ran in its contestant process: what it left ended with that process, and the report says so
    report = (tmp_path / "r" / "report.md").read_text()
    if kind in ("thread", "process"):
        assert "Left threads or processes running after their calls" in report
        left = "1 thread, 0 processes" if kind == "thread" else "0 threads, 1 process"
        assert f"_leaves:Start ({left})" in report, report
    # a forked child that carried on out of the start is ended there, and said, once a child (it
    # was ended without a word); anything else leaves nothing to say
    # (said in its sandbox, so relayed under its name: contest/relay.py)
    said = set(proc.stderr.splitlines())
    assert said == (set() if kind != "fork" else {"[the variant 'guest_leaves:Start'] dc: the start 'guest_leaves:Start' "
                                                  "forked a process that carried on out of its code: it was ended "
                                                  "there, running nothing of dc's"}), \
        proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mods", "r"]
    assert not any(p.name.startswith(".") for p in (tmp_path / "r").iterdir() if p.name != ".dc-output.json")


@pytest.mark.parametrize("kind", sorted(OUTLIVES))
def test_nothing_a_plugin_method_starts_outlives_a_simulation(tmp_path, kind):
    """Outside the judge (dc simulate runs a plug-in method in its own loop), dc ends its own
    process: what the plug-in left is ended, and said."""
    import os
    mods = tmp_path / "mods"
    mods.mkdir()
    (mods / "guest_leaves.py").write_text(LEAVER.format(body=OUTLIVES[kind], **AS_METHOD))
    proc = subprocess.run([sys.executable, "-m", "deepcontact.cli.main", "simulate", "pile", "--param", "count=6",
                           "--steps", "150", "--solver", "pgs", "--accelerate", "guest_leaves:Start", "-q", "-o",
                           str(tmp_path / "r")], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(mods)}, cwd=tmp_path)
    assert proc.returncode == 0, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr and "finalizer" not in proc.stderr, proc.stderr
    if kind == "thread":
        assert "thread a plug-in started was still running" in proc.stderr
    if kind in ("process", "orphan"):
        assert "still running; killed" in proc.stderr
    if kind == "fork":   # the child ended where it came out of the plug-in, said once
        assert proc.stderr == ("dc: the solver method 'guest_leaves:Start' forked a process that carried on out "
                               "of its code: it was ended there, running nothing of dc's\n"), proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mods", "r"]


def test_without_its_fence_a_plugin_start_runs_only_when_the_user_says_so(run, tmp_path, monkeypatch):
    """Without bubblewrap a plug-in start ran as a plain process with the user's access, and no
    line said so; the project's own starts still run, their report naming the missing fences."""
    from deepcontact.contest import machine
    name = "guest_start_unfenced"
    write_module(tmp_path, monkeypatch, name, START)
    monkeypatch.setenv("PATH", os.path.dirname(sys.executable))   # (a machine without bubblewrap)
    machine.bwrap.cache_clear()
    try:
        args = ["evaluate", "--no-plots", run, "--every", "40", "--no-budgets", "-q"]
        one_line_naming(dc(*args, "--starts", f"builtin,{name}:Start", "-o", tmp_path / "r"), "only with --unfenced")
        assert not (tmp_path / "r").exists()
        assert dc(*args, "--starts", "zero,builtin", "-o", tmp_path / "own").returncode == 0
        r = dc(*args, "--starts", f"builtin,{name}:Start", "--unfenced", "-o", tmp_path / "r")
        assert r.returncode == 0, r.stderr
        assert r.stderr.strip().splitlines()[-1].startswith("dc evaluate: plug-in code ran without its sandbox, as "
                                                            "--unfenced allowed (missing here: ")
        assert "MISSING here: " in (tmp_path / "r" / "report.md").read_text()
        assert "namespaces" in json.loads((tmp_path / "r" / ".dc-output.json").read_text())["unfenced"]
    finally:
        forget(name)
        monkeypatch.undo()
        machine.bwrap.cache_clear()
