"""Box2D 2.4.1 (Debian's): its own velocity solver, or the project's solver in its loop."""
from collections.abc import Callable
import functools
import math

from ...xmltext import quoteattr
from ...resources import check_step_work
from ...scene.xml import fmt
from ...solver.methods import takes_relaxation
from ...solver.settings import SolveSettings
from .. import stepping
from ..build import build_world
from ..pgs_loop import PGSStepper, check_loop, check_scene_for_loop
from . import Engine, Setting


class Box2D(Engine):
    """Box2D 2.4.1 (Debian's). Without `solver`, its own velocity solver at the scene's iterations
    (or `velocity_iterations`); with `solver` (a SolveSettings), the project's solver in the loop
    from `start` (builtin: Box2D's warm start; zero; garbage), with the settings and the method it
    says (docs/solver.md, "The loop"). start_fn(bodies, contacts, problem, builtin_n, builtin_t)
    -> (normal, tangent), if given, makes each step's first iterate instead (the closed loop's starts;
    no step file records one)."""

    def __init__(self, solver: SolveSettings | None = None, start: str = "builtin",
                 velocity_iterations: int | None = None, start_fn: Callable | None = None):
        from ... import arguments
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

    name, label, rows = "box2d", "Box2D 2.4.1", "box2d"
    poses_box2d_problem = continuous = sleeps = block_solve = rests_in_skin = True
    SETTINGS = {"iterations": Setting(int, 1, 100_000, "velocity iterations per step (the scene's unless given)",
                                      sweep=(1, 2, 4, 8, 16, 32, 64, 128, 256), fast=(1, 8, 64))}

    @classmethod
    def from_settings(cls, iterations=None):
        """Box2D's own solver at `iterations` velocity iterations (--set iterations=N)."""
        if iterations is not None:
            iterations = cls.SETTINGS["iterations"].parse("iterations", iterations)
        return cls(velocity_iterations=iterations)

    @classmethod
    def version(cls) -> str:
        from ..._box2d import box2d_version
        return box2d_version

    def settings(self) -> dict:
        return {} if self.velocity_iterations is None else {"iterations": self.velocity_iterations}

    @property
    def solver_name(self) -> str:
        """What its step files' `<solver name>` and the manifest's `solver` say: box2d or pgs."""
        return "box2d" if self.solver is None else "pgs"

    def header_lines(self, scene) -> str:
        """2.4.1's iterations per step (<iterations>): its files' own header line."""
        s = scene.solver
        velocity = s.velocity_iterations if self.velocity_iterations is None else self.velocity_iterations
        return f'    <iterations velocity="{velocity}" position="{s.position_iterations}"/>\n'

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

    def solve_line(self, solution, stats=None) -> str:
        """The line a step file's header gets for how the step was solved (`<solve>`), or ""."""
        return "" if self.solver is None else _solve_xml(self.solver, self.start, solution)

    def manifest(self) -> dict:
        """What the run's manifest records of the engine besides its name: the project's solver's
        options and where its method comes from."""
        from ...solver.methods import method_origin
        if self.solver is None:
            return {"pgs": None, "engine_settings": self.settings()}
        o = self.solver
        return {"pgs": dict(start=self.start, mode=o.mode, max_iterations=o.max_iterations, tolerance=o.tolerance,
                            stop_on=o.stop_on, relaxation=o.relaxation, accelerate=o.accelerate,
                            accelerate_origin=method_origin(o.accelerate),
                            **({} if o.guard else {"guard": False}))}   # (the guard is on unless said)

    def __repr__(self):
        return f"Box2D(solver={self.solver!r}, start={self.start!r})" if self.solver is not None else "Box2D()"


def _solve_xml(options, start, solution):
    """A step header's `<solve>` line: the options the step was solved with, where its method comes
    from, and what the solve did (iterations, the residual, a global method's work)."""
    from ...solver.methods import GLOBAL
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
    from ...solver.methods import method_origin
    o = method_origin(accelerate)
    keys = ("origin",) if o["origin"] == "built-in" else ("origin", "target", "distribution", "version")
    return "".join(f" {k}={quoteattr(str(o[k]))}" for k in keys if o.get(k) is not None)
