"""Step files hold the problem the discrete velocity solver really solved:
continuous collision and sleeping islands included, and recording never changes the simulation."""
from pathlib import Path

import numpy as np
import pytest

from conftest import dc
from deepcontact.scene.generators import generate
from deepcontact.scene.xml import read_scene
from deepcontact.simulate.build import build_world
from deepcontact.step.reader import read_step

SCENES = Path(__file__).parent.parent / "datasets" / "scenes"


def trajectory(scene, steps, record):
    world = build_world(scene)
    out = []
    for _ in range(steps):
        world.step(scene.dt, scene.solver.velocity_iterations, scene.solver.position_iterations,
                   record=record)
        b = world.bodies()
        out.append(np.concatenate([b[k].ravel() for k in ("position", "angle", "velocity", "omega")]))
    return np.array(out)


@pytest.mark.parametrize("name", ["bullet", "sleeping"])
def test_recording_leaves_the_trajectory_bit_for_bit_unchanged(name):
    # With continuous collision the recorder runs the time-of-impact phase itself, after the
    # discrete solve: the bodies must still move exactly as in an unrecorded Box2D step.
    scene = generate("bullet", 0, {}) if name == "bullet" else read_scene(SCENES / "sleeping.xml")
    assert scene.effects.continuous or scene.solver.sleeping
    a, b = trajectory(scene, 120, True), trajectory(scene, 120, False)
    assert np.array_equal(a, b)


@pytest.mark.parametrize("args", [["bullet", "--steps", "120"], [str(SCENES / "sleeping.xml")]])
def test_replay_is_exact_with_continuous_collision_and_sleeping(tmp_path, args):
    out = tmp_path / "run"
    assert dc("simulate", *args, "-q", "-o", str(out)).returncode == 0
    r = dc("validate", "--replay", "-q", str(out))
    assert r.returncode == 0 and "largest difference 0: exact" in r.stdout, r.stdout + r.stderr


def test_sleeping_islands_drop_out_and_wake_with_their_stored_impulses(tmp_path):
    out = tmp_path / "run"
    assert dc("simulate", str(SCENES / "sleeping.xml"), "-q", "-o", str(out)).returncode == 0
    steps = [read_step(p) for p in sorted(out.glob("seed-*/step-*.xml"))]
    counts = [len(c["body_a"]) for _, _, c in steps]
    asleep = [i for i, n in enumerate(counts) if n == 0]
    assert asleep and asleep[0] > 10, "the boxes settle, then fall asleep: no contact is solved"
    woken = next(i for i in range(asleep[0], len(counts)) if counts[i] > 0)
    _, _, c = steps[woken]
    # the stack's contacts resume from the impulses stored when it fell asleep, not from zero
    stack = (c["body_a"] != 5) & (c["body_b"] != 5)
    assert stack.any() and (c["start_normal_impulse"][stack] > 0).all()
