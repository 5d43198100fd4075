"""What does one sweep of our PGS cost, next to Box2D's own, in the same run?

Box2D's solver is not exported, so its cost per contact-iteration is measured as the difference
between a Step with 2N and one with N velocity iterations from the same state (the pile at step
300, about 190 contact points), divided by N x points. Ours: the same difference between solves
of that step with 2N and N sweeps (assembly cancels out). Also: the cost of the residual checked
after every sweep to stop on it (a tolerance never met), of recording the three convergence
measures every sweep, the slow Python reference, and what leaving out rows the scene
does not need (no friction: no tangent rows) saves.

Usage: python benchmarks/bench_solver.py [--repeats N] [--iterations N]
"""
import statistics
import sys
import time
from pathlib import Path

from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.solver.pgs import solve
from deepcontact.solver.problem import StepProblem

sys.path.insert(0, str(Path(__file__).parent.parent / "tests"))   # the slow reference lives with the tests
import reference_lcp as L  # noqa: E402
from common import arguments  # noqa: E402

WARMUP_STEPS = 300


def world_at(scene, steps):
    world = build_world(scene)
    for _ in range(steps):
        bodies, contacts = world.step(scene.dt, 8, 3, record=True)
    return world, bodies, contacts


def box2d_step_seconds(scene, iterations, repeats):
    times = []
    for _ in range(repeats):
        world, _, _ = world_at(scene, WARMUP_STEPS)
        t = time.perf_counter()
        world.step(scene.dt, iterations, 3)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def our_solve_seconds(problem, iterations, repeats, **kw):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        solve(problem, max_iterations=iterations, final_residual=False, **kw)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def per_contact_iteration(t_n, t_2n, n, points):
    return (t_2n - t_n) / (n * points) * 1e9


def main():
    args = arguments(__doc__, repeats=7, iterations=500)
    n, r = args.iterations, args.repeats
    scene = generate("pile", 0)
    _, bodies, contacts = world_at(scene, WARMUP_STEPS)
    problem = StepProblem.from_arrays(bodies, contacts, dt=scene.dt, gravity=scene.effects.gravity)
    points = problem.points
    rows = {}
    rows["Box2D Step (its own solver)"] = per_contact_iteration(
        box2d_step_seconds(scene, n, r), box2d_step_seconds(scene, 2 * n, r), n, points)
    for label, kw in [("ours, exact (float32)", dict(mode="exact")),
                      ("ours, float64", dict(mode="float64")),
                      ("ours, float64, stopping on the residual", dict(mode="float64", tolerance=1e-300,
                                                                       stop_on="residual")),
                      ("ours, float64 + 3 measures per sweep", dict(mode="float64", history=True))]:
        rows[label] = per_contact_iteration(our_solve_seconds(problem, n, r, **kw),
                                            our_solve_seconds(problem, 2 * n, r, **kw), n, points)
    lcp = L.build_lcp(problem)
    t = time.perf_counter()
    L.pgs(lcp, problem.start_normal, problem.start_tangent, 3)
    rows["Python reference (per row of the LCP)"] = (time.perf_counter() - t) / (3 * len(lcp.b)) * 1e9

    base = rows["Box2D Step (its own solver)"]
    print(f"pile, step {WARMUP_STEPS}: {points} contact points; {n} vs {2 * n} iterations, median of {r}")
    print(f"{'':42s}{'ns / contact-iteration':>24s}{'x Box2D':>9s}")
    for label, ns in rows.items():
        print(f"{label:42s}{ns:24.1f}{ns / base:9.2f}")

    # Only the effects a scene calls for: a frictionless scene has no tangent rows.
    confined = generate("confined", 0)
    _, b, c = world_at(confined, 200)
    p = StepProblem.from_arrays(b, c, dt=confined.dt, gravity=(0.0, 0.0))
    lean = our_solve_seconds(p, 200, r, mode="float64")
    full = our_solve_seconds(p, 200, r, mode="float64", prune=False)
    s_lean = solve(p, mode="float64", max_iterations=1).stats
    s_full = solve(p, mode="float64", max_iterations=1, prune=False).stats
    print(f"\nconfined (625 circles, no friction), {p.points} points, 200 sweeps:")
    print(f"  all rows     {s_full['normal_rows'] + s_full['tangent_rows']:5d} rows  {full * 1e3:7.3f} ms")
    print(f"  effects-only {s_lean['normal_rows'] + s_lean['tangent_rows']:5d} rows  {lean * 1e3:7.3f} ms"
          f"  ({full / lean:.2f}x faster, same impulses)")


if __name__ == "__main__":
    main()
