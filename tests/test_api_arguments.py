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
        "Box2D": (dc.Box2D, dict(solver=None, start="builtin")),
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
