"""One step's contact problem, from a recorded step file or from a live world.

It holds exactly what Box2D's velocity solver starts from: the bodies at the start of the step
(before gravity), every contact point in island order with its local manifold, and the
solver's settings (dt, gravity, block solver). deepcontact._box2d.solve_contacts assembles the
rows from it (lever arms, effective masses, restitution bias, 2x2 blocks) and solves.
"""
from dataclasses import dataclass, field

import numpy as np

from .. import arguments
from .._box2d import SOLVER_BODY_FIELDS, SOLVER_CONTACT_FIELDS, StepSettings, World
from ..errors import InputError
from ..step.engines import engine_of, poses_box2d_problem

# The columns the native solver reads: its rows of the record tables (native/records.hpp).
BODY_KEYS = SOLVER_BODY_FIELDS
CONTACT_KEYS = SOLVER_CONTACT_FIELDS

KEY_COLUMNS = ("fixture_a", "child_a", "fixture_b", "child_b", "id_key")


def contact_keys(contacts: dict) -> list[tuple]:
    """What identifies a contact point across steps, as Box2D matches them: both fixtures and
    child indices, and the feature id (a body pair alone is not enough: a circle in a corner
    touches two walls of one static body)."""
    _require_columns(contacts, KEY_COLUMNS, "contacts")
    columns = [np.asarray(contacts[k]) for k in KEY_COLUMNS]
    for name, a in zip(KEY_COLUMNS, columns):
        if a.dtype.kind not in "iu" or a.shape != columns[0].shape[:1]:
            raise InputError(f"contacts column {name!r} must be whole numbers, one a contact point (as read_step "
                             f"returns them), got {a.dtype} of shape {a.shape}")
    return list(zip(*(a.tolist() for a in columns)))


def _require_columns(table, names, what):
    """InputError naming the columns a table (a dict of arrays) lacks."""
    if not isinstance(table, dict):
        raise InputError(f"{what} must be a dict of arrays (as read_step returns), got {type(table).__name__}")
    missing = [k for k in names if k not in table]
    if missing:
        raise InputError(f"{what} lack the columns {', '.join(missing)} (as read_step returns them)")


def _layout():
    """{column: (dtype, shape of one row)} of the record tables, as the native solver reads them."""
    global _LAYOUT
    if _LAYOUT is None:
        world = World(0.0, 0.0)
        _LAYOUT = {k: (v.dtype, v.shape[1:]) for table in (world.bodies(), world.contacts()) for k, v in table.items()}
    return _LAYOUT


_LAYOUT = None


def _columns(table, names, what):
    """The columns `names` of a table (a dict of arrays), each of one row a body or point, in the
    native dtype (converted where every value is kept: float64 positions to float32, say),
    contiguous; InputError naming the first that is text, of another shape, or whose whole numbers
    the native dtype cannot hold. (Every value the solver reads is held finite where it reads it.)"""
    _require_columns(table, names, what)
    out, rows = {}, None
    layout = _layout()
    for name in names:
        dtype, shape = layout[name]
        a = table[name]
        a = a if type(a) is np.ndarray else np.asarray(a)
        rows = len(a) if rows is None and a.ndim else rows
        if a.dtype is dtype and a.shape[1:] == shape and len(a) == rows:   # (as read: the closed loop's every step)
            out[name] = a if a.flags.c_contiguous else np.ascontiguousarray(a)
            continue
        if a.dtype.kind not in "biuf" or a.shape != (rows, *shape):
            raise _column_error(what, name, rows, f"got {a.dtype} of shape {a.shape}")
        if a.dtype != dtype:
            converted = np.ascontiguousarray(a, dtype=dtype)
            if dtype.kind in "iu" and not np.array_equal(converted, a):
                raise _column_error(what, name, rows, f"it holds values {dtype} cannot "
                                                      f"({'fractions' if a.dtype.kind == 'f' else 'beyond its range'})")
            a = converted
        out[name] = np.ascontiguousarray(a)
    return out


def _column_error(what, name, rows, got):
    dtype, shape = _layout()[name]
    row = f" ({', '.join(map(str, shape))} a row)" if shape else ""
    return InputError(f"{what} column {name!r} must be {rows} rows of {dtype}{row}, as read_step returns it; {got}")


def impulses_by_key(keys: list[tuple], normal: np.ndarray, tangent: np.ndarray) -> dict:
    """{contact key: (normal, tangent)}: a solution, to be matched to a later step's contacts."""
    if not isinstance(keys, (list, tuple)) or not all(isinstance(k, tuple) for k in keys):
        raise arguments.refuse("keys", "a list of contact keys (tuples, as contact_keys returns them)", keys)
    sizes = [len(keys), *(np.size(v) for v in (normal, tangent))]
    if len(set(sizes)) > 1:
        raise InputError(f"arguments 'keys', 'normal' and 'tangent' must have one entry per contact point; "
                         f"they have {', '.join(map(str, sizes))}")
    normal, tangent = (arguments.vector(v, name, len(keys)) for v, name in ((normal, "normal"), (tangent, "tangent")))
    return dict(zip(keys, zip(normal.tolist(), tangent.tolist())))


def _rows(index, bodies):
    """The row of each body (scene index) among the step's bodies `index`; vectorised, since the
    closed loop builds a problem every step."""
    index, bodies = np.asarray(index), np.asarray(bodies)
    if len(bodies) == 0:
        return np.zeros(0, np.int32)
    rows = None
    if len(index):
        # bodies come in scene order (World.bodies(), step files): sorted, so no argsort is needed
        rows = np.minimum(np.searchsorted(index, bodies), len(index) - 1)
        if np.any(index[rows] != bodies):
            order = np.argsort(index, kind="stable")
            rows = order[np.minimum(np.searchsorted(index, bodies, sorter=order), len(index) - 1)]
    if rows is None or np.any(index[rows] != bodies):
        known = set(index.tolist())
        missing = next(int(b) for b in bodies.tolist() if b not in known)
        raise InputError(f"a contact names body {missing}, which the step does not hold")
    return rows.astype(np.int32)


def refused(engine) -> str:
    """Why a step of another engine than 2.4.1 has no contact problem here (replay, dc validate
    --replay, dc evaluate, export)."""
    own = {"box2d3": "a Box2D v3 step (solver box2d3): its soft step (substeps, soft contacts, a relax pass)"}
    return (f"{own.get(engine, f'a step of the {engine} engine: its own contact model')} does not pose Box2D "
            "2.4.1's contact problem, which replaying and evaluating solve; simulate with --engine box2d for that")


@dataclass
class StepProblem:
    """One step's contact problem as Box2D poses it: the bodies, the contact points (manifolds,
    normals, friction, restitution) and Box2D's own warm start; `from_step` / `from_step_file`
    read it from a step file, and `solver.pgs.solve` solves it from any start."""

    bodies: dict                 # the columns BODY_KEYS, one row per body
    contacts: dict               # the columns CONTACT_KEYS plus row_a, row_b, one row per point
    dt: float
    gravity: tuple
    block_solve: bool = True
    velocity_iterations: int = 8
    start_normal: np.ndarray = None      # Box2D's first iterate (its warm start)
    start_tangent: np.ndarray = None
    normal_impulse: np.ndarray = None    # what Box2D produced, when known
    tangent_impulse: np.ndarray = None
    keys: np.ndarray = field(default=None, repr=False)   # (fixture_a, child_a, fixture_b, child_b, id)
    index: int = 0

    @property
    def points(self):
        return len(self.contacts["manifold"])

    def settings(self, prune=True) -> StepSettings:
        """The step the native solver assembles the problem for."""
        try:   # (held here as from_arrays holds them: a problem edited by hand reaches no native error)
            arguments.number(self.dt, "dt", low=0)
            arguments.vector(self.gravity, "gravity", 2)
            arguments.flag(self.block_solve, "block_solve")
        except InputError as e:
            raise InputError(f"the step's problem: {e}") from None
        return StepSettings(dt=self.dt, gravity=self.gravity, block_solve=self.block_solve, prune=prune)

    @classmethod
    def from_arrays(cls, bodies, contacts, *, dt, gravity, block_solve=True, velocity_iterations=8, index=0):
        """From the arrays of World.step(record=True) or of step.reader.read_step."""
        bodies = _columns(bodies, ("index", *BODY_KEYS), "bodies")
        contacts = _columns(contacts, (*CONTACT_KEYS, "body_a", "body_b", *KEY_COLUMNS, "start_normal_impulse",
                                       "start_tangent_impulse", "normal_impulse", "tangent_impulse"), "contacts")
        rows = _rows(bodies["index"], np.concatenate((contacts["body_a"], contacts["body_b"])))   # (one search)
        return cls._of_columns(bodies, contacts, rows, dt=float(np.float32(arguments.number(dt, "dt", low=0))),
                               gravity=tuple(arguments.vector(gravity, "gravity", 2).tolist()),
                               block_solve=arguments.flag(block_solve, "block_solve"),
                               velocity_iterations=arguments.whole(velocity_iterations, "velocity_iterations"),
                               index=arguments.whole(index, "index"))

    @classmethod
    def _from_world(cls, bodies, contacts, *, dt, gravity, block_solve, velocity_iterations):
        """from_arrays of the columns World.bodies() and World.contacts() returned, as they are
        (each of its native dtype and shape, contiguous): none checked or converted. The closed
        loop makes one a step; the loop's settings are held where it starts."""
        index, both = bodies["index"], np.concatenate((contacts["body_a"], contacts["body_b"]))
        # (a world's bodies are in scene order, each once: from 0 to n - 1 they are every index,
        # and a body's row is its index; a step file's may be anything, and are searched)
        fast = len(index) and index[0] == 0 and index[-1] == len(index) - 1
        rows = both.astype(np.int32) if fast else _rows(index, both)
        return cls._of_columns(bodies, contacts, rows, dt=float(np.float32(dt)),
                               gravity=(float(gravity[0]), float(gravity[1])), block_solve=bool(block_solve),
                               velocity_iterations=int(velocity_iterations))

    @classmethod
    def _of_columns(cls, bodies, contacts, rows, **scalars):
        """The problem of columns of the native dtypes and shapes, `rows` the bodies' rows of
        every point's body a, then of its body b."""
        c = {k: contacts[k] for k in CONTACT_KEYS}
        c["row_a"], c["row_b"] = rows[:len(rows) // 2], rows[len(rows) // 2:]
        keys = np.array([contacts[k] for k in KEY_COLUMNS], dtype=np.int64).T.reshape(-1, len(KEY_COLUMNS))
        return cls(bodies={k: bodies[k] for k in BODY_KEYS}, contacts=c, start_normal=contacts["start_normal_impulse"],
                   start_tangent=contacts["start_tangent_impulse"], normal_impulse=contacts["normal_impulse"],
                   tangent_impulse=contacts["tangent_impulse"], keys=keys, **scalars)

    @classmethod
    def from_step_file(cls, path):
        # with the schema: the rules `dc validate` holds a step to (friction >= 0, ...), in the same pass
        # (the reader, and the run folder and output rules below it: not imported in a contestant's
        # start, 20 ms of its 120)
        from ..step.reader import read_step
        return cls.from_step(*read_step(path, validate=True), path=path)

    @classmethod
    def from_step(cls, header, bodies, contacts, path=None):
        """From what step.reader.read_step returns; errors name `path`. A Box2D v3 step is refused:
        its soft step (substeps, soft contacts, relax) is not the contact problem posed here."""
        for value, name in ((header, "header"), (bodies, "bodies"), (contacts, "contacts")):
            arguments.mapping(value, name)   # (read_step's three values)
        if not isinstance(arguments.mapping(header, "header", ("solver", "dt", "gravity", "velocity_iterations", "index"))["solver"], dict):
            raise arguments.refuse("header", "a step header as read_step returns it", header)
        if not poses_box2d_problem(header):
            raise InputError(refused(engine_of(header)), path)
        block = header["solver"].get("block_solve")
        if block not in ("true", "false", "1", "0"):
            raise InputError(f"<solver block_solve> must be true or false, got {block!r}", path)
        try:
            return cls.from_arrays(bodies, contacts, dt=header["dt"], gravity=header["gravity"],
                                   block_solve=block in ("true", "1"),
                                   velocity_iterations=header["velocity_iterations"], index=header["index"])
        except InputError as e:
            raise InputError(e.message, path) from None
