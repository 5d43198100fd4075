"""A plug-in engine as a guest: its code runs only in a sandbox of its own (sandbox.py), where it
is loaded, made from its settings, builds each world and steps it; dc's own process receives each
step's arrays as data (never unpickled), checks them and writes them.

`guest_engine(name, settings)` is what `dc simulate --engine pkg.mod:Class` (or an installed
plug-in's name) steps: a GuestEngine, an Engine whose attributes its sandbox described. Whatever
leaves the plug-in's code (an exception, sys.exit, os._exit, a hang past the deadline, a signal
it ignores) is one line naming it; what it changes in its process (the working folder, the umask,
threads, forks) reaches nothing of dc's; a user's stop ends it with dc's sandboxes.
"""
import math
import pickle

import numpy as np

from ..errors import InputError
from ..plugins import PluginError
from ..simulate.engines import Engine, layout_error
from ..simulate.pgs_loop import LoopStep
from . import shape
from .client import CALL_FLOOR, Contestant

FLAGS = ("poses_box2d_problem", "continuous", "sleeps", "block_solve", "rests_in_skin")
# What its sandbox says of a plug-in engine (guest._engine_made), every field typed before any is
# read (wire.unpack): a flag true or false ("no" read as Python reads text was true), its settings
# each a name and a value of its own account.
shape.declare("engine described", shape.Record({
    "name": shape.Text(), "label": shape.Text(), "version": shape.Text(), "rows": shape.Text(),
    "settings": shape.Table(shape.Scalar(), most=256),
    "flags": shape.Record({f: shape.Flag() for f in FLAGS}, required=FLAGS),
}, required=("name", "label", "version", "rows", "settings", "flags")))


def guest_engine(name, settings=None):
    """The plug-in engine `name` with `settings` (name -> text or value), described from a
    sandbox of its own; PluginError naming it if it cannot be loaded or made."""
    c = Contestant(name, "engine", engine=(name, dict(settings or {})), who=f"the engine {name!r}")
    try:
        c.begin()
        described = c.header.get("engine")
    finally:
        c.close()
    return GuestEngine(name, dict(settings or {}), _described(name, described))


def _described(name, d):
    """The engine's description, checked (a plug-in's answer is data)."""
    ok = isinstance(d, dict) and all(isinstance(d.get(k), str) and d.get(k) for k in ("name", "label", "version")) \
        and d.get("rows") == "own" and isinstance(d.get("settings"), dict) and isinstance(d.get("flags"), dict)
    if not ok:
        raise PluginError(f"the engine {name!r} described itself as {d!r}: a name, label and version, its own rows "
                          f"(a plug-in engine's step files hold no Box2D rows) and its settings")
    from ..step.writer import engine_xml   # (the step writer: dc's side only, never a contestant's start)
    try:   # (what its step files' <engine> would say, refused now, naming the plug-in as the user named it)
        engine_xml(d["name"], d["version"], d["settings"])
    except InputError as e:
        raise PluginError(f"the engine {name!r} described itself in text no step file can hold: {e.message}") from None
    return d


def unheld(values, dtype):
    """What in `values` (float64, as an answer carries them) the field's `dtype` cannot hold as it
    is, in words ("" where it holds them all): a fraction or a number past an integer's range (a
    body type of 258 was written as 2, one of 1e300 as 0: static), past float32's. Cast, they
    would be written as another number, silently."""
    kind = np.dtype(dtype)
    if kind.kind in "biu":
        low, high = (0, 1) if kind.kind == "b" else (int(np.iinfo(kind).min), int(np.iinfo(kind).max))
        if not np.all(values == np.round(values)):
            return "a fraction in a whole-number field"
        if len(values) and not (values.min() >= low and values.max() < high + 1):   # (high + 1: a power of 2, exact)
            return f"a value {dtype} cannot hold (a whole number from {low} to {high})"
    elif kind == np.float32 and len(values) and np.abs(values).max() > np.finfo(np.float32).max:
        return "a value float32 cannot hold (beyond its largest, 3.4e38)"
    return ""


class GuestEngine(Engine):
    """A plug-in engine whose code runs in its own sandbox: each world a sandbox of its own."""

    def __init__(self, target, settings, described):
        self.target, self.asked, self.described = target, settings, described
        self.name, self.label, self.rows = described["name"], described["label"], "own"
        for flag in FLAGS:
            setattr(self, flag, described["flags"][flag])
        self._settings = dict(described["settings"])

    def version(self) -> str:
        return self.described["version"]

    def build(self, scene, source=None):
        return GuestWorld(self, scene, source)

    def stepper(self, world, scene, record=True):
        return world.step


class GuestWorld:
    """One world of a plug-in engine, in its sandbox: stepped and edited by requests."""

    def __init__(self, engine, scene, source=None):
        self.engine = engine
        self.label = f"the engine {engine.target!r}"
        self.contestant = Contestant(engine.target, "engine", engine=(engine.target, engine.asked), who=self.label)
        try:
            self.contestant.begin()
            self._call({"op": "build", "scene": pickle.dumps(scene), "source": None if source is None else str(source)})
        except BaseException:
            self.close()
            raise

    def _call(self, request):
        try:
            return self.contestant.call(request, CALL_FLOOR)
        except BaseException:
            self.close()
            raise

    def step(self):
        _, header, arrays = self._call({"op": "step"})
        tables = {"bodies": {}, "contacts": {}}
        # (each entry's dtype and shape typed and bounded already: wire.unpack, shape.LAYOUT)
        for key, (dtype, shape) in header.get("layout", {}).items():
            table, _, field = key.partition(".")
            if table not in tables or key not in arrays or math.prod(shape) != arrays[key].size:
                raise PluginError(f"{self.label} returned the array {key!r} in a form no step file holds")
            values = arrays[key]
            wrong = unheld(values, dtype)
            if wrong:
                raise PluginError(f"{self.label} returned {key} with {wrong}")
            tables[table][field] = values.reshape(shape).astype(dtype)
        wrong = layout_error(tables["bodies"], tables["contacts"])
        if wrong:   # (the writer's own refusal was not a message of ours)
            raise PluginError(f"{self.label} returned {wrong}")
        stats, ratio = header.get("stats") or None, header.get("dt_ratio")
        return LoopStep(tables["bodies"], tables["contacts"], None, float(header.get("deepest", 0.0)),
                        dt_ratio=None if ratio is None else float(ratio), engine_stats=stats)

    def remove_body(self, index):
        self._call({"op": "remove", "index": int(index)})

    def close(self):
        self.contestant.close()
