"""The engines a run can be stepped by, and how a step file says which.

Box2D 2.4.1 (Debian's, the default: its velocity solver, or the project's with `--solver pgs`)
and Box2D v3 (3.1, the pyb2d3 wheel's library: the soft step). A step file names its engine in
`<solver name>` (box2d or pgs: 2.4.1; box2d3: v3) and holds that engine's own elements
(native/step_names.hpp)."""
ENGINES = ("box2d", "box2d3")
V3_SOLVER = "box2d3"   # <solver name> of a Box2D v3 step
RELAX_ITERATIONS = 1   # relax iterations per substep: a constant of v3's library (solver.c), not a setting


def engine_of(header) -> str:
    """The engine a step file's header (a reader's dict) names: box2d or box2d3."""
    return "box2d3" if header["solver"].get("name") == V3_SOLVER else "box2d"


def foreign_fields(engine) -> frozenset:
    """The contact fields a step of `engine` does not record (the other engine's, read back as 0):
    from the step file's names table (native/step_names.hpp)."""
    from .._box2d import STEP_CONTACT_XML
    other = "box2d3" if engine == "box2d" else "box2d"
    return frozenset(row[2] for row in STEP_CONTACT_XML if row[4] == other)
