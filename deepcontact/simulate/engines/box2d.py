"""Box2D 2.4.1 (Debian's): its own velocity solver, or the project's solver in its loop."""
from collections.abc import Callable
import functools
import logging

from ... import arguments
from ..._box2d import box2d_version
from ...errors import InputError, show_path
from ...resources import check_step_work
from ...scene.xml import fmt
from ...solver.methods import GLOBAL, method_origin, takes_relaxation
from ...xmltext import quoteattr
from ...solver.settings import SolveSettings
from .. import stepping
from ..build import build_world
from ..pgs_loop import PGSStepper, check_loop, check_scene_for_loop
from . import Engine, Setting

log = logging.getLogger(__name__)


class Box2D(Engine):
    """Box2D 2.4.1 (Debian's) with its own velocity solver at the scene's iterations (or
    `velocity_iterations`). Given `solver` (a SolveSettings), the engine is a Box2DLoop instead:
    the project's solver in Box2D's loop (docs/solver.md, "The loop")."""

    def __new__(cls, solver: SolveSettings | None = None, start: str | None = None,
                velocity_iterations: int | None = None, start_fn: Callable | None = None):
        return super().__new__(Box2DLoop if cls is Box2D and solver is not None else cls)

    def __init__(self, solver: SolveSettings | None = None, start: str | None = None,
                 velocity_iterations: int | None = None, start_fn: Callable | None = None):
        if not isinstance(self, Box2DLoop) and (start is not None or start_fn is not None):
            # (Box2D's own solver starts from its own warm start: a start would be dropped without a word)
            given = "start" if start is not None else "start_fn"
            raise InputError(f"argument {given!r} is where the project's solver starts: give solver=SolveSettings(...) "
                             "too (Box2D's own solver, solver=None, starts from its own warm start)")
        if start is not None:
            arguments.text(start, "start")
        if velocity_iterations is not None:
            arguments.whole(velocity_iterations, "velocity_iterations")
        if start_fn is not None and not callable(start_fn):
            raise arguments.refuse("start_fn", "a callable", start_fn)
        self.velocity_iterations = velocity_iterations

    name, label, rows = "box2d", "Box2D 2.4.1", "box2d"
    poses_box2d_problem = continuous = sleeps = block_solve = rests_in_skin = True
    SETTINGS = {"iterations": Setting(int, 1, 100_000, "velocity iterations per step (the scene's unless given)")}

    @classmethod
    def from_settings(cls, iterations=None):
        """Box2D's own solver at `iterations` velocity iterations (--set iterations=N)."""
        if iterations is not None:
            iterations = cls.SETTINGS["iterations"].parse("iterations", iterations)
        return cls(velocity_iterations=iterations)

    @classmethod
    def version(cls) -> str:
        return box2d_version

    def settings(self) -> dict:
        return {} if self.velocity_iterations is None else {"iterations": self.velocity_iterations}

    def header_lines(self, scene) -> str:
        """2.4.1's iterations per step (<iterations>): its files' own header line."""
        s = scene.solver
        velocity = s.velocity_iterations if self.velocity_iterations is None else self.velocity_iterations
        return f'    <iterations velocity="{velocity}" position="{s.position_iterations}"/>\n'

    def check(self, scene, source=None):
        """Refuses a step whose work would run for hours (InputError naming `source`)."""
        velocity = scene.solver.velocity_iterations if self.velocity_iterations is None else self.velocity_iterations
        check_step_work(len(scene.bodies), velocity + scene.solver.position_iterations,
                        f"{velocity:,} velocity and {scene.solver.position_iterations:,} position iterations a step")

    def build(self, scene, source=None):
        """The scene's world."""
        return build_world(scene)

    def stepper(self, world, scene, record=True):
        """A function stepping `world` once, returning a pgs_loop.LoopStep (stepping.steps runs it)."""
        return stepping.box2d(world, scene, self.velocity_iterations, record=record)

    def solve_line(self, solution, stats=None) -> str:
        return ""

    def manifest(self) -> dict:
        return {"pgs": None, "engine_settings": self.settings()}

    def __repr__(self):
        return "Box2D()"


class Box2DLoop(Box2D):
    """Box2D 2.4.1 stepped with the project's solver (`solver`, a SolveSettings) from `start`
    (builtin: Box2D's warm start; zero; garbage), with the settings and the method it says.
    start_fn(bodies, contacts, problem, builtin_n, builtin_t) -> (normal, tangent), if given, makes
    each step's first iterate instead (the closed loop's starts; no step file records one). Made
    by Box2D(solver=...)."""

    def __init__(self, solver: SolveSettings, start: str | None = "builtin", velocity_iterations: int | None = None,
                 start_fn: Callable | None = None):
        start = "builtin" if start is None else start
        super().__init__(None, start, velocity_iterations, start_fn)
        arguments.instance(solver, "solver", SolveSettings, "a SolveSettings (or None: Box2D's own solver)")
        check_loop(solver, start, own_start=start_fn is not None)
        if not takes_relaxation(solver.accelerate):   # (recorded as not taken, not as a w of 1)
            solver = solver.but(relaxation=None)
        self.solver, self.start, self.start_fn = solver, start, start_fn

    @property
    def solver_name(self) -> str:
        """What its step files' `<solver name>` and the manifest's `solver` say."""
        return "pgs"

    def solve_settings(self):
        return self.solver

    def check(self, scene, source=None):
        """Refuses a scene the loop cannot step (continuous collision, sleeping) and a step whose
        work would run for hours (InputError naming `source`)."""
        check_scene_for_loop(scene, source)
        if self.solver.mode == "exact":
            _say_where_exact_is_not_box2ds(scene, source)
        cap = self.solver.max_iterations
        # (a cap the scene's own velocity_iterations gave, no --max-iterations: the scene's line)
        from_scene = cap == scene.solver.velocity_iterations
        try:
            check_step_work(len(scene.bodies), cap, f"a cap of {cap:,} sweeps a step" + (
                " (the scene's velocity_iterations; --max-iterations sets another)" if from_scene else ""))
        except InputError as e:
            raise InputError(e.message, source if from_scene else None,
                             scene.lines.get("solver") if from_scene and source else None) from None

    def stepper(self, world, scene, record=True, residual=None):
        """As Engine.stepper; residual: each step states its residual (PGSStepper's: by default
        where recorded or solved to a tolerance, so that a timed step at a fixed sweep count skips it)."""
        return PGSStepper(world, scene, self.solver, self.start, start_fn=self.start_fn, record=record,
                          residual=residual).step

    def solve_line(self, solution, stats=None) -> str:
        """The line a step file's header gets for how the step was solved (`<solve>`)."""
        return _solve_xml(self.solver, self.start, solution)

    def manifest(self) -> dict:
        """The project's solver's options and where its method comes from."""
        o = self.solver
        return {"pgs": dict(start=self.start, mode=o.mode, max_iterations=o.max_iterations, tolerance=o.tolerance,
                            stop_on=o.stop_on, relaxation=o.relaxation, accelerate=o.accelerate,
                            accelerate_origin=method_origin(o.accelerate),
                            **({} if o.guard else {"guard": False}),   # (the guard is on unless said)
                            **({} if o.order == "island" else {"order": o.order}))}   # (island unless said)

    def __repr__(self):
        return f"Box2D(solver={self.solver!r}, start={self.start!r})"


_SAID = set()


def _say_where_exact_is_not_box2ds(scene, source):
    """One warning, once a scene, where the exact mode cannot give Box2D's own answer: a static
    body given a velocity, which Box2D's step moves once for each island it is in before it poses
    the next island's contacts, where the loop poses every island's first (docs/solver.md)."""
    moving = [k for k, b in enumerate(scene.bodies) if b.type == "static" and (b.vx or b.vy or b.omega)]
    if not moving or (scene.name, str(source)) in _SAID:
        return
    _SAID.add((scene.name, str(source)))
    where = f"{show_path(source)}: " if source else ""
    log.warning("%sbody %d is static with a velocity, which Box2D's own step moves once for each island it is in: "
                "--mode exact poses every island before it moves, so its answers are not Box2D's where such a "
                "body touches more than one island", where, moving[0])


def _solve_xml(options, start, solution):
    """A step header's `<solve>` line: the options the step was solved with, where its method comes
    from, and what the solve did (iterations, the residual, a global method's work). The residual is
    finite: run.py refuses a step whose residual is not before it is written (it read 0 here once)."""
    o = options
    w = 1.0 if o.relaxation == "auto" else o.relaxation   # (None: the method takes no w)
    if solution is None:
        iterations, residual, sanitized = 0, 0.0, 0
    else:
        iterations, residual, w = solution.iterations, solution.residual, solution.relaxation
        sanitized = sum(solution.sanitized.values())
    work = ""
    if o.accelerate in GLOBAL:   # a global method's work is more than its iterations
        s = solution
        counts = (0, 0, 0, 0) if s is None else (s.factorizations, s.newton_iterations, s.outer_iterations,
                                                 s.newton_fallbacks)
        work = (' factorizations="%d" newton_iterations="%d" outer_iterations="%d" fallbacks="%d"' % counts)
    relaxation = "" if w is None else f' relaxation="{fmt(w)}"'
    order = "" if o.order == "island" else f'order="{o.order}" '   # (island unless said: as before)
    return (f'    <solve start="{start}" mode="{o.mode}" stop_on="{o.stop_on}" tolerance="{fmt(o.tolerance)}" '
            f'max_iterations="{o.max_iterations}"{relaxation} accelerate="{o.accelerate}"{_origin_xml(o.accelerate)} '
            f'{order}'
            f'iterations="{iterations}" '
            f'residual="{fmt(residual)}" sanitized="{sanitized}"{work}/>\n')


@functools.lru_cache(maxsize=None)
def _origin_xml(accelerate):
    """The <solve> attributes saying where the method comes from (method_origin), once per name."""
    o = method_origin(accelerate)
    keys = ("origin",) if o["origin"] == "built-in" else ("origin", "target", "distribution", "version")
    return "".join(f" {k}={quoteattr(str(o[k]))}" for k in keys if o.get(k) is not None)
