"""Reading step files (`step-NNNNNN.xml`, or `.xml.gz`) back into the arrays the binding produces.

The native reader streams each file through libxml2's SAX2 parser (and zlib): no tree, no
XPath, about a millisecond for a 100-circle pile step. Every value is checked to be present and
finite (integers in range), and a problem is an InputError naming the file and line. With
validate=True the XSD is checked in the same pass. step.reader_lxml is the slow reference that
the tests hold this reader to, value for value.
"""
from functools import lru_cache
import os

from .. import arguments
from .._box2d import StepFileError, StepSchema, StrictTable, read_step_file
from ..errors import InputError
from ..schema import schema_path
from .engines import engine_of
from .run_folder import step_index
from .strict import table

_GRID_BODY = ("center", "velocity", "mass", "omega", "type")
_GRID_CONTACT = ("position", "normal", "normal_impulse", "tangent_impulse")


@lru_cache(maxsize=None)
def step_schema() -> StepSchema:
    """schemas/step.xsd compiled once per process for the native reader and validator."""
    return StepSchema(schema_path("step"))


@lru_cache(maxsize=None)
def strict_table() -> StrictTable:
    """The step schema's table (strict.py), compiled once per process."""
    return StrictTable(table())


def read_step(path: str | os.PathLike, validate: bool = True) -> tuple[dict, dict, dict]:
    """Returns (header dict, bodies dict of arrays, contacts dict of arrays). validate: held to
    the step schema, by its table as the file is read (strict.py): a file it accepts is valid; one
    it refuses or leaves to the XSD is validated by the XSD itself, which says what is wrong (or,
    being the authority, accepts it)."""
    arguments.path(path, "path")
    try:
        try:
            step = read_step_file(str(path), None, strict_table() if validate else None)
        except StepFileError:
            if not validate:
                raise
            step = read_step_file(str(path), step_schema())
    except StepFileError as e:
        message, line = e.args
        raise InputError(message, path, line or None) from None
    problem = manifold_problem(step[2])
    if problem:
        raise InputError(problem, path)
    return step


def manifold_problem(contacts):
    """Why the contact points do not form manifolds (each manifold's points in consecutive
    rows, point 0 first, all with the manifold's point count of 1 or 2), or None. The schema
    cannot say it; the solver assumes it."""
    import numpy as np
    m, point, count = contacts["manifold"], contacts["point"], contacts["point_count"]
    n = len(m)
    if not n:
        return None
    bad = (count < 1) | (count > 2) | (point < 0) | (point >= count)
    first = point == 0
    # a point k > 0 follows point k - 1 of the same manifold, with the same count
    follows = np.zeros(n, bool)
    follows[1:] = (m[1:] == m[:-1]) & (point[1:] == point[:-1] + 1) & (count[1:] == count[:-1])
    bad |= ~first & ~follows
    # a manifold is complete: its last point is count - 1, and a new manifold starts after it
    last = np.ones(n, bool)
    last[:-1] = point[1:] == 0
    bad |= last & (point != count - 1)
    if bad.any():
        k = int(np.argmax(bad))
        return (f"contact point {k} (manifold {int(m[k])}, point {int(point[k])} of {int(count[k])}): the points "
                "of a manifold must be consecutive, point 0 first")
    return None


def read_step_for_grid(path):
    """The fields rasterizing needs, checked, held to the schema in the same pass (the table: a
    tenth of the read; a dataset was built from files the XSD refuses)."""
    header, bodies, contacts = read_step(path)
    header = {k: header[k] for k in ("scene", "seed", "index", "solver")}   # (solver: its engine)
    return header, {k: bodies[k] for k in _GRID_BODY}, {k: contacts[k] for k in _GRID_CONTACT}


def check_origin(header, scene, seed, path, engine=None):
    """A step file belongs where it lies: the simulation's scene name and seed, its engine (where
    the run's manifest names one), and the step its name gives (a step copied over its neighbour
    would be read twice)."""
    if header["scene"] != scene or header["seed"] != seed:
        raise InputError(f"the step file is of scene {header['scene']!r} seed {header['seed']}, but lies in a "
                         f"simulation of scene {scene!r} seed {seed} (copied from another run?)", path, 1)
    if engine is not None and engine_of(header) != engine:   # (a header without <solver> is a reader's bug)
        raise InputError(f"the step file was stepped by {engine_of(header)}, but lies in a run of {engine} (copied "
                         f"from another run?)", path, 1)
    if "index" in header and header["index"] != step_index(path):
        raise InputError(f"the step file is step {header['index']} by its header, but is named step "
                         f"{step_index(path)} (copied over another step?)", path, 1)
