"""Grid datasets: what `dc rasterize` writes and `dc train` reads.

A dataset is a folder of plain NumPy `.npy` arrays plus `metadata.json` (see docs/formats.md).
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
import dataclasses
import errno
import hashlib
import io
import json
import logging
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__, arguments, jsontext, output, workers
from .._box2d import box2d_version
from ..errors import InputError
from ..resources import check_disk, check_memory
from ..step.reader import check_origin, read_step_for_grid
from ..step.run_folder import MANIFEST, require_regular, simulation_folder, step_path
from .sources import collect
from .spec import GridSpec
from .splat import DEFAULT_INPUTS, DEFAULT_LABELS, check_channels, rasterize_step
from .window import grid_for

log = logging.getLogger(__name__)
FORMAT = 2   # 2: runs are named relative to the dataset folder (1: relative to where rasterize ran)
ARRAYS = ("inputs", "labels", "simulation", "step", "contact_offsets", "contact_position", "contact_impulse")
# What each array must be; C: channels, N: samples, M: contact points (from the metadata).
ARRAY_LAYOUT = {"inputs": (np.float32, ("N", "C_in", "H", "W")), "labels": (np.float32, ("N", "C_out", "H", "W")),
                "simulation": (np.int32, ("N",)), "step": (np.int32, ("N",)),
                "contact_offsets": (np.int64, ("N+1",)), "contact_position": (np.float32, ("M", 2)),
                "contact_impulse": (np.float32, ("M", 2))}
# Everything a dataset folder holds: what --overwrite may replace.
DATASET_FILES = output.Owned("dataset", ["metadata\\.json"] + [f"{name}\\.npy" for name in ARRAYS])


# Steps a worker rasterizes per task: the images in memory at once are CHUNK samples per worker,
# however long the simulations.
CHUNK = 64


def _rasterize_steps(args):
    """Rasterizes consecutive step files of one simulation and writes their images straight into
    the dataset's image files at their rows (`places`: (path, byte offset) for inputs and labels;
    the images never travel back through a pipe). Returns step numbers, contact positions and
    impulses, and how many contact points fell outside the grid."""
    spec, inputs, labels, files, (scene, engine), seed, places = args
    xi = np.empty((len(files), len(inputs), spec.ny, spec.nx), np.float32)
    yl = np.empty((len(files), len(labels), spec.ny, spec.nx), np.float32)
    steps = np.empty(len(files), np.int32)
    counts = np.empty(len(files), np.int64)
    positions, impulses, outside = [], [], 0
    for k, path in enumerate(files):
        header, bodies, contacts = read_step_for_grid(path)
        check_origin(header, scene, seed, path, engine)
        xi[k], yl[k] = rasterize_step(spec, bodies, contacts, inputs, labels)
        steps[k] = header["index"]
        counts[k] = len(contacts["position"])
        positions.append(contacts["position"])
        impulses.append(np.stack([contacts["normal_impulse"], contacts["tangent_impulse"]], axis=1))
        outside += int(np.count_nonzero(spec.outside(contacts["position"])))
    for (path, offset), images in zip(places, (xi, yl)):
        _write_at(path, offset, images)
    pos = np.concatenate(positions) if positions else np.empty((0, 2), np.float32)
    imp = np.concatenate(impulses) if impulses else np.empty((0, 2), np.float32)
    return steps, counts, pos, imp, outside


def _write_at(path, offset, array):
    """array's bytes into the file at offset (the file's space is reserved: see _NpyWriter)."""
    view = memoryview(np.ascontiguousarray(array)).cast("B")
    try:
        fd = output.open_fd(path, os.O_WRONLY)
        try:
            while view:
                written = os.pwrite(fd, view, offset)
                view, offset = view[written:], offset + written
        finally:
            os.close(fd)
    except OSError as e:
        raise OSError(e.errno, e.strerror, os.fspath(path)) from None


def split_simulations(count, validation_fraction, seed):
    """{"train": [...], "validation": [...]} of simulation indices, chosen by a seeded shuffle."""
    order = np.random.default_rng(seed).permutation(count)
    n_val = int(round(validation_fraction * count))
    if validation_fraction > 0 and count > 1:
        n_val = min(max(n_val, 1), count - 1)
    else:
        n_val = 0
    return {"train": sorted(int(i) for i in order[n_val:]), "validation": sorted(int(i) for i in order[:n_val])}


class _NpyWriter:
    """An .npy file of a known shape whose rows are written in place (`place(row)` says where;
    workers write there with pwrite, no memory map: a full disk is an OSError naming the file, not
    a SIGBUS). Its space is reserved first where the file system can, so a disk too small fails
    before any work."""

    def __init__(self, path, dtype, shape):
        self.path = os.fspath(path)
        self.dtype = np.dtype(dtype)
        header = {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False, "shape": tuple(shape)}
        with self._naming():
            self.f = output.open_new(self.path, "wb")
            np.lib.format.write_array_header_1_0(self.f, header) if np.prod(shape) * self.dtype.itemsize < 2 ** 32 \
                else np.lib.format.write_array_header_2_0(self.f, header)
            self.f.flush()
            self.data_offset = self.f.tell()
            self.row_bytes = int(np.prod(shape[1:])) * self.dtype.itemsize
            size = self.f.tell() + int(np.prod(shape)) * self.dtype.itemsize
            try:
                os.posix_fallocate(self.f.fileno(), 0, size)
            except OSError as e:
                if e.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
                    raise

    @contextmanager
    def _naming(self):
        try:
            yield
        except OSError as e:
            raise OSError(e.errno, e.strerror, self.path) from None

    def place(self, row):
        """(path, byte offset) of a row."""
        return self.path, self.data_offset + row * self.row_bytes

    def close(self):
        with self._naming():
            self.f.close()


@dataclass
class DatasetSettings:
    """How runs become a dataset: the grid, the channels, which steps, and the split."""
    cell: float = 0.5                # d, the node spacing
    h: float = 0.5                   # the smoothing length
    kernel: str = "poly6"
    renormalize: bool = True
    inputs: list = None              # channel names (default splat.DEFAULT_INPUTS)
    labels: list = None              # (default splat.DEFAULT_LABELS)
    window: tuple = None             # (x0, y0, x1, y1), or None: default_window
    include_contactless: bool = False
    validation_fraction: float = 0.2
    seed: int = 0                    # of the split

    def checked(self):
        """A copy with the default channels filled in; InputError for what cannot be."""
        s = dataclasses.replace(self, inputs=list(self.inputs or DEFAULT_INPUTS),
                                labels=list(self.labels or DEFAULT_LABELS))
        check_channels(s.inputs, "input")
        check_channels(s.labels, "label")
        if not 0 <= s.validation_fraction < 1:
            raise InputError(f"--validation must be in [0, 1), got {s.validation_fraction}")
        return s


def write_dataset(run_dirs, out, settings=None, *, jobs=1, overwrite=False, progress=None, max_memory=None):
    """Rasterize every step of the runs into a dataset folder, atomically. Returns its metadata.

    progress(total_steps) makes a tqdm-like counter of steps (or progress is None).

    Refuses (before writing) work whose images would not fit in max_memory GB (each worker holds
    CHUNK steps' images) or on the disk."""
    s = (settings or DatasetSettings()).checked()
    out = Path(out)
    # The output is checked and locked first: nothing is read or logged for an output refused.
    with output.output_folder(out, DATASET_FILES, overwrite, command="rasterize") as tmp:
        sims, manifests = collect(run_dirs, s.include_contactless)
        spec, which = grid_for(sims, s.cell, s.h, s.kernel, s.renormalize, s.window)
        _check_resources(sims, spec, s, jobs, max_memory, out)
        outside = _write_arrays(tmp, sims, spec, s, jobs,
                                progress(sum(len(sim.files) for sim in sims)) if progress is not None else None)
        if outside:
            log.info("%d contact points lie outside the grid: on a boxed scene these are the contacts on the box's "
                     "walls, on or just beyond its edge where the grid ends (expected; interpolation clamps them "
                     "to the edge)", outside)
        metadata = _metadata(out.resolve(), sims, manifests, spec, which, s, outside)
        output.write_text(tmp / "metadata.json", json.dumps(metadata, indent=2) + "\n")
    return metadata


def _check_resources(sims, spec, s, jobs, max_memory, out):
    """Refuse a dataset with no samples, or one that would not fit in memory or on the disk."""
    n = sum(len(sim.files) for sim in sims)
    if n == 0:
        raise InputError("no steps with contacts in these runs (use --include-contactless to keep them)")
    per_sample = (len(s.inputs) + len(s.labels)) * spec.nx * spec.ny * 4
    longest = min(max(len(sim.files) for sim in sims), CHUNK)
    check_memory(per_sample * longest * jobs,
                 max_memory, f"rasterizing at d = {spec.cell:g} ({spec.nx} x {spec.ny} nodes)")
    m = sum(sum(sim.contacts) for sim in sims)
    check_disk(per_sample * n + 28 * m + 16 * n, out, None, "the dataset")
    radii = [sim.radius for sim in sims if sim.radius is not None]
    for w in spec.rule_warnings(min(radii) if radii else None):
        log.warning(w)


def _write_arrays(tmp, sims, spec, s, jobs, progress):
    """Every array of the dataset into tmp, simulation by simulation (in workers with jobs > 1);
    returns how many contact points lie outside the grid."""
    n = sum(len(sim.files) for sim in sims)
    m = sum(sum(sim.contacts) for sim in sims)
    shapes = {"N": n, "N+1": n + 1, "M": m, "C_in": len(s.inputs), "C_out": len(s.labels), "H": spec.ny,
              "W": spec.nx}
    images = {name: _NpyWriter(tmp / f"{name}.npy", ARRAY_LAYOUT[name][0],
                               [shapes.get(d, d) for d in ARRAY_LAYOUT[name][1]]) for name in ("inputs", "labels")}
    arrays = {
        "simulation": np.empty(n, np.int32), "step": np.empty(n, np.int32),
        "contact_offsets": np.zeros(n + 1, np.int64),
        "contact_position": np.empty((m, 2), np.float32), "contact_impulse": np.empty((m, 2), np.float32),
    }
    row = point = outside = 0
    # tasks of CHUNK consecutive steps of one simulation; each writes its images at its rows
    chunks = [(i, first) for i, sim in enumerate(sims) for first in range(0, len(sim.files), CHUNK)]
    tasks, start = [], 0
    for i, first in chunks:
        files = sims[i].files[first:first + CHUNK]
        tasks.append((spec, s.inputs, s.labels, files, (sims[i].scene, sims[i].engine), sims[i].seed,
                      [images[name].place(start) for name in ("inputs", "labels")]))
        start += len(files)
    with workers.for_jobs(jobs, tasks) as pool:
        for (i, first), (steps, found, pos, imp, out_count) in zip(chunks, pool.imap(_rasterize_steps, tasks)):
            k = len(steps)
            arrays["simulation"][row:row + k] = i
            arrays["step"][row:row + k] = steps
            counts = np.array(sims[i].contacts[first:first + k], dtype=np.int64)
            if not np.array_equal(counts, found):
                bad = first + int(np.argmax(counts != found))
                raise InputError(f"holds {found[bad - first]} contact points where {counts[bad - first]} were "
                                 f"counted before reading (the manifest's record, or the file changed while "
                                 f"rasterizing)", sims[i].files[bad])
            arrays["contact_offsets"][row + 1:row + k + 1] = point + np.cumsum(counts)
            arrays["contact_position"][point:point + len(pos)] = pos
            arrays["contact_impulse"][point:point + len(imp)] = imp
            row, point, outside = row + k, point + len(pos), outside + out_count
            if progress is not None:
                progress.update(k)
    for writer in images.values():
        writer.close()
    for name, a in arrays.items():
        output.write_bytes(tmp / f"{name}.npy", _npy_bytes(a))
    return outside


def _metadata(where, sims, manifests, spec, which, s, outside):
    return {
        "format": FORMAT,
        "kind": "deepcontact-dataset",
        "samples": sum(len(sim.files) for sim in sims),
        "contact_points": sum(sum(sim.contacts) for sim in sims),
        "grid": spec.as_dict(),
        "window": which,   # where the grid's extent came from
        "inputs": s.inputs,
        "labels": s.labels,
        "contactless_steps": "kept" if s.include_contactless else "skipped",
        "contacts_outside_grid": outside,
        "simulations": [{"run": _relative(sim.run, where), "dir": sim.dir, "seed": sim.seed, "scene": sim.scene,
                         "samples": len(sim.files)} for sim in sims],
        "sources": [dict(src, run=_relative(src["run"], where)) for src in manifests],
        "split": split_simulations(len(sims), s.validation_fraction, s.seed),
        "split_seed": s.seed,
        "versions": {"deepcontact": __version__, "box2d": box2d_version, "numpy": np.__version__},
    }


def _relative(run, dataset):
    """A run's path as the dataset records it: relative to the dataset folder, so the two can be
    moved together and the dataset read from any working directory."""
    return os.path.relpath(Path(run).resolve(), dataset)


def _npy_bytes(array):
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


class GridDataset:
    """A dataset folder, memory-mapped. `torch_dataset(split)` gives torch tensors."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(arguments.path(path, "path"))
        meta = self.path / "metadata.json"
        if not meta.is_file():
            raise InputError("not a dataset (no metadata.json)", self.path)
        try:
            self.metadata = jsontext.loads(meta.read_bytes())
        except (ValueError, UnicodeDecodeError) as e:
            raise InputError(f"unreadable metadata: {e}", meta) from None
        self._check_metadata(meta)
        try:
            self.spec = GridSpec.from_dict(self.metadata["grid"])
        except ValueError as e:
            raise InputError(str(e), meta) from None
        self.arrays = {name: self._map(self.path / f"{name}.npy") for name in ARRAYS}
        self._check_arrays(meta)
        self._folders, self._verified_runs = {}, set()

    def _check_metadata(self, meta):
        """metadata.json holds what a dataset's does, of the right kinds (InputError naming it)."""
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
        for key in ("inputs", "labels"):
            if not m[key] or not all(isinstance(c, str) for c in m[key]):
                raise InputError(f"{key!r} must be a list of channel names", meta)
        n_sims = len(m["simulations"])
        for part in ("train", "validation"):
            ids = m["split"].get(part)
            if not isinstance(ids, list) or not all(type(i) is int and 0 <= i < n_sims for i in ids):
                raise InputError(f"split {part!r} must be a list of simulation numbers 0..{n_sims - 1}", meta)

    @staticmethod
    def _map(path):
        """The array at path, memory-mapped (InputError naming a missing or damaged one)."""
        try:
            return np.load(require_regular(path), mmap_mode="r", allow_pickle=False)
        except InputError:
            raise InputError("missing dataset array", path) from None
        except OSError as e:
            if e.errno == errno.ENOMEM:   # the machine's limit, not the file's fault
                raise MemoryError(f"cannot map {path}: {e.strerror}") from None
            raise InputError(f"damaged dataset array (truncated?): {e}", path) from None
        except ValueError as e:
            raise InputError(f"damaged dataset array (truncated?): {e}", path) from None

    def _check_arrays(self, meta):
        """Every array of the dtype and shape the metadata implies, indices within range."""
        m, a = self.metadata, self.arrays
        points = len(a["contact_position"])
        sizes = {"N": m["samples"], "N+1": m["samples"] + 1, "M": points, "C_in": len(m["inputs"]),
                 "C_out": len(m["labels"]), "H": self.spec.ny, "W": self.spec.nx}
        for name, (dtype, dims) in ARRAY_LAYOUT.items():
            want = tuple(sizes.get(d, d) for d in dims)
            path = self.path / f"{name}.npy"
            if a[name].dtype != dtype:
                raise InputError(f"holds {a[name].dtype}, a dataset's {name} are {np.dtype(dtype)}", path)
            if a[name].shape != want:
                raise InputError(f"shape {a[name].shape}, the metadata implies {want}", path)
        offsets = np.asarray(a["contact_offsets"])
        if offsets[0] != 0 or offsets[-1] != points or np.any(np.diff(offsets) < 0):
            raise InputError(f"must rise from 0 to the {points} contact points", self.path / "contact_offsets.npy")
        sim = np.asarray(a["simulation"])
        if len(sim) and (sim.min() < 0 or sim.max() >= len(m["simulations"])):
            raise InputError(f"names simulations outside 0..{len(m['simulations']) - 1}",
                             self.path / "simulation.npy")

    def check_step_sources(self):
        """Refuse at once a dataset whose simulations cannot be followed back to their step files."""
        for k in np.unique(self.arrays["simulation"]).tolist():
            self._simulation_folder(k)

    def step_file(self, i):
        """The step file sample i was made from, found through the run it came from.

        The metadata names that run; it is only followed if it is one of the dataset's sources,
        its manifest is unchanged (the recorded SHA-256) and the simulation folder lies inside it."""
        folder = self._simulation_folder(int(self.arrays["simulation"][i]))
        return step_path(folder, int(self.arrays["step"][i]))

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
        if not isinstance(run, str) or run not in sources:
            raise InputError(f"simulation run {run!r} is not one of the dataset's sources", meta)
        folder = self.path / run   # relative to the dataset (an absolute path stays as it is)
        if run not in self._verified_runs:
            manifest = folder / MANIFEST
            try:
                digest = hashlib.sha256(manifest.read_bytes()).hexdigest()
            except OSError as e:
                raise InputError(f"the run this dataset was made from cannot be read: {e.strerror or e}",
                                 manifest) from None
            if digest != sources[run]:
                raise InputError("the run changed since the dataset was made (manifest SHA-256 differs)", manifest)
            self._verified_runs.add(run)
        self._folders[k] = simulation_folder(folder, sim.get("dir"), meta)
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
