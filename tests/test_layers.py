"""The house plan: each package of deepcontact imports only the floors below it: output (how every
command writes) at the bottom, then the path scene → step → solver → exchange → simulate → grid → model → warm start → contest → evaluate → studies → render."""
import re
from pathlib import Path

PACKAGE = Path(__file__).parent.parent / "deepcontact"
FLOORS = ["output", "scene", "step", "solver", "exchange", "simulate", "grid", "model", "warmstart", "contest", "evaluate", "studies", "render"]


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


def test_no_module_imports_itself_back():
    """No import cycle among the package's modules (module-level imports, relative and absolute):
    a cycle hidden by a local import is still a cycle in the design, so imports inside functions
    count too."""
    import ast
    modules = {}
    for f in PACKAGE.rglob("*.py"):
        parts = f.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        modules[name] = f
    graph = {}
    for name, f in modules.items():
        package = name if f.name == "__init__.py" else name.rpartition(".")[0]
        found = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")
                    base = ".".join(up[:len(up) - node.level + 1] + ([base] if base else []))
                for alias in node.names:
                    target = f"{base}.{alias.name}"
                    found.add(target if target in modules else base)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
        graph[name] = {m for m in found if m in modules and m != name and not name.startswith(m + ".")
                       and not m.startswith(name + ".")}
    cycles = []

    def visit(node, path, done):
        for nxt in sorted(graph[node]):
            if nxt in path:
                cycles.append(" -> ".join(path[path.index(nxt):] + [nxt]))
            elif nxt not in done:
                done.add(nxt)
                visit(nxt, path + [nxt], done)
    for start in sorted(graph):
        visit(start, [start], {start})
    assert not cycles, sorted(set(cycles))[:10]


def test_the_native_readme_lists_every_native_file():
    native = PACKAGE / "native"
    text = (native / "README.md").read_text()
    named = set()
    for cell in re.findall(r"^\| `([^`]+)` \|", text, flags=re.M):
        stem, _, exts = cell.partition(".{")
        named |= {f"{stem}.{e}" for e in exts.rstrip("}").split(",")} if exts else {cell}
    files = {f.name for f in native.iterdir() if f.suffix in (".hpp", ".cpp")}
    assert files - named == set(), f"native/README.md does not list {sorted(files - named)}"
    assert named - files == set(), f"native/README.md lists files that are gone: {sorted(named - files)}"


def test_no_library_code_prints():
    """Data goes to files and to what the caller is given (a study's StudyText, a report); logs and
    progress to the logger. Only the CLI writes to stdout."""
    import ast
    calls = []
    for f in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                calls.append(f"{f.relative_to(PACKAGE)}:{node.lineno}")
    assert calls == []


def test_benchmarks_import_no_study_and_no_other_benchmark():
    """benchmarks/ only times: what it steps and solves comes from the library's own builders
    (simulate.problems), and what two scripts share lives in common.py."""
    wrong = []
    for f in sorted((PACKAGE.parent / "benchmarks").glob("*.py")):
        for name in re.findall(r"^\s*(?:from|import) ((?:deepcontact\.studies|bench_)[\w.]*)", f.read_text(), flags=re.M):
            wrong.append(f"{f.name} imports {name}")
    assert wrong == []
