"""What accuracy costs at scale: the frontier of time per step against accuracy on scenes of
hundreds to thousands of bodies, Box2D 2.4.1 and v3 beside the project's solver.

Families (each a line of settings, cheapest first):
  Box2D 2.4.1   its velocity solver at 1, 2, 4, ..., 256 iterations a step
  Box2D v3      the soft step at 1, 2, 4, 8, 16 substeps
  PGS, PSOR 1.7, NNCG, lagged
                the project's solver in the loop from Box2D's warm start (float64; plain, at
                w = 1.7, with conjugate directions, the solve in body space with a lagged factor)
                to residuals 1e-2 ... 1e-8 within 1000 sweeps, and PGS and PSOR at fixed budgets
                of 8, 32 and 128 sweeps

Accuracy by measures that chaos does not swamp (a pile's trajectory drifts from any other by a
body's size whatever the solver: drift measures chaos there):
  one-step residual   from the same recorded states (Box2D 2.4.1 at the scene's 8 iterations,
                      `samples` steps spread over the run's second half, each from Box2D's warm
                      start), the setting's step solved and judged by the project's residual (the
                      min-map residual every solve reports); Box2D 2.4.1 at k iterations is its own
                      PGS replayed bit for bit (mode exact). Median and largest over the samples.
  velocity error      of that step against the reference step (the exact solver, float64 to
                      1e-12, its own residual stated: at a thousand bodies it may stop short), the
                      largest over the bodies, median over the samples. Exact solutions of a
                      frictional step need not be unique, even in body velocity: the residual is
                      the measure, this one its illustration.
  the stability criteria, penetration and energy rise of a whole run (studies/stability.py),
                      and, for the project, the steps the sweep cap stopped above the tolerance:
                      a setting with any is marked "cap hit on N steps: not at its tolerance" and
                      is never named the cheapest project setting at least as accurate.
v3's step is a soft step of another contact model: it has no one-step residual here, and is
judged by the criteria and its penetration. The time per step is the mean of a second, unrecorded
run (one thread). A reference trajectory (every step solved to 1e-12) is not made at this scale:
one such solve of the 1000-circle pile took 14-15 s, 3 hours for a run.

    dc study frontier [--fast] -o DIR
"""
import functools
import math
from dataclasses import dataclass

import numpy as np

from deepcontact import output, workers
from deepcontact.simulate.problems import problems
from deepcontact.solver.methods import solve
from deepcontact.solver.reference import reference_solution
from deepcontact.solver.settings import CAP
from deepcontact.studies import units
from . import stability as S
from deepcontact.contest import RemoteMethod
from deepcontact.solver.methods import is_native
from .engines import (Setting, applicable, engine_families, engine_settings, families_of, picked, plugin_line,
                      plugin_settings, run_setting, step_ms, work_of)
from .tables import (SettingRow, accuracy_plot, csv_text, fmt as _fmt, markdown_table, setting_cell,
                     short_of_tolerance, slug)

TOLERANCES = (1e-2, 1e-4, 1e-6, 1e-8)
BUDGETS = (8, 32, 128)
PROJECT = (("PGS", 1.0, "none"), ("PSOR 1.7", 1.7, "none"), ("NNCG", 1.0, "nncg"), ("lagged", 1.0, "lagged"))
FAMILIES = (*engine_families(), *(name for name, _, _ in PROJECT))
REFERENCE_POINTS = 2500   # a reference step above this many contact points is not solved (minutes each)

SCALE = [
    S.Case("pile 1000", "pile", dict(count=1000, box=95.0, sigma=19.0, steps=800), rests=False),
    S.Case("pile 10000", "pile", dict(count=10000, box=300.0, sigma=60.0, steps=400), rests=False),
    S.Case("confined 625", "confined", dict(count=625), rests=False),
    S.Case("confined 2500", "confined", dict(count=2500), rests=False),
    S.Case("pyramid 40", "pyramid", dict(base=40)),
    S.Case("pyramid 5050", "pyramid", dict(base=100)),
]
FAST = [
    S.Case("pile 30", "pile", dict(count=30, box=16.0, sigma=4.0, steps=240), rests=False),
    S.Case("pyramid 5", "pyramid", dict(base=5, steps=120)),
]
FAST_SAMPLES = 2
# What `dc study frontier -o DIR` writes (what --overwrite may replace).
FRONTIER_FILES = output.Owned("frontier study folder", [r"frontier\.md", r"frontier\.csv", r"frontier-[a-z0-9-]+\.png"])


def settings(fast=False, families=None, tolerances=None, plugins=()):
    """Every setting of every family, in the order of the tables (fewer with fast); only the
    `families` named (a family, or one setting as 'FAMILY:SETTING': engines.picked) and the
    project's `tolerances` given, where given; then a family per plug-in
    method in `plugins`, at those tolerances (engines.plugin_settings)."""
    default_tolerances, budgets = ((1e-2, 1e-4), (8,)) if fast else (TOLERANCES, BUDGETS)
    tolerances = default_tolerances if tolerances is None else tolerances
    out = engine_settings(fast)
    for family, w, method in PROJECT:
        out += [Setting(family, f"{n} sweeps", "pgs", n, 0.0, w, method) for n in budgets if method == "none"]
        out += [Setting(family, f"residual {t:g}", "pgs", CAP, t, w, method) for t in tolerances]
    return picked(out, families) + plugin_settings(plugins, tolerances)


@dataclass
class Row(SettingRow):
    residual_median: float    # one-step residual over the samples; nan for v3
    residual_max: float
    velocity_error: float     # median over the samples of the largest |v - v_ref| (m/s); nan: no reference
    penetration: float        # deepest at rest (m)
    energy_rise: float
    energy_allowed: float
    capped: int | None        # steps a cap stopped above the tolerance (the project's, or MuJoCo's own);
                              # None where nothing says
    samples: int


@dataclass
class Sample:
    problem: object
    reference: object        # Solution, or None above REFERENCE_POINTS


def samples_of(case, count):
    """`count` step problems of the case stepped by Box2D 2.4.1 at its own iterations, spread over
    the run's second half, each with its reference solution (None where too large to solve)."""
    scene = S.case_scene(case)
    first = scene.steps // 2
    every = max(1, (scene.steps - first) // max(count, 1))
    chosen = []
    for _, problem in problems(scene, first=first, every=every):
        reference = reference_solution(problem) if problem.points <= REFERENCE_POINTS else None
        chosen.append(Sample(problem, reference))
        if len(chosen) == count:
            break
    return chosen


def poses_problem(setting):
    """Whether a setting's step is Box2D 2.4.1's contact problem (the project's solver, or 2.4.1's
    own): only those have a one-step residual here."""
    return setting.solver == "pgs" or S._engine_class(setting.solver).poses_box2d_problem


def one_step(setting, samples):
    """(median residual, largest residual, median velocity error) of the setting's step on the samples."""
    if not poses_problem(setting) or not samples:
        return float("nan"), float("nan"), float("nan")
    asked = setting.solve_settings
    residuals, errors = [], []
    remote = None if is_native(asked.accelerate) else RemoteMethod(asked.accelerate)   # (its own process)
    try:
        solutions = [solve(s.problem, settings=asked) if remote is None else
                     remote.solve(s.problem, s.problem.start_normal, s.problem.start_tangent, asked) for s in samples]
    finally:
        if remote is not None:
            remote.close()
    for s, solution in zip(samples, solutions):
        residuals.append(solution.residual)
        if s.reference is not None and len(s.reference.velocity):
            errors.append(float(np.abs(solution.velocity - s.reference.velocity).max()))
    return (float(np.median(residuals)), float(np.max(residuals)),
            float(np.median(errors)) if errors else float("nan"))


def run_scene(case, chosen, samples):
    """Every applicable setting on one case (Rows, in order), each a unit of work kept (units:
    a resumed run reuses those measured with the same options), and the line on its samples."""
    picked = functools.cache(lambda: samples_of(case, samples))   # (made only where a unit is measured)
    rows, work = [], work_of(case)
    for setting in chosen:
        if not applicable(case, setting):
            continue
        before = units.measured()
        rows.append(units.kept({"scene": case, "setting": setting, "samples": samples},
                               lambda: measure(case, setting, picked()), Row))
        workers.progress(1, work, kept=units.measured() == before)
    return rows, units.kept({"scene": case, "samples": samples, "line": "reference"},
                            lambda: _reference_line(case, picked()))


def measure(case, setting, picked):
    """The Row of one setting on one case, its one-step measures on the sampled steps `picked`."""
    r = run_setting(case, setting)
    median, largest, error = one_step(setting, picked)
    return Row(scene=case.label, family=setting.family, setting=setting.label, passed=r.passed,
               finite=r.finite, ms_per_step=step_ms(case, setting) if r.finite else float("nan"),
               residual_median=median, residual_max=largest, velocity_error=error,
               penetration=r.penetration, energy_rise=r.energy_rise, energy_allowed=r.energy_allowed,
               capped=r.capped, samples=len(picked))


def _reference_line(case, picked):
    solved = [s.reference for s in picked if s.reference is not None]
    if not picked:
        return f"{case.label}: no step with contact points to sample."
    points = ", ".join(str(s.problem.points) for s in picked)
    if not solved:
        return (f"{case.label}: {len(picked)} sampled steps ({points} contact points); no reference step (above "
                f"{REFERENCE_POINTS:,} points): no velocity error.")
    worst = max(s.residual for s in solved)
    return (f"{case.label}: {len(picked)} sampled steps ({points} contact points); the reference steps reached "
            f"a residual of {worst:.1e} at worst.")


def study(cases, chosen, samples, jobs=1, progress=None):
    """(rows of every case in order, a line per case on its reference steps); cases side by side
    in `jobs` worker processes."""
    tasks = [(case, chosen, samples) for case in cases]
    rows, lines = [], []
    with workers.for_jobs(jobs, tasks, progress) as pool:
        for scene_rows, line in pool.imap(_scene_task, tasks):
            rows += scene_rows
            lines.append(line)
    return rows, lines


def _scene_task(task):
    return run_scene(*task)


def tasks_count(cases, chosen):
    """The settings the study runs (what its progress counts)."""
    return sum(applicable(c, s) for c in cases for s in chosen)


# --- reports -------------------------------------------------------------------------------

def _project(row):
    return row.family not in engine_families()


def matches(rows):
    """For each engine setting of one scene, the cheapest project setting at least as accurate: by
    the one-step residual (median and largest) against Box2D 2.4.1, by penetration at rest against
    v3 (its step has no residual here), and passing the criteria where the engine setting does;
    never one whose cap stopped steps above its tolerance (tables.short_of_tolerance).
    (engine row, project row or None)."""
    ours = [r for r in rows if _project(r) and r.finite and math.isfinite(r.ms_per_step) and not short_of_tolerance(r)]
    out = []
    for e in (r for r in rows if not _project(r) and math.isfinite(r.ms_per_step)):
        good = [r for r in ours if _as_accurate(r, e)]
        out.append((e, min(good, key=lambda r: r.ms_per_step) if good else None))
    return out


def _as_accurate(ours, engine):
    """Whether a project row is at least as accurate as an engine's (matches' rule)."""
    if engine.passed and not ours.passed:
        return False
    if math.isfinite(engine.residual_median):   # (an engine posing 2.4.1's problem: by its residual)
        return ours.residual_median <= engine.residual_median and ours.residual_max <= engine.residual_max
    return ours.penetration <= engine.penetration


def summary_table(rows):
    """One line per engine setting of every scene: the cheapest project setting at least as
    accurate and the ratio of its time to the engine's."""
    lines = ["| scene | engine setting | passes | ms / step | one-step residual (median / largest) | cheapest project "
             "setting at least as accurate | passes | ms / step | time ratio |",
             "| --- | --- | --- | ---: | ---: | --- | --- | ---: | ---: |"]
    for scene in dict.fromkeys(r.scene for r in rows):
        ran = any(_project(r) for r in rows if r.scene == scene)
        for e, p in matches([r for r in rows if r.scene == scene]):
            accuracy = (f"{_fmt(e.residual_median)} / {_fmt(e.residual_max)}" if math.isfinite(e.residual_median)
                        else f"penetration {_fmt(e.penetration, 100)} cm")
            # ("none" only where the project's settings ran and none was as accurate)
            ours = f"{p.family}, {p.setting}" if p is not None else "none" if ran else "not run (no project family asked)"
            lines.append(f"| {scene} | {e.family}, {e.setting} | {'yes' if e.passed else 'no'} | "
                         f"{_fmt(e.ms_per_step)} | {accuracy} | {ours} | "
                         f"{'' if p is None else ('yes' if p.passed else 'no')} | {'' if p is None else _fmt(p.ms_per_step)} | "
                         f"{'' if p is None else _fmt(p.ms_per_step / e.ms_per_step, digits=2) + 'x'} |")
    return "\n".join(lines) + "\n"


def at_equal_time(rows):
    """For each Box2D 2.4.1 setting of one scene, the project setting with the smallest one-step
    residual (median) among those whose time per step is at most the engine's: what the project
    reaches in the same time, whatever its method (a budget or a tolerance, capped or not: at equal
    time the residual reached is what counts). (engine row, project row or None)."""
    ours = [r for r in rows if _project(r) and r.finite and math.isfinite(r.ms_per_step)
            and math.isfinite(r.residual_median)]
    out = []
    for e in (r for r in rows if r.family == "Box2D 2.4.1" and math.isfinite(r.ms_per_step)):
        fits = [r for r in ours if r.ms_per_step <= e.ms_per_step]
        out.append((e, min(fits, key=lambda r: (r.residual_median, r.ms_per_step)) if fits else None))
    return out


def equal_time_table(rows):
    """One line per Box2D 2.4.1 setting of every scene: the best project residual in at most its
    time per step, and how it compares (the ratio of the project's median residual to 2.4.1's:
    below 1, the project is more accurate in the same time)."""
    lines = ["| scene | Box2D 2.4.1 | ms / step | residual (median) | best project setting in at most that time | "
             "ms / step | residual (median) | residual ratio |", "| --- | --- | ---: | ---: | --- | ---: | ---: | ---: |"]
    for scene in dict.fromkeys(r.scene for r in rows):
        for e, p in at_equal_time([r for r in rows if r.scene == scene]):
            best = "none as fast" if p is None else f"{p.family}, {setting_cell(p)}"
            lines.append(f"| {scene} | {e.setting} | {_fmt(e.ms_per_step)} | {_fmt(e.residual_median)} | {best} | "
                         f"{'' if p is None else _fmt(p.ms_per_step)} | {'' if p is None else _fmt(p.residual_median)} | "
                         f"{'' if p is None else _fmt(p.residual_median / e.residual_median, digits=2) + 'x'} |")
    return "\n".join(lines) + "\n"


COLUMNS = [("family", lambda r: r.family), ("setting", setting_cell),
           ("passes", lambda r: "yes" if r.passed else "no"), ("ms / step", lambda r: _fmt(r.ms_per_step)),
           ("one-step residual (median / largest)", lambda r: f"{_fmt(r.residual_median)} / {_fmt(r.residual_max)}"),
           ("velocity error (m/s)", lambda r: _fmt(r.velocity_error)),
           ("penetration at rest (cm)", lambda r: _fmt(r.penetration, 100)),
           ("energy rise / allowed (J)", lambda r: f"{_fmt(r.energy_rise)} / {_fmt(r.energy_allowed)}"),
           ("capped steps", lambda r: "" if r.capped is None else r.capped)]


def scene_table(rows):
    return markdown_table(COLUMNS, rows)


def _plot(rows, path, accuracy, ylabel, title):
    """Time per step against accuracy(row), a line per family; labels: the iterations, substeps or
    sweeps, or the tolerance; hollow markers fail the scene's criteria."""
    def label(r):
        return r.setting.split()[0] if r.setting[:1].isdigit() else r.setting.split()[-1]
    points = {f: [(r.ms_per_step, accuracy(r), r.passed, label(r), False) for r in rows if r.family == f]
              for f in families_of(rows)}
    accuracy_plot(families_of(rows), points, path, ylabel,
                  f"{rows[0].scene}: {title}\n(labels: iterations, substeps, sweeps, tolerance; hollow: fails "
                  "the criteria)")


def frontier_plot(rows, path):
    """Time per step against the one-step residual, a line per family with a residual (v3's,
    pymunk's and MuJoCo's steps have none)."""
    _plot(rows, path, lambda r: r.residual_median, "one-step residual (median over the samples)",
          "accuracy against time")


def penetration_plot(rows, path):
    """Time per step against the deepest penetration at rest, every family: the one measure every
    engine has."""
    _plot(rows, path, lambda r: r.penetration * 100, "deepest penetration at rest (cm)",
          "penetration against time, every engine")


def markdown(rows, lines, fast, protocol_text):
    setting = "fast (the test suite's small variants)" if fast else "full"
    parts = [f"# What accuracy costs at scale: {setting}\n",
             __doc__.split("\n\n")[0].replace("\n", " ").rstrip(".") + ".\n",
             f"Criteria: {S.CRITERIA}\n", protocol_text + "\n", "Samples: " + " ".join(lines) + "\n",
             *plugin_line(rows, FAMILIES),
             "## For each engine setting, the cheapest project setting at least as accurate\n",
             summary_table(rows),
             "## At equal time: for each Box2D 2.4.1 setting, the project's best residual in at most its time\n",
             equal_time_table(rows)]
    for scene in dict.fromkeys(r.scene for r in rows):
        parts += [f"## {scene}\n", f"![{scene}](frontier-{slug(scene)}.png)\n",
                  f"![{scene}: penetration](frontier-{slug(scene)}-penetration.png)\n",
                  scene_table([r for r in rows if r.scene == scene])]
    return "\n".join(parts)


def write(rows, lines, out_dir, fast, protocol_text):
    """frontier.md, frontier.csv and two plots per scene (by residual, by penetration) into
    out_dir (an open output folder)."""
    from pathlib import Path
    out_dir = Path(out_dir)
    for scene in dict.fromkeys(r.scene for r in rows):
        mine = [r for r in rows if r.scene == scene]
        frontier_plot(mine, out_dir / f"frontier-{slug(scene)}.png")
        penetration_plot(mine, out_dir / f"frontier-{slug(scene)}-penetration.png")
    output.write_text(out_dir / "frontier.csv", csv_text(rows, Row))
    text = markdown(rows, lines, fast, protocol_text)
    output.write_text(out_dir / "frontier.md", text)
    return text
