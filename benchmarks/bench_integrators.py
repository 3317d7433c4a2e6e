"""Time integrators (seed 001 §2): cost per step, Newton iterations, energy after 1 s vs h, and the
artificial damping measured on a 3-D co-rotated cantilever vs the 1-DOF amplification-matrix prediction.

    .venv/bin/python benchmarks/bench_integrators.py [--cells 40 8 5] [--steps 10] [--quick]
        [--only damping energy cost profile]

Prints markdown tables. Cost: co-rotated P1 beam (box mesh, 6 tets per cell; 40 x 8 x 5 cells = 9600
tets), clamped, released from rest under gravity, h = 1/30 s, direct (CHOLMOD refactorisation each
Newton iteration, symbolic analysis reused) vs rotated PCG (one reused factor); profile: the stages of
one SI step. Table 2: P2 co-rotated beam bent by a tip load and released,
total energy after 1 s relative to the initial energy. Table 3: the beam started in its first bending
mode (small amplitude), hω1 = 1 and 3: d/ω1 measured from the decay of the modal energy vs
-(2/(hω)) ln ρ(T) from `physar damping`.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import scipy.sparse.linalg as spla

from physar.fem import Corotated, ElasticModel, FESpace, fixed_dofs, solve_static, traction_load
from physar.geometry import box_mesh
from physar.integrators import SolidModel, damping_curve, make_integrator, simulate
from physar.integrators.analysis import euler_bernoulli_cantilever_omega

METHODS = [("symplectic_euler", {}), ("si", {}), ("be", {}), ("midpoint", {}), ("genalpha", {"r": 0.0}),
           ("genalpha", {"r": 0.5}), ("genalpha", {"r": 1.0}), ("theta", {"theta": 0.5}),
           ("theta", {"theta": 1.0}), ("trbdf2", {})]


def label(m, kw):
    return m + "".join(f" {k}={v:g}" for k, v in kw.items())


def beam_p1(cells, tangent="exact"):
    L, W, H = 1.0, 0.1, 0.1
    sp_ = FESpace(box_mesh((L, W, H), cells), "P1")
    el = ElasticModel(sp_, Corotated(1e7, 0.3), density=1000.0)
    fixed = fixed_dofs(sp_, box=[[0, 0, 0], [0, W, H]])
    return SolidModel(el, fixed, gravity=(0, 0, -9.81), tangent=tangent)


def _run_cost(cells, m, kw, tangent, linear_solver, steps, h):
    model = beam_p1(cells, tangent)
    integ = make_integrator(m, **kw, tol=1e-6, linear_solver=linear_solver)
    s = integ.init(model)
    s = integ.step(model, s, h)  # warm-up: patterns, symbolic analysis, first factor
    f0, c0 = integ.solver.n_factorizations, integ.solver.n_cg_iterations
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        s = integ.step(model, s, h)
        times.append(time.perf_counter() - t0)
    dt = float(np.median(times))  # median: the machine is shared, outliers are other people's work
    it = integ.stats.newton_iterations[1:]
    return dict(dt=dt, it_mean=np.mean(it), it_max=max(it), sag=-s.q[2::3].min(),
                fact=(integ.solver.n_factorizations - f0) / steps, cg=(integ.solver.n_cg_iterations - c0) / steps)


def table_cost(cells, steps, quick=False):
    h = 1 / 30
    n_tets = 6 * int(np.prod(cells))
    print(f"\n### Cost per step: co-rotated P1 beam 1 x 0.1 x 0.1 m, cells {tuple(cells)} ({n_tets} tets, "
          f"{beam_p1(cells).n_dofs} dofs), E = 10 MPa, h = 1/30 s, {steps} steps from rest under gravity\n")
    runs = [("si", {}, "warped", "direct"), ("si", {}, "warped", "pcg"), ("si", {}, "exact", "direct"),
            ("si", {}, "exact", "pcg")]
    if not quick:
        runs += [(m, kw, "exact", ls) for m, kw in METHODS if m not in ("symplectic_euler", "si")
                 for ls in ("direct", "pcg")]
    print("| method | tangent | linear solver | ms/step | steps/s | factorisations/step | CG it./step "
          "| Newton it. (mean/max) | tip sag [m] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for m, kw, tangent, ls in runs:
        r = _run_cost(cells, m, kw, tangent, ls, steps, h)
        print(f"| {label(m, kw)} | {tangent} | {ls} | {1e3 * r['dt']:.0f} | {1 / r['dt']:.1f} | {r['fact']:.2f} "
              f"| {r['cg']:.1f} | {r['it_mean']:.1f} / {r['it_max']} | {r['sag']:.4f} |")


def table_profile(cells):
    """Where an SI step's time goes (warped tangent, rotated PCG), one stage at a time."""
    from physar.integrators.model import fast_polar

    model = beam_p1(cells, "warped")
    k = model.kernel
    integ = make_integrator("si", linear_solver="pcg")
    s = integ.init(model)
    for _ in range(5):
        s = integ.step(model, s, 1 / 30)
    q = s.q

    def tm(f, n=10):
        f()
        best = np.inf
        for _ in range(n):
            t0 = time.perf_counter()
            f()
            best = min(best, time.perf_counter() - t0)
        return 1e3 * best  # best of n: the least disturbed by the shared machine's other load

    F = k._F(q)
    R, _ = fast_polar(F)
    lin = model.linearize(q, s.v)
    J = model.system_matrix(lin, 1.0, 1 / 30, 1 / 900)
    fac = integ.solver._factor[1]
    b = np.ones(J.shape[0])
    rows = [("F = I + grad u (all tets)", tm(lambda: k._F(q))),
            ("polar decomposition (vectorised Newton)", tm(lambda: fast_polar(F))),
            ("forces f_int", tm(lambda: k._scatter(k._nodal(R)))),
            ("warped element matrices R K0 Rᵀ", tm(lambda: k._warped(R))),
            ("assembly (fixed CSR pattern)", tm(lambda: k._pattern.assemble(k._warped(R))) - tm(lambda: k._warped(R))),
            ("Newton matrix M + h D + h² K (pattern data)", tm(lambda: model.system_matrix(lin, 1.0, 1 / 30, 1 / 900))),
            ("node rotations (PCG frame)", tm(lambda: k.node_rotations(q + 0.0))),
            ("CHOLMOD numeric refactorisation", tm(lambda: integ.solver._factorize(J), 5)),
            ("CHOLMOD solve (one PCG preconditioner apply)", tm(lambda: fac(b))),
            ("sparse J x (one CG matvec)", tm(lambda: J @ b))]
    print(f"\n### Profile of one SI step, {6 * int(np.prod(cells))} tets (ms, best of 10)\n")
    print("| stage | ms |")
    print("|---|---|")
    for name, t in rows:
        print(f"| {name} | {t:.1f} |")


def beam_p2(cells=(10, 1, 1), rayleigh=(0.0, 0.0)):
    L, B = 1.0, 0.05
    sp_ = FESpace(box_mesh((L, B, B), cells), "P2")
    el = ElasticModel(sp_, Corotated(1e6, 0.3), density=1000.0)
    fixed = fixed_dofs(sp_, box=[[0, 0, 0], [0, B, B]])
    return SolidModel(el, fixed, rayleigh=rayleigh), sp_, el, fixed


def table_energy(quick):
    model, sp_, el, fixed = beam_p2()
    f = traction_load(sp_, [[1.0, 0, 0], [1.0, 0.05, 0.05]], [0, 0, -0.05])
    q0 = solve_static(el, f, fixed, steps=5, tol=1e-8).u
    e0 = model.energy(q0, np.zeros(model.n_dofs))["total"]
    w1 = euler_bernoulli_cantilever_omega(1e6, 1000.0, 1.0, 0.05, 0.05)
    hs = [1 / 10, 1 / 30, 1 / 100] if quick else [1 / 5, 1 / 10, 1 / 30, 1 / 100]
    print(f"\n### Energy after 1 s / initial energy: P2 co-rotated beam 1 x 0.05 x 0.05 m, 10x1x1 cells "
          f"({model.n_dofs} dofs), tip load released (tip {-q0[2::3].min():.3f} m), no physical damping "
          f"(ω1 ≈ {w1:.2f} rad/s)\n")
    print("| method | " + " | ".join(f"h = 1/{round(1 / h)}" for h in hs) + " |")
    print("|---|" + "---|" * len(hs))
    for m, kw in METHODS:
        cells = []
        for h in hs:
            n = round(1.0 / h)
            try:
                with np.errstate(all="ignore"):
                    s = simulate(model, make_integrator(m, **kw, tol=1e-8), h, n, q0)
                    ratio = model.energy(s.q, s.v)["total"] / e0
                cells.append(f"{ratio:.4f}" if np.isfinite(ratio) and ratio < 1e3 else "blow-up")
            except Exception as exc:  # noqa: BLE001 - a blow-up is a result here
                cells.append("blow-up" if "blew" in str(exc) or "NaN" in str(exc) else type(exc).__name__)
        print(f"| {label(m, kw)} | " + " | ".join(cells) + " |")


def table_damping():
    model, *_ = beam_p2()
    lin = model.linearize(np.zeros(model.n_dofs), np.zeros(model.n_dofs))
    w2, phi = spla.eigsh(lin.K, k=1, M=model.mass_ff, sigma=0, which="LM")
    w, p = float(np.sqrt(w2[0])), phi[:, 0]
    p /= np.sqrt(p @ (model.mass_ff @ p))
    amp = 1e-3 / np.abs(p).max()  # 1 mm peak
    print(f"\n### Artificial damping on the beam (first mode, ω1 = {w:.4f} rad/s, 1 mm amplitude) vs 1-DOF "
          "prediction\n")
    print("| method | hω1 | d/ω measured on beam | d/ω predicted (1-DOF T) |")
    print("|---|---|---|---|")
    for m, kw in [("be", {}), ("si", {}), ("genalpha", {"r": 0.0}), ("genalpha", {"r": 0.5}),
                  ("theta", {"theta": 1.0}), ("theta", {"theta": 0.5}), ("trbdf2", {}), ("midpoint", {})]:
        for hw in (1.0, 3.0):
            h = hw / w
            q0 = np.zeros(model.n_dofs)
            q0[model.free] = amp * p
            E = []

            def cb(k, s):
                a = p @ (model.mass_ff @ s.q[model.free])
                b = p @ (model.mass_ff @ s.v[model.free])
                E.append(0.5 * (b * b + w * w * a * a))

            n = 30
            simulate(model, make_integrator(m, **kw, tol=1e-10), h, n, q0, callback=cb)
            E = np.array(E)
            # skip the start-up of multistep/α memory; stop before round-off (energy < 1e-12 E0)
            k = np.arange(3, n + 1)
            k = k[E[k] > 1e-12 * E[0]]
            slope = np.polyfit(k, 0.5 * np.log(E[k]), 1)[0]  # ln rho per step
            d_meas = -2.0 * slope / hw
            d_pred = damping_curve(m, [hw], **kw)["d_over_omega"][0]
            print(f"| {label(m, kw)} | {hw:g} | {d_meas:.4f} | {d_pred:.4f} |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cells", type=int, nargs=3, default=[40, 8, 5])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", choices=["damping", "energy", "cost", "profile"], nargs="*")
    a = ap.parse_args()
    only = set(a.only or ["damping", "energy", "cost", "profile"])
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"# bench_integrators ({time.strftime('%Y-%m-%d %H:%M')}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cpus, load average {load:.1f})")
    if "damping" in only:
        table_damping()
    if "energy" in only:
        table_energy(a.quick)
    if "cost" in only:
        table_cost(a.cells, a.steps, a.quick)
    if "profile" in only:
        table_profile(a.cells)


if __name__ == "__main__":
    main()
