"""deepcontact: Box2D contact solving with learned warm starts.

The path of data is visible in the subpackages: ``scene`` (what to simulate) → ``simulate``
(Box2D steps) → ``step`` (the per-step XML files) → grids, models, warm starts, solver, reports.
"""
__version__ = "0.1.0"
