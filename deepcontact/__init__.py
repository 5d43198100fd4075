"""deepcontact: Box2D contact solving with learned warm starts.

The path of data is visible in the subpackages: ``scene`` (what to simulate) → ``simulate``
(Box2D steps) → ``step`` (the per-step XML files) → grids, models, warm starts, solver, reports.

The public API is the names below (docs/api.md), each imported only when first used (reading a
step does not import torch)::

    import deepcontact as dc
    header, bodies, contacts = dc.read_step("runs/pile/seed-000000/step-000300.xml")
    problem = dc.StepProblem.from_step(header, bodies, contacts)
    solution = dc.solve(problem, tolerance=1e-4, max_iterations=1000)
"""
__version__ = "0.1.0"

# What `import deepcontact` offers, each name loaded from its module on first use: module -> names.
_MODULES = {
    "step.run_folder": ("read_run",),
    "step.reader": ("read_step",),
    "step.table": ("run_tables",),
    "scene.xml": ("read_scene",),
    "scene.generators": ("generate",),
    "scene.model": ("Scene", "Body", "Circle", "Polygon", "Edge", "Effects"),
    "simulate.source": ("SceneSource",),
    "simulate.engines": ("SoftStep", "Box2D", "Box2D3", "Engine", "ENGINES", "engine_named", "empty_bodies",
                         "empty_contacts", "scene_bodies"),
    "simulate.pgs_loop": ("LoopStep",),
    "simulate.world": ("World",),
    "studies": ("Study", "STUDIES"),
    "solver.problem": ("StepProblem", "contact_keys", "impulses_by_key"),
    "solver.methods": ("solve", "judge", "SOLVERS", "MethodResult"),
    "solver.local": ("local_problem", "LocalProblem"),
    "solver.settings": ("SolveSettings",),
    "solver.reference": ("reference_solution",),
    "grid.spec": ("GridSpec",),
    "grid.dataset": ("GridDataset",),
    "grid.splat": ("rasterize",),
    "model.train": ("train",),
    "model.config": ("TrainConfig",),
    "model.inference": ("Predictor",),
    "model.arch": ("NETWORKS",),
    "warmstart.starts": ("STARTS", "StartValue", "StepContext", "make_starts"),
    "evaluate.closed_loop": ("closed_loop",),
    "errors": ("InputError",),
}
# ... and those named apart from their attribute ("simulate" is the subpackage): name -> (module, attribute)
_RENAMED = {
    "simulate_run": ("simulate.run", "run"),
    "local_residual": ("solver.local", "residual"),
    "evaluate_starts": ("evaluate.replay", "evaluate"),
    "EngineSetting": ("simulate.engines", "Setting"),
    "SceneSolver": ("scene.model", "Solver"),
}
_PUBLIC = {**{name: (module, name) for module, names in _MODULES.items() for name in names}, **_RENAMED}
__all__ = ["__version__", *_PUBLIC]


def __getattr__(name):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'deepcontact' has no attribute {name!r}")
    import importlib
    module, attribute = _PUBLIC[name]
    value = getattr(importlib.import_module(f"{__name__}.{module}"), attribute)
    globals()[name] = value
    return value


def __dir__():
    return sorted(__all__)
