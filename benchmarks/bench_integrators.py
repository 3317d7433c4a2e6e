"""Time integrators (seed 001 §2): cost per step, Newton iterations, energy after 1 s vs h, and the
artificial damping measured on a 3-D co-rotated cantilever vs the 1-DOF amplification-matrix prediction.

    .venv/bin/python benchmarks/bench_integrators.py [--cells 40 8 5] [--steps 10] [--quick] [--rounds 3]
        [--only damping energy cost variants profile]

Prints markdown tables. Cost: co-rotated P1 beam (box mesh, 6 tets per cell; 40 x 8 x 5 cells = 9600
tets), clamped, released from rest under gravity, h = 1/30 s, direct (CHOLMOD refactorisation each
Newton iteration, symbolic analysis reused) vs rotated PCG (one reused factor), kernel backend warp when
installed; variants: SI steps/s for each speed-up in turn (numpy -> threads -> warm start -> Warp), in
interleaved rounds, with ratios to the previous default; profile: the stages of one SI step, numpy vs
Warp, and CG on the assembled matrix vs matrix-free. Table 2: P2 co-rotated beam bent by a tip load and released,
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


def beam_p1(cells, tangent="exact", backend="numpy"):
    L, W, H = 1.0, 0.1, 0.1
    sp_ = FESpace(box_mesh((L, W, H), cells), "P1")
    el = ElasticModel(sp_, Corotated(1e7, 0.3), density=1000.0)
    fixed = fixed_dofs(sp_, box=[[0, 0, 0], [0, W, H]])
    return SolidModel(el, fixed, gravity=(0, 0, -9.81), tangent=tangent, backend=backend)


def _run_cost(cells, m, kw, tangent, linear_solver, steps, h, backend="numpy", **ikw):
    model = beam_p1(cells, tangent, backend)
    integ = make_integrator(m, **kw, tol=1e-6, linear_solver=linear_solver, **ikw)
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
    return {"dt": dt, "it_mean": np.mean(it), "it_max": max(it), "sag": -s.q[2::3].min(),
            "fact": (integ.solver.n_factorizations - f0) / steps,
            "cg": (integ.solver.n_cg_iterations - c0) / steps, "times": times, "q": s.q}


def _has_warp():
    try:
        import physar.integrators.warp_kernels  # noqa: F401
    except ImportError:
        return False
    return True


def table_cost(cells, steps, quick=False):
    h = 1 / 30
    n_tets = 6 * int(np.prod(cells))
    backend = "warp" if _has_warp() else "numpy"
    print(f"\n### Cost per step: co-rotated P1 beam 1 x 0.1 x 0.1 m, cells {tuple(cells)} ({n_tets} tets, "
          f"{beam_p1(cells).n_dofs} dofs), E = 10 MPa, h = 1/30 s, {steps} steps from rest under gravity, "
          f"kernel backend {backend}\n")
    runs = [("si", {}, "warped", "direct"), ("si", {}, "warped", "pcg"), ("si", {}, "exact", "direct"),
            ("si", {}, "exact", "pcg")]
    if not quick:
        runs += [(m, kw, "exact", ls) for m, kw in METHODS if m not in ("symplectic_euler", "si")
                 for ls in ("direct", "pcg")]
    print("| method | tangent | linear solver | ms/step | steps/s | factorisations/step | CG it./step "
          "| Newton it. (mean/max) | tip sag [m] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for m, kw, tangent, ls in runs:
        r = _run_cost(cells, m, kw, tangent, ls, steps, h, backend)
        print(f"| {label(m, kw)} | {tangent} | {ls} | {1e3 * r['dt']:.0f} | {1 / r['dt']:.1f} | {r['fact']:.2f} "
              f"| {r['cg']:.1f} | {r['it_mean']:.1f} / {r['it_max']} | {r['sag']:.4f} |")


# the SI variants, each adding one change to the previous (name, backend, linear solver, integrator options)
SI_VARIANTS = [
    ("numpy kernel, direct CHOLMOD refactorisation", "numpy", "direct", {}),
    ("numpy kernel, rotated PCG, BLAS/OpenMP threads as set (previous default)", "numpy", "pcg",
     {"linear_threads": None}),
    ("+ preconditioner solves on 1 thread (new default)", "numpy", "pcg", {}),
    ("+ Warp CPU kernels (polar, forces, assembly, frames)", "warp", "pcg", {}),
    ("+ CG warm start from the previous Δv", "warp", "pcg", {"warm_start": True}),
    ("Warp kernels, rotated PCG, threads as set", "warp", "pcg", {"linear_threads": None}),
    ("Warp kernels, direct CHOLMOD refactorisation", "warp", "direct", {}),
    ("Warp kernels, rotated PCG to linear_rtol = 1e-6 (looser than the default 1e-8)", "warp", "pcg",
     {"linear_rtol": 1e-6}),
]


def table_si_variants(cells, steps, rounds=3):
    """SI (warped tangent) steps/s for each variant, run in interleaved rounds so that every variant sees
    the same machine load; ratio = the variant's median step time over the previous default's, per round."""
    h = 1 / 30
    variants = [v for v in SI_VARIANTS if v[1] == "numpy" or _has_warp()]
    times = {v[0]: [] for v in variants}
    ratios = {v[0]: [] for v in variants}
    q_ref = None
    dev, cg = {}, {}
    for _ in range(rounds):
        med = {}
        for name, backend, ls, kw in variants:
            r = _run_cost(cells, "si", {}, "warped", ls, steps, h, backend, **kw)
            times[name] += r["times"]
            med[name] = r["dt"]
            cg[name] = r["cg"]
            if q_ref is None:
                q_ref = r["q"]
            dev[name] = max(dev.get(name, 0.0), float(np.abs(r["q"] - q_ref).max() / np.abs(q_ref).max()))
        base = med[SI_VARIANTS[1][0]]
        for name, dt in med.items():
            ratios[name].append(base / dt)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\n### SI step variants: co-rotated P1 beam, {6 * int(np.prod(cells))} tets, warped tangent, "
          f"h = 1/30 s, {rounds} interleaved rounds x {steps} steps (load average after: {load:.1f})\n")
    print("| variant | ms/step (median) | steps/s | speed-up vs previous default (median of rounds) "
          "| CG it./step | max |q - q_direct| / max |q| |")
    print("|---|---|---|---|---|---|")
    for name, *_ in variants:
        dt = float(np.median(times[name]))
        print(f"| {name} | {1e3 * dt:.1f} | {1 / dt:.1f} | {np.median(ratios[name]):.2f} | {cg[name]:.1f} "
              f"| {dev[name]:.1e} |")


def _tm(f, n=15):
    """Median and best of n timed calls [ms] (after one warm-up call)."""
    f()
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts)), 1e3 * min(ts)


def table_profile(cells):
    """Where an SI step's time goes (warped tangent, rotated PCG): numpy vs Warp stage by stage, and the
    matrix-free alternative to assembling (SOFA's approach), measured back to back."""
    from physar.fem.solvers import has_cholmod
    from physar.integrators.linalg import thread_limit

    h = 1 / 30
    warp = _has_warp()
    mods = {"numpy": beam_p1(cells, "warped")}
    if warp:
        mods["warp"] = beam_p1(cells, "warped", "warp")
    states = {}
    for b, model in mods.items():
        integ = make_integrator("si", linear_solver="pcg")
        s = integ.init(model)
        for _ in range(5):
            s = integ.step(model, s, h)
        states[b] = (integ, s)
    integ, s = states["numpy"]
    model = mods["numpy"]
    q, v = s.q, s.v
    kn = model.kernel
    R = kn.rotations(q)
    lin = model.linearize(q, v)
    J = model.system_matrix(lin, 1.0, h, h * h)
    fr = model.free
    x = np.random.default_rng(0).normal(size=model.n_dofs)
    rows = []

    def row(name, fn, fw=None):
        a = _tm(fn)
        b = _tm(fw) if fw is not None else None
        rows.append((name, a, b))

    def fresh():
        return q + 0.0  # a new array: defeats the kernels' last-point caches

    kw = mods["warp"].kernel if warp else None
    if warp:
        kw.force_tangent(q)
    row("F, polar decomposition, forces f_int", lambda: kn.force(fresh()), warp and (lambda: kw.force(fresh())))
    row("warped element matrices R K0 Rᵀ + CSR assembly", lambda: kn._pattern.assemble(kn._warped(R)),
        warp and (lambda: kw._wk.warped_assemble("full")))
    row("node frames (PCG rotation)", lambda: kn.node_rotations(q), warp and (lambda: kw.node_rotations(q)))
    row("matrix-free K x (Σ_e R K0 Rᵀ x_e)", lambda: kn.tangent_matvec(q, x), warp and (lambda: kw.tangent_matvec(q, x)))
    row("assembled sparse J x (one CG matvec)", lambda: J @ x[fr])
    row("Newton matrix M + h D + h² K (pattern data)", lambda: model.system_matrix(lin, 1.0, h, h * h))
    if has_cholmod() and integ.solver._factor is not None and integ.solver._factor[0] == "cholmod":
        fac = integ.solver._factor[1]
        b = x[fr]
        row("CHOLMOD solve, BLAS/OpenMP threads as set", lambda: fac(b))
        with thread_limit(1):
            row("CHOLMOD solve, 1 thread", lambda: fac(b))
        rows.append(("CHOLMOD numeric refactorisation", _tm(lambda: integ.solver._factorize(J), 3), None))
    if warp:
        # one full SI linear solve: CG on the assembled J vs CG on the matrix-free operator, same
        # preconditioner (the reused factor in the rotated frame), same right-hand side
        integ_w, s_w = states["warp"]
        mw = mods["warp"]
        qw = s_w.q
        lin_w = mw.linearize(qw, s_w.v)
        Jw = mw.system_matrix(lin_w, 1.0, h, h * h)
        rhs = (h * lin_w.f)[fr]
        sol = integ_w.solver
        n = len(fr)
        Mf = mw.mass_ff
        kwk = mw.kernel

        def mf(y):
            full = np.zeros(mw.n_dofs)
            full[fr] = y
            return Mf @ y + (h * h) * kwk.tangent_matvec(qw, full)[fr]

        Jmf = spla.LinearOperator((n, n), matvec=mf, dtype=float)
        frame = (lambda: mw.frame(qw))
        it0 = sol.n_cg_iterations
        x_a = sol.solve(Jw, rhs, frame=frame)
        it_a = sol.n_cg_iterations - it0
        x_m = sol.solve(Jmf, rhs, frame=frame)
        it_m = sol.n_cg_iterations - it0 - it_a
        assert np.abs(x_a - x_m).max() <= 1e-6 * np.abs(x_a).max()
        rows.append((f"CG solve on the assembled J ({it_a} it.; + assembly + Newton matrix above)",
                     _tm(lambda: sol.solve(Jw, rhs, frame=frame)), None))
        rows.append((f"CG solve on the matrix-free Warp operator M + h² K ({it_m} it.; no assembly)",
                     _tm(lambda: sol.solve(Jmf, rhs, frame=frame)), None))
    print(f"\n### Profile of one SI step, {6 * int(np.prod(cells))} tets (ms, median of 15 / best; numpy and "
          "Warp CPU kernels back to back)\n")
    print("| stage | numpy ms (median / best) | Warp ms (median / best) | numpy / Warp |")
    print("|---|---|---|---|")
    for name, a, b in rows:
        wcol = f"{b[0]:.2f} / {b[1]:.2f}" if b else "–"
        rcol = f"{a[0] / b[0]:.1f}" if b else "–"
        print(f"| {name} | {a[0]:.2f} / {a[1]:.2f} | {wcol} | {rcol} |")


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

            def cb(k, s, E=E):
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
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the SI variants table")
    ap.add_argument("--only", choices=["damping", "energy", "cost", "variants", "profile"], nargs="*")
    a = ap.parse_args()
    only = set(a.only or ["damping", "energy", "cost", "variants", "profile"])
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"# bench_integrators ({time.strftime('%Y-%m-%d %H:%M')}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cpus, load average {load:.1f})")
    if "damping" in only:
        table_damping()
    if "energy" in only:
        table_energy(a.quick)
    if "cost" in only:
        table_cost(a.cells, a.steps, a.quick)
    if "variants" in only:
        table_si_variants(a.cells, a.steps, a.rounds)
    if "profile" in only:
        table_profile(a.cells)


if __name__ == "__main__":
    main()
