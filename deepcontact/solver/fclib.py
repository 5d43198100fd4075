"""A step's contact problem in FCLIB's HDF5 layout: the frictional-contact community's exchange
format (fclib_local: W, q, mu, spacedim 2), so that other solvers, Siconos among them, can be run
on exactly the problem our solver solves.

The local problem of FCLIB is: find r (per contact: normal r_n, tangent r_t) and u = W r + q with
Coulomb's law, 0 <= r_n complementary to u_n >= 0, |r_t| <= mu r_n, u_t = 0 inside the bound and
r_t = -mu r_n sign(u_t) when sliding. In 2D that is exactly the problem PGS solves: W = J M^-1 J^T
on the rows of the contact points the solver uses (per point its normal row, then its tangent
row), q = J v* - bias, from the native assembly (deepcontact._box2d.contact_rows), in float64. A
point of an ill-conditioned two-point manifold that Box2D drops is left out, as the solver leaves
it out.

File layout (fclib.c's writer, reproduced with h5py): /fclib_local/spacedim, /fclib_local/W (a
CSC matrix: nzmax, m, n, nz = -1, p, i, x), /fclib_local/vectors/{q, mu}, /fclib_local/info/
{title, description, math_info}; optionally /solution/{u, r} and /guesses (number_of_guesses,
then groups 1..N with u, r).
"""
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from .. import atomic, workers
from .._box2d import contact_rows
from ..errors import InputError
from ..step.run_folder import read_run
from .problem import StepProblem
from .reference import reference_solution


@dataclass
class LocalProblem:
    W: sp.csc_matrix      # (2m, 2m), per contact point its normal row, then its tangent row
    q: np.ndarray         # (2m,)
    mu: np.ndarray        # (m,)
    points: np.ndarray    # (m,) the problem's contact point (row of StepProblem.contacts) of each contact

    def reaction(self, normal, tangent):
        """Per-point impulses of the StepProblem as FCLIB's r."""
        r = np.empty(2 * len(self.points))
        r[0::2] = np.asarray(normal, np.float64)[self.points]
        r[1::2] = np.asarray(tangent, np.float64)[self.points]
        return r

    def impulses(self, r, count):
        """FCLIB's r back as per-point (normal, tangent) arrays of length count (0 where left out)."""
        normal, tangent = np.zeros(count), np.zeros(count)
        normal[self.points] = r[0::2]
        tangent[self.points] = r[1::2]
        return normal, tangent


def local_problem(problem) -> LocalProblem:
    """The step's problem as FCLIB's local problem (float64)."""
    rows = contact_rows(problem.bodies, problem.contacts, problem.settings(prune=False))
    points = np.nonzero(rows["active"])[0]
    m, nb = len(points), len(problem.bodies["inv_mass"])
    normal = rows["normal"][points]
    tangent = np.stack([normal[:, 1], -normal[:, 0]], axis=1)    # cross(normal, 1), as the solver
    a, b = rows["row_a"][points], rows["row_b"][points]
    r_a, r_b = rows["r_a"][points], rows["r_b"][points]
    # J: rows (2 per point) x body dofs (vx, vy, w per body)
    J_rows, J_cols, J_vals = [], [], []
    for k, d in ((0, normal), (1, tangent)):
        row = 2 * np.arange(m) + k
        cross_a = r_a[:, 0] * d[:, 1] - r_a[:, 1] * d[:, 0]
        cross_b = r_b[:, 0] * d[:, 1] - r_b[:, 1] * d[:, 0]
        for body, sign, cross in ((a, -1.0, cross_a), (b, 1.0, cross_b)):
            for dof, value in ((0, d[:, 0]), (1, d[:, 1]), (2, cross)):
                J_rows.append(row)
                J_cols.append(3 * body + dof)
                J_vals.append(sign * value)
    J = sp.csr_matrix((np.concatenate(J_vals), (np.concatenate(J_rows), np.concatenate(J_cols))),
                      shape=(2 * m, 3 * nb))
    inv_m = np.repeat(problem.bodies["inv_mass"].astype(np.float64), 3)
    inv_m[2::3] = problem.bodies["inv_inertia"].astype(np.float64)
    W = (J @ sp.diags(inv_m) @ J.T).tocsc()
    W.sort_indices()
    v = np.zeros(3 * nb)
    v[0::3], v[1::3], v[2::3] = rows["velocity"][:, 0], rows["velocity"][:, 1], rows["omega"]
    q = J @ v
    q[0::2] -= rows["bias"][points]
    return LocalProblem(W=W, q=q, mu=rows["friction"][points].astype(np.float64), points=points)


def write_problem(problem, path, *, solution=None, guess=None, title="", description="", lp=None):
    """Writes the step's problem (and optionally a solution and a guess, per-point (normal,
    tangent) pairs) to path as an FCLIB local problem, atomically; returns path. lp: the step's
    local_problem, where the caller has it already."""
    import h5py
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


def read_problem(path) -> LocalProblem:
    """An FCLIB local problem written by write_problem (points numbered 0..m-1)."""
    import h5py
    with h5py.File(path, "r") as f:
        W = f["fclib_local/W"]
        n = int(W["n"][0])
        matrix = sp.csc_matrix((W["x"][()], W["i"][()], W["p"][()]), shape=(int(W["m"][0]), n))
        q, mu = f["fclib_local/vectors/q"][()], f["fclib_local/vectors/mu"][()]
    return LocalProblem(W=matrix, q=q, mu=mu, points=np.arange(len(mu)))


def point_residuals(lp: LocalProblem, r) -> np.ndarray:
    """Per contact, the larger |F| of its normal and tangent rows (velocity units, unnormalised)."""
    u = lp.W @ r + lp.q
    k = lp.W.diagonal()
    kn, kt = k[0::2], k[1::2]
    rn, rt, un, ut = r[0::2], r[1::2], u[0::2], u[1::2]
    fn = np.minimum(kn * rn, un)
    hi = lp.mu * kt * rn
    ft = kt * rt - np.clip(kt * rt - ut, -hi, hi)
    ft = np.where(lp.mu > 0, ft, kt * rt)
    return np.maximum(np.abs(fn), np.abs(ft))


def residual_scale(lp: LocalProblem) -> float:
    """The residual's denominator: the step's largest free relative velocity (of the rows solved)."""
    return max(np.abs(lp.q[0::2]).max(initial=0.0), np.abs(np.where(lp.mu > 0, lp.q[1::2], 0.0)).max(initial=0.0), 1e-30)


def residual(lp: LocalProblem, r) -> float:
    """The solver's normalised min-map residual of r on the local problem (docs/solver.md)."""
    return float(point_residuals(lp, r).max(initial=0.0) / residual_scale(lp))


# What `dc export` writes (atomic.output_folder replaces nothing else).
EXPORT_FILES = atomic.Owned("FCLIB export", [r"seed-\d{6,}/", r"seed-\d{6,}/step-\d{6,}\.hdf5", r"index\.json"])
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
    run = read_run(run_dir)
    if not run.step_files:
        raise InputError("the run has no step files", run_dir)
    scene = run.manifest.get("scene", "scene")
    with atomic.output_folder(out, EXPORT_FILES, overwrite, command="export") as work:
        tasks = []
        for sim in run.simulations:
            (work / sim.dir).mkdir()
            tasks += [(path, work, sim.dir, sim.seed, scene, solution, k % every == 0) for k, path in enumerate(sim.files)]
        with workers.for_jobs(jobs, tasks, progress) as pool:
            index = [entry for entry in pool.imap(_export_step, tasks) if entry is not None]
        atomic.write_text(work / "index.json", json.dumps({"format": "fclib_local", "spacedim": 2,
                                                           "problems": index}, indent=1) + "\n")
    return index


def _export_step(task):
    """One step file as a local problem in the export's folder: its index entry, or None (a step
    left out by --every, or without contacts)."""
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

