"""A scene's world stepped in memory, one step per call: what a notebook reaches for (pymunk's
`Space.step`, MuJoCo's `mj_step`), over the same engines, stepping loop and arrays `dc simulate`
writes to step files."""
import os
import sys

from .. import arguments
from ..errors import InputError
from ..scene.check import check_scene
from ..scene.model import Scene
from ..scene.xml import read_scene
from .build import check_overlaps
from .engines import Engine
from .engines.box2d import Box2D, Box2DLoop
from .stepping import Stepped, steps


class World:
    """The world of `scene` (a Scene, or a scene file's path) stepped by `engine` (simulate.engines:
    Box2D() by default, Box2D(solver=SolveSettings(...)) for the project's solver with any method,
    Box2D3(SoftStep()) for Box2D v3, engine_named("pymunk" or "mujoco", settings) for the peers, or
    any Engine of one's own). record: keep each step's bodies and contacts (False: None, a step
    the engine's own alone; the project's solver still states each step's residual).

    Each `step()` applies the scene's removal events due, steps once and returns a Stepped: the
    bodies before the step and the contacts the solver saw (arrays, as a step file records them),
    the project's Solution (or None) and the step's wall time. `bodies()` is the state now. A scene
    the engine cannot step is refused when the world is made (InputError, one line)."""

    def __init__(self, scene: "Scene | str | os.PathLike", engine: "Engine | None" = None,
                 record: bool = True):
        if isinstance(scene, (str, os.PathLike)):
            scene = read_scene(scene)   # (checked as it is read)
        else:
            # what a scene file is held to, for a scene made or edited in memory: Box2D's asserts
            # (a NaN position, a collinear polygon) would abort the process, a notebook's kernel
            check_scene(arguments.instance(scene, "scene", Scene, "a Scene or a scene file's path"))
        if engine is not None:
            arguments.instance(engine, "engine", Engine, "an engine: Box2D(), Box2D3(), engine_named(NAME), ...")
        self.scene = scene
        self.engine = Box2D() if engine is None else engine
        check_overlaps(scene)
        self.engine.check(scene)
        self._world = self.engine.build(scene)
        # (stepped on past the scene's own count as long as asked: the removals are at their steps)
        self._steps = steps(self._world, scene, _stepper(self.engine, self._world, scene, record), count=sys.maxsize)
        self.index = 0   # the next step's number

    def step(self) -> Stepped:
        """One step: its index, bodies (before it), contacts, solution, deepest penetration, seconds."""
        if getattr(self, "_failed", None):
            raise InputError(self._failed)
        try:
            done = next(self._steps)
        except BaseException as e:   # (its stepping cannot go on: said on every later call, not StopIteration)
            self._failed = (f"this World stopped at step {self.index}, where its step raised {type(e).__name__}: {e}; "
                            f"make a new World to step the scene again")
            raise
        self.index = done.index + 1
        return done

    def bodies(self) -> dict:
        """Every body's state now (position, angle, velocity, omega, ...), as arrays."""
        return self._world.bodies()

    def __repr__(self):
        return f"World({self.scene.name!r}, {self.engine!r}, step {self.index})"


def _stepper(engine, world, scene, record):
    """The engine's step function; the project's solver's states each step's residual, recorded or
    not (a notebook reads it: only a timed loop skips it)."""
    if isinstance(engine, Box2DLoop):
        return engine.stepper(world, scene, record, residual=True)
    return engine.stepper(world, scene, record)
