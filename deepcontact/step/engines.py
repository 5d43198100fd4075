"""How a step file says which engine stepped it, and which rows that engine records.

A step file names its engine in `<solver name>`: box2d (or pgs, the project's solver in Box2D
2.4.1's loop), box2d3 (Box2D v3), or any other engine's registered name (pymunk, mujoco, a
plug-in's), whose header then has an `<engine>` line with its version and settings. Rows: the
Box2D engines record contact rows of their own (2.4.1's warm start and local manifold, v3's total
impulse and anchors: native/step_names.hpp); every other engine records the common rows only.
Only 2.4.1's rows let a reader rebuild 2.4.1's contact problem (replay, evaluate, export)."""
from .._box2d import STEP_CONTACT_XML

RELAX_ITERATIONS = 1   # relax iterations per substep: a constant of v3's library (solver.c), not a setting
ROWS = ("box2d", "box2d3", "own")   # whose own rows a file holds ("own": none but the common ones)


def rows_of(solver_name) -> str:
    """Whose own rows a step file whose `<solver name>` is `solver_name` holds."""
    return {"box2d": "box2d", "pgs": "box2d", "box2d3": "box2d3"}.get(solver_name, "own")


def engine_of(header) -> str:
    """The engine a step file's header (a reader's dict) names (box2d for the project's solver,
    which steps 2.4.1's loop)."""
    name = header["solver"].get("name")
    return "box2d" if rows_of(name) == "box2d" else name


def poses_box2d_problem(header) -> bool:
    """Whether the step (a reader's header) holds Box2D 2.4.1's contact problem: its rows."""
    return rows_of(header["solver"].get("name")) == "box2d"


def foreign_fields(rows) -> frozenset:
    """The contact fields a step of `rows` (rows_of) does not record (read back as 0): from the
    step file's names table (native/step_names.hpp)."""
    return frozenset(row[2] for row in STEP_CONTACT_XML if row[4] in ("box2d", "box2d3") and row[4] != rows)
