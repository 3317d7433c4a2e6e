"""Linear elasticity on a box cantilever: physar (direct and AMG) vs scikit-fem, time and memory.

    python benchmarks/bench_fem.py [--cells NX NY NZ] [--element P1 P2]        # one mesh, vs scikit-fem
    python benchmarks/bench_fem.py --scaling [--p1 NX NY NZ ...] [--p2 ...]    # three sizes per element

The first form prints the assembly/solve table of issue 2 (scikit-fem with its default solver and with
CHOLMOD). `--scaling` runs every case in its own process (peak memory = that process's max RSS) for
physar `linear = "direct"` (CHOLMOD), physar `linear = "amg"` (CG + smoothed aggregation, rigid-body
near-nullspace, relative residual 1e-10) and scikit-fem + pyamg (same CG tolerance, pyamg's default
smoothed aggregation with the rigid-body modes), prints a markdown table of dofs, assembly/solve/total
seconds, peak memory, CG iterations and tip deflection, then the exponents p of time ∝ dofs^p fitted over
the sizes. The direct solver is skipped where its estimated factor exceeds half the available memory
(`physar.fem.solvers.direct_memory_estimate`) or `--direct-max-dofs`.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
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
    solve_static,
    traction_load,
)
from physar.geometry import box_mesh

L, B, H, E, NU, P = 1.0, 0.1, 0.1, 69e9, 0.334, 1000.0
RTOL = 1e-10
P1_SIZES = [(100, 20, 20), (140, 28, 28), (200, 40, 40)]  # 134k, 356k, 1.01M dofs
P2_SIZES = [(40, 8, 8), (60, 12, 12), (80, 16, 16)]      # 70k, 227k, 526k dofs


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


def compare(a):
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


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def run_case(element: str, method: str, cells) -> dict:
    """One solve in this process: {'dofs', 'assemble', 'solve', 'peak_gb', 'iterations', 'tip'}."""
    mesh = box_mesh((L, B, H), cells)
    out = {"element": element, "method": method, "cells": list(cells)}
    if method == "skfem-amg":
        t, info = {}, {}
        tip = skfem_cantilever(mesh, element, E, NU, L, B, H, P, solver="amg", timings=t, rtol=RTOL, info=info)
        out.update(dofs=3 * (FESpace(mesh, element).n_nodes), assemble=t["assemble"], solve=t["solve"],
                   iterations=info["iterations"], tip=float(tip[2]))
    else:
        t0 = time.perf_counter()
        space = FESpace(mesh, element)
        model = ElasticModel(space, LinearElastic(E, NU))
        model.tangent_stiffness()
        f = traction_load(space, [[L, 0, 0], [L, B, H]], [0, 0, -P])
        fixed = fixed_dofs(space, box=[[0, 0, 0], [0, B, H]])
        t1 = time.perf_counter()
        res = solve_static(model, f, fixed, tol=RTOL, linear=method.removeprefix("physar-"))
        t2 = time.perf_counter()
        out.update(dofs=space.n_dofs, assemble=t1 - t0, solve=t2 - t1,
                   iterations=sum(res.cg_iterations) if res.cg_iterations else None,
                   tip=float(probe(space, res.u, [L, B / 2, H / 2])[2]))
    out["peak_gb"] = _peak_gb()
    return out


def _fit(rows, key):
    x = np.log([r["dofs"] for r in rows])
    y = np.log([r[key] for r in rows])
    return float(np.polyfit(x, y, 1)[0]) if len(rows) >= 2 else float("nan")


def scaling(a):
    from physar.fem.solvers import available_memory, direct_memory_estimate

    print(f"CHOLMOD: {has_cholmod()}; {platform.processor() or platform.machine()}, numpy {np.__version__}; "
          f"available memory {available_memory() / 2**30:.1f} GiB; CG relative residual {RTOL:g}\n", flush=True)
    rows = []
    for element, sizes in (("P1", a.p1), ("P2", a.p2)):
        for cells in sizes:
            cells = tuple(cells)
            for method in a.methods:
                space = FESpace(box_mesh((L, B, H), cells), element) if method == "physar-direct" else None
                if space is not None:
                    n = space.n_dofs
                    est = direct_memory_estimate(n, n * (81 if element == "P1" else 200))
                    if n > a.direct_max_dofs or est > 0.5 * available_memory():
                        print(f"<!-- {element} {cells} direct skipped: {n} dofs, est. factor "
                              f"{est / 2**30:.1f} GiB -->", flush=True)
                        continue
                cmd = [sys.executable, __file__, "--case", element, method, *map(str, cells)]
                proc = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=a.timeout)
                if proc.returncode:
                    print(f"<!-- {element} {cells} {method} failed: {proc.stderr.strip()[-300:]} -->", flush=True)
                    continue
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                r["total"] = r["assemble"] + r["solve"]
                rows.append(r)
                print(f"<!-- {json.dumps(r)} -->", flush=True)
    print("\n| element | method | dofs | assemble [s] | solve [s] | total [s] | peak memory [GB] | CG iterations "
          "| tip u_z [m] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        its = "–" if r["iterations"] is None else str(r["iterations"])
        print(f"| {r['element']} | {r['method']} | {r['dofs']:,} | {r['assemble']:.1f} | {r['solve']:.1f} "
              f"| {r['total']:.1f} | {r['peak_gb']:.2f} | {its} | {r['tip']:.6e} |")
    print("\nFitted exponents p (time ∝ dofs^p over the sizes run):\n")
    print("| element | method | solve | total | peak memory |")
    print("|---|---|---|---|---|")
    for element in ("P1", "P2"):
        for method in a.methods:
            sel = [r for r in rows if r["element"] == element and r["method"] == method]
            if len(sel) >= 2:
                print(f"| {element} | {method} | {_fit(sel, 'solve'):.2f} | {_fit(sel, 'total'):.2f} "
                      f"| {_fit(sel, 'peak_gb'):.2f} |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cells", type=int, nargs=3, default=[50, 20, 17])
    ap.add_argument("--element", nargs="+", default=["P1", "P2"])
    ap.add_argument("--skip-spsolve-above", type=int, default=200_000, help="dofs")
    ap.add_argument("--scaling", action="store_true", help="three sizes per element, direct / AMG / skfem+pyamg")
    ap.add_argument("--p1", type=int, nargs=3, action="append", help="P1 cells (repeatable)")
    ap.add_argument("--p2", type=int, nargs=3, action="append", help="P2 cells (repeatable)")
    ap.add_argument("--methods", nargs="+", default=["physar-direct", "physar-amg", "skfem-amg"])
    ap.add_argument("--direct-max-dofs", type=int, default=600_000)
    ap.add_argument("--timeout", type=float, default=1200.0, help="seconds per case")
    ap.add_argument("--case", nargs=5, metavar=("ELEMENT", "METHOD", "NX", "NY", "NZ"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.case:
        print(json.dumps(run_case(a.case[0], a.case[1], tuple(int(c) for c in a.case[2:]))))
    elif a.scaling:
        a.p1 = a.p1 if a.p1 is not None else P1_SIZES
        a.p2 = a.p2 if a.p2 is not None else P2_SIZES
        scaling(a)
    else:
        compare(a)


if __name__ == "__main__":
    main()
