"""What the studies step each engine at: its effort (the one setting the stability study doubles
until a scene passes), that setting's default and the values the engines and frontier studies
sweep it at. Only the studies read this, so it lives with them, not on the engines.

An engine of one's own is studied at the effort its class names in ``study_effort`` (an Effort);
the built-ins' are here.
"""
from dataclasses import dataclass


@dataclass(frozen=True)
class Effort:
    """setting: the engine's setting the studies raise (its effort); default: its default (None:
    the scene's own 8 iterations); sweep: the values the studies step it at, cheapest first;
    fast: the few of them the fast studies (the test suite's) step it at."""
    setting: str
    default: int = None
    sweep: tuple = ()
    fast: tuple = ()


def _mujoco_frontier(fast):
    """Newton (MuJoCo's default) to tolerances 1e-2 ... 1e-8 and at caps of 1 and 4 iterations;
    CG and PGS to 1e-4 and 1e-8; Newton to 1e-8 at impedances 0.99 and 0.999, stiffer than its
    default (fast: Newton to 1e-8, PGS to 1e-4)."""
    if fast:
        return [("MuJoCo Newton", "tolerance 1e-08", {"solver": "newton", "tolerance": 1e-8}),
                ("MuJoCo PGS", "tolerance 0.0001", {"solver": "pgs", "tolerance": 1e-4})]
    out = [("MuJoCo Newton", f"{n} iteration{'s' * (n > 1)}", {"solver": "newton", "iterations": n})
           for n in (1, 4)]
    out += [("MuJoCo Newton", f"tolerance {t:g}", {"solver": "newton", "tolerance": t})
            for t in (1e-2, 1e-4, 1e-6, 1e-8)]
    out += [(f"MuJoCo {solver.upper()}", f"tolerance {t:g}", {"solver": solver, "tolerance": t})
            for solver in ("cg", "pgs") for t in (1e-4, 1e-8)]
    # the price of rigidity: Newton to 1e-8 on stiffer problems (a penalty of d / (1 - d) effective masses)
    out += [("MuJoCo Newton", f"impedance {d:g}", {"solver": "newton", "tolerance": 1e-8, "impedance": d})
            for d in (0.99, 0.999)]
    return out


EFFORTS = {
    "box2d": Effort("iterations", None, (1, 2, 4, 8, 16, 32, 64, 128, 256), (1, 8, 64)),
    "box2d3": Effort("substeps", 4, (1, 2, 4, 8, 16), (1, 4)),   # (v3's own default, as its samples step)
    "pymunk": Effort("iterations", 10, (1, 2, 4, 8, 10, 16, 32, 64, 128, 256), (1, 10)),
    "mujoco": Effort("iterations", 100, (1, 2, 4, 8, 16, 32, 100)),
}
# Engines whose frontier is more than their effort's sweep.
_FRONTIERS = {"mujoco": _mujoco_frontier}


def effort(engine) -> Effort:
    """The effort of an engine class (a built-in's from EFFORTS, a plug-in's own study_effort)."""
    own = getattr(engine, "study_effort", None)
    if own is not None:
        return own
    if engine.name not in EFFORTS:
        raise ValueError(f"the engine {engine.name!r} names no study_effort: the studies do not know what to step it at")
    return EFFORTS[engine.name]


def frontier(engine, fast=False):
    """[(family, label, settings)]: the settings the studies step an engine class at, cheapest
    first (its effort over its sweep, or its own frontier)."""
    if engine.name in _FRONTIERS and getattr(engine, "study_effort", None) is None:
        return _FRONTIERS[engine.name](fast)
    e = effort(engine)
    return [(engine.label, f"{n} {e.setting}", {e.setting: n}) for n in (e.fast if fast else e.sweep)]


def counted(engine, count, **settings):
    """The engine class with its effort at `count` (and `settings`): what the studies step."""
    return engine.from_settings(**{**settings, effort(engine).setting: count})
