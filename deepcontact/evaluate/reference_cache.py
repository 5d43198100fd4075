"""The closed loop's reference trajectory computed once: it depends on no variant, only on the
scene (its initial state), the steps, the reference's settings and the build that stepped it, and
on the settled 1000-circle pile it was 92% of `dc evaluate --closed-loop` (200 of 216 s).

Each is kept beside the run (`.RUN.references/`, one file per trajectory, named by the SHA-256 of
what determines it: content-addressed), written whole (a temporary name renamed), and checked
before it is used: its stored key must equal the key asked for (a changed scene, step count,
setting or build is another name, and a file renamed into its place is refused by its key), its
arrays must have the shapes the key implies (every step of a finite trajectory) and hash to the
digest stored with them. Anything else is recomputed, and the file replaced. A run folder that
cannot be written beside is no error: the reference is then computed as before; nor is a folder
of references that is a link, which is never followed (computed, not kept, and said). The checks
are against a stale, truncated or damaged file, not a forged one: whoever can write beside a run
can change the run itself.
"""
import hashlib
import io
import json
import logging
import os
import sys
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from .. import jsontext, output, workers
from ..errors import InputError
from ..regular import read_regular
from ..output.names import beside
from ..scene.xml import to_xml
from ..solver.metrics import Positions

log = logging.getLogger(__name__)

VERSION = 1              # of the file's layout
FILE_MAX = 1 << 30       # bytes: a 10,000-body, 1,000-step trajectory is about 240 MB


def folder_for(run):
    """Where a run's reference trajectories are kept: `.RUN.references` beside it."""
    return beside(Path(run), "references")


@dataclass
class Trajectory:
    """What a closed loop records of a trajectory, step by step (the reference's, a variant's)."""
    positions: list            # per step: {body index: position (2,) float64}
    energies: np.ndarray
    iterations: np.ndarray
    seconds: np.ndarray
    deepest: float
    finite: bool
    residuals: np.ndarray = None


def cached(scene, steps, folder, settings, compute):
    """The reference trajectory of scene over steps, each step solved as settings say: read from
    folder where a checked one is there, else compute() (a Trajectory) and kept there. Its steps
    are reported to workers.progress either way (the progress total counts them)."""
    if os.path.islink(folder):
        log.warning("%s is a link, which dc never follows: the reference trajectory is stepped and not kept", folder)
        return compute()
    key = _key(scene, steps, settings)
    path = Path(folder) / f"{hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()}.npz"
    found = _load(path, key)
    if found is not None:
        log.info("the reference trajectory read back from %s, kept by an earlier command (remove it to step it again)",
                 path)
        workers.progress(steps)
        return found
    trajectory = compute()
    _keep(path, key, trajectory)
    return trajectory


@lru_cache(maxsize=None)
def _build():
    """What identifies the arithmetic that stepped a reference: the native module's bytes (its
    compiler and flags), the package's and numpy's versions. (Once a process: the module is
    megabytes, and a run's every simulation asks.)"""
    from .. import _box2d, __version__
    digest = hashlib.sha256()
    with open(_box2d.__file__, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return {"native": digest.hexdigest(), "deepcontact": __version__, "numpy": np.__version__,
            "python": sys.version.split()[0]}


def _key(scene, steps, settings):
    return {"version": VERSION, "scene": hashlib.sha256(to_xml(scene)).hexdigest(), "steps": int(steps),
            "settings": repr(settings), "build": _build()}


# --- The file --------------------------------------------------------------------------------------------

def _arrays(trajectory):
    """The trajectory as flat arrays: each step's bodies' indexes and positions, in order."""
    counts = np.array([len(p) for p in trajectory.positions], dtype=np.int64)
    index = np.array([k for p in trajectory.positions for k in p], dtype=np.int64)
    position = (np.array([v for p in trajectory.positions for v in p.values()], dtype=np.float64).reshape(-1, 2))
    return {"counts": counts, "index": index, "position": position,
            "energies": np.asarray(trajectory.energies, dtype=np.float64),
            "iterations": np.asarray(trajectory.iterations, dtype=np.int64),
            "seconds": np.asarray(trajectory.seconds, dtype=np.float64),
            "residuals": np.asarray(trajectory.residuals, dtype=np.float64),
            "scalars": np.array([trajectory.deepest, float(trajectory.finite)], dtype=np.float64)}


def _digest(arrays):
    h = hashlib.sha256()
    for name in sorted(arrays):
        h.update(name.encode() + str(arrays[name].dtype).encode() + str(arrays[name].shape).encode())
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def _keep(path, key, trajectory):
    arrays = _arrays(trajectory)
    meta = json.dumps({"key": key, "digest": _digest(arrays)}, sort_keys=True)
    buffer = io.BytesIO()
    np.savez(buffer, meta=np.array(meta), **arrays)
    try:
        os.makedirs(path.parent, exist_ok=True)
        if os.path.islink(path):   # (no file of ours: a link is removed, never written through)
            os.unlink(path)
        output.write_bytes(path, buffer.getvalue())
    except (OSError, InputError) as e:   # (a run one may read but not write beside: computed each time)
        log.info("the reference trajectory is not kept (%s): it is computed again next time",
                 getattr(e, "strerror", None) or e)


def _load(path, key):
    """The trajectory kept at path if it is one and its key is key; None otherwise."""
    data = read_regular(path, FILE_MAX)
    if data is None:
        return None
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            meta = jsontext.loads(str(z["meta"]))
            arrays = {name: z[name] for name in z.files if name != "meta"}
        if meta.get("key") != key or meta.get("digest") != _digest(arrays):
            return None
        counts, index, position = arrays["counts"], arrays["index"], arrays["position"]
        n = len(counts)
        finite = bool(arrays["scalars"][1])
        if (n > key["steps"] or (finite and n != key["steps"]) or counts.sum() != len(index)
                or position.shape != (len(index), 2)
                or any(len(arrays[k]) != n for k in ("energies", "iterations", "seconds", "residuals"))):
            return None
    except (ValueError, KeyError, TypeError, OSError, EOFError, RecursionError, zipfile.BadZipFile):
        return None   # (not a file of ours, or not whole: computed again and replaced)
    bounds = np.concatenate([[0], np.cumsum(counts)])
    trail = [Positions(index[a:b], position[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
    deepest, finite = arrays["scalars"]
    return Trajectory(trail, arrays["energies"], arrays["iterations"], arrays["seconds"], float(deepest),
                      bool(finite), arrays["residuals"])
