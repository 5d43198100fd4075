"""The one stepping loop: a scene's removal events applied, the world stepped by Box2D's solver or
the project's, each step yielded with what it did and what it cost.

`dc simulate` writes what it yields, the closed loop measures drift and energy from it, the
stability study its criteria; none of them steps a world itself.

    for done in steps(world, scene, box2d(world, scene)):
        done.index, done.bodies, done.contacts, done.solution, done.seconds
"""
import time
from dataclasses import dataclass

from ..solver.metrics import deepest
from .pgs_loop import LoopStep


@dataclass
class Stepped:
    index: int
    bodies: dict        # the bodies before the step, as a step file records them (None unless recording)
    contacts: dict      # the contacts the velocity solver saw, impulses applied (None unless recording)
    solution: object    # the project's Solution, or None (Box2D's solver, or no contact points)
    dt_ratio: float     # Box2D's warm-start scale for the step
    deepest: float      # the deepest penetration among the step's contact points (m), >= 0
    seconds: float      # wall time of the step itself
    engine_stats: dict = None   # another engine's own account of its solve (MuJoCo's iterations, ...)


def box2d(world, scene, velocity_iterations=None, record=True):
    """A step function for Box2D's own solver (the scene's iterations unless given)."""
    iterations = scene.solver.velocity_iterations if velocity_iterations is None else velocity_iterations
    position = scene.solver.position_iterations

    def step():
        if not record:
            world.step(scene.dt, iterations, position)
            return LoopStep(None, None, None, 0.0)
        bodies, contacts = world.step(scene.dt, iterations, position, record=True)
        return LoopStep(bodies, contacts, None, deepest(contacts), dt_ratio=world.last_dt_ratio)
    return step


def box2d3(world, scene, record=True):
    """A step function for a Box2D v3 world (build.build_world3: the soft step, its substeps as
    the world was built), as box2d's: recording, what a step file holds (the bodies before the
    step, its contact points: the manifolds the step solved, the last substep's impulses);
    without, the soft step alone (the engine's own time)."""
    def step():
        if not record:
            world.step(scene.dt)
            return LoopStep(None, None, None, 0.0, dt_ratio=1.0)
        bodies, contacts = world.step(scene.dt, record=True)
        return LoopStep(bodies, contacts, None, deepest(contacts), dt_ratio=1.0)
    return step


def steps(world, scene, step, count=None, after_removal=None):
    """Yields a Stepped for each of count (default: the scene's) steps of step(), a function
    returning a LoopStep (`box2d(...)`, or a PGSStepper's step), with the scene's removal
    events applied first: every one of them, several in one step included. after_removal(k)
    is called once a step's removals are done, before it is stepped."""
    removals = scene.removals()
    for k in range(scene.steps if count is None else count):
        removed = removals.get(k, ())
        for body in removed:
            world.remove_body(body)
        if removed and after_removal is not None:
            after_removal(k)
        t0 = time.perf_counter()
        done = step()
        seconds = time.perf_counter() - t0
        # Box2D's warm start is scaled by dt_ratio: 0 on a new world's first step, exactly 1 at
        # constant dt (Box2D's solver and the project's loop report their own; an unrecorded Box2D step none).
        dt_ratio = done.dt_ratio if done.dt_ratio is not None else (0.0 if k == 0 else 1.0)
        yield Stepped(index=k, bodies=done.bodies, contacts=done.contacts, solution=done.solution,
                      dt_ratio=dt_ratio, deepest=done.deepest, seconds=seconds, engine_stats=done.engine_stats)

