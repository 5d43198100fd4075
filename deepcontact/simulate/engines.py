"""The engines a scene can be stepped by, as objects: each builds its world, makes its step
function, checks a scene against its own rules, and says what its step files and manifest record.

    Box2D()                    Box2D 2.4.1 with its own velocity solver (the scene's iterations)
    Box2D(solver=SolveSettings(...), start="builtin")
                               Box2D 2.4.1 stepped with the project's solver (`--solver pgs`)
    Box2D3(SoftStep())         Box2D v3's soft step (`--engine box2d3`)

`dc simulate`, `run`, `run_simulation` and `World` take one; no caller infers the engine from
which keywords are set.
"""
import functools
import math
from xml.sax.saxutils import quoteattr

from ..resources import check_step_work
from ..scene.xml import fmt
from ..solver.methods import takes_relaxation
from ..solver.settings import SolveSettings
from ..step.engines import SoftStep
from . import stepping
from .build import build_world, build_world3
from .pgs_loop import PGSStepper, check_loop, check_scene_for_loop


class Box2D:
    """Box2D 2.4.1 (Debian's). Without `solver`, its own velocity solver at the scene's iterations
    (or `velocity_iterations`); with `solver` (a SolveSettings), the project's solver in the loop
    from `start` (builtin: Box2D's warm start; zero; garbage), with the settings and the method it
    says (docs/solver.md, "The loop"). start_fn(bodies, contacts, problem, builtin_n, builtin_t)
    -> (normal, tangent), if given, makes each step's first iterate instead (the closed loop's starts;
    no step file records one)."""

    def __init__(self, solver: SolveSettings | None = None, start: str = "builtin",
                 velocity_iterations: int | None = None, start_fn=None):
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
    defaults if None: step.engines.SoftStep)."""
    name = engine = "box2d3"
    solver = None

    def __init__(self, soft: SoftStep | None = None):
        self.soft = SoftStep() if soft is None else soft

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
