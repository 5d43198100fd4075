"""The package as a user gets it from `pip install .`: a wheel, installed in a fresh venv, runs."""
import os
import site
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
pytestmark = pytest.mark.pipeline


@pytest.fixture(scope="module")
def wheel(request):
    """The wheel `pip wheel .` builds (started when the run began: conftest.BACKGROUND)."""
    from conftest import finished
    (whl,) = finished("wheel", request.config).glob("deepcontact-*.whl")
    return whl


def test_the_wheel_holds_every_package(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    packages = {str(p.parent.relative_to(ROOT)).replace(os.sep, ".") for p in (ROOT / "deepcontact").rglob("__init__.py")}
    for pkg in sorted(packages) + ["deepcontact.cli", "deepcontact.schemas"]:
        assert f"{pkg.replace('.', '/')}/__init__.py" in names, f"{pkg} is missing from the wheel"
    assert any(n.startswith("deepcontact/_box2d") and n.endswith(".so") for n in names)
    assert "deepcontact/schemas/step.xsd" in names


def test_the_wheel_runs_in_a_fresh_venv(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    # the dependencies (numpy, torch, ...) come from this interpreter's site-packages (a .pth file:
    # system_site_packages would take the base interpreter's, which a venv's python is not);
    # deepcontact itself only from the wheel, which the venv's own site-packages puts first
    venv.create(env_dir, with_pip=False)
    py = env_dir / "bin" / "python"
    own = subprocess.run([str(py), "-c", "import site; print(site.getsitepackages()[0])"], check=True,
                         capture_output=True, text=True).stdout.strip()
    Path(own, "deps-of-the-test.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", str(wheel)],
                   check=True, capture_output=True, text=True, timeout=300)
    where = subprocess.run([str(py), "-c", "import deepcontact; print(deepcontact.__file__)"], cwd=tmp_path,
                           check=True, capture_output=True, text=True).stdout
    assert str(env_dir) in where, where
    r = subprocess.run([str(env_dir / "bin" / "dc"), "simulate", "pile", "--steps", "5", "-q", "-o", "run"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "run" / "seed-000000").glob("step-*.xml"))) == 5
