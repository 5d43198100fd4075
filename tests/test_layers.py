"""The house plan: each package of deepcontact imports only the floors below it, along the path
scene → step → solver → exchange → simulate → grid → model → warm start → evaluate → studies → render."""
import re
from pathlib import Path

PACKAGE = Path(__file__).parent.parent / "deepcontact"
FLOORS = ["scene", "step", "solver", "exchange", "simulate", "grid", "model", "warmstart", "evaluate", "studies", "render"]


def imported_floors(folder):
    found = {}
    for f in sorted(folder.glob("*.py")):
        for name in re.findall(r"^\s*from (?:\.\.|deepcontact\.)([a-z_]+)", f.read_text(), flags=re.M):
            if name in FLOORS:
                found.setdefault(name, f.name)
    return found


def test_no_floor_imports_one_above_it():
    wrong = []
    for level, floor in enumerate(FLOORS):
        for name, where in imported_floors(PACKAGE / floor).items():
            if FLOORS.index(name) > level:
                wrong.append(f"{floor}/{where} imports {name}")
    assert wrong == []


def test_every_package_has_its_floor():
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert packages == set(FLOORS)
