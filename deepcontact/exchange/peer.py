"""Siconos as an independent peer: its 2D frictional-contact solvers run on our step problems,
exported in FCLIB's format (exchange/fclib.py), in a subprocess of Debian's own Python
(python3-siconos is built for /usr/bin/python3 and is never imported here).
"""
import json
import os
import shutil
import subprocess
from pathlib import Path

from ..errors import InputError

PYTHON = os.environ.get("DC_SICONOS_PYTHON", "/usr/bin/python3")
SCRIPT = Path(__file__).with_name("siconos_peer.py")


def available():
    """Whether Debian's Python can import Siconos and h5py (make setup installs both)."""
    if not shutil.which(PYTHON) and not Path(PYTHON).exists():
        return False
    return subprocess.run([PYTHON, "-c", "import siconos.numerics, h5py"], capture_output=True).returncode == 0


def run(paths, solver="lemke", tolerance=1e-12, timeout=None):
    """Siconos's results on FCLIB files: a list of {"file", "info", "seconds", "residual",
    "stored_residual", "reaction"} (residuals computed on the Siconos side, by its own code)."""
    proc = subprocess.run([PYTHON, str(SCRIPT), "--solver", solver, "--tolerance", repr(tolerance),
                           *map(str, paths)], capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise InputError(f"Siconos ({PYTHON}) failed: {last}")
    return json.loads(proc.stdout)["results"]


def solve_files(paths, solver="lemke"):
    """(seconds, residuals) per file."""
    results = run(paths, solver)
    return [r["seconds"] for r in results], [r["residual"] for r in results]
