"""The installs as a user on any Linux machine meets them: what `make setup` asks pip for, and the
README's pip block line by line in a fresh venv. They reach the package indexes (PyPI, and
PyTorch's CPU index where it answers), so they are behind their own marker: `make test-packaging`.

Before: `make setup` asked for a plain torch==2.13.0, which PyPI alone resolves to the CUDA build
and about 20 CUDA packages (only a local CPU wheel hid it here); the README's `pip install '.[all]'`
failed on "No matching distribution found for deepcontact-studies==0.1.0"."""
import json
import os
import re
import shlex
import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
pytestmark = pytest.mark.packaging

CUDA = re.compile(r"^(nvidia-|cuda|triton)", re.IGNORECASE)


def setup_commands():
    """The pip lines `make setup` would run for the package's dependencies, as make prints them."""
    out = subprocess.run(["make", "-n", "-B", "-C", str(ROOT), ".stamps/install", f"PYTHON={sys.executable}"],
                         check=True, capture_output=True, text=True, timeout=60).stdout
    return [line for line in out.splitlines() if " -m pip install" in line and "-e " not in line]


def resolved(command, report):
    """What pip would install for one command line (`A || B`: as the shell runs it), on a
    machine that has none of it: {name: version}; None where no alternative resolves."""
    for alternative in command.split("||"):
        argv = shlex.split(alternative.replace("2>/dev/null", ""))
        r = subprocess.run([*argv, "--dry-run", "--ignore-installed", "--report", str(report)],
                           capture_output=True, text=True, timeout=600)
        if r.returncode == 0:
            return {i["metadata"]["name"].lower(): i["metadata"]["version"]
                    for i in json.loads(report.read_text())["install"]}
    return None


def test_what_make_setup_asks_pip_for_is_the_cpu_build_and_no_cuda_package(tmp_path):
    commands = setup_commands()
    torch_lines = [c for c in commands if "torch==" in c]
    assert len(torch_lines) == 1 and "torch==2.13.0+cpu" in torch_lines[0], commands
    for command in commands:
        wanted = resolved(command, tmp_path / "report.json")
        assert wanted is not None, f"pip resolved nothing for: {command}"
        assert not [n for n in wanted if CUDA.match(n)], (command, sorted(wanted))
        if command in torch_lines:
            assert wanted["torch"] == "2.13.0+cpu", wanted


def readme_pip_block():
    text = (ROOT / "README.md").read_text()
    block = text.split("### With pip", 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    return [line.split("  #", 1)[0].strip() for line in block.splitlines() if line.strip()]


def test_the_readmes_pip_block_works_line_by_line_in_a_fresh_venv(tmp_path):
    lines = readme_pip_block()
    assert lines and all(line.startswith("pip install ") for line in lines), lines
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    env = {**os.environ, "PATH": f"{env_dir / 'bin'}{os.pathsep}{os.environ['PATH']}", "VIRTUAL_ENV": str(env_dir),
           "PIP_RETRIES": "1"}   # (an index that does not answer here is tried once a package, not five times)
    env.pop("PYTHONPATH", None)
    for line in lines:
        r = subprocess.run(["bash", "-c", line], cwd=ROOT, env=env, capture_output=True, text=True, timeout=1200)
        assert r.returncode == 0, f"{line}\n{r.stderr[-3000:]}"
    py = str(env_dir / "bin" / "python")
    installed = subprocess.run([py, "-m", "pip", "list", "--format", "json"], env=env, check=True,
                               capture_output=True, text=True).stdout
    names = {p["name"].lower(): p["version"] for p in json.loads(installed)}
    assert names.get("torch") == "2.13.0+cpu" and not [n for n in names if CUDA.match(n)], sorted(names)
    for needed in ("deepcontact", "deepcontact-studies", "pymunk", "mujoco", "pyarrow"):
        assert needed in names, sorted(names)
    # every install hint a command prints works too (each is a README line or a published pin)
    from deepcontact.errors import OPTIONAL
    for hint in OPTIONAL.values():
        line = re.search(r"pip install [^(]*?(?= in a clone| \(|$)", hint).group(0).strip()
        r = subprocess.run(["bash", "-c", line], cwd=ROOT, env=env, capture_output=True, text=True, timeout=1200)
        assert r.returncode == 0, f"{line}\n{r.stderr[-3000:]}"
    # what the lines brought runs: a study listed, an engine of the extras and the CPU torch
    r = subprocess.run([str(env_dir / "bin" / "dc"), "study", "--help"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "frontier" in r.stdout, r.stdout + r.stderr
    r = subprocess.run([str(env_dir / "bin" / "dc"), "simulate", "pile", "--engine", "pymunk", "--steps", "5", "-q",
                        "-o", "run"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
