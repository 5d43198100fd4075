"""The simulations a grid dataset is made from: finished runs, their step files with contacts,
and what the grid needs of each scene."""
import hashlib
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError, count, show_path
from ..scene.xml import read_scene
from ..schema import file_bytes
from ..step import run_folder
from ..step.run_folder import MANIFEST, read_run
from .spec import scene_box


@dataclass(kw_only=True)
class Simulation(run_folder.Simulation):
    """A run folder's simulation (step/run_folder.py) as a dataset's source: its files are the
    steps that become samples (those with contacts, unless asked for all), with the contact
    points of each, and what the grid needs of its scene."""
    run: str             # the run folder, as given
    box: tuple           # the scene's static box (x0, y0, x1, y1), or None
    radius: float        # the scene's smallest circle radius, or None


def _contact_count(path):
    """The contact count a step file declares, found without parsing it (and checked later,
    when the file is read)."""
    try:   # (plain, or dc simulate --compress: inflated within every reader's bound)
        data = file_bytes(path)
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror or e}", path) from None
    i = data.find(b'<contacts count="')
    if i < 0:
        raise InputError("not a step file (no <contacts count=...>)", path)
    j = data.find(b'"', i + 17)
    try:
        n = int(data[i + 17:j])
    except ValueError:
        raise InputError("unreadable <contacts count>", path) from None
    if n == 0 and data.find(b"<contact ", j) >= 0:   # a zero count must not hide a step's contacts
        raise InputError('<contacts count="0"> but it holds <contact> elements', path,
                         data.count(b"\n", 0, i) + 1)
    return n


def _smallest_radius(scene):
    """The smallest circle radius of the scene's moving bodies, or None."""
    radii = [s.radius for b in scene.bodies if b.type != "static" for s in b.shapes if s.kind == "circle"]
    return min(radii) if radii else None


def collect(run_dirs, include_contactless=False):
    """The simulations of finished runs, with the step files that become samples."""
    sims, manifests, seen, simulated = [], [], {}, {}
    for run_dir in map(Path, run_dirs):
        key = run_dir.resolve()
        if key in seen:   # the same simulations in both splits would make validation meaningless
            raise InputError(f"this run is given twice (also as {show_path(seen[key])})", run_dir)
        seen[key] = run_dir
        run = read_run(run_dir)
        raw = (run_dir / MANIFEST).read_bytes()
        manifests.append({"run": str(run_dir), "manifest_sha256": hashlib.sha256(raw).hexdigest(),
                          "scene": run.manifest.get("scene"), "solver": run.manifest.get("solver")})
        for e in run.simulations:
            scene = read_scene(e.scene_file())
            # one simulation in two runs (a copied run) would sit in both training and validation
            same = (e.scene_sha256, e.seed)
            if e.scene_sha256 is not None and same in simulated:
                raise InputError(f"seed {e.seed} of this scene is also in {show_path(simulated[same])}: the same "
                                 "simulation twice (a copied run?) would be in both training and validation", e.path)
            simulated[same] = e.path
            files, counts = [], []
            # the counts the manifest recorded (checked file by file as they are read), else a scan
            for f, n in zip(e.files, e.contacts or map(_contact_count, e.files)):
                if n == 0 and e.contacts and not include_contactless:   # a 0 must not drop a step unread
                    real = _contact_count(f)
                    if real:
                        raise InputError(f"holds {count(real, 'contact point')}, the manifest recorded 0 (changed after "
                                         "the run?)", f)
                if n or include_contactless:
                    files.append(str(f))
                    counts.append(n)
            sims.append(Simulation(**{**vars(e), "files": files, "contacts": counts, "scene": scene.name},
                                   run=str(run_dir), box=scene_box(scene), radius=_smallest_radius(scene)))
    if not sims:
        raise InputError("the runs hold no simulations")
    return sims, manifests
