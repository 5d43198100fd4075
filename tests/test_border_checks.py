"""Checks at the border: option values finite in the precision they are kept in, step
files held to their run's engine, -j capped by the work, closed standard streams, and the library
refusing what the CLI refuses, with the project's error types."""
import math
import shutil
import subprocess

import numpy as np
import pytest

from conftest import RUN_READERS, dc, dc_command, one_line_error, option_error
from deepcontact.errors import InputError, OptionError

pytestmark = pytest.mark.audit

PILE = ["pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5"]


@pytest.mark.parametrize("flag", ["--contact-hertz", "--damping-ratio", "--push-speed"])
@pytest.mark.parametrize("value", ["1e39", "1e308", "3.5e38"])
def test_soft_step_values_beyond_float32_are_option_errors(tmp_path, flag, value):
    r = dc("simulate", *PILE, "--engine", "box2d3", "--steps", "3", flag, value, "-q", "-o", tmp_path / "run")
    option_error(r, flag, "float32")
    assert not (tmp_path / "run").exists()


def test_the_library_refuses_what_the_cli_refuses():
    from deepcontact.grid.spec import GridSpec
    from deepcontact.model.config import TrainConfig
    from deepcontact.simulate.engines import SoftStep
    for bad in (dict(contact_hertz=1e39), dict(damping_ratio=math.nan), dict(push_speed=-1.0), dict(substeps=0),
                dict(substeps=True), dict(contact_hertz="30")):
        with pytest.raises(OptionError):
            SoftStep(**bad)
    for bad in (dict(lr=math.nan), dict(lr=0.0), dict(momentum=2.0), dict(dropout=1.0), dict(batch_size=0),
                dict(epochs=1.5), dict(seed=-1), dict(weight_decay=math.inf)):
        with pytest.raises(OptionError):
            TrainConfig(**bad)
    for bad in (dict(cell=math.nan), dict(nx=-1), dict(h=0.0), dict(kernel="nope"), dict(nx=10 ** 9, ny=10 ** 9)):
        with pytest.raises(ValueError) as info:
            GridSpec(**{**dict(x0=0.0, y0=0.0, cell=0.5, nx=10, ny=10, h=0.5), **bad})
        assert isinstance(info.value, InputError)
    GridSpec(x0=0.0, y0=0.0, cell=0.5, nx=10, ny=10, h=0.5)   # (a good one is made)


def test_seeds_the_step_files_cannot_hold_are_refused_by_the_library(tmp_path):
    import deepcontact as dcl
    source = dcl.SceneSource("pile", {"count": "12", "box": "12", "sigma": "2.5"}, 3)
    for seeds in ([2 ** 40], [-1], [0, 0], [1.5], range(2 ** 31 - 1, 2 ** 31 + 1)):
        with pytest.raises(OptionError):
            dcl.simulate_run(source, seeds, tmp_path / "run")
        assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("flag", ["--contact-hertz", "--damping-ratio", "--push-speed"])
@pytest.mark.parametrize("value", ["1e-300", "1e-39", "-1e-45", "1.1e-38"])
def test_soft_step_values_float32_would_lose_are_option_errors(tmp_path, flag, value):
    # 1e-300 is 0 in v3's float32 (a contact of no stiffness), 1e-39 a denormal: refused before
    # any work, as the file's own schema would refuse what v3 was given
    r = dc("simulate", *PILE, "--engine", "box2d3", "--steps", "3", flag, value, "-q", "-o", tmp_path / "run")
    option_error(r, flag)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("flag", ["--contact-hertz", "--damping-ratio", "--push-speed"])
@pytest.mark.parametrize("value", ["1.2e-38", "1e-6", "3.4e38"])
def test_soft_step_values_float32_holds_make_valid_runs(tmp_path, flag, value):
    r = dc("simulate", *PILE, "--engine", "box2d3", "--steps", "3", flag, value, "-q", "-o", tmp_path / "run")
    assert r.returncode == 0, r.stderr
    assert dc("validate", "-q", tmp_path / "run").returncode == 0


@pytest.fixture(scope="module")
def mixed_run(tmp_path_factory):
    """A 2.4.1 run whose step 100 is the v3 run's step 100 (same scene, seed and index), its
    manifest's contact count made to match: only the engine tells the step is foreign."""
    import json
    tmp = tmp_path_factory.mktemp("mixed")
    assert dc("simulate", *PILE, "--steps", "120", "-q", "-o", tmp / "v2").returncode == 0
    assert dc("simulate", *PILE, "--steps", "120", "--engine", "box2d3", "-q", "-o", tmp / "v3").returncode == 0
    run = shutil.copytree(tmp / "v2", tmp / "mixed")
    shutil.copy(tmp / "v3" / MIXED_STEP, run / MIXED_STEP)
    v3 = json.loads((tmp / "v3" / "manifest.json").read_text())["simulations"][0]["file_contact_points"][100]
    manifest = json.loads((run / "manifest.json").read_text())
    manifest["simulations"][0]["file_contact_points"][100] = v3
    (run / "manifest.json").write_text(json.dumps(manifest))
    return run


MIXED_STEP = "seed-000000/step-000100.xml"

@pytest.mark.parametrize("reader", sorted(RUN_READERS))
def test_a_step_of_another_engine_in_a_run_is_refused_by_every_reader(mixed_run, tmp_path, reader):
    r = dc(*RUN_READERS[reader](mixed_run, tmp_path / "out"))
    if reader == "validate":   # (one line a bad file, then the count)
        assert r.returncode == 1 and "stepped by box2d3, but lies in a run of box2d" in r.stdout + r.stderr
    elif reader == "export":   # (FCLIB: 2.4.1's problem only, said before the origin)
        one_line_error(r, "step-000100.xml")
    else:
        one_line_error(r, "stepped by box2d3", MIXED_STEP)
    assert not any(p.name.startswith("out") for p in tmp_path.iterdir())


def test_jobs_beyond_the_work_fork_no_more_workers(tmp_path, monkeypatch):
    from deepcontact import workers
    made = []
    real = workers.Pool.__init__

    def counting(self, jobs, on_progress=None):
        made.append(jobs)
        real(self, jobs, on_progress)
    monkeypatch.setattr(workers.Pool, "__init__", counting)
    r = dc("simulate", *PILE, "--steps", "20", "--seeds", "0..1", "-j", "100000", "-q", "-o", tmp_path / "run")
    assert r.returncode == 0, r.stderr
    assert made == [2]


def test_training_takes_one_thread(dataset, tmp_path):
    option_error(dc("train", "--no-plots", dataset, "--threads", "2", "--epochs", "1", "-q", "-o", tmp_path / "m"),
                 "--threads")
    assert not (tmp_path / "m").exists()


def closed(stream, *args, cwd):
    """`dc ARGS` with the shell's `>&-` (stream 1) or `2>&-` (stream 2)."""
    return subprocess.run(["bash", "-c", f'exec "$@" {stream}>&-', "_", *dc_command(), *map(str, args)],
                          cwd=cwd, timeout=300, text=True, stdout=None if stream == 1 else subprocess.PIPE,
                          stderr=None if stream == 2 else subprocess.PIPE)


def test_closed_standard_streams(run, tmp_path):
    # stderr closed: the logs go nowhere, the work is done
    r = closed(2, "simulate", *PILE, "--steps", "5", "-o", "quiet-run", cwd=tmp_path)
    assert r.returncode == 0 and (tmp_path / "quiet-run" / "manifest.json").exists()
    # stdout closed where it is the only output: refused before the study
    r = closed(1, "study", "stability", "--fast", cwd=tmp_path)
    assert r.returncode == 2 and "standard output is closed" in r.stderr
    # stdout closed where the output is a folder: the folder is written, exit 0
    r = closed(1, "evaluate", "--no-plots", run, "--starts", "zero", "--every", "60", "--no-budgets", "-o", "report",
               cwd=tmp_path)
    assert r.returncode == 0 and (tmp_path / "report" / "report.md").exists(), r.stderr


def test_a_long_history_draws_a_thin_curve(run, tmp_path):
    """The convergence plot draws at most PLOT_POINTS sweeps a curve, whatever the cap: a cap of
    ten million held a steps x sweeps matrix and wrote a 15 MB SVG before."""
    from deepcontact.evaluate.plots import PLOT_POINTS, plotted_sweeps
    assert list(plotted_sweeps(5)) == [0, 1, 2, 3, 4]
    x = plotted_sweeps(10 ** 7)
    assert len(x) <= PLOT_POINTS and x[0] == 0 and x[-1] == 10 ** 7 - 1 and np.all(np.diff(x) > 0)
    r = dc("evaluate", run, "--starts", "zero", "--tolerance", "1e-300", "--max-iterations", "300000", "--every", "60",
           "--no-budgets", "-q", "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "r" / "convergence.svg").stat().st_size < 2_000_000


def test_lxml_inflates_a_compressed_file_within_the_native_readers_bound(tmp_path):
    """lxml inflates gzip by itself: a small compressed scene must not become gigabytes in it."""
    import gzip
    from deepcontact import schema
    scene = tmp_path / "scene.xml"
    assert dc("simulate", "stack", "--param", "count=2", "--write-scene", scene).returncode == 0
    text = scene.read_bytes()
    with gzip.open(tmp_path / "fine.xml", "wb") as g:
        g.write(text)
    assert schema.validate(tmp_path / "fine.xml")[2] == []   # (a compressed scene is read as before)
    with gzip.open(tmp_path / "bomb.xml", "wb") as g:
        g.write(text.replace(b"</scene>", b"<!--" + b" " * (200 << 20) + b"-->\n</scene>"))
    assert (tmp_path / "bomb.xml").stat().st_size < 1 << 20
    errors = schema.validate(tmp_path / "bomb.xml")[2]
    assert len(errors) == 1 and "inflates to more than 64 times" in errors[0]


def test_a_polygon_box2d_v3_cannot_hull_is_one_line_naming_its_line(tmp_path):
    scene = tmp_path / "scene.xml"
    assert dc("simulate", "stack", "--param", "count=2", "--write-scene", scene).returncode == 0
    text = scene.read_text()
    first, end = text.index("<polygon"), text.index("</polygon>")
    sliver = ('<polygon density="1"><vertex x="-0.5" y="-0.5"/><vertex x="0.5" y="-0.5"/>'
              '<vertex x="0" y="-0.4999"/>')
    scene.write_text(text[:first] + sliver + text[end:])
    line = one_line_error(dc("simulate", scene, "--engine", "box2d3", "--steps", "3", "-q", "-o", tmp_path / "run"),
                          "cannot hull")
    assert f"{scene}:" in line and "not a message of ours" not in line
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("threads", [1, 2])
def test_an_allocation_torch_refuses_is_out_of_memory_naming_the_threads(threads):
    import click
    from click.testing import CliRunner
    from deepcontact.cli import options

    @click.command()
    @click.option("--threads", type=int, default=1)
    @options.verbosity
    @options.command("probe")
    def probe(threads, verbose, quiet):
        raise RuntimeError("[enforce fail at alloc_cpu.cpp:117] DefaultCPUAllocator: can't allocate memory: you "
                           "tried to allocate 1099511627776 bytes.")
    r = CliRunner().invoke(probe, ["--threads", str(threads)])
    assert r.exit_code == 1 and "out of memory" in r.stderr and "not a message of ours" not in r.stderr
    assert ("--threads 2" in r.stderr) == (threads == 2)


def test_the_public_api_raises_the_projects_errors_in_one_line(pile_run):
    """What the audit found raising builtins' TypeError, KeyError, AttributeError or a pybind11
    signature dump: InputError (a ValueError), one line; option values as OptionError naming the flag."""
    import deepcontact as dcl
    problem = dcl.StepProblem.from_step_file(next(pile_run.glob("seed-*/step-000100.xml")))
    calls = {
        "read_run(None)": (lambda: dcl.read_run(None), None),
        "generate(seed=-1)": (lambda: dcl.generate("pile", -1), "--seed"),
        "generate(seed='a')": (lambda: dcl.generate("pile", "a"), "--seed"),
        "solve(tolerance='x')": (lambda: dcl.solve(problem, tolerance="x"), "--tolerance"),
        "solve(tolerance=nan)": (lambda: dcl.solve(problem, tolerance=math.nan), "--tolerance"),
        "solve(max_iterations=-1)": (lambda: dcl.solve(problem, max_iterations=-1), "--max-iterations"),
        "solve(max_iterations=2**40)": (lambda: dcl.solve(problem, max_iterations=2 ** 40), "--max-iterations"),
        "solve(relaxation=3)": (lambda: dcl.solve(problem, relaxation=3.0), "--relaxation"),
        "solve(mode='x')": (lambda: dcl.solve(problem, mode="x"), "--mode"),
        "solve(stop_on='x')": (lambda: dcl.solve(problem, stop_on="x", tolerance=1e-4), "--stop-on"),
        "solve(wrong start)": (lambda: dcl.solve(problem, np.zeros(3), np.zeros(3)), None),
        "solve(None)": (lambda: dcl.solve(None), None),
        "judge(wrong)": (lambda: dcl.judge(problem, np.zeros(2), np.zeros(2)), None),
        "reference_solution(None)": (lambda: dcl.reference_solution(None), None),
        "local_problem(None)": (lambda: dcl.local_problem(None), None),
        "contact_keys({})": (lambda: dcl.contact_keys({}), None),
        "from_arrays({}, {})": (lambda: dcl.StepProblem.from_arrays({}, {}, dt=0.01, gravity=(0, -9.81)), None),
    }
    for name, (call, flag) in calls.items():
        with pytest.raises(InputError) as info:
            call()
        assert isinstance(info.value, ValueError) and "\n" not in str(info.value), name
        if flag:
            assert isinstance(info.value, OptionError) and info.value.option == flag, (name, info.value)
