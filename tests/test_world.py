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
        assert header["solver"]["name"] == engine.name == name
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
