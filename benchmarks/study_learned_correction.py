"""Does a learned correction on the contact graph beat Box2D's warm start?

Data: the 100-circle thesis pile driven by our PGS in the loop (builtin start, residual < 1e-4,
cap 1000), where the builtin start is the previous step's solution at the tolerance. Training
seeds --train (default 0-3), held-out seed 1000; every step with contacts.

Model: deepcontact.model.contact_graph.CorrectionNet, trained (Adam, fixed seed) on the residual
after --sweeps differentiable coloured Gauss-Seidel sweeps from the corrected start.

Reported on the held-out steps, each solved by the real solver (float64 PGS, Box2D's order and
block solver, residual < 1e-4, cap 1000) from builtin and from builtin + correction, at w = 1
and 1.7: median sweeps, median solve time and the median prediction time (torch on the CPU,
graph assembly included), each as a ratio to builtin at w = 1.

Result (docs/results.md, "Faster to the same accuracy"): no fewer sweeps than builtin, and a prediction
that costs several solves. Takes about 2 minutes with --train 0,1 --steps 300, 7 with 0,1,2,3.

Usage: python benchmarks/study_learned_correction.py [--epochs N] [--sweeps K] [--rounds R]
       [--train 0,1,2,3] [--steps N] [--lr LR]
"""
import argparse
import time

import numpy as np
import torch

from deepcontact.model import contact_graph as cg
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world
from deepcontact.simulate.pgs_loop import LoopOptions, PGSStepper
from deepcontact.solver.pgs import solve
from deepcontact.solver.problem import StepProblem
from deepcontact.protocol import current, protocol_line

SETTINGS = dict(mode="float64", max_iterations=1000, tolerance=1e-4, stop_on="residual")


def loop_problems(seed, steps=600):
    """The problems the loop solved, each with the start it was given (the builtin start)."""
    scene = generate("pile", seed, {})
    stepper = PGSStepper(build_world(scene), scene, LoopOptions(mode="float64", max_iterations=1000,
                                                                tolerance=1e-4, relaxation=1.0))
    out = []
    for k in range(steps):
        done = stepper.step()
        if done.solution is not None and k > 0:
            out.append(StepProblem.from_arrays(done.bodies, done.contacts, dt=scene.dt,
                                               gravity=scene.effects.gravity, index=k))
    return out


def datasets(train, steps):
    """The loop steps of the training seeds ("0,1") and every second step of held-out seed 1000."""
    t0 = time.perf_counter()
    train_set = [p for s in train.split(",") for p in loop_problems(int(s), steps)]
    test_set = loop_problems(1000, steps)[::2]
    print(f"data: {len(train_set)} training steps, {len(test_set)} held-out, {time.perf_counter() - t0:.1f} s",
          flush=True)
    return train_set, test_set


def train(problems, epochs, sweeps, batch, seed, lr=3e-4, rounds=2, width=32):
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = cg.CorrectionNet(width=width, rounds=rounds)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    graphs = [cg.graph_of(problems[i:i + batch]) for i in range(0, len(problems), batch)]
    for epoch in range(epochs):
        t0, total, base = time.perf_counter(), 0.0, 0.0
        for i in rng.permutation(len(graphs)):
            g = graphs[i]
            opt.zero_grad()
            value = cg.loss(model, g, sweeps)
            value.backward()
            opt.step()
            total += value.item()
            if epoch == 0:
                with torch.no_grad():
                    base += cg.loss(None, g, sweeps).item()
        msg = f"epoch {epoch + 1}: loss {total / len(graphs):.3f}"
        if epoch == 0:
            msg += f" (builtin {base / len(graphs):.3f})"
        print(msg + f", {time.perf_counter() - t0:.1f} s", flush=True)
    return model


def evaluate(model, problems):
    rows = {label: [] for label in ("builtin", "learned", "builtin@1.7", "learned@1.7")}
    predict = []
    for p in problems:
        t0 = time.perf_counter()
        with torch.no_grad():
            g = cg.graph_of([p])
            n, t = cg.corrected_start(model, g)
        n, t = n.numpy(), t.numpy()
        predict.append(time.perf_counter() - t0)
        for label, (sn, st, w) in {"builtin": (p.start_normal, p.start_tangent, 1.0), "learned": (n, t, 1.0),
                                   "builtin@1.7": (p.start_normal, p.start_tangent, 1.7),
                                   "learned@1.7": (n, t, 1.7)}.items():
            best = float("inf")
            for _ in range(3):
                t0 = time.perf_counter()
                s = solve(p, sn, st, relaxation=w, final_residual=False, **SETTINGS)
                best = min(best, time.perf_counter() - t0)
            rows[label].append((s.iterations, best))
    base_it = np.median([i for i, _ in rows["builtin"]])
    base_s = np.median([s for _, s in rows["builtin"]])
    print(f"held-out: {len(problems)} loop steps, residual < 1e-4, cap 1000; "
          f"prediction {np.median(predict) * 1e3:.3f} ms median (Python + torch)")
    print(f"{'start':<14} {'median sweeps':>14} {'ratio':>6} {'median solve ms':>16} {'ratio':>6} "
          f"{'+ prediction':>13} {'ratio':>6}")
    for label, r in rows.items():
        it = np.median([i for i, _ in r])
        ms = np.median([s for _, s in r])
        extra = np.median(predict) if label.startswith("learned") else 0.0
        print(f"{label:<14} {it:>14.0f} {it / base_it:>6.2f} {ms * 1e3:>16.3f} {ms / base_s:>6.2f} "
              f"{(ms + extra) * 1e3:>13.3f} {(ms + extra) / base_s:>6.2f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--epochs", type=int, default=6)
    ap.add_argument("--sweeps", type=int, default=32, help="differentiable sweeps before the loss (8 misleads: "
                                                          "it prefers zero to builtin)")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=4, help="message-passing rounds")
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--train", default="0,1,2,3")
    ap.add_argument("--steps", type=int, default=600)
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")   # how these times were taken
    train_set, test_set = datasets(args.train, args.steps)
    model = train(train_set, args.epochs, args.sweeps, args.batch, seed=0, lr=args.lr, rounds=args.rounds,
                  width=args.width)
    evaluate(model, test_set)


if __name__ == "__main__":
    main()
