"""Scene → Box2D world, with only the declared effects switched on."""
import numpy as np

from .. import _box2d
from .._box2d import World
from ..errors import InputError
from ..scene.check import check_scene, overlap_tolerance

_TYPE = {"static": 0, "kinematic": 1, "dynamic": 2}


def build_world(scene) -> World:
    e = scene.effects
    gravity = e.gravity if e.gravity is not None else (0.0, 0.0)
    linear, angular = e.damping if e.damping is not None else (0.0, 0.0)
    world = World(*gravity)
    world.continuous = e.continuous
    world.sleeping = scene.solver.sleeping
    world.warm_starting = scene.solver.warm_starting
    world.block_solve = scene.solver.block_solve
    _add_bodies(world, scene, linear, angular)
    return world


def _add_bodies(world, scene, linear, angular, path=None):
    """The scene's bodies and shapes into a world of either engine (the same calls); a shape the
    engine refuses is an InputError naming the body (and, from a scene file at path, its line)."""
    threshold = scene.effects.restitution_threshold
    for b in scene.bodies:
        dynamic = b.type == "dynamic"
        index = world.add_body(_TYPE[b.type], b.x, b.y, angle=b.angle, vx=b.vx, vy=b.vy, omega=b.omega,
                               linear_damping=linear if dynamic else 0.0,
                               angular_damping=angular if dynamic else 0.0,
                               fixed_rotation=b.fixed_rotation, bullet=b.bullet)
        for s in b.shapes:
            material = dict(friction=scene.friction_of(s), restitution=scene.restitution_of(s),
                            restitution_threshold=threshold)
            if s.kind == "circle":
                world.add_circle(index, s.radius, s.x, s.y, density=s.density, **material)
            elif s.kind == "polygon":
                try:
                    world.add_polygon(index, np.asarray(s.vertices, dtype=np.float32), density=s.density,
                                      **material)
                except ValueError as e:   # (v3's hull refuses slivers 2.4.1 takes: the engine's own words)
                    raise InputError(f"body {index}: {e}", path, s.line) from None
            else:
                world.add_edge(index, s.x1, s.y1, s.x2, s.y2, **material)


def build_world3(scene, soft, path=None):
    """The scene as a Box2D v3 world stepped with the soft step `soft` (a simulate.engines.SoftStep), with the same bodies, shapes, materials and effects as build_world's;
    warm starting, sleeping and continuous collision as the scene says. InputError where this
    build has no Box2D v3 (pyb2d3 was not installed when the module was built)."""
    if not hasattr(_box2d, "World3"):
        raise InputError("this build has no Box2D v3: install pyb2d3==0.11.1 and rebuild (make setup)")
    e = scene.effects
    gravity = e.gravity if e.gravity is not None else (0.0, 0.0)
    linear, angular = e.damping if e.damping is not None else (0.0, 0.0)
    world = _box2d.World3(*gravity, substeps=soft.substeps, contact_hertz=soft.contact_hertz,
                          damping_ratio=soft.damping_ratio, push_speed=soft.push_speed,
                          warm_starting=scene.solver.warm_starting,
                          restitution_threshold=e.restitution_threshold, sleeping=scene.solver.sleeping,
                          continuous=e.continuous)
    _add_bodies(world, scene, linear, angular, path)
    return world


def check_overlaps(scene, path=None):
    """Refuse bodies that start overlapping by more than Box2D tolerates at rest.

    Uses a throwaway world, so the world that is simulated is untouched by the check. The scene
    is held first to what a scene file is (a NaN velocity a caller's function set would abort
    the process in Box2D's assert)."""
    check_scene(scene, path)
    world = build_world(scene)
    world.find_new_contacts()
    world.collide()
    c = world.contacts()
    if len(c["separation"]) == 0:
        return
    kinds = [s.kind for _, s in scene.fixtures()]
    tol = np.array([overlap_tolerance(kinds[a], kinds[b])
                    for a, b in zip(c["fixture_a"], c["fixture_b"])], dtype=np.float64)
    depth = -c["separation"].astype(np.float64)
    bad = np.nonzero(depth > tol)[0]
    if bad.size:
        k = bad[np.argmax(depth[bad])]
        a, b = int(c["body_a"][k]), int(c["body_b"][k])
        line = scene.bodies[b].line or scene.bodies[a].line
        raise InputError(f"bodies {a} and {b} overlap by {depth[k]:.4g} m at the start "
                         f"(at most {tol[k]:.3g} m is allowed); {bad.size} overlapping contact "
                         f"point(s) in all", path, line)
