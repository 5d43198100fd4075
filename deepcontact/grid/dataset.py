"""Grid datasets: what `dc rasterize` writes and `dc train` reads.

A dataset is a folder of plain NumPy `.npy` arrays plus `metadata.json` (see datasets/README.md).
`.npy` because every ML user can open it without this package, `numpy.load(..., mmap_mode="r")`
memory-maps it (a 150-simulation dataset is several GB: samples are read as they are used, never
all at once), and it streams in order from disk; no extra dependency (HDF5, zarr) is needed.

    inputs.npy            (N, C_in, H, W) float32
    labels.npy            (N, C_out, H, W) float32
    simulation.npy        (N,) int32   index into metadata["simulations"]
    step.npy              (N,) int32   step index within its simulation
    contact_offsets.npy   (N + 1,) int64: sample i's contact points are rows offsets[i]:offsets[i+1] of
    contact_position.npy  (M, 2) float32
    contact_impulse.npy   (M, 2) float32 (normal, tangent)
    metadata.json         kernel, d, h, renormalisation, grid, channels, sources, split, versions

Train/validation splits are by simulation, never by step (neighbouring steps are nearly equal).
"""
import hashlib
import json
import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__, atomic
from .._box2d import box2d_version
from ..errors import InputError
from ..resources import check_memory, gigabytes
from ..scene.xml import read_scene
from ..step.reader import read_step_for_grid
from ..step.run_folder import MANIFEST, read_run, simulation_folder
from .spec import GridSpec, scene_box
from .splat import check_channels, rasterize_step

log = logging.getLogger(__name__)
FORMAT = 1
ARRAYS = ("inputs", "labels", "simulation", "step", "contact_offsets", "contact_position", "contact_impulse")


@dataclass
class Simulation:
    run: str
    dir: str
    seed: int
    scene: str
    box: tuple
    radius: float
    files: list          # step files with contacts (or all, with include_contactless)
    contacts: list       # contact points per file


def _contact_count(path):
    data = Path(path).read_bytes()
    i = data.find(b'<contacts count="')
    if i < 0:
        raise InputError("not a step file (no <contacts count=...>)", path)
    j = data.find(b'"', i + 17)
    try:
        return int(data[i + 17:j])
    except ValueError:
        raise InputError("unreadable <contacts count>", path) from None


def _smallest_radius(scene):
    radii = [s.radius for b in scene.bodies if b.type != "static" for s in b.shapes if s.kind == "circle"]
    return min(radii) if radii else None


def collect(run_dirs, include_contactless=False):
    """The simulations of finished runs, with the step files that become samples."""
    sims, manifests = [], []
    for run_dir in map(Path, run_dirs):
        run = read_run(run_dir)
        raw = (run_dir / MANIFEST).read_bytes()
        manifests.append({"run": str(run_dir), "manifest_sha256": hashlib.sha256(raw).hexdigest(),
                          "scene": run.manifest.get("scene"), "solver": run.manifest.get("solver")})
        for e in run.simulations:
            scene = read_scene(e.path / "scene.xml")
            files, counts = [], []
            for f in e.files:
                n = _contact_count(f)
                if n or include_contactless:
                    files.append(str(f))
                    counts.append(n)
            sims.append(Simulation(run=str(run_dir), dir=e.dir, seed=e.seed, scene=scene.name,
                                   box=scene_box(scene), radius=_smallest_radius(scene), files=files,
                                   contacts=counts))
    if not sims:
        raise InputError("the runs hold no simulations")
    return sims, manifests


def grid_for(sims, cell, h, kernel, renormalize, window=None):
    if window is None:
        boxes = {s.box for s in sims}
        if None in boxes:
            raise InputError("a scene has no static bodies to take a box from; give --window x0,y0,x1,y1")
        if len(boxes) > 1:
            raise InputError(f"the simulations have different boxes ({', '.join(map(str, sorted(boxes)))}); "
                             f"give one --window x0,y0,x1,y1 for all")
        window = boxes.pop()
    return GridSpec.over(window, cell, h, kernel, renormalize)


def _rasterize_simulation(args):
    spec, inputs, labels, files = args
    xi = np.empty((len(files), len(inputs), spec.ny, spec.nx), np.float32)
    yl = np.empty((len(files), len(labels), spec.ny, spec.nx), np.float32)
    steps = np.empty(len(files), np.int32)
    positions, impulses, outside = [], [], 0
    for k, path in enumerate(files):
        header, bodies, contacts = read_step_for_grid(path)
        xi[k], yl[k] = rasterize_step(spec, bodies, contacts, inputs, labels)
        steps[k] = header["index"]
        positions.append(contacts["position"])
        impulses.append(np.stack([contacts["normal_impulse"], contacts["tangent_impulse"]], axis=1))
        p = contacts["position"]
        outside += int(np.count_nonzero((p[:, 0] < spec.x0) | (p[:, 1] < spec.y0)
                                        | (p[:, 0] > spec.x0 + (spec.nx - 1) * spec.cell)
                                        | (p[:, 1] > spec.y0 + (spec.ny - 1) * spec.cell)))
    pos = np.concatenate(positions) if positions else np.empty((0, 2), np.float32)
    imp = np.concatenate(impulses) if impulses else np.empty((0, 2), np.float32)
    return xi, yl, steps, pos, imp, outside


def split_simulations(count, validation_fraction, seed):
    """{"train": [...], "validation": [...]} of simulation indices, chosen by a seeded shuffle."""
    order = np.random.default_rng(seed).permutation(count)
    n_val = int(round(validation_fraction * count))
    if validation_fraction > 0 and count > 1:
        n_val = min(max(n_val, 1), count - 1)
    else:
        n_val = 0
    return {"train": sorted(int(i) for i in order[n_val:]), "validation": sorted(int(i) for i in order[:n_val])}


def write_dataset(run_dirs, out, *, cell=0.5, h=0.5, kernel="poly6", renormalize=True, inputs=None,
                  labels=None, window=None, include_contactless=False, validation_fraction=0.2, seed=0,
                  jobs=1, overwrite=False, progress=None, max_memory=None):
    """Rasterize every step of the runs into a dataset folder, atomically. Returns its metadata.

    Refuses (before writing) work whose images would not fit in max_memory GB (each worker holds
    one simulation's) or on the disk."""
    from .splat import DEFAULT_INPUTS, DEFAULT_LABELS
    inputs = list(inputs or DEFAULT_INPUTS)
    labels = list(labels or DEFAULT_LABELS)
    check_channels(inputs, "input")
    check_channels(labels, "label")
    out = Path(out)
    atomic.check_replaceable(out, overwrite, ("metadata.json",), "dataset")
    if not 0 <= validation_fraction < 1:
        raise InputError(f"--validation must be in [0, 1), got {validation_fraction}")
    sims, manifests = collect(run_dirs, include_contactless)
    spec = grid_for(sims, cell, h, kernel, renormalize, window)
    n = sum(len(s.files) for s in sims)
    m = sum(sum(s.contacts) for s in sims)
    if n == 0:
        raise InputError("no steps with contacts in these runs (use --include-contactless to keep them)")
    per_sample = (len(inputs) + len(labels)) * spec.nx * spec.ny * 4
    longest = max(len(s.files) for s in sims)
    check_memory(per_sample * longest * min(jobs, len(sims)),
                 max_memory, f"rasterizing at d = {spec.cell:g} ({spec.nx} x {spec.ny} nodes)")
    parent = out.resolve().parent
    while not parent.exists():
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    if per_sample * n > free:
        raise InputError(f"the dataset would take {gigabytes(per_sample * n):.3g} GB on disk; "
                         f"{gigabytes(free):.3g} GB are free there", out)
    radii = [s.radius for s in sims if s.radius is not None]
    for w in spec.rule_warnings(min(radii) if radii else None):
        log.warning(w)

    with atomic.folder(out) as tmp:
        arrays = {
            "inputs": np.lib.format.open_memmap(tmp / "inputs.npy", "w+", np.float32, (n, len(inputs), spec.ny, spec.nx)),
            "labels": np.lib.format.open_memmap(tmp / "labels.npy", "w+", np.float32, (n, len(labels), spec.ny, spec.nx)),
            "simulation": np.empty(n, np.int32), "step": np.empty(n, np.int32),
            "contact_offsets": np.zeros(n + 1, np.int64),
            "contact_position": np.empty((m, 2), np.float32), "contact_impulse": np.empty((m, 2), np.float32),
        }
        row = point = outside = 0
        tasks = [(spec, inputs, labels, s.files) for s in sims]
        if jobs > 1:
            from concurrent.futures import ProcessPoolExecutor
            pool = ProcessPoolExecutor(max_workers=jobs)
            results = pool.map(_rasterize_simulation, tasks)
        else:
            pool, results = None, map(_rasterize_simulation, tasks)
        try:
            for i, (xi, yl, steps, pos, imp, out_count) in enumerate(results):
                k = len(steps)
                arrays["inputs"][row:row + k] = xi
                arrays["labels"][row:row + k] = yl
                arrays["simulation"][row:row + k] = i
                arrays["step"][row:row + k] = steps
                counts = np.array(sims[i].contacts, dtype=np.int64)
                if counts.sum() != len(pos):
                    raise InputError("step files changed while rasterizing", sims[i].run)
                arrays["contact_offsets"][row + 1:row + k + 1] = point + np.cumsum(counts)
                arrays["contact_position"][point:point + len(pos)] = pos
                arrays["contact_impulse"][point:point + len(imp)] = imp
                row, point, outside = row + k, point + len(pos), outside + out_count
                if progress is not None:
                    progress.update(k)
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)
        for name in ("inputs", "labels"):
            arrays[name].flush()
        del arrays["inputs"], arrays["labels"]
        for name, a in arrays.items():
            np.save(tmp / f"{name}.npy", a)
        if outside:
            log.info("%d contact points lie outside the grid (interpolation clamps them to its edge)", outside)
        metadata = {
            "format": FORMAT,
            "kind": "deepcontact-dataset",
            "samples": n,
            "contact_points": m,
            "grid": spec.as_dict(),
            "inputs": inputs,
            "labels": labels,
            "contactless_steps": "kept" if include_contactless else "skipped",
            "contacts_outside_grid": outside,
            "simulations": [{"run": s.run, "dir": s.dir, "seed": s.seed, "scene": s.scene, "samples": len(s.files)}
                            for s in sims],
            "sources": manifests,
            "split": split_simulations(len(sims), validation_fraction, seed),
            "split_seed": seed,
            "versions": {"deepcontact": __version__, "box2d": box2d_version, "numpy": np.__version__},
        }
        (tmp / "metadata.json").write_text(json.dumps(metadata, indent=2) + "\n")
    return metadata


class GridDataset:
    """A dataset folder, memory-mapped. `torch_dataset(split)` gives torch tensors."""

    def __init__(self, path):
        self.path = Path(path)
        meta = self.path / "metadata.json"
        if not meta.is_file():
            raise InputError("not a dataset (no metadata.json)", self.path)
        try:
            self.metadata = json.loads(meta.read_bytes())
        except (ValueError, UnicodeDecodeError) as e:
            raise InputError(f"unreadable metadata: {e}", meta) from None
        m = self.metadata
        if not isinstance(m, dict):
            raise InputError(f"the metadata must be a JSON object, not {type(m).__name__}", meta)
        if m.get("format") != FORMAT:
            raise InputError(f"dataset format {m.get('format')!r} is not {FORMAT}", meta)
        kinds = {"samples": int, "grid": dict, "inputs": list, "labels": list, "simulations": list, "split": dict,
                 "sources": list}
        for key, kind in kinds.items():
            if not isinstance(m.get(key), kind) or isinstance(m.get(key), bool):
                raise InputError(f"{key!r} must be a JSON {kind.__name__.replace('dict', 'object')}", meta)
        self.arrays = {}
        for name in ARRAYS:
            path = self.path / f"{name}.npy"
            try:
                self.arrays[name] = np.load(path, mmap_mode="r", allow_pickle=False)
            except FileNotFoundError:
                raise InputError("missing dataset array", path) from None
            except (OSError, ValueError) as e:
                raise InputError(f"damaged dataset array (truncated?): {e}", path) from None
        n = m["samples"]
        for name in ("inputs", "labels", "simulation", "step"):
            if len(self.arrays[name]) != n:
                raise InputError(f"{len(self.arrays[name])} rows, the metadata says {n} samples",
                                 self.path / f"{name}.npy")
        try:
            self.spec = GridSpec(**m["grid"])
        except TypeError as e:
            raise InputError(f"bad grid description: {e}", meta) from None
        self._folders, self._verified_runs = {}, set()

    def check_step_sources(self):
        """Refuse at once a dataset whose simulations cannot be followed back to their step files."""
        for k in np.unique(self.arrays["simulation"]).tolist():
            self._simulation_folder(k)

    def step_file(self, i):
        """The step file sample i was made from, found through the run it came from.

        The metadata names that run; it is only followed if it is one of the dataset's sources,
        its manifest is unchanged (the recorded SHA-256) and the simulation folder lies inside it."""
        folder = self._simulation_folder(int(self.arrays["simulation"][i]))
        return folder / f"step-{int(self.arrays['step'][i]):06d}.xml"

    def _simulation_folder(self, k):
        """Simulation k's folder, checked once (not per sample: the solver loss asks per sample)."""
        if k in self._folders:
            return self._folders[k]
        meta = self.path / "metadata.json"
        sim = self.metadata["simulations"][k]
        if not isinstance(sim, dict):
            raise InputError("simulation entries must be JSON objects", meta)
        sources = {s.get("run"): s.get("manifest_sha256") for s in self.metadata["sources"] if isinstance(s, dict)}
        run = sim.get("run")
        if run not in sources:
            raise InputError(f"simulation run {run!r} is not one of the dataset's sources", meta)
        if run not in self._verified_runs:
            manifest = Path(run) / MANIFEST
            try:
                digest = hashlib.sha256(manifest.read_bytes()).hexdigest()
            except OSError as e:
                raise InputError(f"the run this dataset was made from cannot be read: {e.strerror or e}",
                                 manifest) from None
            if digest != sources[run]:
                raise InputError("the run changed since the dataset was made (manifest SHA-256 differs)", manifest)
            self._verified_runs.add(run)
        self._folders[k] = simulation_folder(run, sim.get("dir"), meta)
        return self._folders[k]

    def __len__(self):
        return int(self.metadata["samples"])

    def indices(self, split=None):
        """Sample indices of a split ("train", "validation") or all."""
        if split is None:
            return np.arange(len(self))
        sims = np.array(self.metadata["split"][split], dtype=np.int32)
        return np.nonzero(np.isin(self.arrays["simulation"], sims))[0]

    def contacts(self, i):
        """(positions (n, 2), impulses (n, 2)) of sample i's contact points."""
        a, b = self.arrays["contact_offsets"][i], self.arrays["contact_offsets"][i + 1]
        return self.arrays["contact_position"][a:b], self.arrays["contact_impulse"][a:b]

    def torch_dataset(self, split=None):
        import torch

        ds = self
        idx = self.indices(split)

        class _Torch(torch.utils.data.Dataset):
            def __len__(self):
                return len(idx)

            def __getitem__(self, k):
                i = int(idx[k])
                return (torch.from_numpy(np.array(ds.arrays["inputs"][i])),
                        torch.from_numpy(np.array(ds.arrays["labels"][i])))

        return _Torch()
