"""Every public function's bad arguments: the project's InputError (a ValueError) naming the
argument, never Python's TypeError, KeyError or AttributeError from deeper down, a pybind11
error, or an int taken for an open file descriptor. Generated: each argument of a valid call of
each public name, replaced by each bad value."""
import math
import os

import numpy as np
import pytest

import deepcontact as dc
from deepcontact.errors import InputError


@pytest.fixture(scope="module")
def calls(run, tmp_path_factory):
    """{public name: (function, the keyword arguments of a call that works)}."""
    step = run / "seed-000000" / "step-000100.xml"
    header, bodies, contacts = dc.read_step(step)
    problem = dc.StepProblem.from_step(header, bodies, contacts)
    n = problem.points
    scene = dc.read_scene(run / "seed-000000" / "scene.xml")
    spec = dc.GridSpec(x0=0.0, y0=0.0, cell=0.5, nx=30, ny=30, h=0.5)
    empty = tmp_path_factory.mktemp("empty")
    return n, {
        "read_run": (dc.read_run, dict(run_dir=run)),
        "read_step": (dc.read_step, dict(path=step)),
        "run_tables": (dc.run_tables, dict(run_dir=run, every=50)),
        "read_scene": (dc.read_scene, dict(path=run / "seed-000000" / "scene.xml")),
        "generate": (dc.generate, dict(name="pile", seed=0, params={"count": "5"})),
        "SceneSource": (dc.SceneSource, dict(spec="pile", params={}, steps=3)),
        "SoftStep": (dc.SoftStep, dict(substeps=4)),
        "World": (lambda **k: dc.World(**k).step(), dict(scene=scene, engine=dc.Box2D())),
        "Box2D": (dc.Box2D, dict(solver=dc.SolveSettings(), start="builtin")),
        "Box2D3": (dc.Box2D3, dict(soft=None)),
        "StepProblem.from_step": (dc.StepProblem.from_step, dict(header=header, bodies=bodies, contacts=contacts)),
        "contact_keys": (dc.contact_keys, dict(contacts=contacts)),
        "impulses_by_key": (dc.impulses_by_key, dict(keys=dc.contact_keys(contacts), normal=np.zeros(n),
                                                     tangent=np.zeros(n))),
        "solve": (dc.solve, dict(problem=problem, start_normal=np.zeros(n), start_tangent=np.zeros(n),
                                 max_iterations=10, tolerance=1e-4, relaxation=1.0, mode="float64",
                                 accelerate="none", stop_on="residual")),
        "judge": (dc.judge, dict(problem=problem, normal=np.zeros(n), tangent=np.zeros(n))),
        "local_problem": (dc.local_problem, dict(problem=problem)),
        "local_residual": (dc.local_residual, dict(lp=dc.local_problem(problem), r=np.zeros(2 * n))),
        "SolveSettings": (dc.SolveSettings, dict(mode="float64", max_iterations=10, tolerance=1e-4, relaxation=1.0)),
        "reference_solution": (dc.reference_solution, dict(problem=problem, tolerance=1e-10, cap=1000,
                                                           relaxation=1.0)),
        "GridSpec": (dc.GridSpec, dict(x0=0.0, y0=0.0, cell=0.5, nx=30, ny=30, h=0.5)),
        "rasterize": (dc.rasterize, dict(spec=spec, bodies=bodies, contacts=contacts, channels=("mass", "vx"))),
        "TrainConfig": (dc.TrainConfig, dict(lr=0.01)),
        "make_starts": (dc.make_starts, dict(names=["builtin", "zero"])),
        "evaluate_starts": (dc.evaluate_starts, dict(run_dirs=[run], starts=dc.make_starts(["zero"]), every=50)),
        "closed_loop": (dc.closed_loop, dict(scene=scene, starts=dc.make_starts(["zero"]), steps=3,
                                             settings=dc.SolveSettings())),
        "engine_named": (dc.engine_named, dict(name="pymunk", settings={"iterations": 5})),
        "GridDataset": (dc.GridDataset, dict(path=empty)),
        "Predictor": (dc.Predictor, dict(checkpoint=empty / "none.pt")),
    }


def bad_values(n):
    """Values no argument of the API takes in every role: wrong types, non-finite and huge
    numbers, whole numbers beyond any count (and 0 and 1, which are open file descriptors),
    arrays of the wrong shape or with NaN."""
    return {"None": None, "str": "nope", "neg": -1, "zero": 0, "one": 1, "nan": math.nan, "inf": math.inf,
            "huge": 1e300, "list": [], "dict": {}, "object": object(), "bool": True, "bigint": 2 ** 70,
            "array2d": np.zeros((3, 3)), "nan-array": np.full(n, np.nan), "short-array": np.zeros(max(n - 1, 0))}


VALID_ONLY = {"Predictor": {"checkpoint"}, "GridDataset": {"path"}}   # (their valid call fails too: no file)


@pytest.mark.parametrize("name", ["read_run", "read_step", "run_tables", "read_scene", "generate", "SceneSource",
                                  "SoftStep", "World", "Box2D", "Box2D3", "StepProblem.from_step", "contact_keys",
                                  "impulses_by_key", "solve", "judge", "local_problem", "local_residual",
                                  "SolveSettings", "reference_solution", "GridSpec", "rasterize", "TrainConfig",
                                  "make_starts", "evaluate_starts", "closed_loop", "engine_named", "GridDataset",
                                  "Predictor"])
def test_every_bad_argument_is_the_projects_error_naming_it(calls, name):
    n, table = calls
    function, good = table[name]
    stdout_before = os.fstat(1)
    for argument in good:
        for what, bad in bad_values(n).items():
            try:
                function(**{**good, argument: bad})
            except InputError as e:
                # a value of the wrong kind is named by its argument (or its option); a str is
                # a name or a path, and the error names that instead
                named = argument in str(e) or argument.replace("_", " ") in str(e) \
                    or "--" + argument.replace("_", "-") in str(e)
                assert named or isinstance(bad, str) or name in VALID_ONLY, (name, argument, what, str(e))
            except Exception as e:   # noqa: BLE001 (what this test is for)
                pytest.fail(f"{name}({argument}={what}) raised {type(e).__module__}.{type(e).__name__}: {e}")
    assert os.fstat(1) == stdout_before   # (no path argument took 1 for the descriptor and closed it)


def test_a_scene_a_callers_function_makes_is_held_to_a_scene_files_rules(tmp_path):
    """simulate_run(callable) with a NaN velocity aborted Python in Box2D's assert (SIGABRT):
    the scene is checked as a scene file is, one line, before any world is built."""
    import subprocess
    import sys
    code = ("import deepcontact as dc\n"
            "def make(seed):\n"
            "    s = dc.generate('stack', seed, {'count': 2})\n"
            "    s.bodies[-1].vx = float('nan')\n"
            "    return s\n"
            f"dc.simulate_run(make, [0], {str(tmp_path / 'o')!r})\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "InputError" in r.stderr and "velocity and spin must be finite" in r.stderr, \
        (r.returncode, r.stderr[-500:])


def _refused(call, kind=InputError, *words):
    """call() raises the project's `kind` whose one line holds each of `words` (no pybind11 text)."""
    with pytest.raises(kind) as info:
        call()
    text = str(info.value)
    assert "\n" not in text and "incompatible function arguments" not in text, text
    assert all(w in text for w in words), (words, text)


def test_what_a_call_cannot_use_is_refused_when_it_is_given(run, tmp_path):
    """The older audits' API cases: an engine that is no engine (a function loaded by name, an
    object to simulate_run), a setting it does not take, a start without the solver it starts, a
    solver method no registry can name, or a guard that is no bool were Python's AttributeError or
    TypeError, pybind11's text, or accepted and dropped (or refused only at the first step)."""
    from deepcontact.errors import OptionError
    from deepcontact.plugins import PluginError
    source = dc.SceneSource("pile", {"count": "3"}, steps=3)
    _refused(lambda: dc.engine_named("os.path:join"), PluginError, "'os.path:join'", "not a deepcontact Engine")
    _refused(lambda: dc.engine_named("box2d", {"substeps": 4}), OptionError, "no setting 'substeps'")
    _refused(lambda: dc.simulate_run(source, [0], tmp_path / "a", engine=object()), InputError, "'engine'")
    _refused(lambda: dc.simulate_run(source, [0], tmp_path / "b", engine="box2d"), InputError, "'engine'")
    _refused(lambda: dc.simulate_run(lambda seed: 5, [0], tmp_path / "c"), InputError, "'make_scene'", "int")
    _refused(lambda: dc.simulate_run(source, [0], tmp_path / "d", jobs="2"), InputError, "'jobs'")
    assert not any(tmp_path.iterdir())   # (nothing made for any of them)
    _refused(lambda: dc.Box2D(start="zero"), InputError, "'start'", "solver=")
    _refused(lambda: dc.Box2D(start_fn=lambda *a: None), InputError, "'start_fn'", "solver=")
    assert dc.Box2D(solver=dc.SolveSettings()).start == "builtin"
    _refused(lambda: dc.SolveSettings(accelerate="cooling-nowhere"), OptionError, "--accelerate", "'cooling-nowhere'")
    _refused(lambda: dc.Box2D(solver=dc.SolveSettings(accelerate="Not A Name")), OptionError, "--accelerate")
    _refused(lambda: dc.SolveSettings(guard="no"), OptionError, "guard")
    _refused(lambda: dc.TrainConfig(targets=[5]), OptionError, "--targets")
    _refused(lambda: dc.TrainConfig(model=5), OptionError, "--arch")
    _refused(lambda: dc.STARTS.register("five", 5), PluginError, "'five'")
    _refused(lambda: dc.NETWORKS.register("Not A Name", lambda **k: None), PluginError, "'Not A Name'")


def test_a_solve_refuses_what_it_cannot_use_in_the_projects_words(run):
    """dc.solve's settings, flags and starts, and a problem's arrays edited by hand: a number for the
    settings, a str for a flag, a complex start, a tolerance of text for a plug-in method, a row of
    a float dtype or three gravity components were Python's or pybind11's errors."""
    import copy
    from deepcontact.errors import OptionError
    problem = dc.StepProblem.from_step_file(run / "seed-000000" / "step-000100.xml")
    n = problem.points
    assert n
    _refused(lambda: dc.solve(problem, settings=5), InputError, "'settings'")
    _refused(lambda: dc.solve(problem, history="yes"), InputError, "'history'")
    _refused(lambda: dc.solve(problem, np.zeros(n, complex), np.zeros(n)), InputError, "'start_normal'")
    _refused(lambda: dc.solve(problem, np.array([None] * n), np.zeros(n)), InputError, "'start_normal'")
    _refused(lambda: dc.solve(problem, accelerate="os.path:join", tolerance="x"), OptionError, "--tolerance")
    for column, value in (("row_a", problem.contacts["row_a"].astype(float)),
                          ("inv_mass", np.array(["1"] * len(problem.bodies["inv_mass"])))):
        edited = copy.deepcopy(problem)
        (edited.contacts if column in edited.contacts else edited.bodies)[column] = value
        _refused(lambda: dc.solve(edited), InputError, repr(column))
        _refused(lambda: dc.local_problem(edited), InputError, repr(column))
    for field, value in (("gravity", (0.0, -9.81, 0.0)), ("dt", "0.01")):
        edited = copy.deepcopy(problem)
        setattr(edited, field, value)
        _refused(lambda: dc.solve(edited), InputError, repr(field))


def test_a_problem_is_made_only_from_arrays_it_can_use(run):
    """StepProblem.from_step/from_arrays took text, fractions and columns of another length or width
    and failed later in numpy or the native solver (or never); each is one line naming the column,
    and a float64 column the native solver reads in float32 is converted, not refused."""
    header, bodies, contacts = dc.read_step(run / "seed-000000" / "step-000100.xml")
    n = len(contacts["manifold"])

    def made(table, column, value):
        edited = dict(bodies if table == "bodies" else contacts, **{column: value})
        args = (edited, contacts) if table == "bodies" else (bodies, edited)
        return dc.StepProblem.from_step(header, *args)
    for table, column, value in (("contacts", "body_a", np.array(["1"] * n)),
                                 ("contacts", "body_a", contacts["body_a"] + 0.5),
                                 ("contacts", "friction", contacts["friction"][:-1]),
                                 ("contacts", "local_normal", np.zeros((n, 3), np.float32)),
                                 ("contacts", "start_normal_impulse", [["x"]] * n),
                                 ("contacts", "id_key", np.full(n, 2 ** 40)),
                                 ("bodies", "index", np.array(["0"] * len(bodies["index"]))),
                                 ("bodies", "center", bodies["center"][:, :1])):
        _refused(lambda: made(table, column, value), InputError, f"{table} column {column!r}")
    wide = made("bodies", "center", bodies["center"].astype(np.float64))
    assert wide.bodies["center"].dtype == np.float32
    same = dc.solve(dc.StepProblem.from_step(header, bodies, contacts), max_iterations=20)
    assert np.array_equal(dc.solve(wide, max_iterations=20).normal_impulse, same.normal_impulse)
    for keyword, value in (("dt", "x"), ("gravity", 5), ("velocity_iterations", 1.5), ("block_solve", "no")):
        kw = {**dict(dt=0.01, gravity=(0.0, -9.81), velocity_iterations=8, block_solve=True), keyword: value}
        _refused(lambda: dc.StepProblem.from_arrays(bodies, contacts, **kw), InputError, repr(keyword))
    _refused(lambda: dc.contact_keys({k: np.array(["a"]) for k in ("fixture_a", "child_a", "fixture_b", "child_b",
                                                                   "id_key")}), InputError, "'fixture_a'")


def test_a_network_factory_that_builds_no_network_is_named(dataset, tmp_path):
    """A function registered where a network's factory goes returned a function, and dc train
    failed in parameter_count with "'function' object has no attribute 'parameters'" (the catch-all)."""
    from deepcontact.plugins import PluginError
    dc.NETWORKS.register("hands-back-a-function", lambda in_channels, out_channels, height, width: (lambda x: x))
    _refused(lambda: dc.train(dataset, tmp_path / "m", dc.TrainConfig(model="hands-back-a-function", epochs=1),
                              plots=False), PluginError, "'hands-back-a-function'", "not a torch.nn.Module")
    assert not (tmp_path / "m").exists()
