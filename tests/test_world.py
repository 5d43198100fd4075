"""Engines as objects and a world stepped in memory: the same engines `dc simulate` steps with,
the same arrays its step files record."""
import numpy as np
import pytest

import deepcontact as dc
from deepcontact.step.reader import read_step


def test_a_world_in_memory_steps_as_dc_simulate_records(tmp_path):
    """The bodies and contacts World.step returns are the ones dc simulate writes, number for
    number (float32 both), for each engine."""
    scene = dc.generate("pile", 5, {"count": 12, "box": 12, "sigma": 2.5})
    for name, engine in (("box2d", dc.Box2D()), ("pgs", dc.Box2D(solver=dc.SolveSettings(accelerate="nncg"))),
                         ("box2d3", dc.Box2D3(dc.SoftStep(substeps=2)))):
        out = tmp_path / name
        dc.simulate_run(lambda seed: dc.generate("pile", seed, {"count": 12, "box": 12, "sigma": 2.5}), [5], out,
                        engine=engine)
        world = dc.World(scene, engine)
        for _ in range(60):
            done = world.step()
        header, bodies, contacts = read_step(out / "seed-000005" / "step-000059.xml")
        assert header["solver"]["name"] == engine.solver_name == name
        np.testing.assert_array_equal(done.bodies["position"], bodies["position"])
        np.testing.assert_array_equal(done.contacts["normal_impulse"], contacts["normal_impulse"])
        assert (done.solution is not None) == (name == "pgs")


def test_a_world_steps_on_past_the_scenes_count_and_says_where_it_is():
    scene = dc.generate("pile", 0, {"count": 5, "box": 8, "sigma": 2, "steps": 3})
    world = dc.World(scene)
    for _ in range(5):
        world.step()
    assert world.index == 5 and "step 5" in repr(world)
    assert world.bodies()["position"].shape == (len(scene.bodies), 2)


def test_an_engine_refuses_a_scene_it_cannot_step_when_the_world_is_made():
    scene = dc.generate("bullet", 0)   # continuous collision: the project's solver cannot step it
    with pytest.raises(dc.InputError, match="continuous collision"):
        dc.World(scene, dc.Box2D(solver=dc.SolveSettings()))
    dc.World(scene)   # (Box2D's own solver can)
    from deepcontact.errors import OptionError
    with pytest.raises(OptionError, match="--start"):
        dc.Box2D(solver=dc.SolveSettings(), start="somewhere")


# Edits a notebook may make to a scene in memory, each of a value a scene file is refused for.
SCENE_EDITS = {
    **{f"body {k} {v}": f"scene.bodies[1].{k} = {v}" for k in ("x", "y", "angle", "vx", "vy", "omega")
       for v in ("math.nan", "math.inf", "1e300")},
    **{f"radius {v}": f"scene.bodies[1].shapes[0].radius = {v}" for v in ("math.nan", "0.0", "-1.0", "1e300")},
    **{f"density {v}": f"scene.bodies[1].shapes[0].density = {v}" for v in ("math.nan", "-1.0", "1e300")},
    "collinear polygon": "scene.bodies[1].shapes[:] = [Polygon(((0, 0), (1, 0), (2, 0)), density=1.0)]",
    "tiny polygon": "scene.bodies[1].shapes[:] = [Polygon(((0, 0), (1e-9, 0), (0, 1e-9)), density=1.0)]",
    "gravity nan": "scene.effects.gravity = (0.0, math.nan)",
    "friction nan": "scene.effects.friction = math.nan",
    "dt nan": "scene.dt = math.nan",
}
WORLD_EDIT = """
import math, sys
import deepcontact as dc
from deepcontact.scene.model import Polygon
for name, edit in {edits!r}.items():
    for where in ("World", "closed_loop"):
        scene = dc.generate("pile", 0, {{"count": "5", "box": "10", "sigma": "1"}})
        exec(edit)
        try:
            if where == "World":
                dc.World(scene).step()
            else:
                dc.closed_loop(scene, dc.make_starts(["zero"]), steps=2)
            print("ACCEPTED", where, name, flush=True)
        except dc.InputError:
            print("refused", where, name, flush=True)
"""


def test_a_scene_edited_in_memory_is_refused_as_its_file_would_be_never_aborting():
    """Box2D's asserts abort the process (a notebook's kernel dies): World and closed_loop hold
    an in-memory scene to what a scene file is held to. In a process of its own, since an abort
    would take the test runner with it."""
    import subprocess
    import sys
    r = subprocess.run([sys.executable, "-c", WORLD_EDIT.format(edits=SCENE_EDITS)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, (r.returncode, r.stdout[-500:], r.stderr[-500:])
    lines = r.stdout.splitlines()
    assert len(lines) == 2 * len(SCENE_EDITS) and not [x for x in lines if x.startswith("ACCEPTED")], lines


@pytest.mark.parametrize("spec, params", [("pile", dict(count=40, box=18, sigma=4)), ("pyramid", {})])
def test_the_loops_step_skips_box2ds_second_collide_bit_for_bit(spec, params):
    """The loop collides, solves and writes its impulses, then steps Box2D with 0 velocity
    iterations: Box2D's Step collided the same positions again (the same manifolds, the impulses
    carried onto themselves by feature id), a third of the loop's fixed cost at 1,000 circles.
    Skipping it (collided=True) changes no bit of the trajectory, over steps where contacts
    come and go."""
    from deepcontact.scene.generators import generate
    from deepcontact.simulate.build import build_world
    from deepcontact.solver.methods import solve
    from deepcontact.solver.problem import StepProblem
    from deepcontact.solver.settings import SolveSettings
    scene = generate(spec, 3, params)
    worlds = [build_world(scene), build_world(scene)]
    settings = SolveSettings(max_iterations=20, tolerance=0)
    for step in range(150):
        states = []
        for collided, world in zip((False, True), worlds):
            bodies = world.bodies()
            world.collide()
            contacts = world.contacts()
            if len(contacts["manifold"]):
                problem = StepProblem.from_arrays(bodies, contacts, dt=scene.dt, gravity=scene.effects.gravity,
                                                  block_solve=scene.solver.block_solve, velocity_iterations=8)
                s = solve(problem, contacts["normal_impulse"], contacts["tangent_impulse"], settings=settings)
                world.set_manifold_impulses(s.normal_impulse.astype(np.float32), s.tangent_impulse.astype(np.float32))
            world.inv_dt0 = 1.0 / scene.dt
            world.step(scene.dt, 0, scene.solver.position_iterations, collided=collided)
            states.append(world.bodies())
        for key in ("position", "angle", "velocity", "omega"):
            assert np.array_equal(states[0][key], states[1][key]), (step, key)


def test_a_world_stepped_without_recording_still_states_each_residual():
    """record=False keeps no bodies nor contacts, but the project's solver at a fixed sweep count
    still states each step's residual (it read NaN once the loop skipped the residual nothing
    recorded asked), the same as the recorded world's, on the same iterates."""
    scene = dc.generate("pile", 3, {"count": 30, "box": 16, "sigma": 4})
    engine = dc.Box2D(solver=dc.SolveSettings(max_iterations=8, tolerance=0))
    bare, recorded = dc.World(scene, engine, record=False), dc.World(scene, engine)
    solved = 0
    for _ in range(80):
        a, b = bare.step(), recorded.step()
        assert a.bodies is None and (a.solution is None) == (b.solution is None)
        if a.solution is not None:
            solved += 1
            assert np.isfinite(a.solution.residual) and a.solution.residual == b.solution.residual
    assert solved > 40


@pytest.mark.parametrize("spec, params", [("pyramid", {"base": 6}), ("pile", dict(count=30, box=16, sigma=4))])
def test_contacts_are_box2ds_solve_order_and_reading_them_changes_no_bit(spec, params):
    """World.contacts() (a contact seen marked by Box2D's own island flag, which it leaves set)
    lists the points in the order Box2D's solve records them, on boxes (2-point manifolds) and
    after a body in the middle is removed; read twice between steps, it changes no bit of the
    trajectory nor of what the steps record."""
    from deepcontact.simulate.build import build_world
    scene = dc.generate(spec, 0, params)
    worlds = [build_world(scene), build_world(scene)]   # (the second read each step)
    for world in worlds:
        world.find_new_contacts()   # (as Step would first: the first step's contacts touch)
    columns = ("body_a", "body_b", "fixture_a", "fixture_b", "id_key", "point", "manifold", "island")
    points = 0
    for step in range(60):
        if step == 20:
            for world in worlds:
                world.remove_body(5)
        recorded = []
        for reads, world in enumerate(worlds):
            world.collide()
            read = [world.contacts(), world.contacts()] if reads else []
            recorded.append(world.step(scene.dt, scene.solver.velocity_iterations,
                                       scene.solver.position_iterations, record=True))
            for contacts in read:
                for key in columns:
                    assert np.array_equal(contacts[key], recorded[-1][1][key]), (step, key)
            points += len(read[0]["manifold"]) if read else 0
        for table in (0, 1):
            for key, column in recorded[0][table].items():
                assert np.array_equal(column, recorded[1][table][key], equal_nan=True), (step, key)
    assert points > 100 and 5 not in worlds[1].bodies()["index"]
