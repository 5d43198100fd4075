"""Contestants that attack what the judge decides from, keeps and says (issue 72, items 4 and 7),
each written here as a hostile plug-in author would: a start installed under a name that reads as
a variant label, answers carrying arrays no answer holds, an error line that names another
contestant, an engine describing itself in fields of the wrong type. Each is one line naming
it (exit 1; 2 for a name no registry takes), no traceback, nothing written."""
import sys
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
