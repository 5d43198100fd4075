"""The engines a run can be stepped by, and how a step file says which.

Box2D 2.4.1 (Debian's, the default: its velocity solver, or the project's with `--solver pgs`)
and Box2D v3 (3.1, the pyb2d3 wheel's library: the soft step). A step file names its engine in
`<solver name>` (box2d or pgs: 2.4.1; box2d3: v3) and holds that engine's own elements
(native/step_names.hpp)."""
import math
import struct
from dataclasses import dataclass

from ..errors import InputError

ENGINES = ("box2d", "box2d3")
V3_SOLVER = "box2d3"   # <solver name> of a Box2D v3 step
RELAX_ITERATIONS = 1   # relax iterations per substep: a constant of v3's library (solver.c), not a setting


def _float32(value):
    """value as Box2D's float32 holds it (inf beyond its range)."""
    try:
        return struct.unpack("f", struct.pack("f", value))[0]
    except OverflowError:
        return math.inf


@dataclass(frozen=True)
class SoftStep:
    """Box2D v3's soft step, as `dc simulate --engine box2d3` runs it (v3's defaults).

    substeps: per step (v3's `subStepCount`); contact_hertz, damping_ratio: the soft contact's
    stiffness and damping; push_speed: the most speed (m/s) v3 uses to push overlapping bodies
    apart. Warm starting, sleeping and continuous collision come from the scene, as for 2.4.1."""
    substeps: int = 4
    contact_hertz: float = 30.0
    damping_ratio: float = 10.0
    push_speed: float = 3.0

    def __post_init__(self):
        # (OptionError names the flag: dc simulate exits 2 on these, as for any bad option value,
        # and a library caller gets the same one line)
        from ..errors import OptionError
        if not (isinstance(self.substeps, int) and not isinstance(self.substeps, bool) and self.substeps >= 1):
            raise OptionError(f"substeps must be a whole number >= 1, got {self.substeps!r}", "--substeps")
        for name, lowest in (("contact_hertz", "positive"), ("damping_ratio", ">= 0"), ("push_speed", ">= 0")):
            value = getattr(self, name)
            flag = "--" + name.replace("_", "-")
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise OptionError(f"{name.replace('_', ' ')} must be a number, got {value!r}", flag)
            if not (value > 0 if lowest == "positive" else value >= 0):
                raise OptionError(f"{name.replace('_', ' ')} must be {lowest}, got {value!r}", flag)
            if not math.isfinite(_float32(value)):   # v3 takes float32: 1e39 would be inf there
                raise OptionError(f"{name.replace('_', ' ')} {value!r} is beyond float32 (Box2D v3's floats: at "
                                  f"most about 3.4e38)", flag)


def engine_of(header) -> str:
    """The engine a step file's header (a reader's dict) names: box2d or box2d3."""
    return "box2d3" if header["solver"].get("name") == V3_SOLVER else "box2d"


def foreign_fields(engine) -> frozenset:
    """The contact fields a step of `engine` does not record (the other engine's, read back as 0):
    from the step file's names table (native/step_names.hpp)."""
    from .._box2d import STEP_CONTACT_XML
    other = "box2d3" if engine == "box2d" else "box2d"
    return frozenset(row[2] for row in STEP_CONTACT_XML if row[4] == other)
