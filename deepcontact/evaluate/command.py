"""`dc evaluate`'s work as one library call: the settings as one value, the starts made, replay
or the closed loop run over every simulation given, the report written into a folder."""
from collections.abc import Callable
import dataclasses
from dataclasses import dataclass, field

from ..contest import missing_fences
from ..errors import InputError, OptionError
from ..grid import sources
from ..grid.spec import node_weight_problem
from ..grid.window import grid_for
from ..model.checkpoint_file import checkpoint_file
from ..protocol import protocol, use_threads
from ..scene.xml import read_scene
from ..solver.methods import method_origin
from ..solver.settings import VERDICT_CAP, SolveSettings
from ..warmstart import starts as registry
from . import reference_cache
from .closed_loop import every_simulation, pooled, steps_stepped
from .loop_report import write_loop_report
from .replay import box2d_runs, evaluate
from .report import summary_table, write_report
from .summary import summarize
from .verdicts import base_start, noise_of


@dataclass
class EvaluateSettings:
    """What to compare and how (the options of `dc evaluate`, checked by the command)."""
    runs: list                      # run folders of one kind of scene
    starts: list                    # start names (built-ins, installed plug-ins, package.module:Name)
    checkpoint: str | None = None   # a trained model, for the starts that use one
    solve: SolveSettings = SolveSettings(max_iterations=VERDICT_CAP)   # every solve's mode, tolerance, cap and measure (a variant's
                                             # w and method replace its own)
    every: int = 1                  # replay: every N-th step
    cell: float = 0.5               # the sph start's grid, without a checkpoint
    smoothing: float = 0.5
    kernel: str = "poly6"
    seed: int = 0                   # of the random start
    closed_loop: bool = False
    steps: int | None = None        # closed loop: steps to simulate (default the scene's)
    relaxations: tuple = (1.0,)
    accelerations: tuple = ("none",)
    budgets: bool = True
    bands: bool | None = None
    plots: bool = True              # the report's pictures (PNG and SVG); False: its tables alone
    jobs: int = 1
    threads: int = 1
    _read: list = field(default=None, repr=False, compare=False)

    @property
    def variants(self):
        return len(self.starts) * len(self.relaxations) * len(self.accelerations)

    def checked(self) -> "EvaluateSettings":
        """These settings, or OptionError naming the flag of the first rule they break (the same
        one line for the command line and a library caller): the solve settings (SolveSettings'
        rules, each method against the mode), a model for the starts that need one, a grid the
        sph start can draw; and InputError for a checkpoint path that cannot be one (before torch
        is imported to read it)."""
        for w in self.relaxations:   # (made, a SolveSettings checks itself: each w, each method)
            self.solve.but(relaxation=w)
        for method in self.accelerations:
            self.solve.but(accelerate=method)
        learned = [n for n in self.starts if registry.trait(n, "needs_model")]
        if learned and not self.checkpoint:
            raise OptionError(f"the start(s) {', '.join(learned)} need a trained model: give --checkpoint FILE",
                              "--checkpoint")
        if self.checkpoint:
            checkpoint_file(self.checkpoint)
        problem = "sph" in self.starts and not self.checkpoint and node_weight_problem(self.kernel, self.cell,
                                                                                       self.smoothing)
        if problem:
            raise OptionError(problem, "--cell")
        return self

    def read_runs(self) -> list:
        """The runs, each read (and checked) once, the first time they are asked for: a
        step.run_folder.Run each, passed down to replay and the closed loop."""
        if self._read is None:
            self._read = box2d_runs(self.runs)
        return self._read

    def sph_grid(self):
        """The sph start's grid without a checkpoint: over the window the manifests record (the
        scenes' static box, else where the bodies went), as dc rasterize draws it; runs from before
        manifests recorded the box are read as a dataset would read them."""
        runs = self.read_runs()
        if all("static_box" in e for r in runs for e in r.manifest["simulations"]):
            sims = [sim for r in runs for sim in r.simulations]
        else:
            sims, _ = sources.collect(self.runs)
        return grid_for(sims, self.cell, self.smoothing, self.kernel, True)[0]


def history_bytes(s: EvaluateSettings):
    """What replay's convergence histories hold at most (bytes) and a line saying of what."""
    total = sum(-(-len(sim.files) // s.every) for r in s.read_runs() for sim in r.simulations)
    # kept: a float per sweep for each step and variant (counted twice, for the copies made on the
    # way); and while one step is solved, its whole trace: the native record (3 doubles a sweep, up
    # to twice that as the vector grows) and its numpy copy (a row of MEASURES a sweep). The
    # convergence plot draws at most report.PLOT_POINTS sweeps, whatever the cap.
    kept = total * s.variants * (s.solve.max_iterations + 1) * 8 * 2
    tracing = (s.solve.max_iterations + 1) * 8 * (2 * 3 + 4)
    return (kept + tracing,
            f"the convergence histories of {total:,} steps x {s.variants} variants up to {s.solve.max_iterations:,} sweeps")


def run_evaluation(s: EvaluateSettings, out, bar: Callable | None = None) -> str:
    """Replay (or the closed loop) into the report folder out; returns the summary table.
    bar(total, unit) gives a progress callback for that many units."""

    predictor, spec = None, None
    if s.checkpoint:
        from ..model.inference import Predictor  # (torch: imported only where a model is evaluated)
        predictor = Predictor(s.checkpoint, threads=s.threads)
        spec = predictor.spec
    measured = protocol(s.threads, s.jobs)   # (the load average now, before the work adds to it)
    measured["missing_fences"] = missing_fences()   # (the contestants' fences this machine refused: said, never dropped)
    if "sph" in s.starts and spec is None:
        spec = s.sph_grid()
    table = registry.make_starts(s.starts, spec=spec, predictor=predictor)
    use_threads(s.threads)   # (after the starts: a plug-in start may bring torch with it)
    progress = bar or (lambda total, unit: None)
    if s.closed_loop:
        return _closed_loop(s, out, table, measured, progress)
    return _replay(s, out, table, measured, progress)


def _replay(s, out, table, measured, progress):
    total = sum(-(-len(sim.files) // s.every) for r in s.read_runs() for sim in r.simulations)   # (the evaluated)
    rows = evaluate(s.read_runs(), table, settings=s.solve, every=s.every, seed=s.seed, progress=progress(total, "step"),
                    relaxations=s.relaxations, budgets=s.budgets, accelerations=s.accelerations, jobs=s.jobs)
    summary = summarize(rows, table, s.solve.max_iterations)
    _record_origins(summary, table)
    settings = dict(runs=[str(r) for r in s.runs], starts=s.starts, relaxation=s.relaxations,
                    accelerate=s.accelerations, model=s.checkpoint, tolerance=s.solve.tolerance,
                    max_iterations=s.solve.max_iterations, stop_on=s.solve.stop_on, mode=s.solve.mode,
                    order=s.solve.order, every=s.every,
                    steps=len({(r.run, r.seed, r.step) for r in rows}), protocol=measured, bands=s.bands,
                    plots=s.plots, noise=noise_of(rows, summary))
    write_report(out, rows, summary, settings)
    return summary_table(summary, settings["noise"])


def _record_origins(summary, table):
    """Each variant's start and solver method, where they come from (built-in, or a plug-in with
    its target, distribution and version): in summary.json and the report."""
    for name, s in summary.items():
        s["start_origin"] = registry.STARTS.origin(base_start(name))
        s["method_origin"] = method_origin(s["accelerate"])


def _closed_loop(s, out, table, measured, progress):
    """Every simulation of every run given, its rows per seed and pooled over all of them."""

    sims = [(r.path, sim) for r in s.read_runs() for sim in r.simulations]
    scenes = [read_scene(sim.scene_file()) for _, sim in sims]
    if len({scene.name for scene in scenes}) > 1:
        raise InputError(f"the runs hold different scenes ({', '.join(sorted({sc.name for sc in scenes}))}); "
                         "the closed loop pools one kind of scene at a time")
    per_simulation = every_simulation(
        scenes, table, budgets=s.budgets, jobs=s.jobs,
        references=[reference_cache.folder_for(run) for run, _ in sims],
        progress=progress(steps_stepped(scenes, s.variants, s.budgets, s.steps), "step"),
        settings=s.solve, steps=s.steps, relaxations=s.relaxations, accelerations=s.accelerations)
    results = plotted = per_simulation[0] if len(sims) == 1 else pooled(per_simulation)
    if len(sims) > 1:   # the pooled rows first (plotted), then each simulation's, named by its run and seed
        results = plotted + [dataclasses.replace(r, start=f"{r.start} · {run} seed {sim.seed}")
                             for (run, sim), rows in zip(sims, per_simulation) for r in rows]
    what = (f"{scenes[0].name}, {len(sims)} simulation{'s' if len(sims) != 1 else ''} of "
            f"{', '.join(map(str, s.runs))}")
    return write_loop_report(out, results, what, s.solve, measured,
                             simulations=len(sims), plotted=plotted, plots=s.plots)
