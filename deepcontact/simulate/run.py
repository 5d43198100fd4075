"""Runs simulations and writes one folder per simulation, one XML file per step, and the
run's manifest last.

Layout of OUTDIR::

    seed-000000/scene.xml          the scene exactly as simulated (generator output included)
    seed-000000/step-000000.xml    one file per step (schemas/step.xsd)
    manifest.json                  written last: its presence means the run is complete

Every file is written atomically, so an interrupted run leaves only complete files and no
manifest.
"""
import hashlib
import json
import logging
import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__, atomic
from .._box2d import box2d_version
from ..errors import InputError
from ..scene.xml import fmt, to_xml
from ..step.run_folder import MANIFEST
from ..step.writer import step_filename, step_writer
from .build import build_world, check_overlaps
from .pgs_loop import PGSStepper, check_scene_for_loop

log = logging.getLogger(__name__)



def sim_dirname(seed: int) -> str:
    return f"seed-{seed:06d}"


@dataclass
class SimulationResult:
    seed: int
    dir: str
    steps: int
    files: int
    contact_points: int
    scene_sha256: str


def _solve_xml(options, solution):
    o = options
    w = 1.0 if o.relaxation == "auto" else o.relaxation
    if solution is None:
        iterations, residual, sanitized = 0, 0.0, 0
    else:
        iterations, residual, w = solution.iterations, solution.residual, solution.relaxation
        sanitized = sum(solution.sanitized.values())
    residual = residual if np.isfinite(residual) else 0.0
    return (f'    <solve start="{o.start}" mode="{o.mode}" stop_on="{o.stop_on}" tolerance="{fmt(o.tolerance)}" '
            f'max_iterations="{o.max_iterations}" relaxation="{fmt(w)}" accelerate="{o.accelerate}" '
            f'iterations="{iterations}" '
            f'residual="{fmt(residual)}" sanitized="{sanitized}"/>\n')


def run_simulation(scene, out_dir, seed, skip_contactless=False, on_step=None, loop=None) -> SimulationResult:
    """Simulate one scene into out_dir (which must exist). on_step(k) is called after each step.

    loop: LoopOptions to step with the project's PGS instead of Box2D's own solver."""
    out_dir = Path(out_dir)
    scene_xml = to_xml(scene)
    atomic.write_bytes(out_dir / "scene.xml", scene_xml)
    world = build_world(scene)
    writer = step_writer(scene, seed, "box2d" if loop is None else "pgs")
    stepper = None if loop is None else PGSStepper(world, scene, loop)
    removals = {}
    for ev in scene.events:
        removals.setdefault(ev.step, []).append(ev.body)
    s = scene.solver
    files = points = 0

    def write(k, dt_ratio, bodies, contacts, extra):
        xml = writer.render(k, k * float(scene.dt), dt_ratio, bodies, contacts, extra)
        atomic.write_bytes(out_dir / step_filename(k), xml)

    # Rendering and writing a step (GIL released in both) overlap with stepping the next one.
    with ThreadPoolExecutor(max_workers=2) as pool:
        pending = deque()
        try:
            for k in range(scene.steps):
                for body in removals.get(k, ()):
                    world.remove_body(body)
                if stepper is None:
                    bodies, contacts = world.step(scene.dt, s.velocity_iterations, s.position_iterations,
                                                  record=True)
                    extra = ""
                    dt_ratio = world.last_dt_ratio
                else:
                    done = stepper.step()
                    bodies, contacts, solution = done.bodies, done.contacts, done.solution
                    extra = _solve_xml(loop, solution)
                    dt_ratio = 0.0 if k == 0 else 1.0
                n = len(contacts["manifold"])
                points += n
                if n or not skip_contactless:
                    pending.append(pool.submit(write, k, dt_ratio, bodies, contacts, extra))
                    files += 1
                while pending and (len(pending) > 8 or pending[0].done()):
                    pending.popleft().result()   # re-raises a failed write here
                if on_step is not None:
                    on_step(k)
            while pending:
                pending.popleft().result()
        except BaseException:
            for f in pending:
                f.cancel()
            raise
    return SimulationResult(seed=seed, dir=out_dir.name, steps=scene.steps, files=files,
                            contact_points=points, scene_sha256=hashlib.sha256(scene_xml).hexdigest())


def check_output(out_dir, overwrite):
    """Whether an earlier run in OUTDIR is to be replaced; refuses what must not be touched.

    Only a folder holding nothing but a run (its manifest and seed-* folders) is replaced."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("output path exists and is not a folder", out_dir)
    if not out_dir.exists() or not any(out_dir.iterdir()):
        return False
    if not overwrite:
        raise InputError("output folder is not empty; use --overwrite to replace it", out_dir)
    other = sorted(p.name for p in out_dir.iterdir()
                   if not (p.name == MANIFEST or p.name.startswith(".") or (p.is_dir() and p.name.startswith("seed-"))))
    if other:
        raise InputError(f"refusing to replace a folder that holds more than a run ({', '.join(other[:3])}"
                         f"{', ...' if len(other) > 3 else ''})", out_dir)
    return True


def prepare_output(out_dir, seeds):
    """Create OUTDIR (empty or new) and a folder per simulation."""
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        for seed in seeds:
            (out_dir / sim_dirname(seed)).mkdir()
        probe = out_dir / ".write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise InputError(f"cannot write there: {e.strerror or e}", out_dir) from None
    return out_dir


@contextmanager
def _in_place(out_dir):
    yield out_dir


def _worker(args):
    make_scene, seed, out_dir, skip, loop = args
    scene = make_scene(seed)
    return run_simulation(scene, Path(out_dir) / sim_dirname(seed), seed, skip, loop=loop)


def run(make_scene, seeds, out_dir, *, overwrite=False, skip_contactless=False, jobs=1, progress=None,
        source=None, loop=None):
    """Simulate make_scene(seed) for every seed into out_dir and write the manifest last.

    progress(total_steps) makes a tqdm-like counter of steps (or progress is None).
    Returns the manifest as a dict."""
    seeds = list(seeds)
    if not seeds:
        raise InputError("no seeds to simulate (is the shard empty?)")
    # Build (and check) the first scene before touching the output folder.
    first = make_scene(seeds[0])
    check_overlaps(first, source)
    if loop is not None:
        check_scene_for_loop(first, source)
    out_dir = Path(out_dir)
    # An earlier run is replaced only once the new one is complete: it is built beside it.
    replace = check_output(out_dir, overwrite)
    with (atomic.folder(out_dir) if replace else _in_place(out_dir)) as work:
        manifest = _run_into(prepare_output(work, seeds), make_scene, first, seeds, skip_contactless, jobs,
                             progress, source, loop)
    log.info("wrote %d simulations, %d step files to %s", len(manifest["simulations"]),
             sum(r["files"] for r in manifest["simulations"]), os.fspath(out_dir))
    return manifest


def _run_into(out_dir, make_scene, first, seeds, skip_contactless, jobs, progress, source, loop):
    if progress is not None:
        progress = progress(first.steps * len(seeds))
    try:
        results = _simulate_all(make_scene, first, seeds, out_dir, skip_contactless, jobs, progress, source, loop)
    finally:
        if progress is not None:
            progress.close()
    manifest = {
        "format": 1,
        "kind": "deepcontact-run",
        "scene": first.name,
        "source": source,
        "generator": first.generator,
        "params": first.params,
        "solver": "box2d" if loop is None else "pgs",
        "pgs": None if loop is None else dict(loop.__dict__),
        "velocity_iterations": first.solver.velocity_iterations,
        "position_iterations": first.solver.position_iterations,
        "dt": float(fmt(first.dt)),
        "skip_contactless": skip_contactless,
        "versions": {"deepcontact": __version__, "box2d": box2d_version},
        "simulations": [r.__dict__ for r in results],
    }
    atomic.write_text(out_dir / MANIFEST, json.dumps(manifest, indent=2) + "\n")
    return manifest


def _simulate_all(make_scene, first, seeds, out_dir, skip_contactless, jobs, progress, source, loop):
    results = []
    if jobs <= 1:
        for seed in seeds:
            scene = first if seed == seeds[0] else make_scene(seed)
            if seed != seeds[0]:
                check_overlaps(scene, source)
            tick = (lambda k: progress.update(1)) if progress is not None else None
            results.append(run_simulation(scene, out_dir / sim_dirname(seed), seed, skip_contactless, tick,
                                          loop=loop))
    else:
        for seed in seeds[1:]:
            check_overlaps(make_scene(seed), source)
        from concurrent.futures import ProcessPoolExecutor, as_completed  # 12 ms: only when used
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = [pool.submit(_worker, (make_scene, seed, str(out_dir), skip_contactless, loop))
                       for seed in seeds]
            for f in as_completed(futures):
                r = f.result()
                results.append(r)
                if progress is not None:
                    progress.update(r.steps)
    results.sort(key=lambda r: r.seed)
    return results
