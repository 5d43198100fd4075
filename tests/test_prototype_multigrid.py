"""The nonsmooth multigrid prototype (benchmarks/prototype_multigrid.py, before its
gate): its coarse correction does what a coarse correction is for, on a problem small enough to see."""
import argparse
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.solver.local import residual

pytest.importorskip("pyamg")   # (the prototype's extra: pip install '.[prototype]')

SCRIPT = Path(__file__).parent.parent / "benchmarks" / "prototype_multigrid.py"


@pytest.fixture(scope="module")
def prototype():
    spec = importlib.util.spec_from_file_location("prototype_multigrid", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def stacked_circles(prototype, steps):
    """The step after `steps` of three stacked circles (the top one 100 times as dense), its problem
    as the prototype solves it."""
    scene = generate("warm-start-energy", 0, {})
    world = build_world(scene)
    for _ in range(steps):
        world.step(scene.dt, 8, scene.solver.position_iterations)
    return prototype.StepSolve(prototype.next_problem(world, scene), 3, 1e-6, "smoothed")


@pytest.mark.parametrize("kind", ["normal", "cone"])
def test_the_coarse_correction_beats_the_same_sweeps_alone(prototype, kind):
    """From no impulse, one cycle (a PGS sweep, the truncated coarse step, a sweep) on a stack with a
    100:1 mass ratio, where sweeps alone carry the heavy top's weight down slowly: the coarse step
    solves the stack's pressed rows at once, so its residual is a small part of the sweeps' alone."""
    step = stacked_circles(prototype, 100)
    start = np.zeros(step.W.shape[0])
    alone, _, _ = step.cycle(start, prototype.Variant("none", 1, 1.0))
    corrected, alpha, _ = step.cycle(start, prototype.Variant(kind, 1, 1.0))
    assert alpha > 0.5
    assert residual(step.lp, alone) > 0.1
    assert residual(step.lp, corrected) < 0.01 * residual(step.lp, alone)


def test_the_coarse_step_never_raises_the_tresca_energy(prototype):
    """The projected correction's step length minimises the energy along it in [0, 1]: never worse
    than no step (a sign error in the line search would climb)."""
    step = stacked_circles(prototype, 100)
    r = step.smooth(np.zeros(step.W.shape[0]), 1, 1.0)
    bound = step.bounds(r)
    before = step.clip(r, bound)
    after, _, _ = step.coarse_step(r, "normal")

    def energy(x):
        return 0.5 * x @ (step.W @ x) + step.lp.q @ x
    assert energy(after) < energy(before)


def test_a_variant_is_kind_sweeps_and_w(prototype):
    assert prototype.parse_variants("cone:5:1.7,none:2:1") == [prototype.Variant("cone", 5, 1.7),
                                                                prototype.Variant("none", 2, 1.0)]
    for bad in ("cone:5", "coarse:5:1.7", "cone:0:1", "cone:5:2", "cone:5:1:1"):
        with pytest.raises(argparse.ArgumentTypeError):
            prototype.parse_variants(bad)


def test_the_coarse_correction_is_the_same_bits_every_time(prototype):
    """pyamg estimates its smoother's spectral radius from a random vector: unseeded, the same step
    gave other impulses each build (and the gate's run other cycle counts: 88 then 89)."""
    scene = generate("pile", 0, dict(count=200, box=60.0, sigma=12.0))
    world = build_world(scene)
    for _ in range(500):   # (settled: some 370 contact points, a hierarchy of more than one level)
        world.step(scene.dt, 8, scene.solver.position_iterations)
    step = prototype.StepSolve(prototype.next_problem(world, scene), 3, 1e-6, "smoothed")
    r = step.smooth(step.lp.reaction(step.problem.start_normal, step.problem.start_tangent), 5, 1.7)
    first = step.coarse_step(r, "normal")[0]
    np.random.rand(7)   # (numpy's global random state moved on, as another build would move it)
    assert np.array_equal(step.coarse_step(r, "normal")[0], first)
