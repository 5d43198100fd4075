"""Time to a tolerance, ours against Siconos's 2D solvers, in one run.

The same step problems (held-out pile: seeds 1000-1001, every `--every`th step with contacts;
pyramid, base 20, every 50th step; with --scene pyramid40 the first five steps of a base-40
pyramid, 820 boxes, ours alone: Siconos's 2D solvers take W dense, 6,400 rows) are solved from zero to each tolerance by our solver
(every built-in method: float64 PGS, NNCG, proximal Newton, subspace minimization, the solve in
body space plain and with a lagged factor; in-process, assembly included) and by
Siconos 4.4 (`fc2d` NSGS with the same number as its tolerance, and Lemke on the pile; Debian's
python3-siconos in a subprocess on the FCLIB export of the same steps, its solve time alone).
Every answer is judged by the same measure, our normalised min-map residual (Siconos's by the
Siconos side's own code, which reproduces ours): NSGS's own stopping error is not ours, so a
solver "reaches" a tolerance only if its answer's residual is below it.

    dc study peer [--scene pile|pyramid|both|pyramid40] [--every 5] [--tolerances 1e-4,1e-8]
       [--cap 100000]
"""
import statistics
import tempfile
from pathlib import Path

from deepcontact.errors import InputError
from deepcontact.exchange import fclib, peer
from deepcontact.scene.generators import generate
from deepcontact.solver.methods import BUILTIN as OURS   # every built-in method (the native table)
from .exact import problems, timed
from .text import StudyText



def ours(steps, accelerate, tolerance, cap):
    runs = [timed(p, accelerate, tolerance, cap) for p in steps]
    return [t for _, t in runs], [s.residual for s, _ in runs]


def row(label, tolerance, times, residuals, out):
    reached = sum(r < tolerance for r in residuals)
    med = statistics.median(times)
    out(f"| {tolerance:g} | {label} | {reached} of {len(times)} | {max(residuals):.1e} | {med * 1e3:.2f} | "
          f"{sum(times):.2f} |")


def first_steps(base, count):
    """The first `count` steps with contacts of a pyramid, from its initial gaps."""
    scene = generate("pyramid", 0, {"base": base, "steps": count})
    return problems("pyramid", 1, [scene])


def solvers(name):
    """The solvers of a scene's table at each tolerance: ours, and Siconos's where it runs."""
    return len(OURS) + (0 if name == "pyramid40" else 2 if name == "pile" else 1)


def scenes(scene="both"):
    return ["pyramid40"] if scene == "pyramid40" else ["pile", "pyramid"] if scene == "both" else [scene]


def rows_count(scene="both", tolerances=(1e-4, 1e-8)):
    """The rows the study measures (what its progress counts)."""
    return sum(solvers(name) for name in scenes(scene)) * len(tolerances)


def report(name, steps, tolerances, cap, out, progress=lambda n: None):
    out(f"\n{name}: {len(steps)} steps, {statistics.mean(p.points for p in steps):.0f} contact points on average")
    out("| tolerance | solver | reach it (our residual) | worst residual | median ms | total s |")
    out("| ---: | --- | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        paths = [fclib.write_problem(p, Path(tmp) / f"step-{i:04d}.hdf5") for i, p in enumerate(steps)
                 if name != "pyramid40"]
        for tolerance in tolerances:
            for accelerate in OURS:
                row(f"ours, {accelerate}", tolerance, *ours(steps, accelerate, tolerance, cap), out)
                progress(1)
            if name == "pyramid40":
                continue
            results = peer.run(paths, "nsgs", tolerance)
            row("Siconos NSGS", tolerance, [r["seconds"] for r in results], [r["residual"] for r in results], out)
            progress(1)
            if name == "pile":   # Lemke on the pyramid's 1,600-row dense problems takes minutes a step
                results = peer.run(paths, "lemke", tolerance)
                row("Siconos Lemke", tolerance, [r["seconds"] for r in results], [r["residual"] for r in results],
                    out)
                progress(1)


def run(scene="both", every=5, tolerances=(1e-4, 1e-8), cap=100_000, out=None, progress=None) -> StudyText:
    """The study's tables (a StudyText; `out` one to add to); progress(1) as each row is measured
    (rows_count in all)."""
    if not peer.available():
        raise InputError("Siconos is not installed for /usr/bin/python3 (make setup installs python3-siconos)")
    out = StudyText() if out is None else out
    progress = progress or (lambda n: None)
    if scene == "pyramid40":
        report("pyramid40", first_steps(40, 5), list(tolerances), cap, out, progress)
        return out
    for name in scenes(scene):
        report(name, problems(name, every if name == "pile" else 50), list(tolerances), cap, out, progress)
    return out
