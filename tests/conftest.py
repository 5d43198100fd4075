import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from deepcontact.simulate.run import run as simulate_run
from deepcontact.simulate.source import SceneSource

# Progress lines off a terminal come every 30 s (cli/options.py); the suite's commands, slow on a
# loaded machine, hold their standard error to what they say without them (its own test sets it).
os.environ["DC_PROGRESS_EVERY"] = "1e9"

# The audits of hostile input and of what a failure may lose, and the studies' fast runs: whole
# modules, in `make test`, not in `make test-quick` (the inner loop).
AUDITS = {"test_nothing_lost", "test_hostile", "test_mutations", "test_bad_input"}
STUDIES = {"test_stability", "test_study", "test_study_resume"}   # the fast runs of dc study's measurements


def pytest_collection_modifyitems(config, items):
    """Marks the audits' and the studies' tests; runs the pipeline group (packaging, the smoke pipeline) last, so
    that a quick failure elsewhere shows first, and within it the tests that wait for a background job
    last of all, so that the job has had the longest to run (and no long test trails the rest)."""
    for item in items:
        if item.module.__name__ in AUDITS:
            item.add_marker(pytest.mark.audit)
        if item.module.__name__ in STUDIES:
            item.add_marker(pytest.mark.study)
    waiting = {module for module, _ in BACKGROUND.values()}

    def group(item):
        if item.get_closest_marker("pipeline") is None:
            return 0
        return 2 if item.module.__name__ in waiting else 1
    items.sort(key=group)


# What the pipeline group runs in processes of its own (the wheel, the smoke pipeline), started once
# as soon as the run is known (pytest_collection_finish; by the first of `-n 2`'s workers), so that
# it works beside the other tests rather than after them; the tests, in whichever worker, wait for
# it (its rc file) and check what it made.
STARTED = {}
ROOT = Path(__file__).parent.parent


def wheel_command(out):
    # No build isolation and no dependencies: CI has no network; the build tools are installed.
    return [sys.executable, "-m", "pip", "wheel", "-q", "--no-build-isolation", "--no-deps", "-w", str(out), str(ROOT)]


def smoke_command(out):
    return ["make", "-s", "-C", str(ROOT), "smoke-pipeline", f"SMOKE={out / 'smoke'}"]


BACKGROUND = {"wheel": ("test_packaging", wheel_command), "smoke": ("test_evaluate", smoke_command)}


def start(name, out):
    """BACKGROUND[name] into the folder out, its output to out/log (a pipe nobody reads could fill
    and stall it) and its exit status to out/rc when it ends; returns out."""
    out.mkdir(parents=True, exist_ok=True)
    command = " ".join(shlex.quote(str(a)) for a in BACKGROUND[name][1](out))
    with open(out / "log", "w") as log:
        STARTED[name] = (subprocess.Popen(["sh", "-c", f"{command}; echo $? > rc.part && mv rc.part rc"], cwd=out,
                                          stdout=log, stderr=subprocess.STDOUT), out)
    return out


def _shared(config, name):
    """The folder a background job of this test run lives in, the same for every xdist worker: in
    the run's own temporary folder (pytest keeps the last few runs' and removes older ones)."""
    base = config._tmp_path_factory.getbasetemp()
    return (base.parent if hasattr(config, "workerinput") else base) / f"background-{name}"


def finished(name, config):
    """The finished background job `name`, started when the run began (by the first xdist worker
    if there are several: the job is found by its folder) or now: its folder."""
    out = _shared(config, name)
    if name not in STARTED and not out.exists():
        start(name, out)
    deadline = time.monotonic() + 900
    while not (out / "rc").exists():   # (perhaps another worker's process: its rc file says it ended)
        assert time.monotonic() < deadline, f"{name} did not finish within 900 s"
        time.sleep(0.2)
    assert (out / "rc").read_text().strip() == "0", (out / "log").read_text()[-4000:]
    return out


def pytest_collection_finish(session):
    """Starts the pipeline group's jobs (once per test run: in the first xdist worker alone)."""
    if getattr(session.config, "workerinput", {}).get("workerid", "gw0") != "gw0":
        return
    modules = {item.module.__name__ for item in session.items if item.get_closest_marker("pipeline")}
    for name, (module, _) in BACKGROUND.items():
        if module in modules and (name != "smoke" or shutil.which("make")):
            start(name, _shared(session.config, name))


def pytest_sessionfinish(session, exitstatus):
    """Stops this process's background jobs: at once if the run was cut short; under xdist,
    after they end otherwise (another worker may still wait for one)."""
    for proc, _ in STARTED.values():
        if proc.poll() is None and exitstatus == 0 and hasattr(session.config, "workerinput"):
            try:
                proc.wait(timeout=900)
            except subprocess.TimeoutExpired:
                pass
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    STARTED.clear()


def wait_for(predicate, seconds=60):
    """Polls until predicate() is true; AssertionError after `seconds`."""
    deadline = time.time() + seconds
    while not predicate():
        if time.time() > deadline:
            raise AssertionError("timed out waiting")
        time.sleep(0.02)


# A small pile: enough contacts (two-point manifolds on the walls included) to exercise every
# field, fast enough for every test run.
SMALL_PILE = dict(count="30", box="16", sigma="4", steps="150")


def simulate(out_dir, spec="pile", seeds=(0,), params=None, **kw):
    params = dict(SMALL_PILE if params is None and spec == "pile" else (params or {}))
    steps = params.pop("steps", None)
    source = SceneSource(spec, params, int(steps) if steps else None)
    return simulate_run(source, list(seeds), out_dir, **kw)


@pytest.fixture(scope="session")
def pile_run(tmp_path_factory):
    """A finished small-pile run folder (read-only for tests: copy before changing)."""
    out = tmp_path_factory.mktemp("pile") / "run"
    simulate(out)
    return out


def dc(*args, check=False):
    """`dc ARGS` run in this process (click's CliRunner): the exit code, stdout and stderr a shell
    would see, as a CompletedProcess, without a process start (0.4 s each). A test that needs a
    real process (signals, locks between processes, the environment, the installed entry point)
    uses dc_process."""
    import signal
    import traceback

    from click.testing import CliRunner

    from deepcontact.cli.main import cli
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        result = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=True)
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)
    code, stderr = result.exit_code, result.stderr
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        # what a real process shows for an exception nobody caught: a traceback, exit 1
        code, stderr = 1, stderr + "".join(traceback.format_exception(result.exception))
    done = subprocess.CompletedProcess(["dc", *map(str, args)], code, result.stdout, stderr)
    if check:
        done.check_returncode()
    return done


def installed(script):
    """The console script `script` installed beside this interpreter (not the first one on PATH:
    `make test PYTHON=venv/bin/python` runs with the venv not activated), or None."""
    exe = Path(sys.executable).parent / script
    return str(exe) if exe.is_file() and os.access(exe, os.X_OK) else None


def dc_command():
    """The installed `dc` as a command line: the console script, or this interpreter's -m."""
    exe = installed("dc")
    return [exe] if exe else [sys.executable, "-m", "deepcontact.cli.main"]


def dc_process(*args, check=False, timeout=120, env=None):
    """Run the installed `dc` in its own process, as a user would; returns the CompletedProcess."""
    return subprocess.run([*dc_command(), *args], capture_output=True, text=True, timeout=timeout, check=check,
                          env=env)


def one_line_error(r, *needles):
    """The CLI's promise: exit 1, one line on stderr naming what is wrong, no traceback."""
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    for n in needles:
        assert str(n) in lines[0], (n, lines[0])
    return lines[0]


def option_error(r, *needles):
    """A bad option value: exit 2 with click's usage message naming the option, no traceback."""
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr, r.stderr
    for n in needles:
        assert str(n) in r.stderr, (n, r.stderr)


def snapshot(folder):
    """Every file under folder with its bytes: equal snapshots mean nothing was lost or changed."""
    from pathlib import Path
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(Path(folder).rglob("*")) if p.is_file()}


def written(out, *args):
    """`dc ARGS -q -o OUT`, which must succeed; returns OUT."""
    r = dc(*args, "-q", "-o", str(out))
    assert r.returncode == 0, r.stderr
    return out


def simulated(tmp_path_factory, name, *args):
    """A run folder `dc simulate ARGS` wrote (read-only for tests: copy before changing)."""
    return written(tmp_path_factory.mktemp(name) / "run", "simulate", *args)


# A small pile run, its dataset and a one-epoch model, shared by the tests of hostile input
# (read-only: copy before changing).
HOSTILE_PILE = ["pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5"]


@pytest.fixture(scope="session")
def run(tmp_path_factory):
    return simulated(tmp_path_factory, "hostile", *HOSTILE_PILE, "--steps", "120", "--seeds", "0..1")


@pytest.fixture(scope="session")
def dataset(run):
    return written(run.parent / "data", "rasterize", str(run), "--cell", "1", "--smoothing", "1", "--validation", "0.5")


@pytest.fixture(scope="session")
def model(dataset):
    return written(dataset.parent / "model", "train", str(dataset), "--epochs", "1", "--width", "4", "--depth", "2",
                   "--no-plots")   # (a resume draws one)


def step_problems(generator, params, wanted, seed=0):
    """The contact problems of the steps `wanted` (those with contacts) of a generated scene,
    stepped by Box2D 2.4.1 at 8 velocity iterations."""
    from deepcontact.scene.generators import generate
    from deepcontact.simulate.build import build_world
    from deepcontact.solver.problem import StepProblem
    scene = generate(generator, seed, params)
    world = build_world(scene)
    out = []
    for k in range(max(wanted) + 1):
        bodies, contacts = world.step(scene.dt, 8, 3, record=True)
        if k in wanted and len(contacts["manifold"]):
            out.append(StepProblem.from_arrays(bodies, contacts, dt=scene.dt, index=k,
                                               gravity=scene.effects.gravity or (0.0, 0.0),
                                               block_solve=scene.solver.block_solve))
    return out


def hold_threads(cpus):
    """Every thread of this process held to `cpus`, as `taskset` holds a command's (a thread that
    ended meanwhile skipped)."""
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(tid), cpus)
        except OSError:
            pass


def plugin_modules(tmp_path, monkeypatch, modules):
    """Writes `modules` ({name: source}) where this process imports them (tmp_path/mods, first on
    sys.path); returns forget(), which removes every trace of them from this process (the modules,
    and the registries' loaded and described entries)."""
    mods = tmp_path / "mods"
    mods.mkdir(exist_ok=True)
    for name, text in modules.items():
        (mods / f"{name}.py").write_text(text)
        sys.modules.pop(name, None)
    monkeypatch.syspath_prepend(str(mods))
    return lambda: forget_plugins(tuple(modules))


def forget_plugins(names):
    """Every trace of the plug-in modules `names` removed from this process: the modules, and the
    registries' loaded and described entries of names beginning with them."""
    from deepcontact.model.arch import NETWORKS
    from deepcontact.solver import methods
    from deepcontact.warmstart.starts import STARTS
    names = tuple(names)
    for name in names:
        sys.modules.pop(name, None)
    for registry in (STARTS, methods.SOLVERS, NETWORKS):
        registry.described = {k: v for k, v in registry.described.items() if not k.startswith(names)}
        registry._loaded = {k: v for k, v in registry._loaded.items() if not k.startswith(names)}
    methods._instances = {k: v for k, v in methods._instances.items() if not k.startswith(names)}


# Every command that reads a run's step files: (run, an output path) -> its arguments.
RUN_READERS = {
    "validate": lambda run, out: ["validate", "-q", run],
    "replay": lambda run, out: ["validate", "--replay", "-q", run],
    "rasterize": lambda run, out: ["rasterize", run, "-q", "-o", out],
    "evaluate": lambda run, out: ["evaluate", "--no-plots", run, "--starts", "zero", "--every", "50",
                                  "--no-budgets", "-q", "-o", out],
    "export": lambda run, out: ["export", run, "-q", "-o", out],
    "export-csv": lambda run, out: ["export", run, "--format", "csv", "-q", "-o", out],
    "render-run": lambda run, out: ["render", run, "--every", "50", "-q", "-o", f"{out}.gif"],
    "render-viewer": lambda run, out: ["render", run, "--every", "50", "-q", "-o", f"{out}.html"],
}
