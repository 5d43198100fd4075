"""Start-up: each `dc` command imports what it needs and nothing heavier, so that a Makefile calling
it hundreds of times does not pay for torch, scipy or matplotlib at each call. The times
are benchmarks/bench_startup.py's; these tests hold the import sets, which a new top-level import
would change silently.

Each case runs in a fresh interpreter (a real process: the suite's own has imported everything)
that calls the CLI in-process and reports the modules it then holds."""
import json
import subprocess
import sys

import click
import pytest

from deepcontact.cli.main import COMMANDS, cli

pytestmark = pytest.mark.process

# The modules that cost tens of milliseconds or more to import, and that only some commands use.
HEAVY = ("torch", "scipy", "matplotlib", "lxml", "h5py", "PIL", "pyarrow", "tqdm", "pandas", "sklearn")

PROBE = """
import json, sys
from deepcontact.cli.main import cli
try:
    cli(sys.argv[2:], prog_name="dc")
except SystemExit as e:
    code = e.code or 0
else:
    code = 0
with open(sys.argv[1], "w") as f:
    json.dump({"code": code, "modules": sorted(sys.modules)}, f)
"""


def imported(tmp_path, *args):
    """(exit code, the top-level packages of HEAVY that `dc ARGS` imported, every module's name)."""
    out = tmp_path / "modules.json"
    subprocess.run([sys.executable, "-c", PROBE, str(out), *map(str, args)], check=True, timeout=300,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    got = json.loads(out.read_text())
    heavy = {m.split(".")[0] for m in got["modules"]} & set(HEAVY)
    return got["code"], heavy, set(got["modules"])


def test_the_listing_is_each_commands_own_first_line():
    """`dc --help` lists COMMANDS without importing the subcommands: what it lists must be what
    each command's own help says."""
    ctx = click.Context(cli)
    for name, short in COMMANDS.items():
        command = cli.get_command(ctx, name)
        assert command is not None and command.name == name
        assert command.get_short_help_str(limit=1000) == short, name


def test_dc_help_imports_no_subcommand_and_nothing_heavy(tmp_path):
    code, heavy, modules = imported(tmp_path, "--help")
    assert code == 0
    assert heavy == set()
    assert "numpy" not in modules and "deepcontact._box2d" not in modules
    assert not any(m.startswith("deepcontact.cli.") and m not in ("deepcontact.cli.main",) for m in modules), \
        sorted(m for m in modules if m.startswith("deepcontact.cli."))


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_commands_help_imports_nothing_heavy(tmp_path, name):
    code, heavy, _ = imported(tmp_path, name, "--help")
    assert code == 0
    assert heavy == set(), name


def test_the_pipelines_common_commands_import_what_they_need(tmp_path):
    """simulate needs Box2D and numpy alone; validate and rasterize also lxml (scene files are
    checked against their XSD through it; step files are read natively)."""
    run, data = tmp_path / "run", tmp_path / "data"
    code, heavy, modules = imported(tmp_path, "simulate", "pile", "--param", "count=20", "--param", "box=14",
                                    "--steps", "40", "-q", "-o", run)
    assert code == 0 and (run / "manifest.json").exists()
    assert heavy == set()
    assert "deepcontact._box2d" in modules   # (the probe did simulate)
    code, heavy, _ = imported(tmp_path, "validate", "-q", run)
    assert code == 0 and heavy <= {"lxml"}
    code, heavy, _ = imported(tmp_path, "rasterize", run, "-o", data, "-q")
    assert code == 0 and (data / "metadata.json").exists()
    assert heavy <= {"lxml"}


def test_a_contestants_start_imports_none_of_the_judges_side():
    """Every contestant is a fresh interpreter that imports contest.guest (a thousand of them in a
    run of the suite): the judge's side, the step file reader and writer and the output rules are
    not its to pay for."""
    probe = "import json, sys; import deepcontact.contest.guest; print(json.dumps(sorted(sys.modules)))"
    modules = set(json.loads(subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                                            check=True, timeout=120).stdout))
    judges = {"deepcontact.contest.client", "deepcontact.contest.broker", "deepcontact.contest.sandbox",
              "deepcontact.step.reader", "deepcontact.step.writer", "deepcontact.output", "deepcontact.scene.xml"}
    assert modules & judges == set()
    assert {m.split(".")[0] for m in modules} & set(HEAVY) == set()
    assert "deepcontact.solver.methods" in modules   # (the probe imported the guest)
