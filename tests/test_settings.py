"""One owner for a solve's settings: solver/settings.py names the defaults, checks a request on
construction (one line naming the flag) and makes the native struct; the CLI reads its defaults
from there, and a plug-in method receives the same object."""
import numpy as np
import pytest

from deepcontact.errors import OptionError
from deepcontact.solver.settings import TOLERANCE, VERDICT_CAP, SolveSettings


@pytest.mark.parametrize("changes,flag,words", [
    (dict(relaxation=2.5), "--relaxation", "relaxation must be in (0, 2)"),
    (dict(relaxation="fast"), "--relaxation", "must be a number"),
    (dict(max_iterations="many"), "--max-iterations", "must be a number"),
    (dict(max_iterations=-1), "--max-iterations", "max_iterations must be >= 0"),
    (dict(tolerance=float("nan")), "--tolerance", "tolerance must be finite"),
    (dict(mode="exact", relaxation=1.5), "--relaxation", "exact is Box2D's PGS"),
    (dict(mode="exact", accelerate="nncg"), "--accelerate", "exact is Box2D's PGS"),
    (dict(mode="float32", accelerate="newton"), "--accelerate", "float64 only"),
])
def test_a_bad_request_is_refused_on_construction_naming_its_flag(changes, flag, words):
    with pytest.raises(OptionError) as e:
        SolveSettings(**changes)
    assert words in str(e.value)
    if flag:
        assert flag in str(e.value)


def test_the_native_struct_holds_the_values_given():
    s = SolveSettings(tolerance=3e-5, max_iterations=77, relaxation=1.3, accelerate="nncg", mode="float32")
    native = s.native(dt=1 / 60)
    assert (native.tolerance, native.max_iterations, native.relaxation) == (3e-5, 77, 1.3)
    assert native.accelerate.name == "nncg" and native.mode.name == "float32" and native.stop_on.name == "residual"
    # no tolerance: a fixed count, whatever measure was named
    assert SolveSettings(tolerance=0.0).native(dt=1 / 60).stop_on.name == "none"
    # a plug-in's settings are made (its rules are its own); the native struct is only the built-ins'
    plugin = SolveSettings(relaxation=None, accelerate="somepkg:Method")
    with pytest.raises(OptionError, match="accelerate"):
        plugin.native(dt=1 / 60)
    assert SolveSettings(relaxation="auto").native(dt=1 / 60).relaxation == 1.0
    assert s.but(tolerance=1e-6).tolerance == 1e-6 and s.tolerance == 3e-5   # (frozen)


def test_every_command_that_solves_to_a_tolerance_takes_its_defaults_from_the_settings():
    from deepcontact.cli.evaluate import evaluate
    from dcstudies.commands import figures
    for command in (evaluate, figures):
        defaults = {p.name: p.default for p in command.params}
        # (the cap at which a verdict can name a variant: solver/settings.VERDICT_CAP)
        assert defaults["tolerance"] == TOLERANCE and defaults["max_iterations"] == VERDICT_CAP, command.name
    from deepcontact.evaluate.command import EvaluateSettings
    s = EvaluateSettings(runs=[], starts=[])
    assert (s.solve.tolerance, s.solve.max_iterations) == (TOLERANCE, VERDICT_CAP)


def test_a_plug_in_method_receives_the_settings_object(run):
    import deepcontact as dc
    from deepcontact.solver import methods
    from deepcontact.step.run_folder import read_run
    seen = []

    class Records:
        def __call__(self, problem, normal, tangent, settings):
            seen.append(settings)
            return dc.MethodResult(normal, tangent, np.zeros(1))

    class RecordsW(Records):
        takes_relaxation = True

    problem = dc.StepProblem.from_step_file(read_run(run).simulations[0].files[40])
    try:
        for name, factory in (("records", Records), ("records-w", RecordsW)):
            dc.SOLVERS.register(name, factory)
            dc.solve(problem, tolerance=1e-3, max_iterations=5, accelerate=name)
        with pytest.raises(dc.InputError, match="takes no over-relaxation"):
            dc.solve(problem, tolerance=1e-3, max_iterations=5, relaxation=1.5, accelerate="records")
        dc.solve(problem, tolerance=1e-3, max_iterations=5, relaxation=1.5, accelerate="records-w")
    finally:
        for name in ("records", "records-w"):
            dc.SOLVERS._builtin.pop(name, None)
            methods._instances.pop(name, None)
    assert all(isinstance(s, SolveSettings) for s in seen)
    assert [(s.accelerate, s.relaxation, s.tolerance, s.max_iterations) for s in seen] == [
        ("records", None, 1e-3, 5), ("records-w", 1.0, 1e-3, 5), ("records-w", 1.5, 1e-3, 5)]
