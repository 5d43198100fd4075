"""The engines a scene can be stepped by, as objects: each builds its world, makes its step
function, checks a scene against its own rules, and says what its step files and manifest record.

    Box2D()                    Box2D 2.4.1 with its own velocity solver (the scene's iterations)
    Box2D(solver=SolveSettings(...), start="builtin")
                               Box2D 2.4.1 stepped with the project's solver (`--solver pgs`)
    Box2D3(SoftStep())         Box2D v3's soft step (`--engine box2d3`)

`dc simulate`, `run`, `run_simulation` and `World` take one; no caller infers the engine from
which keywords are set.
"""
from collections.abc import Callable
import functools
import math
import struct
from dataclasses import dataclass

from ..xmltext import quoteattr
from ..errors import InputError
from ..resources import check_step_work
from ..scene.xml import fmt
from ..solver.methods import takes_relaxation
from ..solver.settings import SolveSettings
from . import stepping
from .build import build_world, build_world3
from .pgs_loop import PGSStepper, check_loop, check_scene_for_loop


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
    from .. import _box2d
    if not hasattr(_box2d, "soft_step_defaults"):
        raise InputError("this build has no Box2D v3: install pyb2d3==0.11.1 and rebuild (make setup)")
    return dict(_box2d.soft_step_defaults())


class Box2D:
    """Box2D 2.4.1 (Debian's). Without `solver`, its own velocity solver at the scene's iterations
    (or `velocity_iterations`); with `solver` (a SolveSettings), the project's solver in the loop
    from `start` (builtin: Box2D's warm start; zero; garbage), with the settings and the method it
    says (docs/solver.md, "The loop"). start_fn(bodies, contacts, problem, builtin_n, builtin_t)
    -> (normal, tangent), if given, makes each step's first iterate instead (the closed loop's starts;
    no step file records one)."""

    def __init__(self, solver: SolveSettings | None = None, start: str = "builtin",
                 velocity_iterations: int | None = None, start_fn: Callable | None = None):
        from .. import arguments
        if solver is not None:
            arguments.instance(solver, "solver", SolveSettings, "a SolveSettings (or None: Box2D's own solver)")
        arguments.text(start, "start")
        if velocity_iterations is not None:
            arguments.whole(velocity_iterations, "velocity_iterations")
        if start_fn is not None and not callable(start_fn):
            raise arguments.refuse("start_fn", "a callable", start_fn)
        if solver is not None:
            check_loop(solver, start, own_start=start_fn is not None)
            if not takes_relaxation(solver.accelerate):   # (recorded as not taken, not as a w of 1)
                solver = solver.but(relaxation=None)
        self.solver, self.start, self.start_fn = solver, start, start_fn
        self.velocity_iterations = velocity_iterations

    @property
    def name(self) -> str:
        """What its step files' `<solver name>` and the manifest's `solver` say: box2d or pgs."""
        return "box2d" if self.solver is None else "pgs"

    engine = "box2d"   # the manifest's `engine`: the library that steps the world
    soft = None

    def check(self, scene, source=None):
        """Refuses a scene this engine cannot step as asked (InputError naming `source`): a step
        whose work would run for hours; with the project's solver, continuous collision or sleeping."""
        bodies = len(scene.bodies)
        if self.solver is not None:
            check_scene_for_loop(scene, source)
            check_step_work(bodies, self.solver.max_iterations, f"a cap of {self.solver.max_iterations:,} sweeps a step")
            return
        velocity = scene.solver.velocity_iterations if self.velocity_iterations is None else self.velocity_iterations
        check_step_work(bodies, velocity + scene.solver.position_iterations,
                        f"{velocity:,} velocity and {scene.solver.position_iterations:,} position iterations a step")

    def build(self, scene, source=None):
        """The scene's world."""
        return build_world(scene)

    def stepper(self, world, scene, record=True):
        """A function stepping `world` once, returning a pgs_loop.LoopStep (stepping.steps runs it)."""
        if self.solver is None:
            return stepping.box2d(world, scene, self.velocity_iterations, record=record)
        return PGSStepper(world, scene, self.solver, self.start, start_fn=self.start_fn, record=record).step

    def solve_line(self, solution) -> str:
        """The line a step file's header gets for how the step was solved (`<solve>`), or ""."""
        return "" if self.solver is None else _solve_xml(self.solver, self.start, solution)

    def manifest(self) -> dict:
        """What the run's manifest records of the engine besides its name: the project's solver's
        options and where its method comes from."""
        from ..solver.methods import method_origin
        if self.solver is None:
            return {"pgs": None}
        o = self.solver
        return {"pgs": dict(start=self.start, mode=o.mode, max_iterations=o.max_iterations, tolerance=o.tolerance,
                            stop_on=o.stop_on, relaxation=o.relaxation, accelerate=o.accelerate,
                            accelerate_origin=method_origin(o.accelerate),
                            **({} if o.guard else {"guard": False}))}   # (the guard is on unless said)

    def __repr__(self):
        return f"Box2D(solver={self.solver!r}, start={self.start!r})" if self.solver is not None else "Box2D()"


class Box2D3:
    """Box2D v3 (3.1, the pyb2d3 wheel's library) stepping with its soft step `soft` (v3's
    defaults if None: SoftStep)."""
    name = engine = "box2d3"
    solver = None

    def __init__(self, soft: SoftStep | None = None):
        from .. import arguments
        self.soft = SoftStep() if soft is None else arguments.instance(soft, "soft", SoftStep, "a SoftStep")

    def check(self, scene, source=None):
        """Refuses a step whose work would run for hours, and a polygon v3 cannot hull (naming it)."""
        check_step_work(len(scene.bodies), self.soft.substeps, f"{self.soft.substeps:,} substeps a step")
        build_world3(scene, self.soft, source)

    def build(self, scene, source=None):
        return build_world3(scene, self.soft, source)

    def stepper(self, world, scene, record=True):
        return stepping.box2d3(world, scene, record=record)

    def solve_line(self, solution) -> str:
        return ""

    def manifest(self) -> dict:
        return {"pgs": None}

    def __repr__(self):
        return f"Box2D3({self.soft!r})"


def _solve_xml(options, start, solution):
    """A step header's `<solve>` line: the options the step was solved with, where its method comes
    from, and what the solve did (iterations, the residual, a global method's work)."""
    from ..solver.methods import GLOBAL
    o = options
    w = 1.0 if o.relaxation == "auto" else o.relaxation   # (None: the method takes no w)
    if solution is None:
        iterations, residual, sanitized = 0, 0.0, 0
    else:
        iterations, residual, w = solution.iterations, solution.residual, solution.relaxation
        sanitized = sum(solution.sanitized.values())
    residual = residual if math.isfinite(residual) else 0.0
    work = ""
    if o.accelerate in GLOBAL:   # a global method's work is more than its iterations
        s = solution
        counts = (0, 0, 0, 0) if s is None else (s.factorizations, s.newton_iterations, s.outer_iterations,
                                                 s.newton_fallbacks)
        work = (' factorizations="%d" newton_iterations="%d" outer_iterations="%d" fallbacks="%d"' % counts)
    relaxation = "" if w is None else f' relaxation="{fmt(w)}"'
    return (f'    <solve start="{start}" mode="{o.mode}" stop_on="{o.stop_on}" tolerance="{fmt(o.tolerance)}" '
            f'max_iterations="{o.max_iterations}"{relaxation} accelerate="{o.accelerate}"{_origin_xml(o.accelerate)} '
            f'iterations="{iterations}" '
            f'residual="{fmt(residual)}" sanitized="{sanitized}"{work}/>\n')


@functools.lru_cache(maxsize=None)
def _origin_xml(accelerate):
    """The <solve> attributes saying where the method comes from (method_origin), once per name."""
    from ..solver.methods import method_origin
    o = method_origin(accelerate)
    keys = ("origin",) if o["origin"] == "built-in" else ("origin", "target", "distribution", "version")
    return "".join(f" {k}={quoteattr(str(o[k]))}" for k in keys if o.get(k) is not None)
