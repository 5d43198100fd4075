"""What accuracy costs in time, across engines: Box2D 2.4.1, Box2D v3 and the project's solver
on the same scenes, each engine from its own rest (stability.own_rest: the resting contacts of
a scene start where that engine rests them; they differ by one linear slop).

Families (each a line of settings, cheapest first):
  Box2D 2.4.1   its velocity solver at 1, 2, 4, ..., 256 iterations a step
  Box2D v3      the soft step at 1, 2, 4, 8, 16 substeps; at 4 substeps with warm starting off
                (v3's relax pass is a constant of its library, one per substep: it cannot be
                switched off without rebuilding Box2D v3)
  project       the project's solver in the loop (float64 sweeps from Box2D's warm start, as
                `dc simulate --solver pgs --tolerance T`) to residuals 1e-2 ... 1e-8, 1000 sweeps
                at most a step (steps stopped by the cap are counted; a setting with any is
                marked "cap hit on N steps: not at its tolerance" and is never named its family's
                cheapest passing setting, whatever its criteria: it did not solve to its tolerance)
  lagged        the same with the solve in body space and its lagged factor (`--accelerate
                lagged`, the factor carried from step to step) to 1e-4 and 1e-8

Each setting is judged by the stability study's criteria (studies/stability.py: finite, at rest
within 3 linear slops, no energy gained beyond its allowance, a stack's top within 1 cm, at rest
at the end) and measured: time per step (a second run without recording, one thread), the drift
from the reference trajectory (every step from the same initial state solved to a residual of
1e-12; none where the project's solver cannot step the scene: continuous collision), the deepest
contact at rest (a heavy body's sinking), the energy rise, the stack top's drift and the fastest
body at the end. On a chaotic scene (a pile, the confined circles) any difference grows until
the bodies are a body's size apart: drift there measures chaos, not accuracy.

    dc study engines [--fast] -o DIR
"""
import math
from dataclasses import dataclass

import numpy as np

from deepcontact import output, workers
from deepcontact.evaluate.closed_loop import reference_trajectory
from deepcontact.scene.generators import parameters
from deepcontact.simulate import stepping
from deepcontact.solver.metrics import drift
from deepcontact.solver.settings import CAP, SolveSettings
from deepcontact.studies import units
from . import efforts, stability as S
from .tables import (SettingRow, accuracy_plot, csv_text, fmt as _fmt, markdown_table, setting_cell,
                     short_of_tolerance, slug)

TOLERANCES = (1e-2, 1e-4, 1e-6, 1e-8)


def engine_settings(fast=False, names=None):
    """Each engine's own frontier (efforts.frontier: the built-ins', or those `names`) as Settings,
    in the registry's order."""
    from deepcontact.simulate.engines import ENGINES
    out = []
    for name in ENGINES.builtin() if names is None else names:
        cls = ENGINES.load(name)
        effort = efforts.effort(cls)
        for family, label, given in efforts.frontier(cls, fast):
            count = given.get(effort.setting, effort.default or 8)
            rest = tuple(sorted((k, v) for k, v in given.items() if k != effort.setting))
            out.append(Setting(family, label, name, count, engine_settings=rest))
    return out


def engine_families():
    """The families of the engines' own settings (not the project's solver), in order."""
    return tuple(dict.fromkeys(s.family for s in engine_settings()))

# the project's families: their methods and tolerances
PROJECT = {"project": ("none", TOLERANCES), "lagged": ("lagged", (1e-4, 1e-8))}

# (a pile is not asked to be still at the end: its circles may still roll)
FULL = [S.Case("thesis pile", "pile", {}, rests=False), *S.FULL]
# What `dc study engines -o DIR` writes (what --overwrite may replace).
ENGINE_FILES = output.Owned("engines study folder", [r"engines\.md", r"engines\.csv", r"pareto-[a-z0-9-]+\.png"])
FAST = [S.Case("pile 30", "pile", dict(count=30, box=16.0, sigma=4.0, steps=240), rests=False), *S.FAST]


@dataclass(frozen=True)
class Setting:
    family: str
    label: str
    solver: str            # stability.stepper's: box2d, box2d3 or pgs
    count: int             # iterations, substeps, or the sweep cap
    tolerance: float = 0.0
    relaxation: float = 1.0   # the project's over-relaxation w and solver method
    accelerate: str = "none"
    warm_starting: bool = True
    rest: str = "own"      # own: from where the engine rests resting contacts; box2d: 2.4.1's (stability.own_rest)
    variant: bool = False  # an ablation beside the family's sweep (not a candidate for the cheapest)
    engine_settings: tuple = ()   # (name, value) pairs of the engine's other settings (MuJoCo's solver, ...)

    @property
    def solve_settings(self) -> SolveSettings:
        """How this setting solves one step: Box2D 2.4.1's own PGS (exact) or the project's (v3 has
        no step problem of 2.4.1's kind)."""
        if self.solver == "box2d":
            return SolveSettings(mode="exact", max_iterations=self.count, tolerance=0.0)
        return SolveSettings(max_iterations=self.count, tolerance=self.tolerance, relaxation=self.relaxation,
                             accelerate=self.accelerate)


FAMILIES = (*engine_families(), "project", "lagged")


def families_of(rows):
    """The families among rows, in the tables' order: the built-in ones, then plug-in methods'."""
    return [f for f in FAMILIES if any(r.family == f for r in rows)] + \
        list(dict.fromkeys(r.family for r in rows if r.family not in FAMILIES))


def is_project(family):
    """Whether a family is the project's solver (a built-in method's, or a plug-in method's)."""
    return family not in engine_families()


def plugin_line(rows, known=FAMILIES):
    """A line saying how plug-in methods' rows were measured, where there are any (families not
    among the study's `known` ones)."""
    plugins = list(dict.fromkeys(r.family for r in rows if r.family not in known))
    if not plugins:
        return []
    from deepcontact.escape import md_text
    return [f"Plug-in methods ({', '.join(md_text(p) for p in plugins)}): each step goes through Python, each solve "
            f"in the method's own process (never this one), its answer judged here and its round trip (an echo of "
            f"the same request) subtracted; the Python path itself is in their times, as it is in no built-in row "
            f"(the built-ins step in one native call).\n"]


def plugin_settings(methods, tolerances):
    """A family per plug-in solver method (`--accelerate`), at the study's tolerances: each solve in
    the method's own process, timed and judged as dc evaluate does (deepcontact.contest)."""
    return [Setting(name, f"residual {t:g}", "pgs", CAP, tolerance=t, accelerate=name) for name in methods
            for t in tolerances]


def picked(settings, families):
    """The settings `families` names (all without): a family by its name, one setting by
    'FAMILY:SETTING' (its names in the tables, e.g. 'pymunk:10 iterations'). OptionError where a
    'FAMILY:SETTING' names no setting of the study, listing the family's."""
    if families is None:
        return settings
    for name in families:
        family, _, label = name.partition(":")
        if label and not any(s.family == family and s.label == label for s in settings):
            from deepcontact.errors import OptionError
            labels = [s.label for s in settings if s.family == family]
            raise OptionError(f"{family} has no setting {label!r} here; its settings are: {', '.join(labels)}",
                              "--families")
    return [s for s in settings if s.family in families or f"{s.family}:{s.label}" in families]


def settings(families=None, plugins=(), fast=False):
    """Every setting of every family (only those of `families`, where given), in the order of the
    tables; then a family per plug-in method named in `plugins`. fast: each engine's few settings
    of the fast studies (Engine.frontier)."""
    out = engine_settings(fast)
    at = max(k for k, s in enumerate(out) if s.solver == "box2d3") + 1   # (v3's ablations after its sweep)
    out[at:at] = [Setting("Box2D v3", "4 substeps, no warm start", "box2d3", 4, warm_starting=False, variant=True),
                  Setting("Box2D v3", "4 substeps, from 2.4.1's rest", "box2d3", 4, rest="box2d", variant=True)]
    out += [Setting(family, f"residual {t:g}", "pgs", CAP, tolerance=t, accelerate=method)
            for family, (method, tolerances) in PROJECT.items() for t in tolerances]
    return picked(out, families) + plugin_settings(plugins, TOLERANCES)


@dataclass
class Row(SettingRow):
    drift: float              # largest over the run, from the reference trajectory (m); nan: none
    penetration: float        # deepest at rest (m)
    peak_penetration: float
    energy_rise: float
    energy_allowed: float
    top_drift: float          # stacks (m); nan otherwise
    final_speed: float        # the fastest body at the end (m/s)
    capped: int | None        # steps a cap stopped short of the tolerance (the project's, or an engine's own
                              # where it says so, MuJoCo's); None where nothing says
    variant: bool = False     # an ablation (Setting.variant)


def applicable(case, setting):
    if setting.rest != "own" and S.own_rest(case, setting.solver) == S.own_rest(case, "box2d"):
        return False   # (the same scene as the setting from its own rest)
    return S.applicable(case, setting.solver)


def params_of(case, setting):
    """The scene parameters a setting runs from."""
    return S.own_rest(case, setting.solver if setting.rest == "own" else setting.rest)


def step_ms(case, setting):
    """Mean wall time of a step (ms), stepped without recording: the engine's own time."""
    scene = S.case_scene(case, setting.warm_starting, params_of(case, setting))
    world, step = S.stepper(scene, setting.solver, "builtin", setting.count, setting.relaxation, setting.accelerate,
                            tolerance=setting.tolerance, record=False, engine_settings=dict(setting.engine_settings))
    remote = getattr(step, "remote", None)   # (a plug-in method's process: its round trips are not its time)
    try:
        seconds = [done.seconds - (remote.take_transport() if remote is not None else 0.0)
                   for done in stepping.steps(world, scene, step)]
    finally:
        S.close(step)
    return 1e3 * float(np.mean(seconds)) if seconds else float("nan")


def run_setting(case, setting, **kw):
    """stability.run_case under every field of the setting (solver, count, tolerance, w, method,
    warm starting) from the setting's own rest: the one place a study turns a Setting into a run."""
    return S.run_case(case, setting.solver, "builtin", setting.count, setting.relaxation, setting.accelerate,
                      tolerance=setting.tolerance, warm_starting=setting.warm_starting,
                      params=params_of(case, setting), engine_settings=dict(setting.engine_settings), **kw)


def run_scene(case, chosen=None):
    """Every applicable setting on one case, against one reference trajectory."""
    chosen = settings() if chosen is None else chosen
    references = {}   # by the parameters a setting starts from: each against its own initial state

    def reference_of(params):
        key = repr(sorted(params.items()))
        if key not in references:
            scene = S.case_scene(case, params=params)
            # (its steps are not the settings the study counts: unreported)
            references[key] = reference_trajectory(scene, scene.steps, report=False).positions
        return references[key]

    rows, work = [], work_of(case)
    for setting in chosen:
        if not applicable(case, setting):
            continue
        # (a unit of work: kept, and reused by a resumed run measured with the same options)
        before = units.measured()
        rows.append(units.kept({"scene": case, "setting": setting}, lambda: measure(case, setting, reference_of), Row))
        workers.progress(1, work, kept=units.measured() == before)
    return rows


def measure(case, setting, reference_of):
    """The Row of one setting on one case; reference_of(params): the reference trajectory's
    positions from those scene parameters."""
    trail = []
    params = params_of(case, setting)
    r = run_setting(case, setting, trail=trail)
    far = float("nan")
    reference = reference_of(params) if S.applicable(case, "pgs") else None
    if reference is not None:
        n = min(len(trail), len(reference))
        far = max((drift(trail[k], reference[k]) for k in range(n)), default=0.0)
        if not r.finite:
            far = float("inf")
    return Row(scene=case.label, family=setting.family, setting=setting.label, passed=r.passed,
               finite=r.finite, ms_per_step=step_ms(case, setting) if r.finite else float("nan"),
               drift=far, penetration=r.penetration, peak_penetration=r.peak_penetration,
               energy_rise=r.energy_rise, energy_allowed=r.energy_allowed, top_drift=r.top_drift,
               final_speed=r.final_speed, capped=r.capped, variant=setting.variant)


def study(cases, jobs=1, progress=None, chosen=None):
    """Rows of every case (in order); cases side by side in `jobs` worker processes."""
    tasks = [(case, chosen) for case in cases]
    with workers.for_jobs(jobs, tasks, progress) as pool:
        return [row for rows in pool.imap(_scene_task, tasks) for row in rows]


def _scene_task(task):
    return run_scene(*task)


def tasks_count(cases, chosen=None):
    """The settings the study runs (what its progress counts)."""
    chosen = settings() if chosen is None else chosen
    return sum(applicable(c, s) for c in cases for s in chosen)


def tasks_work(cases, chosen=None):
    """What those settings weigh in all (work_of each): the progress bar's time left follows it."""
    chosen = settings() if chosen is None else chosen
    return sum(work_of(c) * sum(applicable(c, s) for s in chosen) for c in cases)


def work_of(case):
    """What a setting on the case is expected to cost, for a progress bar's time left: bodies x
    steps (a setting of a 10,000-circle pile weighs 8 of a pyramid of 820 boxes). The bodies by the
    generator's count where it has one (generating a 10,000-circle pile takes 20 s)."""
    p = {**parameters(case.generator), **case.params}
    if "count" in p:
        bodies = p["count"]
    elif "base" in p:
        bodies = p["base"] * (p["base"] + 1) // 2
    else:
        bodies = len(S.case_scene(case).bodies)
    return int(bodies) * int(p["steps"])


# --- reports -------------------------------------------------------------------------------

TIE = 0.05   # times within 5% of each other are one time (timing noise on microsecond steps)


def cheapest(rows):
    """{family: the passing row of its sweep (not an ablation) with the least time per step, or
    None} of one scene's rows. Rows within TIE of the least time count as tied, and the tie goes
    to the least effort (the first in the sweep's order). A row whose cap stopped steps above its
    tolerance is not a candidate (tables.short_of_tolerance)."""
    out = {}
    for family in families_of(rows):
        mine = [r for r in rows if r.family == family and not r.variant]
        if not mine:
            continue
        ok = [r for r in mine if r.passed and math.isfinite(r.ms_per_step) and not short_of_tolerance(r)]
        if not ok:
            out[family] = None
            continue
        least = min(r.ms_per_step for r in ok)
        out[family] = next(r for r in ok if r.ms_per_step <= least * (1 + TIE))
    return out


def _most(rows, family):
    """The last setting of a family's sweep (for "none up to ...")."""
    return [r for r in rows if r.family == family and not r.variant][-1].setting


COLUMNS = [("family", lambda r: r.family), ("setting", setting_cell),
           ("passes", lambda r: "yes" if r.passed else "no"), ("ms / step", lambda r: _fmt(r.ms_per_step)),
           ("drift from reference (cm)", lambda r: _fmt(r.drift, 100)),
           ("penetration at rest (cm)", lambda r: _fmt(r.penetration, 100)),
           ("energy rise / allowed (J)", lambda r: f"{_fmt(r.energy_rise)} / {_fmt(r.energy_allowed)}"),
           ("top drift (cm)", lambda r: _fmt(r.top_drift, 100)), ("fastest at end (m/s)", lambda r: _fmt(r.final_speed)),
           ("capped steps", lambda r: "" if r.capped is None else r.capped)]


def scene_table(rows):
    return markdown_table(COLUMNS, rows)


def verdict_table(rows):
    """One line per scene: the cheapest passing setting of each family and its time per step."""
    scenes = list(dict.fromkeys(r.scene for r in rows))
    families = families_of(rows)   # (the families run)
    lines = ["| scene | " + " | ".join(families) + " |", "| --- |" + " --- |" * len(families)]
    for scene in scenes:
        mine = [r for r in rows if r.scene == scene]
        best = cheapest(mine)
        cells = []
        for family in families:
            if family not in best:
                cells.append("n/a")
            elif best[family] is None:
                cells.append(f"none up to {_most(mine, family)}")
            else:
                b = best[family]
                cells.append(f"{b.setting}: {_fmt(b.ms_per_step)} ms")
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _short(row):
    """A point's label on the plot: its count, tolerance or ablation."""
    if row.variant:
        return "no warm start" if "warm" in row.setting else "from 2.4.1's rest"
    return row.setting.split()[0] if row.setting[:1].isdigit() else row.setting.split()[-1]


def pareto_plot(rows, path):
    """Time per step against drift from the reference, one line per family; hollow markers fail
    the scene's criteria, stars are v3's ablations."""
    points = {f: [(r.ms_per_step, r.drift * 100, r.passed, _short(r), r.variant) for r in rows if r.family == f]
              for f in families_of(rows)}
    accuracy_plot(families_of(rows), points, path, "largest drift from the reference (cm)",
                  f"{rows[0].scene}: accuracy against time\n(labels: iterations, substeps, residual; "
                  "hollow: fails the criteria; stars: v3 ablations)")


def markdown(rows, fast, protocol_text, pictures=True):
    setting = "fast (the test suite's small variants)" if fast else "full"
    parts = [f"# Accuracy against time across engines: {setting}\n",
             __doc__.split("\n\n")[0].replace("\n", " ").rstrip(".") + ".\n",
             f"Criteria: {S.CRITERIA}\n", protocol_text + "\n",
             *plugin_line(rows),
             "## The cheapest setting of each family that meets the criteria\n", verdict_table(rows)]
    for scene in dict.fromkeys(r.scene for r in rows):
        mine = [r for r in rows if r.scene == scene]
        parts.append(f"## {scene}\n")
        if pictures:
            parts.append(f"![{scene}](pareto-{slug(scene)}.png)\n")
        parts.append(scene_table(mine))
    return "\n".join(parts)


def write(rows, out_dir, fast, protocol_text):
    """engines.md, engines.csv and a Pareto plot per scene into out_dir (an open output folder)."""
    from pathlib import Path
    out_dir = Path(out_dir)
    for scene in dict.fromkeys(r.scene for r in rows):
        pareto_plot([r for r in rows if r.scene == scene], out_dir / f"pareto-{slug(scene)}.png")
    output.write_text(out_dir / "engines.csv", csv_text(rows, Row))
    text = markdown(rows, fast, protocol_text)
    output.write_text(out_dir / "engines.md", text)
    return text
