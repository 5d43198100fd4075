"""What a contestant's sandbox is granted, decided by the judge from what the contestant is (its
plug-ins' names and modules, the files it is given), never from a path or argument a job hands
it: the same for a contestant of `dc evaluate` and one a fenced job asks the broker for. Its
command is the guest's, built here; no option of the job's reaches bubblewrap."""
import importlib.machinery
import importlib.util
import os
import shlex
import stat
import sys
from dataclasses import dataclass

import deepcontact

from ..errors import show_path
from ..output.argument import output_argument
from ..model.arch import NETWORKS
from ..plugins import PluginError
from ..simulate.engines import ENGINES
from ..solver.methods import SOLVERS
from ..warmstart.starts import STARTS
from .shape import KEY_MOST, NAMES_MOST

# a grant's names (or modules, or files), and the characters of each (the broker's form of a request)
NAMES_MAX, NAME_MAX = NAMES_MOST, KEY_MOST


@dataclass(frozen=True)
class Grant:
    """What a contestant runs, as the judge reads it: plug-in names (a registry's name or
    module:attr), modules (an object's), files it is given (a checkpoint)."""
    names: tuple = ()
    modules: tuple = ()
    files: tuple = ()

    def __post_init__(self):
        for field in ("names", "modules", "files"):
            object.__setattr__(self, field, tuple(getattr(self, field)))

    def as_request(self):
        return {"names": list(self.names), "modules": list(self.modules), "files": list(self.files)}

    @classmethod
    def from_request(cls, request, writable=()):
        """A job's grant, each field checked (ValueError naming what is wrong): lists of short
        strings; a file a regular file (a checkpoint), named without a link in any part, outside
        /proc, /sys and /dev and outside every folder the job may write (`writable`): bubblewrap
        binds it by its path after this check, so nothing the job can change may lie on that path
        (a link flipped to `/`, or to /proc/PID/cmdline of a process the job cannot see)."""
        fields = {}
        for field in ("names", "modules", "files"):
            values = request.get(field)
            if not (isinstance(values, list) and len(values) <= NAMES_MAX
                    and all(isinstance(v, str) and 0 < len(v) <= NAME_MAX and "\0" not in v for v in values)):
                raise ValueError(f"{field} must be a list of at most {NAMES_MAX} names")
            fields[field] = values
        fenced = [os.path.realpath(w) for w in writable] + ["/proc", "/sys", "/dev"]
        for path in fields["files"]:
            if (not os.path.isabs(path) or os.path.realpath(path) != os.path.normpath(path)
                    or any(path == w or path.startswith(w.rstrip("/") + "/") for w in fenced)
                    or not stat.S_ISREG(os.lstat(path).st_mode)):
                raise ValueError(f"a file given to a contestant must be a regular file named without a link, "
                                 f"outside the job's own folders: {path!r}")
        for module in fields["modules"]:
            if not all(part.isidentifier() for part in module.split(".")):
                raise ValueError(f"not a module name: {module!r}")
        return cls(**fields)

    def readable(self):
        return readable_paths(self.names, self.modules, self.files)


def package_folder():
    """The folder of the deepcontact this process runs (a contestant imports the same one)."""
    return os.path.dirname(os.path.abspath(deepcontact.__file__))


def guest_argv(channel, torch=False):
    """The contestant's command: the guest, its module imported by name (not run as __main__: the
    one copy a plug-in could patch is the one that serves) from the judge's own deepcontact (its
    folder's parent put first: the interpreter's own path may find another copy), its line to the
    judge the descriptor `channel`; torch: loaded before its clock (a checkpoint's network)."""
    return [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv.pop(2)); "
            "from deepcontact.contest.guest import main; main(sys.argv)",
            str(int(channel)), os.path.dirname(package_folder())] + (["torch"] if torch else [])


def _module_root(module, plain_folder=True):
    """The file or folder of the top-level module `module` belongs to (found, never imported), or
    None; plain_folder: also where it is a folder with no __init__.py (a namespace package)."""
    top = module.split(".")[0]
    if not top or top in sys.builtin_module_names or top in sys.stdlib_module_names:
        return None
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        return None
    if spec is None:
        return None
    if spec.submodule_search_locations:
        return list(spec.submodule_search_locations) if spec.origin is not None or plain_folder else None
    return [spec.origin] if spec.origin and os.path.isabs(spec.origin) else None


def _imported_tops(path):
    """The top-level modules a source file imports (read, never run)."""
    import ast
    try:
        with open(path, "rb") as f:
            tree = ast.parse(f.read())
    except (OSError, SyntaxError, ValueError):
        return []
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.append(node.module)
    return out


def _own_files(who, module, readable):
    """The files and folders of the plug-in `who`'s module (its package's folder, or its one
    file) and of the modules and packages its one file imports (its own helpers), outside what is
    readable already; never a plain folder an import statement names (no __init__.py: a run's, a
    dataset's, which `import runs` with PYTHONPATH=. named into view). PluginError where one lies
    in a folder holding the working directory or a path of this command."""
    out, todo, done = [], [(module, True)], set()
    while todo and len(done) < 100:
        name, own = todo.pop()
        top = name.split(".")[0]
        if top in done:
            continue
        done.add(top)
        for root in _module_root(top, plain_folder=own) or []:
            root = os.path.abspath(root)
            if any(_within(root, r) for r in [*readable, *out]):
                continue
            _refuse_data_folder(who, root)
            _refuse_link_out(who, root)
            out.append(root)
            if root.endswith(".py"):
                todo += [(t, False) for t in _imported_tops(root)]
    return out


def _refuse_data_folder(who, root):
    """PluginError, in one line naming the plug-in, where its module's folder (`root`, or the
    folder of `root`, its one file) is or holds the working directory (a package) or a path this
    command reads or writes (a run, a dataset, a checkpoint, its output)."""
    folder = root if os.path.isdir(root) else os.path.dirname(root)
    cwd = os.getcwd()
    held = [p for p in command_paths() if _within(p, folder)]
    if os.path.isdir(root) and _within(cwd, folder):
        held.insert(0, cwd)
    if held:
        what = "the working directory" if held[0] == cwd else show_path(held[0])
        raise PluginError(f"the plug-in {who!r} lives in {show_path(folder)}, which holds {what} of this command: "
                          f"a plug-in's sandbox reads only its own module's files; move it to a folder of its own "
                          f"(on PYTHONPATH) or install it")


def _refuse_link_out(who, root):
    """PluginError where `root` is a link (or lies in a linked folder) to what no import reads as a
    module, or to a folder holding the working directory or a path of this command: bubblewrap
    binds what the link points at, so `helper.py -> ~/.ssh/id_rsa` (an import in a try) or a
    package linked to `/` would be read under the plug-in's name."""
    real = os.path.realpath(root)
    if real == root:
        return
    if os.path.isfile(real) and not real.endswith(tuple(importlib.machinery.all_suffixes())):
        raise PluginError(f"the plug-in {who!r} names {show_path(root)}, a link to {show_path(real)}, which is no "
                          f"module: a plug-in's sandbox reads only its own module's files")
    _refuse_data_folder(who, real)


def _within(path, folder):
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def command_paths():
    """The paths this dc command names (its runs, datasets, checkpoints, its -o output), absolute,
    read from its command line as the user gave it."""
    from .. import protocol
    try:
        args = shlex.split(protocol.command_line or "")[1:]
    except ValueError:
        return []
    found = [v for a in args for v in (a, a.partition("=")[2] if a.startswith("--") else "") if v]
    out = [os.path.abspath(p) for p in found if os.path.lexists(p)]
    target = output_argument(args)[2]
    return out + ([os.path.abspath(target)] if target else [])


def _plugin_modules(names):
    """([(name, module)], metadata folders) of the plug-ins named here (module:attr names, entry points of
    installed packages: their distribution's metadata too, where the entry point is read), read
    from their names and the packages' metadata, nothing imported."""
    out, metadata = [], []
    for name in names:
        if not isinstance(name, str):
            continue
        if ":" in name:
            out.append((name, name.partition(":")[0]))
            continue
        registries = (STARTS, SOLVERS, NETWORKS, ENGINES)
        if any(name in r.builtin() for r in registries):   # (a built-in's: no scan of the installed packages)
            continue
        for registry in registries:
            found = registry.installed().get(name)
            if found is not None:
                out.append((name, found.value.partition(":")[0]))
                folder = getattr(getattr(found, "dist", None), "_path", None)
                if folder is not None:
                    metadata.append(os.fspath(folder))
                break
    return out, metadata


def runs_plugin_code(names, modules):
    """Whether a contestant runs code that is not the project's: an object's module, or a name
    no registry has built in."""
    registries = (STARTS, SOLVERS, NETWORKS, ENGINES)
    return bool(modules) or any(isinstance(n, str) and not any(n in r.builtin() for r in registries) for n in names)


def readable_paths(names=(), modules=(), files=()):
    """What a contestant's sandbox may read: the interpreter and its installed packages,
    deepcontact, the plug-ins' own modules (by name, and `modules`: each its package's folder or
    its one file, never a folder holding the working directory or a path of this command:
    PluginError) and `files`."""
    import site
    out = [*_interpreter_parts(sys.prefix, sys.base_prefix, sys.exec_prefix),
           os.path.dirname(os.path.realpath(sys.executable)), os.path.dirname(deepcontact.__file__), *_cli_folder()]
    try:
        out += site.getsitepackages() + [site.getusersitepackages()]
    except AttributeError:
        pass
    out = [os.path.abspath(p) for p in out]
    found, metadata = _plugin_modules(names)
    for who, module in [*found, *((m, m) for m in modules)]:
        out += _own_files(who, module, out)
    out += metadata
    out += [os.fspath(f) for f in files if f]
    return [p for p in dict.fromkeys(os.path.abspath(p) for p in out) if os.path.exists(p)]


# What of an environment's folder the interpreter reads (a venv's, a conda environment's)
PREFIX_PARTS = ("bin", "lib", "lib64", "include", "pyvenv.cfg", "conda-meta", "share", "ssl")


def _interpreter_parts(*prefixes):
    """The interpreter's folders: each prefix whole, or, where it holds the working directory or a
    path of this command (a venv made in the project's own folder: `python3 -m venv .`), only its
    PREFIX_PARTS: before, a contestant read the project folder, its runs with it."""
    held = [os.getcwd(), *command_paths()]
    out = []
    for prefix in dict.fromkeys(os.path.abspath(p) for p in prefixes):
        if any(_within(p, prefix) or _within(p, os.path.realpath(prefix)) for p in held):
            out += [os.path.join(prefix, part) for part in PREFIX_PARTS]
        else:
            out.append(prefix)
    return out


def _cli_folder():
    """deepcontact.cli's folder, where it lies apart from the package (an editable install): part
    of the distribution a plug-in may import."""
    try:
        spec = importlib.util.find_spec("deepcontact.cli")
    except (ImportError, ValueError):
        return []
    return list(spec.submodule_search_locations or []) if spec is not None else []


