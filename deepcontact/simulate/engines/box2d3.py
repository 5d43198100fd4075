"""Box2D v3 (3.1, the pyb2d3 wheel's library): the soft step."""
from dataclasses import dataclass
import functools
import math
import struct

from . import Engine, Setting
from .. import stepping
from ... import _box2d, arguments
from ...errors import InputError, OptionError
from ...resources import check_step_work
from ...step.writer import soft_step_xml
from ..build import build_world3

FLOAT32_TINY = 2.0 ** -126   # float32's smallest normal number (about 1.18e-38)


def _float32(value):
    """value as Box2D's float32 holds it (inf beyond its range)."""
    try:
        return struct.unpack("f", struct.pack("f", value))[0]
    except OverflowError:
        return math.inf


@dataclass(frozen=True)
class SoftStep:
    """Box2D v3's soft step, as `dc simulate --engine box2d3` runs it.

    substeps: per step (v3's `subStepCount`); contact_hertz, damping_ratio: the soft contact's
    stiffness and damping; push_speed: the most speed (m/s) v3 uses to push overlapping bodies
    apart. What is not given is v3's own default, read from its library (b2DefaultWorldDef; 4
    substeps, as its samples step). Warm starting, sleeping and continuous collision come from
    the scene, as for 2.4.1."""
    substeps: int = None
    contact_hertz: float = None
    damping_ratio: float = None
    push_speed: float = None

    def __post_init__(self):
        for name, value in soft_step_defaults().items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
        # (OptionError names the flag: dc simulate exits 2 on these, as for any bad option value,
        # and a library caller gets the same one line)
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
            # v3 takes float32, and the step file records what v3 got: 1e-300 would be 0 there (a
            # contact of no stiffness, which the file's own schema refuses), 1e-40 a denormal
            if value != 0 and abs(_float32(value)) < FLOAT32_TINY:
                least = f"at least {FLOAT32_TINY:.3g}" if lowest == "positive" else f"0 or at least {FLOAT32_TINY:.3g}"
                raise OptionError(f"{name.replace('_', ' ')} {value!r} is below float32's smallest normal number "
                                  f"(Box2D v3's floats would hold 0 or a denormal): give {least}", flag)


@functools.lru_cache(maxsize=None)
def soft_step_defaults() -> dict:
    """Box2D v3's own soft step defaults, from its library (b2DefaultWorldDef), as SoftStep's fields;
    InputError where this build has no Box2D v3."""
    if not hasattr(_box2d, "soft_step_defaults"):
        raise InputError("this build has no Box2D v3: install pyb2d3==0.11.1 and rebuild (make setup)")
    return dict(_box2d.soft_step_defaults())


class Box2D3(Engine):
    """Box2D v3 (3.1, the pyb2d3 wheel's library) stepping with its soft step `soft` (v3's
    defaults if None: SoftStep)."""
    name, label, rows = "box2d3", "Box2D v3", "box2d3"
    continuous = sleeps = True
    SETTINGS = {"substeps": Setting(int, 1, 1000, "substeps per step"),
                "contact_hertz": Setting(float, 0, 1e6, "soft contact stiffness (Hz)"),
                "damping_ratio": Setting(float, 0, 1000, "soft contact damping ratio"),
                "push_speed": Setting(float, 0, 1e6, "the most speed (m/s) used to push overlaps apart")}

    def __init__(self, soft: SoftStep | None = None):
        self.soft = SoftStep() if soft is None else arguments.instance(soft, "soft", SoftStep, "a SoftStep")

    @classmethod
    def from_settings(cls, **settings):
        """v3's soft step with `settings` (--set substeps=8): SoftStep's fields."""
        return cls(SoftStep(**cls.parsed(settings)))

    @classmethod
    def version(cls) -> str:
        return getattr(_box2d, "box2d3_version", "not built")

    def settings(self) -> dict:
        return {k: getattr(self.soft, k) for k in self.SETTINGS}

    def header_lines(self, scene) -> str:
        """v3's soft step (<soft_step>): its files' own header line."""
        return soft_step_xml(self.soft, scene.effects.restitution_threshold)

    def check(self, scene, source=None):
        """Refuses a step whose work would run for hours, and a polygon v3 cannot hull (naming it)."""
        check_step_work(len(scene.bodies), self.soft.substeps, f"{self.soft.substeps:,} substeps a step")
        build_world3(scene, self.soft, source)

    def build(self, scene, source=None):
        return build_world3(scene, self.soft, source)

    def stepper(self, world, scene, record=True):
        return stepping.box2d3(world, scene, record=record)

    def solve_line(self, solution, stats=None) -> str:
        return ""

    def manifest(self) -> dict:
        return {"pgs": None, "soft_step": dict(self.soft.__dict__)}   # (its settings)

    def __repr__(self):
        return f"Box2D3({self.soft!r})"
