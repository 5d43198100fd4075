"""A `dc simulate` run folder: its manifest, written and read here, and the step files it lists.

Every reader of runs (validate --replay, rasterize, evaluate) comes through here, so each gets
the same checks: the manifest is a JSON object of the expected shape, every simulation folder it
names lies inside the run folder (no absolute paths, no ``..``), and each folder holds exactly
the number of step files the manifest recorded (a deleted or added file is an error, not a
silently shorter run).
"""
from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import re

from .. import __version__, arguments, jsontext, output
from ..errors import InputError, count
from ..scene.xml import fmt
from .records import check_above, check_pgs

MANIFEST = "manifest.json"
_SIM_DIR = re.compile(r"seed-\d{6,}")
STEP_FILE = re.compile(r"step-(\d{6,})\.xml(\.gz)?")   # plain, or gzip (dc simulate --compress)


@dataclass
class Simulation:
    seed: int
    dir: str          # the folder's name inside the run
    path: Path
    files: list       # its step files, in step order
    extent: tuple = None   # (x0, y0, x1, y1) the bodies stayed in, where the manifest records it
    scene: str = None      # the scene's name, which each step file must repeat (None: not known)
    contacts: list = None  # contact points of each step file, where the manifest records them
    scene_sha256: str = None   # the hash of its scene.xml the manifest recorded
    engine: str = None     # the engine's name, which each step file's header must name (None: not known)
    static_box: tuple = None   # (x0, y0, x1, y1) of the scene's static shapes, where the manifest records it

    def scene_file(self):
        """Its scene.xml, a regular file whose bytes are the ones the run recorded (an edited
        scene would be simulated, or drawn, as another scene than the steps')."""
        import hashlib
        path = require_regular(self.path / "scene.xml")
        if self.scene_sha256 is not None and hashlib.sha256(path.read_bytes()).hexdigest() != self.scene_sha256:
            raise InputError("changed since the run: its SHA-256 is not the one the manifest recorded", path)
        return path


@dataclass
class Run:
    path: Path
    manifest: dict    # None for an unfinished run
    simulations: list

    @property
    def step_files(self):
        return [f for s in self.simulations for f in s.files]


def _int(entry, key, index, path):
    value = entry.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputError(f"simulation {index}: {key!r} must be a non-negative integer, got {value!r}", path)
    return value


def _extent(entry, index, path, key="extent"):
    value = entry.get(key)
    if value is None:
        return None
    ok = (isinstance(value, list) and len(value) == 4
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value))
    if not ok or value[0] > value[2] or value[1] > value[3]:
        raise InputError(f"simulation {index}: {key!r} must be [x0, y0, x1, y1], finite, got {value!r}", path)
    return tuple(float(v) for v in value)


def _file_contacts(entry, index, files, path):
    """The manifest's contact points per step file (written by dc simulate since compressed runs;
    None for older runs): whole numbers, one per file. Readers still check them against the
    files as they read them."""
    value = entry.get("file_contact_points")
    if value is None:
        return None
    if (not isinstance(value, list) or len(value) != files
            or not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 2 ** 31 - 1 for v in value)):
        raise InputError(f"simulation {index}: 'file_contact_points' must list one whole number per step file "
                         f"({files})", path)
    return value


def step_files_in(folder):
    """The step files of a simulation folder, sorted; anything by that name that is not a regular
    file (a FIFO, a device, a folder) is refused: reading it could block or mislead."""
    files, seen = [], {}
    with os.scandir(folder) as it:
        for e in it:
            m = STEP_FILE.fullmatch(e.name)
            if m:
                if not e.is_file():
                    raise InputError("not a regular file", e.path)
                index = int(m.group(1))
                if index in seen:   # step-000007.xml beside step-000007.xml.gz: which one is the step?
                    raise InputError(f"step {index} is there twice ({seen[index]} and {e.name})", folder)
                seen[index] = e.name
                files.append(Path(e.path))
    return sorted(files)


def step_index(path):
    """The step number in a step file's name (step-NNNNNN.xml or .xml.gz)."""
    m = STEP_FILE.fullmatch(Path(path).name)
    if m is None:
        raise InputError("not named like a step file (step-NNNNNN.xml)", path)
    return int(m.group(1))


def step_path(folder, index):
    """The file of step `index` in a simulation folder, plain or compressed."""
    plain = Path(folder) / f"step-{index:06d}.xml"
    packed = plain.with_name(plain.name + ".gz")
    return packed if not plain.exists() and packed.exists() else plain


def require_regular(path):
    """path, if it is a regular file; InputError otherwise (a FIFO would block a reader)."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    if not path.is_file():
        raise InputError("not a regular file", path)
    return path


def write_manifest(run_dir, scene, engine, *, source, pgs, skip_contactless, simulations, compression="none",
                   engine_settings=None, soft_step=None):
    """The run's manifest, written last (its presence means the run is complete); returns it.
    scene: the first simulation's scene; engine: what stepped it (a simulate.engines.Engine);
    simulations: one dict per simulation (seed, dir, steps, files, contact_points, scene_sha256,
    extent)."""
    own_iterations = engine.rows == "box2d"   # (2.4.1's iterations are the scene's; others have settings)
    manifest = {
        "format": 1,
        "kind": "deepcontact-run",
        "scene": scene.name,
        "source": source,
        "generator": scene.generator,
        "params": scene.params,
        "solver": engine.solver_name,
        "pgs": pgs,
        "engine": engine.name,
        "engine_label": engine.label,
        "engine_settings": engine.settings() if engine_settings is None else engine_settings,
        # whether replay, evaluate and export can pose its steps' problem (Box2D 2.4.1's)
        "poses_box2d_problem": engine.poses_box2d_problem,
        "velocity_iterations": scene.solver.velocity_iterations if own_iterations else None,
        "position_iterations": scene.solver.position_iterations if own_iterations else None,
        **({} if soft_step is None else {"soft_step": soft_step}),
        "dt": float(fmt(scene.dt)),
        "skip_contactless": skip_contactless,
        "compression": compression,
        "engine_version": engine.version(),
        # (the Box2D engines' version under "box2d", as their runs always recorded it)
        "versions": {"deepcontact": __version__, "box2d" if engine.rows != "own" else engine.name: engine.version()},
        "simulations": simulations,
    }
    output.write_text(Path(run_dir) / MANIFEST, json.dumps(manifest, indent=2) + "\n")
    return manifest


def read_manifest(run_dir):
    """The manifest of a finished run, checked for shape; InputError naming the file otherwise."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError("not a run folder", run_dir)
    path = run_dir / MANIFEST
    if not path.is_file():
        raise InputError("no manifest.json: not a finished `dc simulate` run", run_dir)
    try:
        m = jsontext.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"unreadable manifest: {e}", path) from None
    if not isinstance(m, dict):
        raise InputError(f"the manifest must be a JSON object, not {type(m).__name__}", path)
    if not isinstance(m.get("simulations"), list):
        raise InputError("the manifest has no list of simulations", path)
    _check_field_kinds(m, path)
    if m.get("solver") == "pgs":
        check_pgs(m.get("pgs"), path)
    for record in m["simulations"]:
        if isinstance(record, dict):
            check_above(record, path)
    return m


# What each field write_manifest writes holds (None: where a run may record none): a reader
# compares, hashes and prints them, and a list where a name goes was the catch-all's TypeError.
_TEXT, _WHOLE, _TABLE = (str,), (int,), (dict,)
FIELD_KINDS = {"format": _WHOLE, "kind": _TEXT, "scene": _TEXT, "source": _TEXT + (type(None),),
               "generator": _TEXT + (type(None),), "params": _TABLE + (type(None),), "solver": _TEXT,
               "pgs": _TABLE + (type(None),), "engine": _TEXT, "engine_label": _TEXT, "engine_settings": _TABLE,
               "poses_box2d_problem": (bool,), "velocity_iterations": _WHOLE + (type(None),),
               "position_iterations": _WHOLE + (type(None),), "soft_step": _TABLE, "dt": (int, float),
               "skip_contactless": (bool,), "compression": _TEXT, "engine_version": _TEXT, "versions": _TABLE}
_KIND_WORDS = {str: "text", int: "a whole number", dict: "an object", bool: "true or false", float: "a number",
               type(None): "null"}


def _check_field_kinds(m, path):
    """InputError naming the first field of the manifest m whose value is of another kind than
    write_manifest writes (a field it lacks is an older run's: its readers say what they need)."""
    for key, kinds in FIELD_KINDS.items():
        value = m.get(key)
        if key in m and (not isinstance(value, kinds) or isinstance(value, bool) and bool not in kinds):
            wanted = " or ".join(dict.fromkeys(_KIND_WORDS[k] for k in kinds))
            shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
            raise InputError(f"the manifest's {key!r} must be {wanted}, got {shown}", path)


def simulation_folder(run_dir, name, manifest_path):
    """The folder `name` inside run_dir; refuses anything that would lead outside it."""
    if not isinstance(name, str) or not _SIM_DIR.fullmatch(name):
        raise InputError(f"simulation folder {name!r} is not a seed-NNNNNN folder of this run "
                         f"(paths leading elsewhere are refused)", manifest_path)
    return Path(run_dir) / name


# What stepped a run, by its manifest's solver (for messages).
STEPPED_BY = {"box2d": "Box2D 2.4.1's own solver", "pgs": "the project's solver (--solver pgs)",
              "box2d3": "Box2D v3 (--engine box2d3), whose soft step does not pose 2.4.1's contact problem"}


def _check_stepped_by(m, path, solver, purpose, problem):
    """Refuses a run stepped by another solver than `solver`, or one whose steps do not pose Box2D
    2.4.1's contact problem where `problem` says what needs it (read_run)."""
    if solver is not None and m.get("solver", "box2d") != solver:
        stepped = STEPPED_BY.get(m.get("solver")) or (
            f"{m['engine_label']} (--engine {m.get('engine')}), which does not pose Box2D 2.4.1's contact problem"
            if isinstance(m.get("engine_label"), str) else repr(m.get("solver")))
        raise InputError(f"{purpose or f'this needs a run of the {solver} solver'}; this run was stepped by "
                         f"{stepped}", path)
    if problem is not None and m.get("poses_box2d_problem", m.get("engine", "box2d") == "box2d") is not True:
        raise InputError(f"{problem} Box2D 2.4.1's contact problem; this run was stepped by "
                         f"{m.get('engine_label') or m.get('engine')!s} (--engine {m.get('engine')}), whose steps do "
                         f"not pose it", path)


def _simulation(run_dir, m, i, e, path, seen):
    """The manifest's simulation i (its entry e), checked against its folder; seen: the dirs and
    seeds of the simulations before it."""
    if not isinstance(e, dict):
        raise InputError(f"simulation {i} must be a JSON object", path)
    if "dir" not in e:
        raise InputError(f"simulation {i} has no 'dir'", path)
    folder = simulation_folder(run_dir, e["dir"], path)
    seed = _int(e, "seed", i, path)
    for key, value in (("dir", e["dir"]), ("seed", seed)):
        if (key, value) in seen:
            raise InputError(f"simulations {seen[key, value]} and {i} have the same {key} {value!r}", path)
        seen[key, value] = i
    if not folder.is_dir():
        raise InputError(f"simulation {i}: folder {e['dir']} is missing", path)
    files = step_files_in(folder)
    if "files" in e:
        want = _int(e, "files", i, path)
        if len(files) != want:
            raise InputError(f"{e['dir']} holds {count(len(files), 'step file')}, the manifest recorded {want} "
                             f"(files deleted or added after the run?)", folder)
    digest = e.get("scene_sha256")
    if digest is not None and not (isinstance(digest, str) and re.fullmatch(r"[0-9a-f]{64}", digest)):
        raise InputError(f"simulation {i}: 'scene_sha256' must be 64 hexadecimal digits", path)
    return Simulation(seed=seed, dir=e["dir"], path=folder, files=files, extent=_extent(e, i, path),
                      scene=m.get("scene"), contacts=_file_contacts(e, i, len(files), path),
                      scene_sha256=digest, engine=m.get("engine", "box2d"),
                      static_box=_extent(e, i, path, "static_box"))


def read_run(run_dir: str | os.PathLike, solver: str | None = None, purpose: str | None = None,
             unfinished: bool = False, problem: str | None = None) -> Run:
    """A finished run: its manifest and each simulation's step files, counted against it.

    solver: refuse runs whose manifest names another solver ("box2d" or "pgs"); purpose says
    why in the message. problem: refuse runs of an engine whose steps do not pose Box2D 2.4.1's
    contact problem (the manifest's poses_box2d_problem); it says what needs it. unfinished: a folder without a manifest (a run still being written, or
    step files copied by hand) is read from its seed-NNNNNN folders, with nothing to check the
    files against."""
    run_dir = Path(arguments.path(run_dir, "run_dir"))   # (a run is a folder's path)
    if unfinished and run_dir.is_dir() and not (run_dir / MANIFEST).exists():
        sims = [Simulation(seed=int(p.name[5:]), dir=p.name, path=p, files=step_files_in(p))
                for p in sorted(run_dir.iterdir()) if _SIM_DIR.fullmatch(p.name) and p.is_dir()]
        return Run(path=run_dir, manifest=None, simulations=sims)
    m = read_manifest(run_dir)
    path = run_dir / MANIFEST
    _check_stepped_by(m, path, solver, purpose, problem)
    sims, seen = [], {}
    for i, e in enumerate(m["simulations"]):
        sims.append(_simulation(run_dir, m, i, e, path, seen))
    return Run(path=run_dir, manifest=m, simulations=sims)
