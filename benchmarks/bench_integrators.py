"""Time integrators (seed 001 §2): cost per step, Newton iterations, energy after 1 s vs h, and the
artificial damping measured on a 3-D co-rotated cantilever vs the 1-DOF amplification-matrix prediction.

    .venv/bin/python benchmarks/bench_integrators.py [--cells 40 8 5] [--steps 10] [--quick]

Prints markdown tables. Table 1: co-rotated P1 beam (box mesh, 6 tets per cell), clamped, released
from rest under gravity, h = 1/30 s. Table 2: P2 co-rotated beam bent by a tip load and released,
total energy after 1 s relative to the initial energy. Table 3: the beam started in its first bending
mode (small amplitude), hω1 = 1 and 3: d/ω1 measured from the decay of the modal energy vs
-(2/(hω)) ln ρ(T) from `physar damping`.
"""

from __future__ import annotations

import argparse
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


def table_cost(cells, steps):
    h = 1 / 30
    print(f"\n### Cost per step: co-rotated P1 beam 1 x 0.1 x 0.1 m, cells {tuple(cells)}, E = 10 MPa, "
          f"h = 1/30 s, {steps} steps from rest under gravity\n")
    rows = []
    for (m, kw), tangent in [((m, kw), "exact") for m, kw in METHODS if m != "symplectic_euler"] + [
            (("si", {}), "warped")]:
        model = beam_p1(cells, tangent)
        integ = make_integrator(m, **kw, tol=1e-6)
        s = integ.init(model)
        s = integ.step(model, s, h)  # warm-up: patterns, symbolic analysis
        t0 = time.perf_counter()
        for _ in range(steps):
            s = integ.step(model, s, h)
        dt = (time.perf_counter() - t0) / steps
        it = integ.stats.newton_iterations[1:]
        rows.append((label(m, kw) + ("" if tangent == "exact" else " (warped K)"), dt, np.mean(it), max(it),
                     -s.q[2::3].min()))
    n_tets = 6 * int(np.prod(cells))
    print(f"{n_tets} tets, {beam_p1(cells).n_dofs} dofs\n")
    print("| method | ms/step | steps/s | Newton it. (mean/max) | tip sag after run [m] |")
    print("|---|---|---|---|---|")
    for name, dt, mi, mx, sag in rows:
        print(f"| {name} | {1e3 * dt:.0f} | {1 / dt:.1f} | {mi:.1f} / {mx} | {sag:.4f} |")


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
    a = ap.parse_args()
    print(f"# bench_integrators ({time.strftime('%Y-%m-%d')}, {platform.processor() or platform.machine()})")
    table_damping()
    table_energy(a.quick)
    table_cost(a.cells, a.steps)


if __name__ == "__main__":
    main()
