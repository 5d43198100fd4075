"""Where a step of the project's solver in the loop spends its time, at 1,000 circles, next to
Box2D 2.4.1's own step in the same run.

The 1000-circle pile (seed 9) is stepped by Box2D at its 8 iterations until settled (500 steps).
Then, on one world, steps alternate: Box2D's own step at 8 iterations, and the loop's step (one
native call: Collide, gather, PGS from Box2D's warm start, write back, Step with 0 velocity
iterations) at a fixed number of sweeps. Then the loop's pieces, as the step in pieces through
Python takes them, each timed on the same state: the bodies and contacts read out, Collide, the
problem posed, the solve at 0 and 8 sweeps (its fixed cost and the sweeps), and Box2D's Step with
0 velocity iterations (integration, islands, position correction), on alternate steps without its
own Collide (as the loop runs it: the manifolds were just collided) and with it (as it ran before);
and one
sweep's cost, from solves of the last state at 64 and 512 sweeps. Medians over
the steps; ratios to Box2D's step in the same run.

Usage: python benchmarks/bench_loop_parts.py [--steps N] [--sweeps N]
"""
import sys
import time
from pathlib import Path

import numpy as np

from deepcontact.scene.generators import generate
from deepcontact.simulate import stepping
from deepcontact.simulate.engines import Box2D
from deepcontact.simulate.pgs_loop import unit_dt_ratio_inv
from deepcontact.solver.methods import solve
from deepcontact.solver.problem import StepProblem
from deepcontact.solver.settings import SolveSettings

sys.path.insert(0, str(Path(__file__).parent))
from common import arguments  # noqa: E402

SETTLE = 500


def main():
    args = arguments(__doc__, steps=60, sweeps=8)
    scene = generate("pile", 9, dict(count=1000, box=95.0, sigma=19.0, steps=SETTLE + 4 * args.steps))
    box2d = Box2D(velocity_iterations=8)
    world = box2d.build(scene)
    own = box2d.stepper(world, scene, record=False)
    for _ in stepping.steps(world, scene, own, SETTLE):
        pass
    times = {}

    def timed(name, fn):
        t = time.perf_counter()
        out = fn()
        times.setdefault(name, []).append(time.perf_counter() - t)
        return out

    loop = Box2D(solver=SolveSettings(max_iterations=args.sweeps, tolerance=0)).stepper(world, scene, record=False)
    for _ in range(args.steps):   # interleaved: the same settled pile for both
        timed("Box2D's step, 8 iterations", own)
        timed(f"the loop's step, {args.sweeps} sweeps (one native call)", loop)
    g, inv = scene.effects.gravity, unit_dt_ratio_inv(scene.dt)
    fixed, swept = SolveSettings(max_iterations=0, tolerance=0), SolveSettings(max_iterations=args.sweeps, tolerance=0)
    for k in range(args.steps):   # the pieces, each on the state the one before left
        timed("Box2D's step, 8 iterations", own)
        bodies = timed("bodies read out", world.bodies)
        timed("Collide", world.collide)
        contacts = timed("contacts read out", world.contacts)
        problem = timed("the problem posed (Python)", lambda: StepProblem.from_arrays(
            bodies, contacts, dt=scene.dt, gravity=g, block_solve=scene.solver.block_solve, velocity_iterations=8))
        start = (contacts["normal_impulse"], contacts["tangent_impulse"])
        timed("solve, 0 sweeps (assembly, starts, answer)", lambda: solve(problem, *start, settings=fixed))
        s = timed(f"solve, {args.sweeps} sweeps", lambda: solve(problem, *start, settings=swept))
        world.set_manifold_impulses(s.normal_impulse.astype(np.float32), s.tangent_impulse.astype(np.float32))
        world.inv_dt0 = inv
        # the loop's Step skips Box2D's own Collide (the same manifolds again); every other step
        # runs it as the loop did before, to show what it cost
        name = "Step, 0 velocity iterations" + (" (its Collide skipped, as the loop)" if k % 2 == 0
                                                 else " (with its own Collide again)")
        timed(name, lambda: world.step(scene.dt, 0, scene.solver.position_iterations, collided=k % 2 == 0))
    for n in (64, 512):   # a sweep's own cost: the difference over the last state's problem
        many = SolveSettings(max_iterations=n, tolerance=0)
        for _ in range(5):
            timed(f"solve, {n} sweeps", lambda: solve(problem, *start, settings=many, final_residual=False))
    sweep = (np.median(times["solve, 512 sweeps"]) - np.median(times["solve, 64 sweeps"])) / 448
    base = float(np.median(times["Box2D's step, 8 iterations"]))
    print(f"the 1000-circle pile, {len(world.contacts()['manifold']):,} contact points at the end, "
          f"{args.steps} steps each")
    print(f"{'':56s} {'median ms':>10s} {'x Box2D step':>13s}")
    for name, values in times.items():
        ms = float(np.median(values))
        print(f"{name:56s} {ms * 1e3:10.3f} {ms / base:12.2f}x")
    print(f"{'one float64 sweep (from 64 and 512 sweeps)':56s} {sweep * 1e3:10.3f} {sweep / base:12.2f}x")


if __name__ == "__main__":
    main()
