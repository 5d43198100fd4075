"""Every field of every message checked by one bounded checker (deepcontact/contest/shape.py), and
the judge's memory capped: each contestant here forges what its own process sends the judge (the
guest's packing replaced from inside its plug-in code), and each forgery is one line naming it,
exit 1, no traceback. Before, a reply header holding a value nested 50 levels deep, or 4.7 MB of
entries, was taken (the latter took dc from 66 to 250 MB); an engine's step layout of plain
numbers was "TypeError: cannot unpack non-iterable int object" naming nobody; a broker request
with an `id` of the wrong type was refused as "TypeError: unhashable type: 'list'", naming no
field; and a method's answer claiming a million residuals (8 MB) for a solve capped at 10,000
sweeps was kept, every step (27 steps took dc from 60 to 330 MB)."""
import json
import sys
import textwrap
import tracemalloc
from pathlib import Path

import pytest

from conftest import dc, one_line_error, plugin_modules
from deepcontact.contest import fences

EXAMPLE = Path(__file__).parent.parent / "examples" / "deepcontact-example-plugins"
PILE = ["pile", "--param", "count=6", "--param", "box=8", "--param", "sigma=2"]

FORGERS = textwrap.dedent("""
    import numpy as np
    from deepcontact.solver.methods import MethodResult
    from deepcontact.warmstart.starts import StartValue
    import dc_example_plugins.engines as example

    def forge(fields=None, arrays=None):
        '''Every answer this process sends from now on carries these header fields and arrays.'''
        import deepcontact.contest.guest as guest
        real = guest.pack
        def forged(header, sent=None):
            sent = dict(sent or {})
            if "claims" in sent and arrays:
                sent.update(arrays)
            return real(dict(header, **(fields or {})), sent)
        guest.pack = forged

    def box2d(ctx):
        return StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), {})

    class DeepHeader:
        '''Its account of its answers holds a value nested 50 levels (within what JSON's parser reads).'''
        def __call__(self, ctx):
            deep = 0
            for _ in range(50):
                deep = [deep]
            forge({"stats": {"a": deep}})
            return box2d(ctx)

    class BigHeader:
        '''Its answers' headers hold 300,000 entries of seconds (4.7 MB).'''
        def __call__(self, ctx):
            forge({"seconds": {f"part {i}": 0.0 for i in range(300_000)}})
            return box2d(ctx)

    class Claims:
        '''Hands its start back, claiming a million residuals (8 MB) for every solve.'''
        def __call__(self, problem, normal, tangent, settings):
            forge({"iterations": 1_000_000}, {"claims": np.full(1_000_000, 1e-9)})
            return MethodResult(normal, tangent, np.array([1e-9]))

    class NumberLayout(example.Circles):
        '''The example engine, its step's layout a plain number for a field.'''
        def stepper(self, world, scene, record=True):
            forge({"layout": {"bodies.index": 5}})
            return super().stepper(world, scene, record)
    """)


@pytest.fixture
def forgers(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    forget = plugin_modules(tmp_path, monkeypatch, {"forgers": FORGERS})
    yield
    forget()
    sys.modules.pop("dc_example_plugins.engines", None)


def evaluate(run, out, *args):
    return dc("evaluate", "--no-plots", "--no-budgets", run, "--every", "20", "-q", "-o", out, *args)


@pytest.mark.parametrize("start, needle", [
    ("DeepHeader", "the field stats['a'] is [[[["),
    ("BigHeader", "more than the 1,048,576 a message of its kind may take"),
])
def test_a_reply_header_past_its_form_is_one_line_naming_its_contestant(run, tmp_path, forgers, start, needle):
    r = evaluate(run, tmp_path / "r", "--starts", f"builtin,forgers:{start}")
    line = one_line_error(r, f"the variant 'forgers:{start}' answered with something that is not an answer", needle)
    assert "not a message of ours" not in line and not (tmp_path / "r").exists()


def test_an_engine_layout_of_plain_numbers_is_one_line_naming_the_engine(tmp_path, forgers):
    r = dc("simulate", *PILE, "--steps", "2", "--engine", "forgers:NumberLayout", "-o", tmp_path / "r")
    one_line_error(r, "the engine 'forgers:NumberLayout' answered with something that is not an answer",
                   "the field layout['bodies.index'] is 5, not a list of 2 entries")
    assert not (tmp_path / "r").exists()


def test_claims_past_the_cap_are_one_line_and_never_kept(run, tmp_path, forgers):
    """The method claims 8 MB of residuals an answer, four answers a step, for a solve capped at
    10,000 sweeps: refused at its first answer, so dc's own allocations (tracemalloc: the judge's
    process; the contestants are processes of their own) stay within a few answers' bytes, where
    keeping them grew by 8 MB a step."""
    tracemalloc.start()
    try:
        r = dc("evaluate", "--no-plots", "--no-budgets", run, "--every", "5", "-q", "-o", tmp_path / "r",
               "--starts", "builtin", "--accelerate", "none,forgers:Claims")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    one_line_error(r, "the variant 'builtin+forgers:Claims' claimed 1,000,000 iterations (or residuals) for a "
                      "solve asked to stop at 10,000 sweeps")
    # (an honest run of these variants peaks near 16 MB here; keeping the claims took 8 MB more a step: 27 steps)
    assert peak < 64e6, f"{peak / 1e6:.0f} MB"


def test_the_checker_names_the_field_and_bounds_every_form():
    from deepcontact.contest import shape
    layout = {"bodies.x": ["float64", [3]], "contacts.normal": ["float32", [2, 2]]}
    assert shape.checked(layout, "engine layout") == layout
    wrong = [({"bodies.x": ["complex128", [3]]}, "the field layout['bodies.x'][0] is 'complex128', not one of bool"),
             ({"bodies.x": ["float64", [-1]]}, "the field layout['bodies.x'][1][0] is -1, not a whole number"),
             ({"bodies.x": ["float64", [1, 1, 1, 1, 1]]}, "the field layout['bodies.x'][1] is [1, 1, 1, 1, 1]")]
    for value, needle in wrong:
        with pytest.raises(shape.ShapeError, match=needle.replace("[", r"\[").replace("]", r"\]")):
            shape.checked(value, "engine layout", "layout")
    with pytest.raises(shape.ShapeError, match="'argv' is not a field it may hold"):
        shape.checked({"op": "start", "argv": ["--bind", "/", "/x"]}, "broker request")
    with pytest.raises(shape.ShapeError, match="the field grant.names is missing"):
        shape.checked({"op": "start", "grant": {"modules": [], "files": []}}, "broker request")
    with pytest.raises(shape.ShapeError, match="more than the 100 a message"):
        shape.parsed(b"[" + b"0," * 100 + b"0]", "answer", 100)
    with pytest.raises(shape.ShapeError, match="NaN is not a number JSON allows"):
        shape.parsed(b'{"arrays": [], "deepest": NaN}', "answer", 1000)
    with pytest.raises(shape.ShapeError, match="nested deeper than 64"):
        shape.parsed(b"[" * 100_000 + b"]" * 100_000, "answer", 1 << 20)
    # (a description's reader declares its form: the hook)
    saved = shape.FORMS["traits"]
    try:
        shape.declare("traits", shape.Table(shape.Flag(), most=4))
        with pytest.raises(shape.ShapeError, match=r"the field traits\['oracle'\] is \[\], not true or false"):
            shape.checked({"arrays": [], "traits": {"oracle": []}}, "answer")
    finally:
        shape.declare("traits", saved)


BROKER_STUDY = textwrap.dedent("""
    import json
    import click
    from deepcontact.studies import Study

    @click.command("asks")
    @click.option("-o", "--output", "out")
    @click.option("--ask")
    def asks(out, ask):
        '''Puts one request of its own making to the judge's broker (uncaught: its refusal ends it).'''
        from deepcontact.contest import broker
        fields = json.loads(ask)
        broker.remote(fields.pop("op"), **fields)
        with open(out, "w") as f:
            f.write("asked")

    class Asks(Study):
        name, summary, order, writes = "asks", "asks the broker what no job of dc's asks", 92, "file"
        command = staticmethod(lambda: asks)
""")


@pytest.fixture
def asking_study(tmp_path, monkeypatch):
    """A study installed as a distribution of its own (dc-asking-study), an entry point of it."""
    lib = tmp_path / "lib"
    info = lib / "dc_asking_study-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dc-asking-study\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[deepcontact.studies]\nasks = dc_asking_study:Asks\n")
    (lib / "dc_asking_study.py").write_text(BROKER_STUDY)
    monkeypatch.syspath_prepend(str(lib))
    yield
    sys.modules.pop("dc_asking_study", None)


@pytest.mark.skipif(not all(fences().values()), reason=f"a fence is missing here: {fences()}")
@pytest.mark.parametrize("ask, needle", [
    ({"op": "cpu", "id": [1]}, "the field id is [1], not a whole number"),
    ({"op": ["start"]}, "the field op is ['start'], not one of fences, start"),
    ({"op": "start", "grant": {"names": [7], "modules": [], "files": []}}, "the field grant.names[0] is 7, not text"),
])
def test_a_broker_request_with_a_wrong_typed_field_is_refused_naming_it(asking_study, tmp_path, ask, needle):
    r = dc("study", "asks", "-o", tmp_path / "out", "--ask", json.dumps(ask))
    one_line_error(r, "the study 'asks'", "refused: " + needle)
    assert not (tmp_path / "out").exists()


def test_a_fenced_commands_result_record_is_held_to_its_form(tmp_path):
    """The record a fenced dc writes as it ends (contest/result.py) is read through the same checker:
    one of another form is no record (nothing is published), whatever it holds."""
    from deepcontact.contest import result
    path = tmp_path / result.NAME
    good = {"ended": "in order", "code": 0, "message": ""}
    path.write_text(json.dumps(good))
    assert result.read(path) == good
    for bad in ({**good, "code": "0"}, {**good, "code": True}, {**good, "ended": ["in order"]},
                {**good, "message": "x" * 2001}, {**good, "published": True}, {"ended": "in order"}):
        path.write_text(json.dumps(bad))
        assert result.read(path) is None, bad
    path.write_text("[" * 100_000 + "]" * 100_000)
    assert result.read(path) is None
