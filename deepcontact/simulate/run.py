"""Runs simulations and writes one folder per simulation, one XML file per step, and the
run's manifest last.

Layout of OUTDIR::

    seed-000000/scene.xml          the scene exactly as simulated (generator output included)
    seed-000000/step-000000.xml    one file per step (schemas/step.xsd; .xml.gz with --compress)
    manifest.json                  written last: its presence means the run is complete

The run is built in a partial folder beside OUTDIR and appears under its name only when complete
(`output.output_folder`): an interrupted or failed run leaves nothing, and an earlier run it was
to replace (--overwrite) as it was.
"""
import hashlib
import logging
import os
import re
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import arguments, interrupts, output, workers
from .._box2d import NonFiniteError
from ..errors import InputError, OptionError, count
from ..resources import COMPRESSION_RATIO, check_disk, step_bytes
from ..scene.check import check_scene
from ..scene.model import Scene
from ..scene.xml import fmt, to_xml
from ..step.check import stray_contact
from ..step.run_folder import MANIFEST, write_manifest
from ..step.writer import compressed, header_xml, step_filename, step_writer
from . import stepping
from .build import check_overlaps
from .engines import Engine
from .engines.box2d import Box2D

log = logging.getLogger(__name__)

# Everything a run folder holds: what --overwrite may replace.
RUN_FILES = output.Owned("run", [re.escape(MANIFEST), r"seed-\d{6,}/", r"seed-\d{6,}/scene\.xml",
                                 r"seed-\d{6,}/step-\d{6,}\.xml(\.gz)?"])


class Extent:
    """The box every body's shapes stayed in over a simulation (for a grid window): the static
    shapes exactly; the moving bodies' origins at every step, widened at the end by the largest
    reach of any moving body (exact for equal bodies, a little generous otherwise). Cheap: a few
    array operations per step, on the hot path of `dc simulate`."""

    def __init__(self, scene):
        box = scene.static_extent()
        self.static = np.array(box if box else (np.inf, np.inf, -np.inf, -np.inf))
        self.reach = max((b.reach() for b in scene.bodies if b.type != "static"), default=0.0)
        self.lo, self.hi = np.full(2, np.inf), np.full(2, -np.inf)
        self._count, self._moving = -1, None

    def add(self, bodies):
        p = bodies["position"]
        if len(p) != self._count:   # the first step, or bodies were removed
            self._count, self._moving = len(p), np.flatnonzero(bodies["type"] != 0)
        if len(self._moving):
            q = p[self._moving]
            np.minimum(self.lo, q.min(axis=0), out=self.lo)
            np.maximum(self.hi, q.max(axis=0), out=self.hi)

    def as_list(self):
        lo = np.minimum(self.static[:2], self.lo - self.reach)
        hi = np.maximum(self.static[2:], self.hi + self.reach)
        if not np.all(np.isfinite(lo)) or not np.all(np.isfinite(hi)):
            return None
        return [float(fmt(v)) for v in (*lo, *hi)]


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
    extent: list = None   # [x0, y0, x1, y1] the bodies stayed in over the run
    static_box: list = None   # [x0, y0, x1, y1] of the static shapes (Scene.static_box), or None: a grid's window
    file_contact_points: list = None   # contact points of each step file written, in order
    capped: int = None   # --solver pgs with a tolerance: steps that stopped at the sweep cap short of it
    above_tolerance: int = None   # --solver pgs, residual tolerance: steps whose residual ended above it, for
                                  # any reason (the cap, a fallback, a method that stopped early): ours, judged


def run_simulation(scene, out_dir, seed, skip_contactless=False, on_step=None, engine=None,
                   compress=False) -> SimulationResult:
    """Simulate one scene into out_dir (which must exist) with `engine` (engines.Box2D() if None).
    on_step(k) is called after each step. compress: write step-NNNNNN.xml.gz (gzip) instead of
    plain XML."""
    engine = Box2D() if engine is None else engine
    out_dir = Path(out_dir)
    # what a scene file is held to, for a scene a caller's function made: Box2D's asserts (a NaN
    # velocity) abort the process
    check_scene(scene)
    scene_xml = to_xml(scene)
    output.write_bytes(out_dir / "scene.xml", scene_xml)
    world = engine.build(scene)
    loop = engine.solve_settings()
    writer = step_writer(scene, seed, engine)
    extent = Extent(scene)

    def write(k, dt_ratio, bodies, contacts, extra):
        try:
            xml = writer.render(k, k * float(scene.dt), dt_ratio, bodies, contacts, extra)
        except NonFiniteError as e:   # no NaN or inf in a file: the scene outran float32
            raise InputError(f"seed {seed}: the simulation became non-finite at step {k} ({e}): the scene asks for "
                             "more than Box2D's float32 holds (bodies too far or too fast, forces too large, or a "
                             "start that diverged); nothing of it was kept") from None
        output.write_bytes(out_dir / step_filename(k, compress), compressed(xml) if compress else xml)
    per_file, capped, above = _stepped(world, scene, engine, write, extent, skip_contactless, on_step, seed)
    judged = loop is not None and loop.tolerance > 0
    return SimulationResult(seed=seed, dir=out_dir.name, steps=scene.steps, files=len(per_file),
                            contact_points=sum(per_file), scene_sha256=hashlib.sha256(scene_xml).hexdigest(),
                            extent=extent.as_list(), file_contact_points=per_file,
                            static_box=_box_list(scene.static_box()), capped=capped if judged else None,
                            above_tolerance=above if judged and loop.stop_on == "residual" else None)


def _stepped(world, scene, engine, write, extent, skip_contactless, on_step, seed):
    """Steps `world` through the scene, each step checked and handed to write(k, dt_ratio, bodies,
    contacts, solve line) (skipped without contacts, if asked); returns (the contact points of each
    file written, the steps at the sweep cap, the steps above the tolerance). seed: what its errors
    name."""
    step, loop = engine.stepper(world, scene), engine.solve_settings()
    per_file, capped, above = [], 0, 0
    # Rendering, compressing and writing a step (GIL released in each) overlap with stepping the next.
    # The pool's and the futures' locks are shared with the writer threads (and the progress bar's
    # with tqdm's): a stop signal waits until the main thread holds none of them (interrupts.held).
    with ThreadPoolExecutor(max_workers=2) as pool:
        pending = deque()
        try:
            for done in stepping.steps(world, scene, step):
                k, bodies, contacts = done.index, done.bodies, done.contacts
                checked_step(k, bodies, contacts, engine, len(scene.bodies))
                _check_residual(seed, k, done.solution, loop)
                extent.add(bodies)
                n = len(contacts["manifold"])
                at_cap, over = _short_of_tolerance(loop, done.solution)
                capped, above = capped + at_cap, above + over
                with interrupts.held():
                    if n or not skip_contactless:
                        extra = engine.solve_line(done.solution, done.engine_stats)
                        pending.append(pool.submit(write, k, done.dt_ratio, bodies, contacts, extra))
                        per_file.append(n)
                    while pending and (len(pending) > 8 or pending[0].done()):
                        pending.popleft().result()   # re-raises a failed write here
                    if on_step is not None:
                        on_step(k)   # a progress bar: its lock is shared with tqdm's monitor thread
            with interrupts.held():
                while pending:
                    pending.popleft().result()
        except BaseException:
            for f in pending:
                f.cancel()
            raise
    return per_file, capped, above


def _check_residual(seed, k, solution, loop):
    """A step of the project's solver is written with its residual: one that is not a number (a
    start used as given in exact mode, 1e30 and NaN: the solver's velocities left float range) is
    no step to record (its file said 0 once). InputError. Another engine's step (loop None) has no
    residual of ours: its solution field is not read."""
    if loop is not None and solution is not None and not np.isfinite(solution.residual):
        raise InputError(f"seed {seed}, step {k}: the project's solver ended without a finite residual "
                         f"({loop.mode} mode, {solution.iterations} sweeps): its velocities left float range, so "
                         "its answer cannot be judged")


def checked_step(k, bodies, contacts, engine, scene_bodies=None):
    """What an engine returned for step k, held to a step file's layout before it is written:
    arrays of one length per table, the bodies' indexes those of the scene's bodies (scene_bodies
    of them, where given), each once, and every contact naming bodies the step has, by that index
    (an engine is anyone's code: contacts naming body 999 of a 7-body scene were written, and
    validated; a removed body leaves a gap in the indexes, not a row). InputError naming the
    engine otherwise."""
    who = f"the engine {engine.name!r}"
    if not isinstance(bodies, dict) or not isinstance(contacts, dict):
        raise InputError(f"{who} returned no bodies and contacts for step {k} (got "
                         f"{type(bodies).__name__} and {type(contacts).__name__})")
    for table, arrays in (("bodies", bodies), ("contacts", contacts)):
        lengths = {name: len(a) for name, a in arrays.items() if hasattr(a, "__len__")}
        if len(set(lengths.values())) > 1:
            raise InputError(f"{who} returned {table} of different lengths for step {k}: "
                             + ", ".join(f"{n} {v}" for n, v in sorted(lengths.items())))
    _check_body_indexes(k, bodies, who, scene_bodies)
    stray = stray_contact(bodies, contacts)
    if stray is not None:
        raise InputError(f"{who} returned a contact of step {k} naming body {stray[2]}, but the step has no "
                         f"body {stray[2]} ({len(bodies.get('index', ()))} bodies)")


def _check_body_indexes(k, bodies, who, scene_bodies):
    """The bodies' `index` column (each body's number in the scene, which contacts name): there,
    no body twice and, given scene_bodies, each below it."""
    if not bodies:
        return
    if "index" not in bodies:
        raise InputError(f"{who} returned bodies of step {k} without their index (each body's number in "
                         "the scene, which its contacts name)")
    index = np.asarray(bodies["index"])
    if len(index) and (len(np.unique(index)) != len(index) or index.min() < 0
                       or (scene_bodies is not None and index.max() >= scene_bodies)):
        raise InputError(f"{who} returned bodies of step {k} whose indexes are not the scene's bodies (each once, "
                         f"from 0 to {'its count' if scene_bodies is None else scene_bodies - 1}): {_shown(index)}")


def _shown(values, most=8):
    """At most `most` values, for a message."""
    head = ", ".join(str(v) for v in values[:most].tolist())
    return head + (", ..." if len(values) > most else "")


def prepare_output(out_dir, seeds):
    """A folder per simulation in the (new, empty) folder the run is built in."""
    out_dir = Path(out_dir)
    try:
        for seed in seeds:
            output.make_dir(out_dir / sim_dirname(seed))
    except OSError as e:
        raise InputError(f"cannot write there: {e.strerror or e}", out_dir) from None
    return out_dir


def _box_list(box):
    return None if box is None else [float(fmt(v)) for v in box]


def _short_of_tolerance(loop, solution):
    """(stopped by the cap short of the tolerance, ended with a residual above it) for one step of
    the project's solver with a tolerance, each 0 or 1. The residual is the project's: a plug-in
    method's answer is judged, whatever it reported."""
    if loop is None or not loop.tolerance > 0 or solution is None:
        return 0, 0
    on_residual = loop.stop_on == "residual"
    at_cap = solution.iterations >= loop.max_iterations and not (on_residual and solution.residual <= loop.tolerance)
    return int(at_cap), int(on_residual and solution.residual > loop.tolerance)


def _worker(args):
    make_scene, seed, out_dir, skip, engine, compress = args
    scene = _made(make_scene, seed)
    return run_simulation(scene, Path(out_dir) / sim_dirname(seed), seed, skip, engine=engine, compress=compress)


SEED_MAX = 2 ** 31 - 1   # what a step file's seed holds (and --seed takes)


def check_seeds(seeds):
    """Seeds are whole numbers from 0 to SEED_MAX, each once (a range is checked at its ends)."""
    ends = (seeds[0], seeds[-1]) if isinstance(seeds, range) else seeds
    bad = next((s for s in ends if isinstance(s, bool) or not isinstance(s, (int, np.integer))
                or not 0 <= s <= SEED_MAX), None)
    if bad is not None:
        raise OptionError(f"a seed is a whole number from 0 to {SEED_MAX}, got {bad!r}", "--seed")
    if not isinstance(seeds, range) and len(set(int(s) for s in seeds)) != len(seeds):
        raise OptionError("a seed is listed twice (each simulation's folder is its seed's)", "--seed")


def run(make_scene: Callable, seeds: Sequence[int], out_dir: str | os.PathLike, *, overwrite: bool = False,
        skip_contactless: bool = False, jobs: int = 1, progress: Callable | None = None, source: str | None = None,
        engine: "Engine | None" = None, max_disk: float | None = None, compress: bool = False) -> dict:
    """Simulate make_scene(seed) for every seed into out_dir and write the manifest last.

    seeds: any sequence (a range stays a range). progress(total_steps) makes a tqdm-like counter
    of steps (or progress is None). max_disk: refuse runs estimated above this many GB (the free
    space is always a limit). compress: gzip every step file. engine: what steps the worlds
    (a simulate.engines.Engine: Box2D(), the default; Box2D(solver=SolveSettings(...), start=...);
    Box2D3(SoftStep()); Pymunk(); MuJoCo()).
    Returns the manifest as a dict."""
    _check_arguments(make_scene, seeds, out_dir, jobs, engine, max_disk, progress,
                     overwrite=overwrite, skip_contactless=skip_contactless, compress=compress)
    if not len(seeds):
        raise InputError("no seeds to simulate (is the shard empty?)")
    check_seeds(seeds)
    engine = Box2D() if engine is None else engine
    # Build (and check) the first scene before touching the output folder.
    first = _made(make_scene, seeds[0])
    check_overlaps(first, source)
    engine.check(first, source)
    header_xml(first, engine)   # (what a plug-in engine says of itself that no step file can hold: refused now)
    out_dir = Path(out_dir)
    with output.output_folder(out_dir, RUN_FILES, overwrite, command="simulate") as work:
        # (by fixtures as well as bodies: a body of many fixtures makes many contact points)
        fixtures = sum(len(b.shapes) for b in first.bodies)
        per_step = step_bytes(len(first.bodies), fixtures) // (COMPRESSION_RATIO if compress else 1)
        check_disk(len(seeds) * first.steps * per_step, out_dir, max_disk,
                   f"{len(seeds):,} simulations of {first.steps:,} steps")
        manifest = _run_into(prepare_output(work, seeds), make_scene, first, seeds, skip_contactless, jobs,
                             progress, source, engine, compress)
    log.info("wrote %s, %s to %s", count(len(manifest["simulations"]), "simulation"),
             count(sum(r["files"] for r in manifest["simulations"]), "step file"), os.fspath(out_dir))
    _warn_short_of_tolerance(manifest, engine.solve_settings())
    return manifest


def _check_arguments(make_scene, seeds, out_dir, jobs, engine, max_disk, progress, **flags):
    """InputError naming the first of run's arguments that it cannot use (before anything is made)."""
    if not callable(make_scene):
        raise arguments.refuse("make_scene", "a function of a seed making its Scene (SceneSource(...), say)", make_scene)
    arguments.instance(seeds, "seeds", (list, tuple, range, np.ndarray), "a list or range of seeds")
    arguments.path(out_dir, "out_dir")
    arguments.whole(jobs, "jobs", 1)
    if engine is not None:
        arguments.instance(engine, "engine", Engine, "an engine: Box2D(), Box2D3(), engine_named(NAME), ...")
    if max_disk is not None:
        arguments.number(max_disk, "max_disk", 0)
    if progress is not None and not callable(progress):
        raise arguments.refuse("progress", "None or a function of a total making a counter", progress)
    for name, value in flags.items():
        arguments.flag(value, name)


def _made(make_scene, seed):
    """make_scene(seed), held to be a Scene (a caller's function may return anything)."""
    scene = make_scene(seed)
    if not isinstance(scene, Scene):
        raise InputError(f"argument 'make_scene' must make a Scene (generate, read_scene and SceneSource do); "
                         f"for seed {seed} it returned {type(scene).__name__}")
    return scene


def _warn_short_of_tolerance(manifest, loop):
    capped = sum(r.get("capped") or 0 for r in manifest["simulations"])
    above = sum(r.get("above_tolerance") or 0 for r in manifest["simulations"])
    if above > capped:   # (a step at the cap is said below; these ended above for another reason too)
        log.warning("%d of %d steps ended with a residual above the tolerance %g (by the project's residual, whatever "
                    "the method reported: stopped early, fell back, or the cap); the manifest counts them per "
                    "simulation (above_tolerance), and dc validate --residuals checks each step file", above,
                    sum(r["steps"] for r in manifest["simulations"]), loop.tolerance)
    if capped:
        log.warning("%d of %d steps stopped at the cap of %d sweeps before the %s measure fell below %g (raise "
                    "--max-iterations; each step file's <solve> says where it stopped)", capped,
                    sum(r["steps"] for r in manifest["simulations"]), loop.max_iterations, loop.stop_on, loop.tolerance)


def _run_into(out_dir, make_scene, first, seeds, skip_contactless, jobs, progress, source, engine, compress):
    if progress is not None:
        progress = progress(first.steps * len(seeds))
    try:
        results = _simulate_all(make_scene, first, seeds, out_dir, skip_contactless, jobs, progress, source, engine,
                                compress)
    finally:
        if progress is not None:
            progress.close()
    return write_manifest(out_dir, first, engine, source=source, **engine.manifest(),
                          skip_contactless=skip_contactless,
                          compression="gzip" if compress else "none",
                          simulations=[r.__dict__ for r in results])


def _simulate_all(make_scene, first, seeds, out_dir, skip_contactless, jobs, progress, source, engine, compress):
    results = []
    if jobs <= 1:
        for seed in seeds:
            scene = first if seed == seeds[0] else _made(make_scene, seed)
            if seed != seeds[0]:
                check_overlaps(scene, source)
            tick = (lambda k: progress.update(1)) if progress is not None else None
            results.append(run_simulation(scene, out_dir / sim_dirname(seed), seed, skip_contactless, tick,
                                          engine=engine, compress=compress))
    else:
        for seed in seeds[1:]:
            check_overlaps(_made(make_scene, seed), source)
        with workers.pool(min(jobs, len(seeds))) as pool:
            tasks = ((make_scene, seed, str(out_dir), skip_contactless, engine, compress) for seed in seeds)
            for r in pool.imap_unordered(_worker, tasks):
                results.append(r)
                if progress is not None:
                    progress.update(r.steps)
    results.sort(key=lambda r: r.seed)
    return results
