"""Reading step files (`step-NNNNNN.xml`, or `.xml.gz`) back into the arrays the binding produces.

The native reader streams each file through libxml2's SAX2 parser (and zlib): no tree, no
XPath, about a millisecond for a 100-circle pile step. Every value is checked to be present and
finite (integers in range), and a problem is an InputError naming the file and line. With
validate=True the XSD is checked in the same pass. step.reader_lxml is the slow reference that
the tests hold this reader to, value for value.
"""
from functools import lru_cache

from .._box2d import StepFileError, StepSchema, read_step_file
from ..errors import InputError
from ..schema import schema_path

_GRID_BODY = ("center", "velocity", "mass", "omega", "type")
_GRID_CONTACT = ("position", "normal", "normal_impulse", "tangent_impulse")


@lru_cache(maxsize=None)
def step_schema() -> StepSchema:
    """schemas/step.xsd compiled once per process for the native reader and validator."""
    return StepSchema(schema_path("step"))


def read_step(path, validate=True):
    """Returns (header dict, bodies dict of arrays, contacts dict of arrays)."""
    try:
        return read_step_file(str(path), step_schema() if validate else None)
    except StepFileError as e:
        message, line = e.args
        raise InputError(message, path, line or None) from None


def read_step_for_grid(path):
    """The fields rasterizing needs, checked, without schema validation (fast)."""
    header, bodies, contacts = read_step(path, validate=False)
    header = {k: header[k] for k in ("scene", "seed", "index")}
    return header, {k: bodies[k] for k in _GRID_BODY}, {k: contacts[k] for k in _GRID_CONTACT}


def check_origin(header, scene, seed, path):
    """A step file belongs to the simulation it lies in: the same scene name and seed."""
    if header["scene"] != scene or header["seed"] != seed:
        raise InputError(f"the step file is of scene {header['scene']!r} seed {header['seed']}, but lies in a "
                         f"simulation of scene {scene!r} seed {seed} (copied from another run?)", path, 1)
