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


def fresh_venv(env_dir, *wheels):
    """A venv at env_dir with wheels installed (no dependencies: those come from this
    interpreter's site-packages through a .pth file, since system_site_packages would take the
    base interpreter's, which a venv's python is not; deepcontact itself only from the wheel,
    which the venv's own site-packages puts first); returns its python."""
    venv.create(env_dir, with_pip=False)
    py = env_dir / "bin" / "python"
    own = subprocess.run([str(py), "-c", "import site; print(site.getsitepackages()[0])"], check=True,
                         capture_output=True, text=True).stdout.strip()
    Path(own, "deps-of-the-test.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", *map(str, wheels)],
                   check=True, capture_output=True, text=True, timeout=300)
    return py


def test_the_wheel_runs_in_a_fresh_venv(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    py = fresh_venv(env_dir, wheel)
    where = subprocess.run([str(py), "-c", "import deepcontact; print(deepcontact.__file__)"], cwd=tmp_path,
                           check=True, capture_output=True, text=True).stdout
    assert str(env_dir) in where, where
    r = subprocess.run([str(env_dir / "bin" / "dc"), "simulate", "pile", "--steps", "5", "-q", "-o", "run"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "run" / "seed-000000").glob("step-*.xml"))) == 5


def _pins(text):
    import re
    return dict(re.findall(r"\b(torch|pymunk|mujoco)==([0-9][0-9.]*(?:\+\w+)?)", text))


def test_a_plain_install_pulls_no_torch_and_the_extras_pin_what_make_setup_pins(wheel):
    """`pip install deepcontact` resolved torch>=2.13 to PyPI's CUDA build (5.7 GB); the optional
    engines were no extra at all; `[studies]` and `[all]` named deepcontact-studies, on no index, so
    the README's `pip install '.[all]'` failed everywhere but here. torch is pinned by its CPU
    build's own version, which no CUDA build has."""
    meta = zipfile.ZipFile(wheel).read("deepcontact-0.1.0.dist-info/METADATA").decode()
    requires = [line.split(":", 1)[1].strip() for line in meta.splitlines() if line.startswith("Requires-Dist:")]
    plain = [r for r in requires if "extra ==" not in r]
    assert not [r for r in plain if r.split(";")[0].strip().startswith(("torch", "nvidia", "pymunk", "mujoco"))]
    extras = {}
    for r in requires:
        if "extra ==" in r:
            what, extra = r.split(";")
            extras.setdefault(extra.split("==")[1].strip().strip('"'), []).append(what.strip())
    pins = _pins((ROOT / "Makefile").read_text())
    assert pins == {"torch": "2.13.0+cpu", "pymunk": "7.3.1", "mujoco": "4.0.1"}, pins
    assert _pins(" ".join(extras["engines"])) == {k: v for k, v in pins.items() if k != "torch"}
    assert _pins(" ".join(extras["torch"])) == {"torch": pins["torch"]}
    assert "studies" not in extras and not [r for r in requires if "deepcontact-studies" in r], requires
    assert set(extras["all"]) >= set(extras["engines"] + extras["torch"])


def test_the_studies_distribution_installs_beside_the_wheel(wheel, tmp_path):
    """`dc study --help` in a fresh venv with the wheel and the studies' own wheel lists them."""
    env_dir = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-build-isolation", "--no-deps", "-w",
                    str(tmp_path), str(ROOT / "studies")], check=True, capture_output=True, timeout=300)
    (studies,) = tmp_path.glob("deepcontact_studies-*.whl")
    fresh_venv(env_dir, wheel, studies)
    r = subprocess.run([str(env_dir / "bin" / "dc"), "study", "--help"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0 and "Broken" not in r.stdout, r.stdout + r.stderr
    for name in ("stability", "engines", "frontier", "figures", "exact", "peer", "scale"):
        assert f"  {name}  " in r.stdout or f"\n  {name} " in r.stdout, r.stdout


WITHOUT = """
import sys
class Missing:   # (the module not installed: every import of it fails as pip's absence would)
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == {name!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, Missing())
from deepcontact.cli.main import main
sys.argv = ["dc", *sys.argv[1:]]
main()
"""


@pytest.mark.parametrize("module, args, needle", [
    ("torch", ["train", "nowhere", "-o", "m"],
     "pip install torch==2.13.0+cpu --extra-index-url https://download.pytorch.org/whl/cpu"),
    ("pymunk", ["simulate", "pile", "--steps", "3", "--engine", "pymunk", "-o", "r"], "pip install pymunk==7.3.1"),
    ("mujoco", ["simulate", "pile", "--steps", "3", "--engine", "mujoco", "-o", "r"], "pip install mujoco==4.0.1"),
])
def test_a_command_that_needs_an_optional_module_says_which_line_brings_it(tmp_path, module, args, needle):
    from conftest import one_line_error
    r = subprocess.run([sys.executable, "-c", WITHOUT.format(name=module), *args], cwd=tmp_path, capture_output=True,
                       text=True, timeout=120)
    one_line_error(r, needle)
