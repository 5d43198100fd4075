"""Checking files as `dc validate` does: every step and scene file named or found under a named
folder, against the schemas and what the schemas cannot see, side by side in worker processes,
reported in file order. (At this floor because a scene's check builds its world: bodies that
start overlapping are refused.)"""
from functools import lru_cache
from itertools import groupby
import math
import os
from pathlib import Path

import numpy as np

from .. import output, workers
from ..errors import InputError, one_line, show_path
from ..scene.xml import read_scene
from ..solver.methods import SOLVERS
from ..solver.pgs import solve
from ..solver.problem import StepProblem
from ..solver.rounding import half_spacing, rounding_bound
from ..solver.settings import SolveSettings
from ..step.check import check_and_read
from ..step.reader import read_step
from ..step.records import check_pgs, solve_line
from ..step.run_folder import MANIFEST, read_run
from .build import check_overlaps

ABOVE = "is above its run's tolerance"   # (in the line held_to_tolerance gives: dc validate counts them)
CHUNK = 50   # files a worker checks per task


def is_xml(path):
    return path.name.endswith((".xml", ".xml.gz")) and not path.name.startswith(".")


def xml_files(paths):
    """Every *.xml and *.xml.gz file named or under a named folder. Anything by such a name that
    is not a regular file (a FIFO would block the parser forever) is refused."""
    for p in map(Path, paths):
        if p.is_dir():
            found = [q for q in (p / r for r in output.entries(p)) if is_xml(q)]   # (any depth, sorted)
        elif p.exists():
            found = [p]
        else:
            raise InputError("no such file or folder", p)
        for q in found:
            if not q.is_file():
                raise InputError("not a regular file", q)
        yield from found


def check_files(task):
    """[(path, error lines, above)] for ([(path, origin, tolerance)], residuals): one worker's share
    of a simulation folder; above: whether the step's residual, recomputed, is above tolerance."""
    chunk, residuals = task
    out = []
    for path, origin, tolerance in chunk:
        kind, errors, step = check_and_read(path, origin)
        above = False
        if not errors and kind == "scene":   # what the schema cannot see
            try:
                check_overlaps(read_scene(path), path)
            except InputError as e:
                errors = [f"{e.path}:{e.line or 0}:0: {e.message}"]
        elif not errors and kind == "step" and residuals:
            try:
                line, counted = held_to_tolerance(path, *(tolerance or (None,)), step=step)
            except InputError as e:
                line, counted = f"{e.message}", False
            if line:
                above = ABOVE in line
                # a step that stopped at its cap above the tolerance, measured as it records, is
                # counted (against the manifest's above_tolerance), not invalid
                errors = [] if counted else [one_line(f"{show_path(path)}:{solve_line(path)}:0: {line}")]
        out.append((path, errors, above))
    return out


def held_to_tolerance(path, tolerance, mode="float64", step=None):
    """What is wrong with a step our solver stepped, judged by the project: the residual of its
    recorded impulses, recomputed in float64 from the file's own problem and never read from the
    file, held to `tolerance`, its run's manifest's (None for a step file alone: then its own
    <solve>'s, and mode), in the run's arithmetic `mode` (the manifest's): (the line saying what
    is wrong or that the step is above the tolerance, or None if neither, or the step was not
    stepped by our solver to a residual; whether the step is above the tolerance as its record
    says, stopped at its cap: counted, not wrong). step: the file's (header, bodies, contacts),
    where the caller has read it; its <solve> checked against itself as it was read.

    One rule per arithmetic, no factor (docs/formats.md, "Validating"). A float64 solve stops on
    its own iterate, which the file holds rounded to float32: the residual every step records must
    be its impulses' to the most that rounding can move it (solver.rounding.rounding_bound, from
    the stored impulses), and the step is held to the tolerance plus that; a step at its cap need
    not meet it, and is counted above it where the residual it records is (as its run counted it).
    A float32 solve (float32, exact) is stored as computed, but measured its residual on the body
    velocities its sweeps carried in float32: a step above the tolerance or at its cap is replayed,
    and passes where the run's own solve, from the step's recorded start with its recorded
    settings, gives its impulses bit for bit and stops below the tolerance, or at the cap with the
    sweeps and residual the step records."""
    header, bodies, contacts = read_step(path, validate=False) if step is None else step
    claim = header.get("solve")
    if claim is None:
        return (None if tolerance is None else ("has no <solve> record, but its run's manifest says the project's "
                                                "solver stepped it (an edited file?)")), False
    source = "its run's manifest"
    if tolerance is None:
        if claim.get("stop_on") != "residual":
            return None, False
        tolerance, mode, source = float(claim["tolerance"]), claim.get("mode"), "its own <solve>, as it lies outside a run"
    if not tolerance > 0 or len(contacts["manifold"]) == 0:
        return None, False
    problem = StepProblem.from_step(header, bodies, contacts, path)
    recorded = (contacts["normal_impulse"].astype(float), contacts["tangent_impulse"].astype(float))
    found = _residual(problem, *recorded)
    # a float64 solve, and a plug-in's in any mode (the project judges its answer in float64),
    # measured the residual of the impulses the file rounds; a built-in float32 solve is replayed
    if mode == "float64" or claim.get("origin") == "plug-in":
        return _judged_on_rounding(problem, claim, recorded, found, (tolerance, source))
    if found <= tolerance and not _at_cap(claim):   # (nearly every step; never where found is NaN)
        return None, False
    return _judged_on_replay(problem, claim, recorded, found, (tolerance, source))


def _at_cap(claim):
    """Whether a <solve> records as many sweeps as its cap."""
    return _whole(claim.get("iterations")) >= _whole(claim.get("max_iterations"))


def _judged_on_rounding(problem, claim, recorded, found, held):
    """held_to_tolerance's verdict on a step whose solve measured, in float64, the impulses the
    file holds rounded to float32 (found: their residual recomputed). The residual the file records
    is the one measured, to the most that rounding moves it; a step that stopped before its cap is
    within that of the tolerance; one at its cap is above the tolerance (counted, as its run counted
    it) where the residual it records is. held: (tolerance, where it comes from)."""
    tolerance, source = held
    claimed, capped = _number(claim.get("residual")), _at_cap(claim)
    # (the bound only where it decides: a residual recorded as recomputed, below the tolerance, needs none)
    decides = not _agrees(found, claimed, 0.0) or (found > tolerance and not capped)
    rounding = rounding_bound(problem, *recorded) if decides else 0.0
    recomputed = f"the step's residual {found:.7g}, recomputed from its problem and impulses (float64)"
    if not capped and found > tolerance + rounding:
        return (f"{recomputed}, {ABOVE} {tolerance:.7g} plus {rounding:.3g}, the most float32 rounding of its "
                f"impulses can move it ({source}; the file records {claim.get('residual')})"), False
    if not _agrees(found, claimed, rounding):
        return _disagreement(claim, found, recomputed, rounding, held), False
    if capped and np.float32(claimed) > np.float32(tolerance):   # (as its run counted it: recorded, above)
        return (f"{recomputed}, as its <solve> records it, {ABOVE} {tolerance:.7g} at its cap of "
                f"{claim.get('max_iterations')} sweeps ({source})"), True
    return None, False


def _disagreement(claim, found, recomputed, rounding, held):
    """The line for a step whose recorded residual is not its impulses' (found) to `rounding`."""
    tolerance, source = held
    above = f" {ABOVE} {tolerance:.7g}" if found > tolerance else ","
    cap = claim.get("max_iterations")
    where = f" at its cap of {cap} sweeps" if _at_cap(claim) else f" after {claim.get('iterations')} of {cap} sweeps"
    return (f"{recomputed}{above}{where}, but the file records {claim.get('residual')}: further apart than the "
            f"most float32 rounding of its impulses and residual can move them "
            f"({rounding + _half_spacing(_number(claim.get('residual'))):.3g}; {source})")


def _judged_on_replay(problem, claim, recorded, found, held):
    """held_to_tolerance's verdict on a step a built-in float32 solve (float32, exact) stepped
    (found: its residual recomputed in float64, above the tolerance): replayed."""
    tolerance, source = held
    replayed = _replayed(problem, claim, recorded, tolerance)
    if replayed is not None:
        return replayed
    # (a step at its cap is replayed though its residual is below the tolerance: said so, not "above")
    where = (f"{ABOVE} {tolerance:.7g}" if not found <= tolerance else
             f"is below its run's tolerance {tolerance:.7g} at its cap of {claim.get('max_iterations')} sweeps")
    return (f"the step's residual {found:.7g}, recomputed from its problem and impulses (float64), {where}, and its "
            f"run's {claim.get('mode')} solve from its recorded start gives other impulses "
            f"({source}; the file records {claim.get('residual')})"), False


def _residual(problem, normal, tangent):
    """The residual of impulses as given (no sweep, no clamp into the cone), in float64."""
    return solve(problem, normal, tangent, max_iterations=0, cone=False, mode="float64").residual


def _replayed(problem, claim, recorded, tolerance):
    """A float32 step above the tolerance, replayed: the run's own solve from the step's recorded
    start with its <solve>'s settings (checked against the run's manifest as the file was read).
    (None, False) where it gives the recorded impulses bit for bit and stops below the tolerance
    after the sweeps and with the residual the step records (the run's arithmetic measured it so);
    (a line, True) where it gives them and stops above it
    at the cap after the sweeps and with the residual the step records (counted, as its run
    recorded); (a line, False) where the step records others; None where it does not give them."""
    try:
        # (in the order it records: island where it says none)
        settings = SolveSettings(mode=claim.get("mode"), tolerance=tolerance, stop_on="residual",
                                 max_iterations=_whole(claim.get("max_iterations")),
                                 relaxation=float(claim.get("relaxation") or 1.0),
                                 accelerate=claim.get("accelerate") or "none", order=claim.get("order") or "island")
        s = solve(problem, problem.start_normal, problem.start_tangent, settings=settings)
    except (InputError, ValueError):   # (settings no solve takes: not the run's own)
        return None
    same = all(np.array_equal(a.astype(np.float32), b.astype(np.float32)) for a, b in
               zip((s.normal_impulse, s.tangent_impulse), recorded))
    if not same:
        return None
    # (the sweeps and residual it records are the replay's, below the tolerance or at the cap)
    recorded_so = (s.iterations == _whole(claim.get("iterations"))
                   and _agrees(s.residual, _number(claim.get("residual")), 0.0))
    below = s.residual < tolerance
    if below and recorded_so:
        return None, False
    line = (f"the step's residual {s.residual:.7g}, as its run's {claim.get('mode')} solve measured it (replayed), "
            + (f"below {tolerance:.7g} after {s.iterations} sweeps" if below else
               f"{ABOVE} {tolerance:.7g} at the cap of {s.iterations} sweeps"))
    if recorded_so:
        return line, True
    return f"{line}, but the file records {claim.get('iterations')} sweeps and residual {claim.get('residual')}", False


def _agrees(measured, claimed, allowance):
    """Whether a residual the file records (the shortest text of a float32) is the one measured, to
    `allowance` (what rounding the impulses can move it) and its own rounding to float32."""
    stored = float(np.float32(claimed))   # (the text reads back to the float32 it was written from)
    return abs(measured - stored) <= allowance + _half_spacing(stored)   # (never where either is NaN)


def _half_spacing(value):
    """Half the float32 spacing at a value (solver.rounding.half_spacing; NaN where it is none)."""
    return float(half_spacing(np.array([value]))[0])


def _number(text):
    """A <solve> value as a number (NaN where it is none)."""
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def _whole(text):
    """A <solve> count as a number (0 where it is none)."""
    try:
        return max(int(text or 0), 0)
    except (TypeError, ValueError):
        return 0


def _key(path):
    """A file's key across the lookups of one validation: its folder resolved (once per folder:
    resolving every file's own path took a tenth of dc validate's time) and its name."""
    return (_resolved_folder(os.fspath(Path(path).parent)), Path(path).name)


@lru_cache(maxsize=4096)
def _resolved_folder(folder):
    return os.fspath(Path(folder).resolve())


def origins(paths):
    """step file -> (scene, seed, engine) of the simulation it lies in, for the runs among paths;
    step file -> (tolerance, mode) its run's manifest held our solver to (runs it stepped to a
    residual); the simulations' manifest records, by their folder; and the error lines of runs
    whose manifest does not match their folders."""

    origin, tolerance, simulations, errors = {}, {}, {}, []
    for run in (Path(p) for p in paths):
        if (run / MANIFEST).is_file():
            try:
                r = read_run(run)
            except InputError as e:
                errors.append(f"{e.path}:{e.line or 0}:0: {e.message}")
                continue
            pgs = r.manifest.get("pgs") if r.manifest.get("solver") == "pgs" else None
            if pgs is not None:   # (its method a built-in's name where it says built-in)
                try:
                    check_pgs(pgs, run / MANIFEST, SOLVERS.builtin())
                except InputError as e:
                    errors.append(f"{e.path}:{e.line or 0}:0: {e.message}")
                    continue
            origin.update({_key(f): (r.manifest.get("scene"), s.seed, s.engine, pgs) for s in r.simulations
                           for f in s.files})
            if isinstance(pgs, dict) and pgs.get("stop_on") == "residual":
                held = (float(pgs.get("tolerance") or 0.0), pgs.get("mode"))
                tolerance.update({_key(f): held for s in r.simulations for f in s.files})
                for s, record in zip(r.simulations, r.manifest["simulations"]):
                    simulations[(run / s.dir).resolve()] = (run / MANIFEST, s.seed, record)
    return origin, tolerance, simulations, errors


def _recounted(simulation, above):
    """An error line where a manifest's count of steps above the tolerance hides steps the
    recomputation found above it; else None (a count that is not one was refused as the run was
    read: step/records.check_above)."""
    manifest, seed, record = simulation
    claimed = record.get("above_tolerance")
    if claimed is None:
        return None
    if above > claimed:
        return (f"{show_path(manifest)}:0:0: simulation {seed}: records {claimed} step(s) above the tolerance; "
                f"recomputed, {above} are")
    return None


def validate(paths, report, jobs=1, progress=None, residuals=False):
    """Checks every file of paths; report(line) gets each error line, in file order whatever
    `jobs`; progress(total files) makes a counter whose update(n) hears of n more files checked
    (or progress is None). residuals: also each step our solver stepped,
    its residual recomputed from the file's problem and held to its run's tolerance
    (held_to_tolerance), and each simulation's count of such steps in the manifest. Returns
    (files checked, invalid files and runs, steps above their tolerance)."""
    files = list(xml_files(paths))
    if not files:
        raise InputError(f"no XML files found in {', '.join(map(str, paths))}")
    origin, tolerance, simulations, errors = origins(paths)
    invalid, above = len(errors), 0
    for line in errors:
        report(line)
    # tasks of up to CHUNK files of one folder (a simulation), in file order
    chunks = [[(f, origin.get(_key(f)), tolerance.get(_key(f))) for f in group[i:i + CHUNK]]
              for group in (list(g) for _, g in groupby(files, key=lambda f: f.parent))
              for i in range(0, len(group), CHUNK)]
    per_folder = {}
    counter = progress(len(files)) if progress is not None else None
    with workers.for_jobs(jobs, chunks) as pool:
        for checked in pool.imap(check_files, [(chunk, residuals) for chunk in chunks]):
            for path, lines, is_above in checked:
                invalid += bool(lines)
                above += is_above
                folder = Path(_key(path)[0])
                per_folder[folder] = per_folder.get(folder, 0) + is_above
                for line in lines:
                    report(line)
            if counter is not None:
                counter.update(len(checked))
    if residuals:
        for folder, simulation in simulations.items():
            line = _recounted(simulation, per_folder.get(folder, 0)) if folder in per_folder else None
            if line:
                invalid += 1
                report(line)
    return len(files), invalid, above
