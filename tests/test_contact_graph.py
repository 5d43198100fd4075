"""The contact-graph correction: its differentiable solver against the real one."""
import numpy as np
import pytest
import torch

from deepcontact.studies import contact_graph as cg
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.solver.pgs import solve
from deepcontact.solver.problem import StepProblem


@pytest.fixture(scope="module")
def problems():
    scene = generate("pile", 0, dict(count=30, box=16.0, sigma=4.0))
    world = build_world(scene)
    out = []
    for k in range(160):
        b, c = world.step(scene.dt, 8, 3, record=True)
        if k >= 100 and k % 20 == 0 and len(c["manifold"]):
            out.append(StepProblem.from_arrays(b, c, dt=scene.dt, gravity=scene.effects.gravity))
    assert len(out) >= 2
    return out


def test_the_start_residual_is_the_solvers(problems):
    # Before any sweep the surrogate and the native solver see the same start (sanitised the
    # same way) and the same velocities: the largest residual agrees to rounding.
    for p in problems:
        g = cg.graph_of([p])
        n, t, vel = cg.sweep(g, g.start_normal, g.start_tangent, 0)
        _, r = cg.residual(g, n, t, vel)
        assert float(r.max()) ** 0.5 == pytest.approx(solve(p, mode="float64", max_iterations=0).residual, rel=1e-12)


def test_the_surrogate_sweeps_converge_to_the_solvers_answer(problems):
    # A different Gauss-Seidel order, no block solver: the same LCP, so the same velocities at
    # convergence (impulses of redundant contacts need not agree).
    p = problems[0]
    g = cg.graph_of([p])
    n, t, vel = cg.sweep(g, g.start_normal, g.start_tangent, 400)
    _, r = cg.residual(g, n, t, vel)
    assert float(r.max()) ** 0.5 < 1e-6
    exact = solve(p, mode="float64", max_iterations=100_000, tolerance=1e-10)
    assert np.abs(vel.v.numpy() - exact.velocity).max() < 1e-5 * g.scale[0].item()


def test_an_untrained_model_is_the_warm_start_and_trains(problems):
    torch.manual_seed(0)
    model = cg.CorrectionNet(width=8, rounds=1)
    g = cg.graph_of(problems)
    n, t = cg.corrected_start(model, g)
    assert torch.equal(n, g.start_normal) and torch.equal(t, g.start_tangent)
    value = cg.loss(model, g, 4)
    assert value.item() == pytest.approx(cg.loss(None, g, 4).item(), abs=1e-12)
    value.backward()
    grad = model.out.weight.grad
    assert torch.all(torch.isfinite(grad)) and grad.abs().sum() > 0
