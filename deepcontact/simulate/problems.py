"""The contact problems of a scene's steps, made one way: the scene stepped through the one
stepping loop (its removals applied) by an engine, each recorded step with contact points posed as
a StepProblem with every setting from the scene. The studies, benchmarks and tests take theirs here."""
from .engines import Box2D
from .stepping import Stepped, steps
from ..solver.problem import StepProblem


def step_problem(scene, done: Stepped, velocity_iterations=None):
    """The contact problem of a recorded step (a Stepped with bodies and contacts), every setting
    from the scene (dt, gravity, the block solver, its velocity iterations unless given)."""
    return StepProblem.from_arrays(done.bodies, done.contacts, dt=scene.dt, gravity=scene.effects.gravity or (0.0, 0.0),
                                   block_solve=scene.solver.block_solve, index=done.index,
                                   velocity_iterations=scene.solver.velocity_iterations if velocity_iterations is None
                                   else velocity_iterations)


def problems(scene, engine=None, *, every=1, first=0, count=None):
    """Yields (Stepped, StepProblem) for every `every`-th step from `first` that has contact points,
    of the scene stepped by `engine` (simulate.engines: Box2D 2.4.1's own solver by default) through
    the one stepping loop (its removals applied), for `count` steps (the scene's by default): the
    problems the studies, benchmarks and tests solve."""
    engine = Box2D() if engine is None else engine
    world = engine.build(scene)
    for done in steps(world, scene, engine.stepper(world, scene), count):
        if done.index >= first and (done.index - first) % every == 0 and len(done.contacts["manifold"]):
            yield done, step_problem(scene, done)


def recorded_between(scene, first, last, count=None):
    """Yields every Stepped of the scene stepped by Box2D 2.4.1's own solver through the one
    stepping loop for `count` steps (the scene's by default), with bodies and contacts recorded only
    for the steps first <= index < last: the rest run unrecorded, at Box2D's own speed (recording
    leaves the trajectory as it is)."""
    engine = Box2D()
    world = engine.build(scene)
    bare, recording = engine.stepper(world, scene, record=False), engine.stepper(world, scene)
    k = -1

    def step():
        nonlocal k
        k += 1
        return (recording if first <= k < last else bare)()
    yield from steps(world, scene, step, count)
