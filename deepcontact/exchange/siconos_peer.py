"""The Siconos side of the peer check, run by Debian's own /usr/bin/python3 (python3-siconos and
python3-h5py are built for it), never imported by deepcontact: it knows only the files.

For each FCLIB local problem given (2D), it solves with one of Siconos's 2D frictional-contact
solvers from zero and computes, with its own code, the normalised min-map residual
(max over rows |F| / max |q|, F_n = min(W_nn r_n, u_n), F_t = W_tt r_t - clip(W_tt r_t - u_t,
+-mu W_tt r_n)) of Siconos's answer and of the /solution stored in the file, if any. Prints one
JSON object: {"results": [{"file", "info", "seconds", "residual", "stored_residual"}, ...]}.

Usage: /usr/bin/python3 siconos_peer.py --solver lemke|nsgs|enum [--tolerance 1e-12] FILE...
"""
import argparse
import json
import sys
import time

import h5py
import numpy as np
import siconos.numerics as sn

SOLVERS = {"lemke": sn.SICONOS_FRICTION_2D_LEMKE, "nsgs": sn.SICONOS_FRICTION_2D_NSGS,
           "enum": sn.SICONOS_FRICTION_2D_ENUM}


def read(path):
    with h5py.File(path, "r") as f:
        W = f["fclib_local/W"]
        if int(f["fclib_local/spacedim"][0]) != 2 or int(W["nz"][0]) != -1:
            raise ValueError(f"{path}: not a 2D problem with W in CSC form")
        m, n = int(W["m"][0]), int(W["n"][0])
        p, i, x = W["p"][()], W["i"][()], W["x"][()]
        dense = np.zeros((m, n))
        for col in range(n):
            dense[i[p[col]:p[col + 1]], col] = x[p[col]:p[col + 1]]
        q, mu = f["fclib_local/vectors/q"][()], f["fclib_local/vectors/mu"][()]
        stored = f["solution/r"][()] if "solution" in f else None
    return dense, q, mu, stored


def residual(W, q, mu, r):
    u = W @ r + q
    kn, kt = np.diag(W)[0::2], np.diag(W)[1::2]
    rn, rt, un, ut = r[0::2], r[1::2], u[0::2], u[1::2]
    fn = np.minimum(kn * rn, un)
    hi = mu * kt * rn
    ft = np.where(mu > 0, kt * rt - np.clip(kt * rt - ut, -hi, hi), kt * rt)
    scale = max(np.abs(q[0::2]).max(initial=0.0), np.abs(np.where(mu > 0, q[1::2], 0.0)).max(initial=0.0), 1e-30)
    return float(max(np.abs(fn).max(initial=0.0), np.abs(ft).max(initial=0.0)) / scale)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--solver", choices=sorted(SOLVERS), default="lemke")
    ap.add_argument("--tolerance", type=float, default=1e-12)
    ap.add_argument("--iterations", type=int, default=100000)
    ap.add_argument("files", nargs="+")
    args = ap.parse_args()
    results = []
    for path in args.files:
        W, q, mu, stored = read(path)
        problem = sn.FrictionContactProblem(2, W, q, mu)
        options = sn.SolverOptions(SOLVERS[args.solver])
        options.dparam[sn.SICONOS_DPARAM_TOL] = args.tolerance
        if args.solver != "enum":
            options.iparam[sn.SICONOS_IPARAM_MAX_ITER] = args.iterations
        r, u = np.zeros(len(q)), np.zeros(len(q))
        t0 = time.perf_counter()
        info = sn.fc2d_driver(problem, r, u, options)
        seconds = time.perf_counter() - t0
        results.append({"file": path, "info": int(info), "seconds": seconds, "residual": residual(W, q, mu, r),
                        "stored_residual": None if stored is None else residual(W, q, mu, stored),
                        "reaction": r.tolist()})
    json.dump({"siconos": "numerics", "solver": args.solver, "results": results}, sys.stdout)


if __name__ == "__main__":
    main()
