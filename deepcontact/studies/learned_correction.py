"""Does a learned correction on the contact graph beat Box2D's warm start?

Data: the 100-circle thesis pile driven by our PGS in the loop (builtin start, residual < 1e-4,
cap 1000), where the builtin start is the previous step's solution at the tolerance. Training
seeds --train (default 0-3), held-out seed 1000; every step with contacts.

Model: studies/contact_graph.py's CorrectionNet, trained (Adam, fixed seed) on the residual
after --sweeps differentiable coloured Gauss-Seidel sweeps from the corrected start.

Reported on the held-out steps, each solved by the real solver (float64 PGS, Box2D's order and
block solver, residual < 1e-4, cap 1000) from builtin and from builtin + correction, at w = 1
and 1.7: median sweeps, median solve time and the median prediction time (torch on the CPU,
graph assembly included), each as a ratio to builtin at w = 1.

Result (docs/results.md, "Faster to the same accuracy"): no fewer sweeps than builtin, and a prediction
that costs several solves. Takes about 2 minutes with --train 0,1 --steps 300, 7 with 0,1,2,3.

    dc study learned-correction [--epochs N] [--sweeps K] [--rounds R] [--train 0,1,2,3] [--steps N] [--lr LR]
"""
import time

import numpy as np
import torch

from ..scene.generators import generate
from ..simulate.problems import problems as step_problems
from ..simulate.engines import Box2D
from ..solver.methods import solve
from ..solver.settings import SolveSettings
from . import contact_graph as cg
from .text import StudyText, progress

SETTINGS = SolveSettings()   # (float64, to a residual of TOLERANCE within CAP sweeps)


def loop_problems(seed, steps=600):
    """The problems the loop solved, each with the start it was given (the builtin start)."""
    scene = generate("pile", seed, {})
    engine = Box2D(solver=SETTINGS)
    return [problem for _, problem in step_problems(scene, engine, first=1, count=steps)]


def datasets(train, steps):
    """The loop steps of the training seeds (0, 1, ...) and every second step of held-out seed 1000."""
    t0 = time.perf_counter()
    train_set = [p for seed in train for p in loop_problems(int(seed), steps)]
    test_set = loop_problems(1000, steps)[::2]
    progress(f"data: {len(train_set)} training steps, {len(test_set)} held-out, {time.perf_counter() - t0:.1f} s")
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
        progress(msg + f", {time.perf_counter() - t0:.1f} s")
    return model


def evaluate(model, problems, out):
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
                s = solve(p, sn, st, settings=SETTINGS.but(relaxation=w), final_residual=False)
                best = min(best, time.perf_counter() - t0)
            rows[label].append((s.iterations, best))
    base_it = np.median([i for i, _ in rows["builtin"]])
    base_s = np.median([s for _, s in rows["builtin"]])
    out(f"held-out: {len(problems)} loop steps, residual < {SETTINGS.tolerance:g}, cap {SETTINGS.max_iterations}; "
          f"prediction {np.median(predict) * 1e3:.3f} ms median (Python + torch)")
    out(f"{'start':<14} {'median sweeps':>14} {'ratio':>6} {'median solve ms':>16} {'ratio':>6} "
          f"{'+ prediction':>13} {'ratio':>6}")
    for label, r in rows.items():
        it = np.median([i for i, _ in r])
        ms = np.median([s for _, s in r])
        extra = np.median(predict) if label.startswith("learned") else 0.0
        out(f"{label:<14} {it:>14.0f} {it / base_it:>6.2f} {ms * 1e3:>16.3f} {ms / base_s:>6.2f} "
              f"{(ms + extra) * 1e3:>13.3f} {(ms + extra) / base_s:>6.2f}")


def run(epochs=6, sweeps=32, batch=16, rounds=4, width=32, lr=3e-4, train_seeds=(0, 1, 2, 3), steps=600,
        out=None) -> StudyText:
    """The study's table (a StudyText; `out` one to add to), on held-out seed 1000."""
    out = StudyText() if out is None else out
    train_set, test_set = datasets(train_seeds, steps)
    model = train(train_set, epochs, sweeps, batch, seed=0, lr=lr, rounds=rounds, width=width)
    evaluate(model, test_set, out)
    return out
