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
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..grid.interpolate import bilinear
from ..grid.splat import splat_points

NAMES = ("zero", "builtin", "prev", "copy", "copy2", "copy0", "sph", "cnn", "random", "bad", "guarded", "cnn-new")
ORACLES = ("copy", "copy2", "copy0", "sph")
NEEDS_MODEL = ("cnn", "guarded", "cnn-new")


@dataclass
class StepContext:
    """What a start may look at: the recorded step and its reference solution."""
    problem: object          # solver.problem.StepProblem
    bodies: dict
    contacts: dict
    reference: object        # solver.pgs.Solution (float64, to 1e-12)
    persisted: np.ndarray    # True where the contact point existed in the previous step
    seed: int = 0
    previous: dict = None    # {contact key: (normal, tangent)} of the previous step's solution
    cache: dict = field(default_factory=dict)


@dataclass
class StartValue:
    normal: np.ndarray
    tangent: np.ndarray
    seconds: dict            # prediction time by stage (empty for free starts)


def _free(n, t):
    return StartValue(np.asarray(n, np.float64), np.asarray(t, np.float64), {})


class Zero:
    def __call__(self, ctx):
        n = ctx.problem.points
        return _free(np.zeros(n), np.zeros(n))


class Builtin:
    def __call__(self, ctx):
        return _free(ctx.problem.start_normal, ctx.problem.start_tangent)


class Previous:
    def __call__(self, ctx):
        from ..solver.problem import contact_keys
        if ctx.previous is None:
            raise InputError("the prev start needs the previous step's solution")
        found = [ctx.previous.get(k, (0.0, 0.0)) for k in contact_keys(ctx.contacts)]
        n, t = (np.array(v, dtype=np.float64) for v in zip(*found)) if found else (np.zeros(0), np.zeros(0))
        return _free(n, t)


class Copy:
    def __init__(self, decimals=None):
        self.decimals = decimals

    def __call__(self, ctx):
        n, t = ctx.reference.normal_impulse, ctx.reference.tangent_impulse
        if self.decimals is not None:
            n, t = np.round(n, self.decimals), np.round(t, self.decimals)
        return _free(n, t)


class SPH:
    def __init__(self, spec):
        self.spec = spec

    def __call__(self, ctx):
        t0 = time.perf_counter()
        pos = ctx.contacts["position"]
        grid = splat_points(self.spec, pos, np.stack([ctx.reference.normal_impulse, ctx.reference.tangent_impulse], 1))
        t1 = time.perf_counter()
        back, _ = bilinear(grid, self.spec, pos)
        if not self.spec.renormalize:
            back = back * self.spec.cell ** 2
        t2 = time.perf_counter()
        return StartValue(back[0], back[1], {"rasterize": t1 - t0, "interpolate": t2 - t1})


class CNN:
    def __init__(self, predictor):
        self.predictor = predictor

    def __call__(self, ctx):
        if "cnn" not in ctx.cache:
            s = self.predictor.predict(ctx.bodies, ctx.contacts)
            ctx.cache["cnn"] = StartValue(s.normal, s.tangent, dict(s.seconds))
        return ctx.cache["cnn"]


class Random:
    def __call__(self, ctx):
        rng = np.random.default_rng([ctx.seed, ctx.problem.index])
        scale = float(np.abs(ctx.reference.normal_impulse).max()) or 1.0
        n = rng.uniform(0, scale, ctx.problem.points)
        mu = ctx.problem.contacts["friction"].astype(np.float64)
        return _free(n, rng.uniform(-1, 1, ctx.problem.points) * mu * n)


class Bad:
    def __call__(self, ctx):
        n = ctx.problem.points
        return _free(np.full(n, 50.0), np.full(n, 50.0))


class Guarded:
    """MuJoCo's idea: of several candidate starts, keep the one closest to solving the problem."""

    def __init__(self, cnn):
        self.candidates = {"cnn": cnn, "builtin": Builtin(), "zero": Zero()}

    def __call__(self, ctx):
        from ..solver.pgs import solve
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
    def __init__(self, cnn):
        self.cnn = cnn

    def __call__(self, ctx):
        learned = self.cnn(ctx)
        keep = ctx.persisted
        return StartValue(np.where(keep, ctx.problem.start_normal, learned.normal),
                          np.where(keep, ctx.problem.start_tangent, learned.tangent), learned.seconds)


def make_starts(names, spec=None, predictor=None):
    """{name: start} for the names asked for; sph needs a grid spec, the learned ones a model."""
    unknown = [n for n in names if n not in NAMES]
    if unknown or not names:
        raise InputError(f"unknown start(s) {', '.join(unknown) or '(none)'}; choose from {', '.join(NAMES)}")
    if any(n in NEEDS_MODEL for n in names) and predictor is None:
        raise InputError(f"the starts {', '.join(n for n in names if n in NEEDS_MODEL)} need a trained --model")
    cnn = CNN(predictor) if predictor is not None else None
    table = {"zero": Zero, "builtin": Builtin, "prev": Previous, "copy": Copy, "copy2": lambda: Copy(2), "copy0": lambda: Copy(0),
             "sph": lambda: SPH(spec), "cnn": lambda: cnn, "random": Random, "bad": Bad,
             "guarded": lambda: Guarded(cnn), "cnn-new": lambda: CNNNew(cnn)}
    return {n: table[n]() for n in names}
