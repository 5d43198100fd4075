"""Contestants that attack what the judge decides from, keeps and says,
each written here as a hostile plug-in author would: a start installed under a name that reads as
a variant label, answers carrying arrays no answer holds, an error line that names another
contestant, an engine describing itself in fields of the wrong type. Each is one line naming
it (exit 1; 2 for a name no registry takes), no traceback, nothing written."""
import textwrap
from pathlib import Path

import pytest

from conftest import dc, one_line_error, option_error, plugin_modules

EXAMPLE = Path(__file__).parent.parent / "examples" / "deepcontact-example-plugins"
PILE = ["pile", "--param", "count=6", "--param", "box=8", "--param", "sigma=2"]

PEEK = textwrap.dedent("""
    from deepcontact.warmstart.starts import StartValue

    class Peek:
        '''Declares that it reads the step's answer, and starts from it: an oracle.'''
        needs_reference = True
        def __call__(self, ctx):
            return StartValue(ctx.reference.normal_impulse.copy(), ctx.reference.tangent_impulse.copy(), {})
    """)


@pytest.fixture
def installed_peek(tmp_path, monkeypatch):
    """The oracle above installed as a distribution of its own, its entry point named as replay
    labels a variant of builtin with a method ('builtin+peek')."""
    lib = tmp_path / "lib"
    info = lib / "dc_peek-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dc-peek\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[deepcontact.starts]\nbuiltin+peek = dc_peek:Peek\n"
                                           "peek@1 = dc_peek:Peek\n")
    (lib / "dc_peek.py").write_text(PEEK)
    monkeypatch.syspath_prepend(str(lib))
    yield
    from conftest import forget_plugins
    forget_plugins(("builtin+peek", "peek@1", "dc_peek"))


@pytest.mark.parametrize("name", ["builtin+peek", "peek@1"])
def test_an_installed_name_that_reads_as_a_variant_label_is_no_start(run, tmp_path, installed_peek, name):
    """A verdict reads a variant's start from its label (up to '+' and '@'). Before, the oracle
    installed as 'builtin+peek' got the answer (1 sweep a step) and was read as builtin: no
    oracle, and, listed first, the yardstick itself ('builtin+peek timed against itself'). An
    installed name is held to the form of a registered one (lower case letters, digits, '-')."""
    r = dc("evaluate", "--no-plots", "--no-budgets", run, "--every", "20", "-q", "-o", tmp_path / "r",
           "--starts", f"{name},builtin")
    option_error(r, f"{name!r} is not a start")
    assert not (tmp_path / "r").exists()


HOSTILE = textwrap.dedent("""
    import numpy as np
    from deepcontact.errors import InputError
    from deepcontact.warmstart.starts import StartValue

    def box2d(ctx):
        return StartValue(ctx.problem.start_normal.copy(), ctx.problem.start_tangent.copy(), {})

    def forge(header=None, arrays=None):
        '''Every solve answer this process sends from now on carries these fields and arrays.'''
        import deepcontact.contest.guest as guest
        real = guest.pack
        def forged(head, sent=None):
            sent = dict(sent or {})
            if "claims" in sent:
                head, sent = dict(head, **(header or {})), dict(sent, **(arrays or {}))
            return real(head, sent)
        guest.pack = forged

    class Ballast:
        '''Box2D's warm start and the built-in sweeps, every solve answer 16 MB heavier: an array
        named 'ballast' that no answer holds, kept by the judge with each answer of a step.'''
        def __call__(self, ctx):
            forge(arrays={"ballast": np.zeros(2_000_000)})
            return box2d(ctx)

    class BuiltinClaims:
        '''The same, its built-in method's answers claiming a million residuals (8 MB) each.'''
        def __call__(self, ctx):
            forge(arrays={"claims": np.full(1_000_000, 1e-9)})
            return box2d(ctx)

    class Framer:
        '''Fails with a line of its own making: blaming builtin, naming itself only past what a line
        shows, with a terminal's escape sequence (a window title) in it.'''
        def __call__(self, ctx):
            raise InputError("the variant 'builtin' answered a negative normal impulse \\x1b]0;owned\\x07"
                             + "!" * 700 + " 'hostile:Framer'")

    """)


# The example engine (one file: a plug-in's sandbox reads its own module only), and one that forges
ENGINE = (EXAMPLE / "dc_example_plugins" / "engines.py").read_text() + textwrap.dedent("""

    class TextFlags(Circles):
        '''The example engine, its description's flag 'continuous' the text "no" (true where read
        as Python reads text).'''
        name = "textflags"
        @classmethod
        def from_settings(cls, **settings):
            import deepcontact.contest.guest as guest
            real = guest.pack
            def forged(head, sent=None):
                if isinstance(head.get("engine"), dict):
                    flags = dict(head["engine"]["flags"], continuous="no")
                    head = dict(head, engine=dict(head["engine"], flags=flags))
                return real(head, sent)
            guest.pack = forged
            return super().from_settings(**settings)

    class WideTypes(Circles):
        '''The example engine, its bodies' types sent past an int8's range (258 for a dynamic body, 2).'''
        name = "widetypes"
        @classmethod
        def from_settings(cls, **settings):
            import deepcontact.contest.guest as guest
            real = guest.pack
            def forged(head, sent=None):
                if "bodies.type" in (sent or {}):
                    sent = dict(sent, **{"bodies.type": sent["bodies.type"] + 256})
                return real(head, sent)
            guest.pack = forged
            return super().from_settings(**settings)
    """)


@pytest.fixture
def hostile(tmp_path, monkeypatch):
    forget = plugin_modules(tmp_path, monkeypatch, {"hostile": HOSTILE, "hostile_engine": ENGINE})
    yield
    forget()


def _evaluate(run, out, *args):
    return dc("evaluate", "--no-plots", "--no-budgets", run, "--every", "20", "-q", "-o", out, *args)


@pytest.mark.parametrize("start, needle", [
    ("Ballast", "answered an array 'ballast', which no answer holds"),
    ("BuiltinClaims", "claimed 1,000,000 iterations (or residuals) for a solve asked to stop at 10,000 sweeps"),
])
def test_what_no_answer_holds_is_refused_not_kept(run, tmp_path, hostile, start, needle):
    """Before, both were taken: every answer of a step kept until the step was judged (four a
    variant a step: 64 MB of ballast), and a built-in method's claims, which the judge never
    reads (it traces the method itself), kept from each step's first answer unbounded by the cap."""
    r = _evaluate(run, tmp_path / "r", "--starts", f"builtin,hostile:{start}")
    one_line_error(r, f"the variant 'hostile:{start}'", needle)
    assert not (tmp_path / "r").exists()


def test_an_error_line_names_its_contestant_first_and_carries_no_escape(run, tmp_path, hostile):
    """Before, a line holding the variant's own name anywhere was said as it came: 'dc evaluate:
    error: the variant 'builtin' answered a negative normal impulse ...', cut at 600 characters
    before its name, with the escape sequence sent to the user's terminal."""
    r = _evaluate(run, tmp_path / "r", "--starts", "builtin,hostile:Framer")
    line = one_line_error(r, "dc evaluate: error: the variant 'hostile:Framer': ")
    assert line.startswith("dc evaluate: error: the variant 'hostile:Framer': "), line
    assert "\x1b" not in r.stderr and "\x07" not in r.stderr and "\\x1b]0;owned" in line, line


def test_an_engines_description_is_typed_field_by_field(tmp_path, hostile):
    """Before, its flags were read as Python reads them: "no" was true, and the run was recorded
    as a continuous engine's."""
    r = dc("simulate", *PILE, "--steps", "2", "--engine", "hostile_engine:TextFlags", "-o", tmp_path / "r")
    one_line_error(r, "the engine 'hostile_engine:TextFlags' answered with something that is not an answer",
                   "engine.flags.continuous is 'no', not true or false")
    assert not (tmp_path / "r").exists()


def test_an_engines_value_its_field_cannot_hold_is_one_line(tmp_path, hostile):
    """Before, a body's type of 258 in an int8 field was cast and written as 2 (dynamic: the step
    files the same as the honest engine's), one of 1e300 as 0 (every body static), silently."""
    r = dc("simulate", *PILE, "--steps", "2", "--engine", "hostile_engine:WideTypes", "-o", tmp_path / "r")
    one_line_error(r, "the engine 'hostile_engine:WideTypes' returned bodies.type with a value int8 cannot hold "
                      "(a whole number from -128 to 127)")
    assert not (tmp_path / "r").exists()


def test_an_answer_naming_an_array_twice_is_not_an_answer():
    """Before, the second array of a name replaced the first (whichever the judge was to read)."""
    import json
    import struct

    import numpy as np

    from deepcontact.contest.wire import unpack
    from deepcontact.plugins import PluginError
    head = json.dumps({"arrays": [["normal", 1], ["normal", 1]]}).encode()
    data = struct.pack("<I", len(head)) + head + np.array([1.0, -1.0]).tobytes()
    with pytest.raises(PluginError, match="the variant 'x' answered with something that is not an answer "
                                          r"\(it names the array 'normal' twice\)"):
        unpack(data, "the variant 'x'")
