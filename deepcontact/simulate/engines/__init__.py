"""The engines a scene can be stepped by: one module each, each a class implementing `Engine`,
each registered in ENGINES (the registry plug-ins use too: an engine of one's own is a package
with a `deepcontact.engines` entry point, or `--engine package.module:Class`).

    Box2D()                    Box2D 2.4.1 with its own velocity solver (the scene's iterations)
    Box2D(solver=SolveSettings(...), start="builtin")
                               Box2D 2.4.1 stepped with the project's solver (`--solver pgs`)
    Box2D3(SoftStep())         Box2D v3's soft step (`--engine box2d3`)
    Pymunk(iterations=10)      pymunk (Chipmunk2D) (`--engine pymunk`)
    MuJoCo(solver="newton")    MuJoCo's planar model of the scene (`--engine mujoco`)

`dc simulate`, `run`, `run_simulation`, `World` and the studies take one; no caller infers the
engine from which keywords are set, and none compares engine names: each asks the engine.
"""
import math
from dataclasses import dataclass

import numpy as np

from ... import arguments
from ..._box2d import World
from ...errors import OptionError
from ...plugins import PluginError, Registry, guest
from ...scene.model import Scene  # noqa: F401  (the annotations)


@dataclass(frozen=True)
class Setting:
    """One setting an engine takes (`dc simulate --set NAME=VALUE`): its kind (int, float or a
    tuple of the words it takes), its range (inclusive; None: unbounded) and a line of help."""
    kind: object
    low: float = None
    high: float = None   # (every built-in's is bounded: a value past what the engine can hold is one line, not its crash)
    help: str = ""

    def parse(self, name, text):
        """The value `text` (a string or a value) asks for; OptionError naming --set NAME."""
        flag = "--set"
        if isinstance(self.kind, tuple):
            if text not in self.kind:
                raise OptionError(f"{name} is one of {', '.join(self.kind)}, got {text!r}", flag)
            return text
        try:
            value = self.kind(text) if isinstance(text, str) else text
        except ValueError:
            raise OptionError(f"{name} must be {'a whole number' if self.kind is int else 'a number'}, "
                              f"got {text!r}", flag) from None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (
                self.kind is int and not isinstance(value, int)) or not math.isfinite(value):
            raise OptionError(f"{name} must be {'a whole number' if self.kind is int else 'a finite number'}, "
                              f"got {text!r}", flag)
        if (self.low is not None and value < self.low) or (self.high is not None and value > self.high):
            span = f"from {self.low:g} to {self.high:g}" if self.high is not None else f"at least {self.low:g}"
            raise OptionError(f"{name} must be {span}, got {text!r}", flag)
        return self.kind(value)


class Engine:
    """What every engine is: it builds a scene's world, steps it, and reports its bodies and
    contacts as the arrays a step file records (`stepping.steps` runs it). The defaults here are
    an engine with no solver of the project's and no rows of Box2D's own.

    A subclass sets `name`, `label`, `SETTINGS` and implements `version`, `build` and `stepper`;
    the world `build` returns has `remove_body(index)` (a scene's removal event, by scene index)
    and `bodies()` (its bodies now, as `empty_bodies`). docs/engines.md, "An engine of your own"."""
    name = None                 # --engine, the manifest's engine, the step files' <engine name>
    label = None                # how tables and reports name it ("pymunk")
    rows = "own"                # whose own contact rows its step files hold: box2d, box2d3, or own (none)
    poses_box2d_problem = False   # its steps pose Box2D 2.4.1's contact problem (replay, evaluate, export)
    continuous = False          # it does continuous collision (the scene's `continuous` effect)
    sleeps = False              # it puts resting bodies to sleep when the scene asks
    block_solve = False         # it has Box2D 2.4.1's block solver
    SETTINGS = {}               # name -> Setting
    rests_in_skin = False       # resting contacts sit one linear slop into each other's skins (2.4.1's
                                # rest, the generators' default); else skins touching (overlap 0)

    def __init__(self, **settings):
        self._settings = self.parsed(settings)

    @classmethod
    def parsed(cls, settings) -> dict:
        """`settings` (name -> value or text) checked against SETTINGS (OptionError naming --set)."""
        unknown = sorted(set(settings) - set(cls.SETTINGS))
        if unknown:
            takes = ", ".join(cls.SETTINGS) or "none"
            raise OptionError(f"{cls.label} has no setting {unknown[0]!r} (it takes: {takes})", "--set")
        return {k: s.parse(k, settings[k]) for k, s in cls.SETTINGS.items() if k in settings}

    @classmethod
    def from_settings(cls, **settings):
        """The engine with `settings` (name -> value, or text as --set gives it)."""
        return cls(**cls.parsed(settings))

    def settings(self) -> dict:
        """The settings in effect, defaults included: what the manifest and `<engine>` record."""
        return dict(self._settings)

    @classmethod
    def version(cls) -> str:
        """The engine library's version."""
        raise NotImplementedError

    def solve_settings(self):
        """The project's SolveSettings where the project's solver steps this engine, else None."""
        return None

    @property
    def solver_name(self) -> str:
        """What `<solver name>` and the manifest's `solver` say: the engine's own name, or the
        project's solver's (pgs) where that steps it."""
        return self.name

    def check(self, scene, source=None):
        """Refuses (InputError naming `source`) a scene this engine cannot step as asked."""

    def build(self, scene, source=None):
        """The scene's world, ready to step."""
        raise NotImplementedError

    def stepper(self, world, scene, record=True):
        """A function stepping `world` once, returning a LoopStep: with `record`, the bodies
        before the step and the contact points it solved (the step file's arrays: empty_bodies',
        empty_contacts' fields); without, the engine's own step alone (what the studies time)."""
        raise NotImplementedError

    def header_lines(self, scene) -> str:
        """The lines a step file's header holds for this engine after <solver>: `<engine>` with
        its name, version and settings."""
        # (the step writer and the scene's XML below it: not imported in a contestant's start, 12 ms of its 120)
        from ...step.writer import engine_xml
        return engine_xml(self.name, self.version(), self.settings())

    def solve_line(self, solution, stats=None) -> str:
        """A step's own header line (how the step was solved), or "": the project's `solution`, or
        the engine's own `stats` (a LoopStep's engine_stats: `<engine_step>`)."""
        if not stats:
            return ""
        from ...step.writer import engine_step_xml   # (as header_lines)
        return engine_step_xml(stats)

    def manifest(self) -> dict:
        """What the run's manifest records of the engine besides its name and version."""
        return {"pgs": None, "engine_settings": self.settings()}

    def __repr__(self):
        args = ", ".join(f"{k}={v!r}" for k, v in self._settings.items())
        return f"{type(self).__name__}({args})"


def step_layout() -> dict:
    """{"bodies": ..., "contacts": ...}: each table's fields, field -> (dtype, shape of one row),
    as a step file records them (the native record tables, records.hpp, as a Box2D world
    reports them): what every engine's step returns (docs/engines.md, "An engine of your own")."""
    global _LAYOUT
    if _LAYOUT is None:
        world = World(0.0, 0.0)
        _LAYOUT = {table: {k: (v.dtype, v.shape[1:]) for k, v in arrays.items()}
                   for table, arrays in (("bodies", world.bodies()), ("contacts", world.contacts()))}
    return _LAYOUT


def empty_bodies(n: int) -> dict:
    """n body rows of zeros in a step file's layout (every field, in its dtype and width), for an
    engine that fills its bodies itself; `scene_bodies` gives a scene's, filled."""
    return _zeros("bodies", n)


def empty_contacts(n: int) -> dict:
    """n contact rows of zeros in a step file's layout (every field, in its dtype and width):
    what an engine other than Box2D fills with its contact points."""
    return _zeros("contacts", n)


def _zeros(table, n):
    return {k: np.zeros((n, *shape), dtype) for k, (dtype, shape) in step_layout()[table].items()}


def scene_bodies(scene: "Scene") -> dict:
    """The scene's bodies at its start, in a step file's layout, with Box2D 2.4.1's mass
    properties (mass, centre of mass, inertia about it, their inverses): what an engine of its own
    starts from, as pymunk's and MuJoCo's do, so that every engine moves the same bodies."""
    from ..build import build_world
    return build_world(scene).bodies()


def layout_error(bodies, contacts) -> str | None:
    """What breaks a step file's layout in an engine's step (a field missing, or of another dtype or
    width), in words, or None. (Each table's lengths and the bodies contacts name: run.checked_step.)"""
    for table, arrays in (("bodies", bodies), ("contacts", contacts)):
        for field, (dtype, shape) in step_layout()[table].items():
            a = arrays.get(field)
            if a is None:
                return f"{table} without {field!r} (every field of empty_{table} is needed)"
            if not isinstance(a, np.ndarray) or a.dtype != dtype or a.shape[1:] != shape or a.ndim != 1 + len(shape):
                got = f"{a.dtype} of shape {a.shape}" if isinstance(a, np.ndarray) else type(a).__name__
                wanted = "(n, " + ", ".join(map(str, shape)) + ")" if shape else "(n,)"
                return f"{table}.{field} as {got}; a step file's is {dtype} of shape {wanted}"
    return None


_LAYOUT = None

ENGINES = Registry("engine", "deepcontact.engines")
ENGINES.register("box2d", "deepcontact.simulate.engines.box2d:Box2D")
ENGINES.register("box2d3", "deepcontact.simulate.engines.box2d3:Box2D3")
ENGINES.register("pymunk", "deepcontact.simulate.engines.pymunk:Pymunk")
ENGINES.register("mujoco", "deepcontact.simulate.engines.mujoco:MuJoCo")


def engine_named(name: str, settings: dict | None = None) -> Engine:
    """The engine registered as `name` with `settings` (name -> value or text, as --set gives)."""
    arguments.text(name, "name")
    settings = {} if settings is None else arguments.mapping(settings, "settings")
    cls = ENGINES.load(name)
    if not (isinstance(cls, type) and issubclass(cls, Engine)):
        raise PluginError(f"the engine {name!r} is not a deepcontact Engine (a subclass of "
                          "deepcontact.simulate.engines.Engine)")
    settings = cls.parsed(settings)   # (a setting it does not take: one line naming --set, not a TypeError)
    if cls.__module__.startswith("deepcontact."):
        return cls.from_settings(**settings)
    with guest(f"the engine {name!r}"):
        return cls.from_settings(**settings)


# The engines by their old place (simulate.engines.Box2D): each module imported on first use,
# pymunk's and MuJoCo's being optional wheels.
def __getattr__(name):
    if name in ("Box2D", "Box2DLoop", "_solve_xml"):
        from . import box2d
        return getattr(box2d, name)
    if name in ("Box2D3", "SoftStep", "soft_step_defaults", "FLOAT32_TINY"):
        from . import box2d3
        return getattr(box2d3, name)
    if name in ("Pymunk",):
        from .pymunk import Pymunk
        return Pymunk
    if name in ("MuJoCo",):
        from .mujoco import MuJoCo
        return MuJoCo
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
