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

# name -> (module, attribute): what `import deepcontact` offers, loaded on first use
_PUBLIC = {
    "read_run": ("deepcontact.step.run_folder", "read_run"),
    "read_step": ("deepcontact.step.reader", "read_step"),
    "run_tables": ("deepcontact.step.table", "run_tables"),
    "read_scene": ("deepcontact.scene.xml", "read_scene"),
    "generate": ("deepcontact.scene.generators", "generate"),
    "simulate_run": ("deepcontact.simulate.run", "run"),   # (not "simulate": that is the subpackage)
    "SceneSource": ("deepcontact.simulate.source", "SceneSource"),
    "SoftStep": ("deepcontact.simulate.engines", "SoftStep"),
    "World": ("deepcontact.simulate.world", "World"),
    "Box2D": ("deepcontact.simulate.engines", "Box2D"),
    "Box2D3": ("deepcontact.simulate.engines", "Box2D3"),
    "Engine": ("deepcontact.simulate.engines", "Engine"),
    "ENGINES": ("deepcontact.simulate.engines", "ENGINES"),
    "engine_named": ("deepcontact.simulate.engines", "engine_named"),
    "Study": ("deepcontact.studies", "Study"),
    "STUDIES": ("deepcontact.studies", "STUDIES"),
    "StepProblem": ("deepcontact.solver.problem", "StepProblem"),
    "contact_keys": ("deepcontact.solver.problem", "contact_keys"),
    "impulses_by_key": ("deepcontact.solver.problem", "impulses_by_key"),
    "solve": ("deepcontact.solver.methods", "solve"),
    "judge": ("deepcontact.solver.methods", "judge"),
    "local_problem": ("deepcontact.solver.local", "local_problem"),
    "LocalProblem": ("deepcontact.solver.local", "LocalProblem"),
    "local_residual": ("deepcontact.solver.local", "residual"),
    "SOLVERS": ("deepcontact.solver.methods", "SOLVERS"),
    "SolveSettings": ("deepcontact.solver.settings", "SolveSettings"),
    "MethodResult": ("deepcontact.solver.methods", "MethodResult"),
    "reference_solution": ("deepcontact.solver.reference", "reference_solution"),
    "GridSpec": ("deepcontact.grid.spec", "GridSpec"),
    "GridDataset": ("deepcontact.grid.dataset", "GridDataset"),
    "rasterize": ("deepcontact.grid.splat", "rasterize"),
    "train": ("deepcontact.model.train", "train"),
    "TrainConfig": ("deepcontact.model.config", "TrainConfig"),
    "Predictor": ("deepcontact.model.inference", "Predictor"),
    "NETWORKS": ("deepcontact.model.arch", "NETWORKS"),
    "STARTS": ("deepcontact.warmstart.starts", "STARTS"),
    "StartValue": ("deepcontact.warmstart.starts", "StartValue"),
    "StepContext": ("deepcontact.warmstart.starts", "StepContext"),
    "make_starts": ("deepcontact.warmstart.starts", "make_starts"),
    "evaluate_starts": ("deepcontact.evaluate.replay", "evaluate"),
    "closed_loop": ("deepcontact.evaluate.closed_loop", "closed_loop"),
    "InputError": ("deepcontact.errors", "InputError"),
}
__all__ = ["__version__", *_PUBLIC]


def __getattr__(name):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'deepcontact' has no attribute {name!r}")
    import importlib
    module, attribute = _PUBLIC[name]
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value


def __dir__():
    return sorted(__all__)
