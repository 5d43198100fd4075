import shutil
import subprocess
import sys

import pytest

from deepcontact.simulate.run import run
from deepcontact.simulate.source import SceneSource

# A small pile: enough contacts (two-point manifolds on the walls included) to exercise every
# field, fast enough for every test run.
SMALL_PILE = dict(count="30", box="16", sigma="4", steps="150")


def simulate(out_dir, spec="pile", seeds=(0,), params=None, **kw):
    params = dict(SMALL_PILE if params is None and spec == "pile" else (params or {}))
    steps = params.pop("steps", None)
    source = SceneSource(spec, params, int(steps) if steps else None)
    return run(source, list(seeds), out_dir, **kw)


@pytest.fixture(scope="session")
def pile_run(tmp_path_factory):
    """A finished small-pile run folder (read-only for tests: copy before changing)."""
    out = tmp_path_factory.mktemp("pile") / "run"
    simulate(out)
    return out


def dc(*args, check=False, timeout=120):
    """Run the installed `dc` as a user would; returns the CompletedProcess."""
    exe = shutil.which("dc")
    cmd = [exe, *args] if exe else [sys.executable, "-m", "deepcontact.cli.main", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=check)
