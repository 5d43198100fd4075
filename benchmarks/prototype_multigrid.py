"""The gate of a nonsmooth multigrid, measured before any native code: does a method whose cost
should not grow with the pile's depth bring each step of the settled rigid pile to 1e-4 in a few
cycles? (docs/results/multigrid.md)

The 1000-circle pile (seed 9) settles under Box2D at its 8 iterations for --settle steps; then the
loop steps it (collide, solve, write the impulses, Box2D's Step with 0 velocity iterations) for
--steps steps. Each step's contact problem (u = W r + q, solver/local.py) is solved from Box2D's
warm start by every variant, each a truncated nonsmooth Newton multigrid cycle (TNNMG, Graeser, Sack
and Sander) on Coulomb's law as a fixed point of Tresca problems:

  pre-smoothing   NU sweeps of the project's native PGS (PSOR at w), on the whole friction cone;
  truncation      the impulses put in the cone (r_n >= 0, |r_t| <= mu r_n: the Tresca bound of this
                  cycle); the rows strictly inside their bounds are free, those at a bound are held
                  (TNNMG's truncation): the free normal rows, and with `cone` the free tangent rows;
  coarse          the defect system W_FF d_F = -u_F of the free rows, W_FF made definite by
                  --regularisation of its diagonal (a rigid pile has more rows than degrees of
                  freedom), solved by pyamg's smoothed (or root-node: --aggregation) aggregation
                  hierarchy of W_FF, built each cycle (--coarse-iterations V-cycles, as a
                  preconditioner of conjugate gradients);
  projection      d' = clip(r + d) - r, the correction projected onto the Tresca box, then the exact
                  minimiser of the Tresca energy 1/2 r.W r + q.r along d' in [0, 1] (a convex
                  quadratic: the step never raises it);
  post-smoothing  NU sweeps again.

A variant `none` is the same sweeps without the coarse step (smoothing alone: what the coarse
correction must beat). A variant is KIND:NU:W, e.g. cone:5:1.7. A step counts the cycles until the
project's residual (solver/local.py: the min-map residual every solve reports) is below
--tolerance, at most --most. The trajectory goes on with the first variant's answer where it
reached the tolerance, else with PSOR's (w = 1.7 from the same start, cap 10,000 sweeps: the
scale, also counted each step).

The gate, set before building anything native: go if the median step reaches 1e-4 within 10 cycles and every step within
40, judged on the best variant. Times are Python's and scipy's (a prototype), per cycle against one
sweep of the native PSOR on the same step; one thread (OMP, OpenBLAS and MKL set to 1 here).

Needs pyamg (pip install '.[prototype]').

Usage: python benchmarks/prototype_multigrid.py [--settle N] [--steps N] [--seed S] [--most N]
           [--tolerance T] [--variants KIND:NU:W,...] [--coarse-iterations K]
           [--aggregation smoothed|rootnode] [--regularisation R]
"""
import os
import sys

if __name__ == "__main__":   # (one thread, before numpy loads its BLAS)
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_var] = "1"

import argparse
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

try:
    import pyamg
except ImportError:
    pyamg = None

from deepcontact.protocol import current, protocol_line
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.solver.local import local_problem, residual
from deepcontact.solver.methods import solve
from deepcontact.solver.problem import StepProblem
from deepcontact.solver.settings import SolveSettings

INSTALL_HINT = "prototype_multigrid.py needs pyamg: pip install '.[prototype]' (or pip install pyamg==5.4.1)"
AGGREGATIONS = {"smoothed": "smoothed_aggregation_solver", "rootnode": "rootnode_solver"}   # pyamg's hierarchies
KINDS = ("none", "normal", "cone")   # the rows the coarse step frees: none, the normal rows, normal and tangent
PSOR_CAP = 10_000


@dataclass(frozen=True)
class Variant:
    kind: str     # one of KINDS
    sweeps: int   # pre- and post-smoothing sweeps each
    w: float      # the smoother's over-relaxation

    @property
    def name(self):
        return f"{self.kind}:{self.sweeps}:{self.w:g}"


def parse_variants(text):
    """Variants from KIND:NU:W,...; a bad one is an argparse error (exit 2)."""
    out = []
    for item in text.split(","):
        parts = item.strip().split(":")
        try:
            kind, nu, w = parts[0], int(parts[1]), float(parts[2])
        except (IndexError, ValueError):
            raise argparse.ArgumentTypeError(f"{item!r} is not KIND:NU:W (e.g. cone:5:1.7)") from None
        if kind not in KINDS or nu < 1 or not 0 < w < 2 or len(parts) != 3:
            raise argparse.ArgumentTypeError(f"{item!r}: KIND one of {', '.join(KINDS)}, NU >= 1, 0 < W < 2")
        out.append(Variant(kind, nu, w))
    return out


class StepSolve:
    """One step's contact problem and the pieces a cycle is made of."""

    def __init__(self, problem, coarse_iterations, regularisation, aggregation):
        self.problem = problem
        self.lp = local_problem(problem)
        self.W = self.lp.W.tocsr()
        self.coarse_iterations = coarse_iterations
        self.regularisation = regularisation   # of W_FF's diagonal: definite, small beside the rows' own stiffness
        self.hierarchy = AGGREGATIONS[aggregation]
        self.breakdowns = 0   # coarse steps skipped: pyamg's hierarchy or its solve not finite

    def smooth(self, r, sweeps, w):
        """r after `sweeps` sweeps of the native PGS (PSOR at w) from r."""
        normal, tangent = self.lp.impulses(r, self.problem.points)
        s = solve(self.problem, normal, tangent, final_residual=False,
                  settings=SolveSettings(max_iterations=sweeps, tolerance=0.0, relaxation=w, guard=False))
        return self.lp.reaction(s.normal_impulse, s.tangent_impulse)

    def bounds(self, r):
        """The Tresca bound of each tangent row (this cycle's): mu r_n, r_n put at >= 0."""
        return self.lp.mu * np.maximum(r[0::2], 0.0)

    def clip(self, r, bound):
        """r in the Tresca box: r_n >= 0, |r_t| <= bound."""
        out = r.copy()
        out[0::2] = np.maximum(r[0::2], 0.0)
        out[1::2] = np.clip(r[1::2], -bound, bound)
        return out

    def free_rows(self, r, bound, kind):
        """The rows strictly inside their bounds (TNNMG's truncation holds the others)."""
        free = np.zeros(len(r), bool)
        free[0::2] = r[0::2] > 0.0
        if kind == "cone":
            free[1::2] = np.abs(r[1::2]) < bound * (1.0 - 1e-12)
        return np.flatnonzero(free)

    def coarse_direction(self, rows, u):
        """d on the free rows: pyamg's aggregation V-cycles on W_FF d = -u_F (CG-accelerated)."""
        WF = self.W[rows][:, rows]
        WF = (WF + sp.diags(self.regularisation * WF.diagonal())).tocsr()
        np.random.seed(0)   # (pyamg estimates spectral radii from a random vector: the same one every build)
        d = np.zeros(self.W.shape[0])
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):   # (a d not finite is counted)
            hierarchy = getattr(pyamg, self.hierarchy)(WF, max_coarse=50)
            d[rows] = hierarchy.solve(-u[rows], x0=np.zeros(len(rows)), tol=1e-12,
                                      maxiter=self.coarse_iterations, accel="cg")
        return d

    def line_search(self, r, u, d, bound):
        """(r moved along its projected correction by the exact minimiser in [0, 1], that step, the
        rows the projection moved)."""
        dp = self.clip(r + d, bound) - r
        clipped = int(np.count_nonzero(np.abs(dp - d) > 1e-12 * np.abs(d).max(initial=0.0)))
        curvature = dp @ (self.W @ dp)
        if curvature <= 0.0:
            return r, 0.0, clipped
        alpha = min(1.0, max(0.0, -(dp @ u) / curvature))
        return r + alpha * dp, alpha, clipped

    def coarse_step(self, r, kind):
        """One truncated, projected coarse correction: (r, its step length, rows clipped)."""
        bound = self.bounds(r)
        r = self.clip(r, bound)
        rows = self.free_rows(r, bound, kind)
        if not len(rows):
            return r, 0.0, 0
        u = self.W @ r + self.lp.q
        try:
            d = self.coarse_direction(rows, u)
        except ValueError:   # (a coarse operator with NaN in it: pyamg's pinv refuses it)
            d = np.full(len(r), np.nan)
        if not np.isfinite(d).all():
            self.breakdowns += 1
            return r, 0.0, 0
        return self.line_search(r, u, d, bound)

    def cycle(self, r, variant):
        """One cycle: (r, the coarse step's length and rows clipped, nan without one)."""
        r = self.smooth(r, variant.sweeps, variant.w)
        alpha, clipped = np.nan, np.nan
        if variant.kind != "none":
            r, alpha, clipped = self.coarse_step(r, variant.kind)
        return self.smooth(r, variant.sweeps, variant.w), alpha, clipped

    def run(self, r, variant, most, tolerance):
        """(r, cycles to the tolerance or inf, seconds a cycle, (step length, rows clipped) a cycle):
        the residual checked after each cycle, its time left out (the native sweeps' too)."""
        seconds, coarse = 0.0, []
        for cycles in range(1, most + 1):
            t = time.perf_counter()
            r, alpha, clipped = self.cycle(r, variant)
            seconds += time.perf_counter() - t
            coarse.append((alpha, clipped))
            if residual(self.lp, r) < tolerance:
                return r, cycles, seconds / cycles, coarse
        return r, np.inf, seconds / most, coarse


def sweep_seconds(step, r, sweeps=200):
    """One sweep of the native PSOR (w = 1.7) on this step, from r: a fixed count timed together."""
    t = time.perf_counter()
    step.smooth(r, sweeps, 1.7)
    return (time.perf_counter() - t) / sweeps


def psor_to_tolerance(step, r, tolerance):
    """(r, sweeps or inf): PSOR at w = 1.7 from r to the tolerance (the scale; the fallback)."""
    normal, tangent = step.lp.impulses(r, step.problem.points)
    s = solve(step.problem, normal, tangent, settings=SolveSettings(max_iterations=PSOR_CAP, tolerance=tolerance,
                                                                      relaxation=1.7))
    reached = s.residual < tolerance
    return step.lp.reaction(s.normal_impulse, s.tangent_impulse), (s.iterations if reached else np.inf)


def settled_pile(args):
    """The 1000-circle pile, settled under Box2D's own solver for --settle steps."""
    scene = generate("pile", args.seed, dict(count=1000, box=95.0, sigma=19.0, steps=args.settle + args.steps + 1))
    world = build_world(scene)
    for _ in range(args.settle):
        world.step(scene.dt, 8, scene.solver.position_iterations)
    return world, scene


def step_world(world, scene, normal, tangent):
    """The loop's Box2D step with these impulses (Collide has run on these positions)."""
    if normal is not None:
        world.set_manifold_impulses(np.asarray(normal, np.float32), np.asarray(tangent, np.float32))
    world.inv_dt0 = 1.0 / scene.dt
    world.step(scene.dt, 0, scene.solver.position_iterations, collided=True)


def next_problem(world, scene):
    """The step's problem after Collide, or None (no contact: the step is taken here)."""
    bodies = world.bodies()
    world.collide()
    contacts = world.contacts()
    if not len(contacts["manifold"]):
        step_world(world, scene, None, None)
        return None
    return StepProblem.from_arrays(bodies, contacts, dt=scene.dt, gravity=scene.effects.gravity,
                                   block_solve=scene.solver.block_solve, velocity_iterations=8)


def solve_one_step(step, args, figures):
    """Every variant and PSOR on this step from Box2D's warm start; the answer the loop goes on with."""
    start = step.lp.reaction(step.problem.start_normal, step.problem.start_tangent)
    figures["points"].append(len(step.lp.points))
    figures["start_residual"].append(residual(step.lp, start))
    figures["sweep"].append(sweep_seconds(step, start))
    answer = None
    for variant in args.variants:
        before = step.breakdowns
        r, cycles, seconds, coarse = step.run(start, variant, args.most, args.tolerance)
        row = figures[variant.name]
        row["breakdowns"].append(step.breakdowns - before)
        row["cycles"].append(cycles)
        row["seconds"].append(seconds)
        row["end_residual"].append(residual(step.lp, r))
        row["alpha"].extend(a for a, _ in coarse if np.isfinite(a))
        row["clipped"].extend(c for _, c in coarse if np.isfinite(c))
        if variant is args.variants[0] and np.isfinite(cycles):
            answer = r
    r, sweeps = psor_to_tolerance(step, start, args.tolerance)
    figures["psor"].append(sweeps)
    return r if answer is None else answer


def run_loop(world, scene, args):
    """The loop's steps, each solved by every variant: the gate's figures, per step."""
    figures = {k: [] for k in ("points", "start_residual", "sweep", "psor")}
    for variant in args.variants:
        figures[variant.name] = {k: [] for k in ("cycles", "seconds", "end_residual", "alpha", "clipped", "breakdowns")}
    for _ in range(args.steps):
        problem = next_problem(world, scene)
        if problem is None:
            continue
        step = StepSolve(problem, args.coarse_iterations, args.regularisation, args.aggregation)
        r = solve_one_step(step, args, figures)
        normal, tangent = step.lp.impulses(r, problem.points)
        step_world(world, scene, normal, tangent)
    return figures


def passes_gate(cycles):
    """The gate: the median step within 10 cycles, every step within 40."""
    return bool(np.median(cycles) <= 10 and np.all(cycles <= 40))


def variant_line(name, row, sweep):
    """One variant's line: cycles to the tolerance, within 10 and 40, time a cycle in sweeps."""
    cycles, ends = np.array(row["cycles"]), np.array(row["end_residual"])
    alpha = np.array(row["alpha"]) if row["alpha"] else np.array([np.nan])
    steps = "no coarse step"
    if np.isfinite(alpha).any():
        steps = (f"coarse step length median {np.median(alpha):.2g}, rows its projection clips median "
                 f"{np.median(row['clipped']):.0f}")
    if sum(row["breakdowns"]):
        steps += f" ({sum(row['breakdowns'])} skipped: the hierarchy not finite)"
    return (f"  {name:>14}: cycles median {np.median(cycles):.0f}, max {cycles.max():.0f}; within 10: "
            f"{100 * np.mean(cycles <= 10):.0f}%, within 40: {100 * np.mean(cycles <= 40):.0f}%; residual after "
            f"the cycles median {np.median(ends):.2g}; a cycle {1e3 * np.median(row['seconds']):.1f} ms = "
            f"{np.median(row['seconds']) / sweep:.0f} sweeps; {steps}; gate {'GO' if passes_gate(cycles) else 'NO-GO'}")


def report(figures, args):
    """The gate's lines, and its verdict on the best variant."""
    sweep, psor = float(np.median(figures["sweep"])), np.array(figures["psor"])
    print(f"the 1000-circle pile (seed {args.seed}) in the loop, steps {args.settle + 1}-{args.settle + args.steps}: "
          f"{len(psor)} steps with contacts, {np.median(figures['points']):.0f} contact points (median); tolerance "
          f"{args.tolerance:g}, at most {args.most} cycles; coarse solve {args.coarse_iterations} CG-accelerated "
          f"V-cycle(s) of pyamg {pyamg.__version__}'s {args.aggregation} aggregation, the system's diagonal "
          f"+{args.regularisation:g}")
    print(f"  Box2D's warm start: residual median {np.median(figures['start_residual']):.2g}; PSOR 1.7 from it: "
          f"sweeps median {np.median(psor):.0f}, max {psor.max():.0f} ({int(np.sum(~np.isfinite(psor)))} above "
          f"{PSOR_CAP}); one native sweep {1e3 * sweep:.3f} ms (median)")
    for variant in args.variants:
        print(variant_line(variant.name, figures[variant.name], sweep))
    best = min(args.variants, key=lambda v: (np.median(figures[v.name]["cycles"]), np.max(figures[v.name]["cycles"]),
                                             np.median(figures[v.name]["end_residual"])))
    go = passes_gate(np.array(figures[best.name]["cycles"]))
    print(f"  gate (median step within 10 cycles, every step within 40), best variant {best.name}: "
          f"{'GO' if go else 'NO-GO'}")


def arguments():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--settle", type=int, default=300)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--most", type=int, default=40, help="cycles at most a step")
    ap.add_argument("--tolerance", type=float, default=1e-4)
    ap.add_argument("--variants", type=parse_variants, default=parse_variants("none:5:1.7,normal:5:1.7,normal:2:1,cone:5:1.7,cone:2:1"),
                    help="KIND:NU:W,... (KIND none, normal or cone; NU sweeps before and after; W the smoother's w)")
    ap.add_argument("--coarse-iterations", type=int, default=3,
                    help="V-cycles of the coarse solve (conjugate gradients preconditioned by them)")
    ap.add_argument("--aggregation", choices=tuple(AGGREGATIONS), default="smoothed",
                    help="pyamg's aggregation of the coarse system: smoothed or root-node")
    ap.add_argument("--regularisation", type=float, default=1e-6,
                    help="added to the coarse system's diagonal, relative to it (W_FF is singular on a rigid pile)")
    args = ap.parse_args()
    if args.settle < 0 or args.steps < 1 or args.most < 1 or args.coarse_iterations < 1 or not args.tolerance > 0 \
            or not args.regularisation > 0:
        ap.error("--settle >= 0, --steps, --most and --coarse-iterations >= 1, --tolerance and --regularisation > 0")
    return args


def main():
    args = arguments()
    if pyamg is None:
        print(INSTALL_HINT, file=sys.stderr)
        sys.exit(1)
    print(protocol_line(current()).rstrip(".") + "; OMP, OpenBLAS and MKL threads set to 1.\n")
    world, scene = settled_pile(args)
    report(run_loop(world, scene, args), args)


if __name__ == "__main__":
    main()
