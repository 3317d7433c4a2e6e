"""Assemble + solve linear elasticity on ~100k tets: physar vs scikit-fem in the same run.

    python benchmarks/bench_fem.py [--cells NX NY NZ] [--element P1 P2]

Prints a markdown table (times in seconds, ratio = scikit-fem / physar, > 1 means physar is faster).
scikit-fem is run with its default solver (scipy spsolve) and, to separate assembly from the solver,
with the same CHOLMOD factorisation physar uses.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from skfem_peer import skfem_cantilever

from physar.fem import (
    ElasticModel,
    FESpace,
    LinearElastic,
    LinearSolver,
    fixed_dofs,
    has_cholmod,
    probe,
    traction_load,
)
from physar.geometry import box_mesh

L, B, H, E, NU, P = 1.0, 0.1, 0.1, 69e9, 0.334, 1000.0


def physar_run(mesh, element):
    t0 = time.perf_counter()
    space = FESpace(mesh, element)
    model = ElasticModel(space, LinearElastic(E, NU))
    model.tangent_stiffness()
    f = traction_load(space, [[L, 0, 0], [L, B, H]], [0, 0, -P])
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, B, H]])
    t1 = time.perf_counter()
    solver = LinearSolver(model, fixed)
    u = solver.solve(f)
    t2 = time.perf_counter()
    u2 = solver.solve(0.5 * f)  # re-solve with the same factorisation (reduced-model builders)
    t3 = time.perf_counter()
    assert np.allclose(u2, 0.5 * u)
    return probe(space, u, [L, B / 2, H / 2]), {"assemble": t1 - t0, "solve": t2 - t1, "resolve": t3 - t2}, space.n_dofs


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cells", type=int, nargs=3, default=[50, 20, 17])
    ap.add_argument("--element", nargs="+", default=["P1", "P2"])
    ap.add_argument("--skip-spsolve-above", type=int, default=200_000, help="dofs")
    a = ap.parse_args()
    mesh = box_mesh((L, B, H), a.cells)
    print(f"mesh {a.cells} -> {mesh.n_cells} tets; CHOLMOD available: {has_cholmod()}; "
          f"{platform.processor() or platform.machine()}, numpy {np.__version__}\n")
    print("| element | dofs | physar assemble | physar solve | physar total | physar re-solve "
          "| skfem assemble | skfem+spsolve total | skfem+CHOLMOD total | ratio (skfem default / physar) "
          "| ratio (skfem+CHOLMOD / physar) | assembly ratio | tip rel. diff |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for el in a.element:
        tip, tp, n = physar_run(mesh, el)
        tc = {}
        peer = skfem_cantilever(mesh, el, E, NU, L, B, H, P, solver="cholmod", timings=tc)
        diff = abs(peer[2] - tip[2]) / abs(peer[2])
        if n <= a.skip_spsolve_above:
            td = {}
            skfem_cantilever(mesh, el, E, NU, L, B, H, P, solver="default", timings=td)
            sp_total = td["assemble"] + td["solve"]
            sp_txt, sp_ratio = f"{sp_total:.2f}", f"{sp_total / (tp['assemble'] + tp['solve']):.2f}"
        else:
            sp_txt, sp_ratio = "skipped", "-"
        ours = tp["assemble"] + tp["solve"]
        chol = tc["assemble"] + tc["solve"]
        print(f"| {el} | {n} | {tp['assemble']:.2f} | {tp['solve']:.2f} | {ours:.2f} | {tp['resolve']:.3f} "
              f"| {tc['assemble']:.2f} | {sp_txt} | {chol:.2f} | {sp_ratio} | {chol / ours:.2f} "
              f"| {tc['assemble'] / tp['assemble']:.2f} | {diff:.1e} |", flush=True)


if __name__ == "__main__":
    main()
