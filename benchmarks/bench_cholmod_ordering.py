"""CHOLMOD's fill-reducing orderings on box-cantilever stiffness matrices (issue 21): NESDIS (physar's choice,
``physar.fem.solvers.CHOLMOD_ORDERING``: installs no signal handler) against CHOLMOD's default (AMD, then
METIS_NodeND, whose GKlib traps SIGTERM), METIS alone and AMD alone.

    python benchmarks/bench_cholmod_ordering.py [--cells NX NY NZ ...] [--repeat 3]

Prints a markdown table: free dofs, ordering, nnz(L), analysis and numeric factorisation seconds (best of
``--repeat``).
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
from sksparse import cholmod

from physar.fem import ElasticModel, FESpace, LinearElastic, fixed_dofs
from physar.geometry import box_mesh


def stiffness(cells):
    space = FESpace(box_mesh((1.0, 0.3, 0.3), cells), "P2")
    K = ElasticModel(space, LinearElastic(69e9, 0.334)).tangent_stiffness()
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, 0.3, 0.3]])
    free = np.setdiff1d(np.arange(space.n_dofs), fixed)
    return sp.csc_matrix(K[free][:, free])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cells", type=int, nargs=3, action="append")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print("| cells | free dofs | ordering | nnz(L) | analyse [s] | factorise [s] |")
    print("|---|---|---|---|---|---|")
    for cells in args.cells or [[20, 8, 8], [30, 10, 10]]:
        A = stiffness(cells)
        for method in ("nesdis", "default", "metis", "amd"):
            ta = tf = np.inf
            for _ in range(args.repeat):
                t = time.perf_counter()
                F = cholmod.analyze(A, ordering_method=method)
                t1 = time.perf_counter()
                F.cholesky_inplace(A)
                t2 = time.perf_counter()
                ta, tf = min(ta, t1 - t), min(tf, t2 - t1)
            print(f"| {' × '.join(map(str, cells))} | {A.shape[0]:,} | {method} | {F.L().nnz:.3e} | {ta:.2f} | "
                  f"{tf:.2f} |", flush=True)


if __name__ == "__main__":
    main()
