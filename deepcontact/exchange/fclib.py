"""A step's contact problem in FCLIB's HDF5 layout: the frictional-contact community's exchange
format (fclib_local: W, q, mu, spacedim 2), so that other solvers, Siconos among them, can be run
on exactly the problem our solver solves: the step's local problem (solver/local.py), which is
FCLIB's local problem in 2D.

File layout (fclib.c's writer, reproduced with h5py): /fclib_local/spacedim, /fclib_local/W (a
CSC matrix: nzmax, m, n, nz = -1, p, i, x), /fclib_local/vectors/{q, mu}, /fclib_local/info/
{title, description, math_info}; optionally /solution/{u, r} and /guesses (number_of_guesses,
then groups 1..N with u, r).
"""
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import output, workers
from ..errors import InputError
from ..solver.problem import StepProblem
from ..step.run_folder import read_run

if TYPE_CHECKING:
    from ..solver.local import LocalProblem

# scipy (the local problem's sparse W) is imported by the functions that build or read one, so
# that `dc export --help` and the option's vocabulary below cost no more than the CLI.


def write_problem(problem, path, *, solution=None, guess=None, title="", description="", lp=None):
    """Writes the step's problem (and optionally a solution and a guess, per-point (normal,
    tangent) pairs) to path as an FCLIB local problem, atomically; returns path. lp: the step's
    local_problem, where the caller has it already."""
    import h5py

    from ..solver.local import local_problem
    path = Path(path)
    lp = local_problem(problem) if lp is None else lp
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        with h5py.File(tmp, "w") as f:
            root = f.create_group("fclib_local")
            root.create_dataset("spacedim", data=np.array([2], np.int32))
            W = root.create_group("W")
            for key, value in (("nzmax", lp.W.nnz), ("m", lp.W.shape[0]), ("n", lp.W.shape[1]), ("nz", -1)):
                W.create_dataset(key, data=np.array([value], np.int32))
            W.create_dataset("p", data=lp.W.indptr.astype(np.int32))
            W.create_dataset("i", data=lp.W.indices.astype(np.int32))
            W.create_dataset("x", data=lp.W.data.astype(np.float64))
            vectors = root.create_group("vectors")
            vectors.create_dataset("q", data=lp.q)
            vectors.create_dataset("mu", data=lp.mu)
            info = root.create_group("info")
            info.create_dataset("title", data=title or f"deepcontact step {problem.index}")
            info.create_dataset("description", data=description or "a Box2D 2.4.1 step's velocity-level contact problem")
            info.create_dataset("math_info", data="2D Coulomb friction, impulses; u = W r + q; per contact (normal, tangent)")
            for group, pair in (("solution", solution), ("guesses/1", guess)):
                if pair is None:
                    continue
                r = lp.reaction(*pair)
                g = f.create_group(group)
                g.create_dataset("r", data=r)
                g.create_dataset("u", data=lp.W @ r + lp.q)
            if guess is not None:
                f["guesses"].create_dataset("number_of_guesses", data=np.array([1], np.int32))
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def read_problem(path) -> "LocalProblem":
    """An FCLIB local problem written by write_problem (points numbered 0..m-1)."""
    import h5py
    import scipy.sparse as sp

    from ..solver.local import LocalProblem
    with h5py.File(path, "r") as f:
        W = f["fclib_local/W"]
        n = int(W["n"][0])
        matrix = sp.csc_matrix((W["x"][()], W["i"][()], W["p"][()]), shape=(int(W["m"][0]), n))
        q, mu = f["fclib_local/vectors/q"][()], f["fclib_local/vectors/mu"][()]
    return LocalProblem(W=matrix, q=q, mu=mu, points=np.arange(len(mu)))


# What `dc export` writes (output.output_folder replaces nothing else).
EXPORT_FILES = output.Owned("FCLIB export", [r"seed-\d{6,}/", r"seed-\d{6,}/step-\d{6,}\.hdf5", r"index\.json"])
SOLUTIONS = ("reference", "recorded", "none")


def export_run(run_dir, out, *, every=1, solution="reference", overwrite=False, progress=None, jobs=1):
    """Every `every`-th step of a run with contacts, as FCLIB local problems under
    out/seed-NNNNNN/step-NNNNNN.hdf5, each with the step's recorded start as its guess and, with
    solution="reference", the reference solution (or "recorded": what the run's solver produced)
    as /solution; out/index.json lists the files with their sizes and the solution's residual.
    Written atomically (a partial export never stands). jobs > 1: steps side by side in worker
    processes (the same files, byte for byte, and the same index). progress(n): n more step
    files done. Returns the index."""
    if solution not in SOLUTIONS:
        raise InputError(f"solution must be one of {', '.join(SOLUTIONS)}, not {solution!r}")
    run = read_run(run_dir, problem="export writes each step's")
    if not run.step_files:
        raise InputError("the run has no step files", run_dir)
    scene = run.manifest.get("scene", "scene")
    with output.output_folder(out, EXPORT_FILES, overwrite, command="export") as work:
        tasks = []
        for sim in run.simulations:
            output.make_dir(work / sim.dir)
            tasks += [(path, work, sim.dir, sim.seed, scene, solution, k % every == 0) for k, path in enumerate(sim.files)]
        with workers.for_jobs(jobs, tasks, progress) as pool:
            index = [entry for entry in pool.imap(_export_step, tasks) if entry is not None]
        output.write_text(work / "index.json", json.dumps({"format": "fclib_local", "spacedim": 2,
                                                           "problems": index}, indent=1) + "\n")
    return index


def _export_step(task):
    """One step file as a local problem in the export's folder: its index entry, or None (a step
    left out by --every, or without contacts)."""
    from ..solver.local import local_problem, residual
    from ..solver.reference import reference_solution  # (scipy, for its pivots: not at the command's start)
    path, work, folder, seed, scene, solution, wanted = task
    workers.progress(1)
    if not wanted:
        return None
    problem = StepProblem.from_step_file(path)
    if not problem.points:
        return None
    pair, stored = None, None   # the stored solution and its residual
    if solution == "reference":
        s = reference_solution(problem)
        pair, stored = (s.normal_impulse, s.tangent_impulse), s.residual
    elif solution == "recorded":
        pair = (problem.normal_impulse, problem.tangent_impulse)
    name = f"{folder}/{path.stem}.hdf5"
    lp = local_problem(problem)
    write_problem(problem, work / name, solution=pair, guess=(problem.start_normal, problem.start_tangent),
                  title=f"{scene} seed {seed} step {problem.index}", lp=lp)
    if pair is not None and stored is None:
        stored = residual(lp, lp.reaction(*pair))
    return {"file": name, "seed": seed, "step": problem.index, "contacts": int(problem.points),
            "solution": solution, "residual": stored}

