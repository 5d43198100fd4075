"""Warm starts: each a small class that gives a step's first iterate and what it cost to make.

    zero      all impulses 0
    builtin   Box2D's own: the previous step's impulses matched by feature key, times dtRatio
              (recorded in every step file as the solver's start)
    prev      the previous step's solution at the tolerance (not Box2D's 8 sweeps), matched by
              contact key (fixtures, children, feature id); new contacts start at 0
    copy      the step's reference solution (an oracle: it is the answer)
    copy2     the oracle rounded to 2 decimals; copy0: to integers
    sph       the oracle through the grid and back (the grid's own loss; an oracle too)
    cnn       a trained checkpoint's prediction
    random    uniform impulses of the step's scale, friction inside the cone (seeded)
    bad       every impulse 50
    guarded   whichever of cnn / builtin / zero has the smallest residual before iterating
    cnn-new   builtin where a contact persists from the previous step, cnn only for new ones
"""
import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from .. import arguments
from ..errors import InputError
from ..grid.interpolate import bilinear
from ..grid.spec import GridSpec
from ..grid.splat import splat_points
from ..plugins import PluginError, Registry, guest
from ..solver.pgs import solve
from ..solver.problem import contact_keys


@dataclass
class StepContext:
    """What a start may look at (docs/api.md, "What a start sees"): the step as it stands before
    its solve, and the converged solution of the step before. The step's own answer (its
    reference solution, and in replay the impulses Box2D recorded for it) only for a start that
    asks for it (needs_reference, needs_recorded), which makes it an oracle (seen_by)."""
    problem: object          # solver.problem.StepProblem
    bodies: dict
    contacts: dict
    reference: object        # solver.pgs.Solution (float64, to 1e-12); None unless asked for
    persisted: np.ndarray    # True where the contact point existed in the previous step
    seed: int = 0
    previous: dict = None    # {contact key: (normal, tangent)} of the previous step's converged solution
    cache: dict = field(default_factory=dict)
    index: int = 0           # the step's index in its simulation
    variant: str = ""        # the variant this call is for (the start with its w and method)
    trajectory: str = "replay"   # "replay" (recorded steps) or "loop" (the start drives the simulation)


ANSWER_COLUMNS = ("normal_impulse", "tangent_impulse")   # a step's recorded answer, in its contacts


def seen_by(name, ctx, variant="", start=None):
    """ctx as the start `name` (the object `start`) may see it, by its one description (described):
    without the step's reference solution unless it asks for it (needs_reference), without the
    impulses recorded for the step (Box2D's answer in replay) unless it asks for them (needs_recorded)."""
    traits = described(name, start)
    changes = {"variant": variant}
    if not traits["needs_reference"]:
        changes["reference"] = None
    if not traits["needs_recorded"]:
        changes["contacts"] = {k: v for k, v in ctx.contacts.items() if k not in ANSWER_COLUMNS}
        changes["problem"] = dataclasses.replace(ctx.problem, normal_impulse=None, tangent_impulse=None)
    out = dataclasses.replace(ctx, **changes)
    return private_copy(out) if isinstance(start, Checked) else out


def held_to_contract(name, start):
    """start as a replay or the closed loop runs it: a built-in start as it is, anything else (a
    plug-in, or an object a library caller hands in a starts table) in Checked, so that it sees
    its own copy of each step and its answer is checked, whichever way it came."""
    if isinstance(start, (Checked, Remote)) or (name in NAMES and type(start).__module__.startswith("deepcontact.")):
        return start
    return Checked(name, start)


def private_copy(ctx):
    """A plug-in's own copy of the step (its cache kept): whatever the start does to it, no other
    start and no later row sees. Made by the caller before the clock starts: it is the platform's
    work, not the start's."""
    import copy
    out = dataclasses.replace(ctx, **{f.name: copy.deepcopy(getattr(ctx, f.name))
                                      for f in dataclasses.fields(ctx) if f.name != "cache"})
    out._private = True
    return out


@dataclass
class StartValue:
    """What a start returns: one normal and one tangent impulse per contact point (float64,
    N·s) and the seconds it spent by stage (reported as prediction time, not solving)."""

    normal: np.ndarray
    tangent: np.ndarray
    seconds: dict            # prediction time by stage (empty for free starts)


def _free(n, t):
    return StartValue(np.asarray(n, np.float64), np.asarray(t, np.float64), {})


class Zero:
    """All impulses 0: the cold start."""

    def __call__(self, ctx):
        n = ctx.problem.points
        return _free(np.zeros(n), np.zeros(n))


class Builtin:
    """Box2D's own warm start: the previous step's impulses by feature key, times dtRatio (the
    solver's first iterate as the step file recorded it)."""

    def __call__(self, ctx):
        return _free(ctx.problem.start_normal, ctx.problem.start_tangent)


class Previous:
    """The previous step's solution at the tolerance, matched by contact key; new contacts start at 0."""

    def __call__(self, ctx):
        if ctx.previous is None:
            raise InputError("the prev start needs the previous step's solution")
        found = [ctx.previous.get(k, (0.0, 0.0)) for k in contact_keys(ctx.contacts)]
        n, t = (np.array(v, dtype=np.float64) for v in zip(*found)) if found else (np.zeros(0), np.zeros(0))
        return _free(n, t)


class Copy:
    """The step's reference solution, optionally rounded (an oracle: it is the answer)."""
    needs_reference = True

    def __init__(self, decimals=None):
        self.decimals = decimals

    def __call__(self, ctx):
        n, t = ctx.reference.normal_impulse, ctx.reference.tangent_impulse
        if self.decimals is not None:
            n, t = np.round(n, self.decimals), np.round(t, self.decimals)
        return _free(n, t)


class SPH:
    """The reference solution splatted onto the grid and interpolated back: the grid's own loss,
    the best any grid-learned start can do (an oracle)."""
    needs_reference = True

    def __init__(self, spec):
        self.spec = spec

    def __call__(self, ctx):
        t0 = time.perf_counter()
        pos = ctx.contacts["position"]
        grid = splat_points(self.spec, pos, np.stack([ctx.reference.normal_impulse, ctx.reference.tangent_impulse], 1))
        t1 = time.perf_counter()
        back, _ = bilinear(grid, self.spec, pos)
        back = back * self.spec.impulse_scale
        t2 = time.perf_counter()
        return StartValue(back[0], back[1], {"rasterize": t1 - t0, "interpolate": t2 - t1})


class CNN:
    """A trained network's prediction (model.inference.Predictor), cached per step so that
    starts built on it pay for it once."""

    def __init__(self, predictor):
        self.predictor = predictor

    def __call__(self, ctx):
        if "cnn" not in ctx.cache:
            s = self.predictor.predict(ctx.bodies, ctx.contacts)
            ctx.cache["cnn"] = StartValue(s.normal, s.tangent, dict(s.seconds))
        return ctx.cache["cnn"]


class Random:
    """Uniform impulses of the step's scale, friction inside the cone, seeded per step."""
    needs_reference = True   # (its scale is the reference's: it peeks, so it is an oracle)

    def __call__(self, ctx):
        rng = np.random.default_rng([ctx.seed, ctx.problem.index])
        scale = float(np.abs(ctx.reference.normal_impulse).max()) or 1.0
        n = rng.uniform(0, scale, ctx.problem.points)
        mu = ctx.problem.contacts["friction"].astype(np.float64)
        return _free(n, rng.uniform(-1, 1, ctx.problem.points) * mu * n)


class Bad:
    """Every impulse 50: a start far from any answer."""

    def __call__(self, ctx):
        n = ctx.problem.points
        return _free(np.full(n, 50.0), np.full(n, 50.0))


class Guarded:
    """MuJoCo's idea: of several candidate starts, keep the one closest to solving the problem."""

    def __init__(self, cnn):
        self.candidates = {"cnn": cnn, "builtin": Builtin(), "zero": Zero()}

    def __call__(self, ctx):
        best, seconds, guard = None, {}, 0.0
        for name, start in self.candidates.items():
            value = start(ctx)               # (the network's prediction counts once, at its own cost)
            for k, v in value.seconds.items():
                seconds[k] = seconds.get(k, 0.0) + v
            t0 = time.perf_counter()
            r = solve(ctx.problem, value.normal, value.tangent, mode="float64", max_iterations=0).residual
            guard += time.perf_counter() - t0
            if best is None or r < best[0]:
                best = (r, value)
        seconds["guard"] = guard
        return StartValue(best[1].normal, best[1].tangent, seconds)


class CNNNew:
    """Box2D's warm start where a contact persists from the previous step, the network's
    prediction only for new contacts."""

    def __init__(self, cnn):
        self.cnn = cnn

    def __call__(self, ctx):
        learned = self.cnn(ctx)
        keep = ctx.persisted
        return StartValue(np.where(keep, ctx.problem.start_normal, learned.normal),
                          np.where(keep, ctx.problem.start_tangent, learned.tangent), learned.seconds)


# --- The registry: built-ins and plug-ins alike ------------------------------------------------
# A factory takes keyword arguments it declares from {spec, predictor} (the grid of --cell/--model,
# the trained model) and returns a start: a callable ctx -> StartValue. Traits: needs_model (a
# trained checkpoint), needs_reference (reads ctx.reference), needs_recorded (reads the step's
# recorded impulses), oracle (knows the answer some other way). A start that asks for the answer
# is an oracle (is_oracle), whatever its name.

STARTS = Registry("start", "deepcontact.starts")
STARTS.register("zero", lambda: Zero())
STARTS.register("builtin", lambda: Builtin())
STARTS.register("prev", lambda: Previous())
# (what a built-in asks for is its class's to say; the registry's trait reads it from there)
STARTS.register("copy", lambda: Copy(), needs_reference=Copy.needs_reference)
STARTS.register("copy2", lambda: Copy(2), needs_reference=Copy.needs_reference)
STARTS.register("copy0", lambda: Copy(0), needs_reference=Copy.needs_reference)
STARTS.register("sph", lambda spec: SPH(spec), needs_reference=SPH.needs_reference)
STARTS.register("cnn", lambda predictor: CNN(predictor), needs_model=True)
STARTS.register("random", lambda: Random(), needs_reference=Random.needs_reference)
STARTS.register("bad", lambda: Bad())
STARTS.register("guarded", lambda predictor: Guarded(CNN(predictor)), needs_model=True)
STARTS.register("cnn-new", lambda predictor: CNNNew(CNN(predictor)), needs_model=True)

NAMES = tuple(STARTS.builtin())
NEEDS_MODEL = tuple(n for n in NAMES if getattr(STARTS.load(n), "needs_model", False))


TRAITS = ("needs_reference", "needs_recorded", "needs_model", "oracle")   # what a start may declare
ORACLE_TRAITS = ("oracle", "needs_reference", "needs_recorded")   # any one of them: it knows the answer


def declared(obj, key, who):
    """The trait `key` as `obj` (a start's factory) declares it: True or False (absent: False);
    anything else is one line naming `who` (a "no" or a [] is not False)."""
    value = getattr(obj, key, False)
    if type(value) is not bool:
        raise PluginError(f"{who} declares {key} = {_short(value)} ({type(value).__name__}), not True or False")
    return value


def _short(value):
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def trait(name, key):
    """A start's trait (oracle, needs_model, needs_reference, needs_recorded), as its factory or
    registration declares it. A plug-in described from its own process (STARTS.described, checked
    as it came: contest.describe) is never imported here."""
    if name not in STARTS._builtin and name in STARTS.described:
        return STARTS.described[name]["traits"][key]
    return declared(STARTS.load(name), key, f"the start {name!r}")


class Remote:
    """A plug-in start that only its own process makes (deepcontact.contest): in the judge's
    process it is a name and the traits its process described, never its code."""

    def __init__(self, name):
        self.name = name
        for key, value in STARTS.described[name]["traits"].items():
            setattr(self, key, value)

    def __call__(self, ctx):
        raise PluginError(f"the start {self.name!r} runs only in a contestant process of its own")


def described(name, start=None):
    """The one description of a start that the judge decides from, taken in the judge's process
    ({trait: bool}): both what its ctx holds (the reference, the recorded impulses) and whether it
    is an oracle (is_oracle). By its name: its registration, its factory's declared traits, or
    what its own process described (contest.describe), never what an instance sets on itself.
    Only a label no registry resolves (an object a library caller hands in under a name of its
    own, as dc study figures does) is described by the object given, read here once."""
    if _resolves(name):
        return {k: trait(name, k) for k in TRAITS}
    inner = getattr(start, "start", start)
    return {k: declared(inner, k, f"the start {name!r}") for k in TRAITS}


def _resolves(name):
    """Whether a registry knows the start `name` (a built-in, a plug-in loaded or described)."""
    if name in STARTS._builtin or name in STARTS.described:
        return True
    try:
        STARTS.load(name)
    except PluginError:
        return False
    return True


def is_oracle(name):
    """Whether a start knows the answer: it asks for the step's reference or recorded impulses,
    or says so (derived from what it asks for, never from a list of names), by its one
    description (described). A name no registry resolves (a label of its own, as dc study
    figures gives) is no oracle."""
    return _resolves(name) and any(trait(name, key) for key in ORACLE_TRAITS)


ORACLES = tuple(n for n in NAMES if is_oracle(n))


class Checked:
    """A plug-in start held to the contract: a StartValue (or anything with normal, tangent and
    seconds) of one finite value per contact point; else one line naming the start."""

    def __init__(self, name, start):
        self.name, self.start = name, start

    def __call__(self, ctx):
        seen = ctx if getattr(ctx, "_private", False) else private_copy(ctx)
        with guest(f"the start {self.name!r}"):
            value = self.start(seen)
        n = ctx.problem.points
        try:
            normal = np.asarray(value.normal, np.float64)
            tangent = np.asarray(value.tangent, np.float64)
            seconds = {str(k): float(v) for k, v in dict(getattr(value, "seconds", {}) or {}).items()}
        except (AttributeError, TypeError, ValueError) as e:
            raise PluginError(f"the start {self.name!r} must return a StartValue(normal, tangent, seconds): "
                              f"{type(e).__name__}: {e}") from None
        for what, a in (("normal", normal), ("tangent", tangent)):
            if a.shape != (n,):
                raise PluginError(f"the start {self.name!r} returned {what} impulses of shape {a.shape}; the step "
                                  f"has {n} contact points, so ({n},)")
            if not np.all(np.isfinite(a)):
                raise PluginError(f"the start {self.name!r} returned a non-finite {what} impulse (step "
                                  f"{ctx.problem.index})")
        if np.any(normal < 0):   # (held as a method's answer is: a contact only pushes)
            raise PluginError(f"the start {self.name!r} returned a negative normal impulse (step {ctx.problem.index}): "
                              f"a contact only pushes")
        if not all(np.isfinite(v) and v >= 0 for v in seconds.values()):
            raise PluginError(f"the start {self.name!r} returned prediction seconds that are not finite and >= 0")
        return StartValue(normal, tangent, seconds)


def make_starts(names: list[str], spec: GridSpec | None = None, predictor: object = None) -> dict:
    """{name: start} for the names asked for: registered built-ins, installed plug-ins (entry
    points in group deepcontact.starts) or package.module:Name. Each factory gets the arguments
    it declares: spec (the grid) and predictor (the trained model). Plug-ins are checked on every
    call (Checked)."""
    import inspect
    names = arguments.texts(names, "names")
    if not names:
        raise InputError(f"no start given (argument 'names' is empty); choose from {', '.join(STARTS.names())}")
    out = {}
    for name in names:
        if name not in STARTS._builtin and name in STARTS.described and name not in STARTS._loaded:
            out[name] = Remote(name)   # (made in its contestant's process, never here)
            continue
        factory = STARTS.load(name)
        try:
            wanted = inspect.signature(factory).parameters
        except (TypeError, ValueError):
            wanted = {}
        given = {"spec": spec, "predictor": predictor}
        if "predictor" in wanted and predictor is None:
            raise InputError(f"the start {name} needs a trained model (--checkpoint)")
        if "spec" in wanted and spec is None:
            raise InputError(f"the start {name} needs a grid (--cell, --smoothing, --kernel, or a --checkpoint)")
        with guest(f"the start {name!r}", "could not be made:"):
            start = factory(**{k: v for k, v in given.items() if k in wanted})
        out[name] = start if name in NAMES else Checked(name, start)
    return out
