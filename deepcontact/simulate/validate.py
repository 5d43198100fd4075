"""Checking files as `dc validate` does: every step and scene file named or found under a named
folder, against the schemas and what the schemas cannot see, side by side in worker processes,
reported in file order. (At this floor because a scene's check builds its world: bodies that
start overlapping are refused.)"""
from itertools import groupby
from pathlib import Path

from .. import atomic, workers
from ..errors import InputError
from ..step.check import ABOVE

CHUNK = 50   # files a worker checks per task


def is_xml(path):
    return path.name.endswith((".xml", ".xml.gz")) and not path.name.startswith(".")


def xml_files(paths):
    """Every *.xml and *.xml.gz file named or under a named folder. Anything by such a name that
    is not a regular file (a FIFO would block the parser forever) is refused."""
    for p in map(Path, paths):
        if p.is_dir():
            found = [q for q in (p / r for r in atomic.entries(p)) if is_xml(q)]   # (any depth, sorted)
        elif p.exists():
            found = [p]
        else:
            raise InputError("no such file or folder", p)
        for q in found:
            if not q.is_file():
                raise InputError("not a regular file", q)
        yield from found


def check_files(task):
    """[(path, error lines)] for ([(path, origin)], residuals): one worker's share of a simulation
    folder."""
    from ..scene.xml import read_scene
    from ..step.check import check_file
    from .build import check_overlaps

    chunk, residuals = task
    out = []
    for path, origin in chunk:
        kind, errors = check_file(path, origin, residuals)
        if not errors and kind == "scene":   # what the schema cannot see
            try:
                check_overlaps(read_scene(path), path)
            except InputError as e:
                errors = [f"{e.path}:{e.line or 0}:0: {e.message}"]
        out.append((path, errors))
    return out


def origins(paths):
    """step file -> (scene, seed) of the simulation it lies in, for the runs among paths; and the
    error lines of runs whose manifest does not match their folders."""
    from ..step.run_folder import MANIFEST, read_run

    origin, errors = {}, []
    for run in (Path(p) for p in paths):
        if (run / MANIFEST).is_file():
            try:
                r = read_run(run)
            except InputError as e:
                errors.append(f"{e.path}:{e.line or 0}:0: {e.message}")
                continue
            origin.update({f.resolve(): (r.manifest.get("scene"), s.seed, s.engine) for s in r.simulations
                           for f in s.files})
    return origin, errors


def validate(paths, report, jobs=1, progress=None, residuals=False):
    """Checks every file of paths; report(line) gets each error line, in file order whatever
    `jobs`; progress(n): n more files checked. residuals: also each step's recorded residual
    against its recorded tolerance (step.check.residual_above). Returns (files checked, invalid
    files and runs, steps above their tolerance)."""
    files = list(xml_files(paths))
    if not files:
        raise InputError(f"no XML files found in {', '.join(map(str, paths))}")
    origin, errors = origins(paths)
    invalid, above = len(errors), 0
    for line in errors:
        report(line)
    # tasks of up to CHUNK files of one folder (a simulation), in file order
    chunks = [[(f, origin.get(f.resolve())) for f in group[i:i + CHUNK]]
              for group in (list(g) for _, g in groupby(files, key=lambda f: f.parent))
              for i in range(0, len(group), CHUNK)]
    with workers.for_jobs(jobs, chunks) as pool:
        for checked in pool.imap(check_files, [(chunk, residuals) for chunk in chunks]):
            for _, lines in checked:
                invalid += bool(lines)
                above += any(ABOVE in line for line in lines)
                for line in lines:
                    report(line)
            if progress is not None:
                progress(len(checked))
    return len(files), invalid, above
