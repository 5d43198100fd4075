"""The judge owns what it decides from. A contestant is described once, by the
judge, from its factory's declared traits (its own process's description, every field checked):
that one description decides both what its ctx holds and whether it is an oracle, never what its
instance sets on itself. A built-in method's answer from a contestant's process is held to the
judge's own run of that method from the same start, bit for bit."""
import json
import sys
import textwrap

import pytest

from conftest import dc, one_line_error

CONTESTANTS = textwrap.dedent("""
    import json
    import deepcontact.contest.guest as guest
    from deepcontact.warmstart.starts import StartValue

    def builtin(ctx):
        return StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), {})

    class SetsItsOwnTrait:
        '''Declares nothing, then sets needs_reference on its instance, and starts from the answer
        wherever it is given one.'''
        def __init__(self):
            self.needs_reference = True
        def __call__(self, ctx):
            if ctx.reference is not None:
                return StartValue(ctx.reference.normal_impulse.copy(), ctx.reference.tangent_impulse.copy(), {})
            return builtin(ctx)

    def _swapped(**changes):
        '''The solve of the contestant's own process, swapped for another built-in method.'''
        plain = guest.solve
        def faster(problem, normal, tangent, settings=None, **kw):
            return plain(problem, normal, tangent, settings=settings.but(**changes), **kw)
        guest.solve = faster

    class NNCGInside:
        '''Box2D's warm start, whose process answers the plain sweeps it is asked for with NNCG.'''
        def __init__(self):
            _swapped(accelerate="nncg")
        def __call__(self, ctx):
            return builtin(ctx)

    class RelaxedInside:
        '''The same with over-relaxation (w 1.7) in place of plain sweeps.'''
        def __init__(self):
            _swapped(relaxation=1.7)
        def __call__(self, ctx):
            return builtin(ctx)

    class BudgetsInside:
        '''Honest on its solves to the tolerance; NNCG on the fixed sweep budgets (tolerance 0).'''
        def __init__(self):
            plain = guest.solve
            def faster(problem, normal, tangent, settings=None, **kw):
                if settings.tolerance == 0:
                    settings = settings.but(accelerate="nncg")
                return plain(problem, normal, tangent, settings=settings, **kw)
            guest.solve = faster
        def __call__(self, ctx):
            return builtin(ctx)

    class SaysNo:
        needs_reference = "no"
        def __call__(self, ctx):
            return builtin(ctx)

    class EmptyOracle:
        oracle = []
        def __call__(self, ctx):
            return builtin(ctx)

    class TraitsAsAList:
        '''Its process's description of it, rewritten on the way out: traits as a list of names.'''
        def __call__(self, ctx):
            return builtin(ctx)

    _dumps = json.dumps
    def _listed(header, **kw):
        if isinstance(header, dict) and isinstance(header.get("described"), dict):
            for name, d in header["described"].get("starts", {}).items():
                if name.endswith(":TraitsAsAList"):
                    d["traits"] = sorted(k for k, v in d["traits"].items() if v) + ["needs_reference"]
        return _dumps(header, **kw)
    from deepcontact import plugins
    if plugins.contained:   # (in a contestant's process only: its own json, not the test's)
        json.dumps = _listed
    """)


@pytest.fixture
def contestants(tmp_path, monkeypatch):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "described.py").write_text(CONTESTANTS)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    yield "described"
    from deepcontact.warmstart.starts import STARTS
    sys.modules.pop("described", None)
    STARTS._loaded = {k: v for k, v in STARTS._loaded.items() if not k.startswith("described:")}
    STARTS.described = {k: v for k, v in STARTS.described.items() if not k.startswith("described:")}


def _evaluate(run, out, starts, *more):
    return dc("evaluate", "--no-plots", run, "--starts", starts, "--every", "20", "-q", "-o", out, *more)


def _iterations(out, start):
    rows = [line.split(",") for line in (out / "steps.csv").read_text().splitlines()[1:]]
    return {(row[1], row[2]): int(row[6]) for row in rows if row[4] == start}


def test_a_trait_set_on_the_instance_gives_no_answer(run, tmp_path, contestants):
    """Declared nothing, so described as asking for nothing: its ctx holds no reference (it starts
    where builtin does, sweep for sweep) and it is no oracle. Before, its own process said what
    its ctx held: it started from the answer (1 sweep against 11) and was named unflagged."""
    r = _evaluate(run, tmp_path / "r", "builtin,described:SetsItsOwnTrait", "--no-budgets")
    assert r.returncode == 0, r.stderr
    sneaky = _iterations(tmp_path / "r", "described:SetsItsOwnTrait")
    assert sneaky and sneaky == _iterations(tmp_path / "r", "builtin")
    report = (tmp_path / "r" / "report.md").read_text()
    assert "| described:SetsItsOwnTrait |" in report   # (no oracle: its description says it asks for nothing)
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())["starts"]
    assert summary["described:SetsItsOwnTrait"]["residual_median"] > 1e-8   # (it never had the answer)


def test_in_the_loop_too_the_description_decides(run, tmp_path, contestants):
    """Before, the loop computed the reference for it (its own process said it asked) and it took
    1 sweep a step where builtin took 12, unflagged."""
    r = dc("evaluate", "--no-plots", run, "--closed-loop", "--starts", "builtin,described:SetsItsOwnTrait",
           "--no-budgets", "-q", "-o", tmp_path / "loop")
    assert r.returncode == 0, r.stderr
    report = (tmp_path / "loop" / "report.md").read_text()
    # (iterations: median, p80, max; the residual: the same sweeps a step, no answer given)
    rows = {line.split("|")[1].strip(): line.split("|")[3:7] for line in report.splitlines()
            if line.startswith("| builtin |") or line.startswith("| described:")}
    assert rows["described:SetsItsOwnTrait"] == rows["builtin"], rows


@pytest.mark.parametrize("cheat", ["NNCGInside", "RelaxedInside"])
def test_a_builtin_methods_answer_is_the_builtins(run, tmp_path, contestants, cheat):
    """Its process answers 'none' with a faster method: named in one line, never in a verdict.
    Before, its answers were judged by their residual alone, and the report gave it the sweeps of
    the judge's own trace (11, '1.00x') beside the faster method's time."""
    r = _evaluate(run, tmp_path / "r", f"builtin,described:{cheat}", "--no-budgets")
    one_line_error(r, f"described:{cheat}", "built-in method 'none'", "the judge's own run")
    assert not (tmp_path / "r").exists()


def test_a_builtin_methods_budget_answers_are_the_builtins(run, tmp_path, contestants):
    """A fixed sweep budget's answer too: the same count of sweeps, other impulses."""
    r = _evaluate(run, tmp_path / "r", "builtin,described:BudgetsInside")
    one_line_error(r, "described:BudgetsInside", "built-in method 'none'", "other impulses")


@pytest.mark.parametrize("start,said", [("SaysNo", "declares needs_reference = 'no' (str)"),
                                        ("EmptyOracle", "declares oracle = [] (list)"),
                                        ("TraitsAsAList", "traits")])
def test_a_description_of_the_wrong_types_is_one_line(run, tmp_path, contestants, start, said):
    """Before, a "no" was True (bool("no")), [] was False, and traits sent as a list failed in
    the judge with a traceback."""
    r = _evaluate(run, tmp_path / "r", f"builtin,described:{start}", "--no-budgets")
    one_line_error(r, f"described:{start}", said)


def test_the_library_path_decides_from_the_same_description(run, contestants):
    import deepcontact as dcl
    starts = dcl.make_starts(["builtin", "described:SetsItsOwnTrait"])   # (loaded here, by the caller's choice)
    rows = dcl.evaluate_starts([run], starts, every=40)
    by = {}
    for row in rows:
        by.setdefault(row.start, []).append(row.iterations)
    assert by["described:SetsItsOwnTrait"] == by["builtin"]   # (no reference in its ctx)
    from deepcontact.warmstart.starts import described, is_oracle
    assert described("described:SetsItsOwnTrait", starts["described:SetsItsOwnTrait"])["needs_reference"] is False
    assert not is_oracle("described:SetsItsOwnTrait")
