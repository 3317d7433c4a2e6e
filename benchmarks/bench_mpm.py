"""MLS-MPM throughput: physar (Warp, CPU) vs a Taichi MLS-MPM of the same scene, forward and forward+backward.

Scene: a neo-Hookean cube (E = 1e5 Pa, nu = 0.3, 1000 kg/m^3, 8 particles per cell) falling under gravity in
the unit cube on a 64^3 grid, dt = 1e-4 s; 8k particles (10^3 cells) and 64k particles (20^3 cells).
Both codes run the same MLS-MPM substep (APIC, quadratic B-splines, Kirchhoff stress
tau = mu (F F^T - I) + lambda log(J) I, float64); the benchmark checks that their particle positions agree.

Rows (every timed code runs once per round, in turn, so that all see the same load; medians of ``--rounds``):
* physar forward: ``MPMSolver.step`` with the grid phase on the particles' node box (``--dense``: also on the
  whole dense grid, ``active_box=False``, the previous implementation);
* physar forward+backward: ``torch_bridge.simulate`` (one frame of S substeps) + ``backward()`` of a loss on
  the final positions w.r.t. per-particle E and the initial velocities, through the fused frame adjoint
  (:mod:`physar.mpm.adjoint`) with 1 thread, 2 threads, and the default (threads chosen per sweep by
  measurement, :class:`physar.mpm.adjoint.ThreadChooser`); ``--generic``: also the generic per-launch tape path
  (``fused=False``);
* Taichi 1.7 (written here, dense 64^3 grid, ``cpu_max_num_threads`` = all cores): forward, and forward +
  backward by the usual diffmpm scheme (all substep states stored, grid recomputed per substep in reverse,
  ``kernel.grad``), gradients w.r.t. E and the initial velocities;
* peak resident memory (above the process's memory before the run) of a 100-frame backward pass with
  per-frame checkpointing, and of a 10-frame pass without it (``--no-memory``: skipped).

Usage: ``python benchmarks/bench_mpm.py [--particles 8000 64000] [--substeps 50] [--rounds 3] [--no-taichi]``.
Timings are wall-clock seconds on whatever else the machine is doing: the load averages (1, 5, 15 min)
are printed with each size.
"""

# (no `from __future__ import annotations`: Taichi reads the kernel annotations as objects)

import argparse
import os
import platform
import time

import numpy as np

RES, SIZE, DT, E, NU, RHO = 64, 1.0, 1.0e-4, 1.0e5, 0.3, 1000.0


def scene_arrays(n_target: int):
    """Box of k^3 cells at 8 particles per cell (k = round((n / 8)^(1/3))), positions and initial velocity."""
    dx = SIZE / RES
    k = round((n_target / 8) ** (1 / 3))
    h = dx / 2
    lo = np.array([0.5, 0.5, 0.5]) - k * dx / 2 + 0.25 * dx  # off the node lattice
    ax = [lo[i] + (np.arange(2 * k) + 0.5) * h for i in range(3)]
    x = np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)
    v = np.tile([0.1, -0.05, -0.2], (len(x), 1))
    return x, v, h**3


def physar_model(x, vol, substeps):
    from physar.mpm.model import MPMModel

    n = len(x)
    return MPMModel(size=SIZE, resolution=RES, dt=DT, substeps=substeps, mass=np.full(n, vol * RHO),
                    volume=np.full(n, vol), E=np.full(n, E), nu=np.full(n, NU), elastic=np.full(n, 2),
                    plastic=np.zeros(n), plastic_params=np.zeros((n, 4)), body=np.zeros(n))


def bench_physar_forward(x, v, vol, S, active_box=True):
    from physar.mpm.model import MPMSolver

    m = physar_model(x, vol, S)
    s = MPMSolver(m, active_box=active_box)
    a, b = m.state(x, v), m.state(x, v)
    s.step(a, b)  # compile / warm up
    a, b = m.state(x, v), m.state(x, v)
    t = time.perf_counter()
    for _ in range(S):
        s.step(a, b)
        a, b = b, a
    el = time.perf_counter() - t
    return S / el, a.x.numpy().copy()


def bench_physar_backward(x, v, vol, S, fused=True, threads=None):
    import torch

    from physar.mpm.adjoint import FusedFrame
    from physar.mpm.torch_bridge import Params, simulate

    m = physar_model(x, vol, S)
    w = torch.tensor(np.random.default_rng(0).standard_normal(x.shape))

    def run(model, frames=1, checkpoint=True):
        if threads is not None:
            model._fused = FusedFrame(model, threads=threads)
        Et = torch.full((len(x),), E, dtype=torch.float64, requires_grad=True)
        vt = torch.tensor(v, requires_grad=True)
        xs, _ = simulate(model, x, vt, Params(E=Et, nu=torch.full((len(x),), NU, dtype=torch.float64)), frames,
                         checkpoint=checkpoint, fused=fused)
        (w * xs[-1]).sum().backward()
        return Et.grad, vt.grad

    from dataclasses import replace

    run(replace(m, substeps=1))  # warm up
    t = time.perf_counter()
    gE, gv = run(m)
    el = time.perf_counter() - t
    return S / el, gE.numpy(), gv.numpy()


def _rss_mb(field="VmRSS"):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field):
                return int(line.split()[1]) / 1024
    return float("nan")


def _reset_peak():  # unused: peak is measured in a fresh process
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def bench_memory(n_target, frames, substeps, checkpoint):
    """Peak resident memory (MB) above the level after setup, of a backward pass, in a fresh process."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, __file__, "--memory-child", str(n_target), str(frames), str(substeps),
                          str(int(checkpoint))], capture_output=True, text=True, check=True).stdout.split()
    return float(out[-2]), float(out[-1])


def _memory_child(n_target, frames, substeps, checkpoint):
    import gc

    import torch

    from physar.mpm.torch_bridge import Params, simulate

    x, v, vol = scene_arrays(n_target)
    m = physar_model(x, vol, substeps)
    from dataclasses import replace

    Et = torch.full((len(x),), E, dtype=torch.float64, requires_grad=True)
    nu = torch.full((len(x),), NU, dtype=torch.float64)
    xs, _ = simulate(replace(m, substeps=1), x, v, Params(E=Et, nu=nu), 1)  # load kernels, warm allocators
    xs[-1].sum().backward()
    del xs
    gc.collect()
    base = _rss_mb()
    t = time.perf_counter()
    xs, _ = simulate(m, x, v, Params(E=Et, nu=nu), frames, checkpoint=checkpoint)
    sum((xx[:, 2]).sum() for xx in xs[1:]).backward()
    el = time.perf_counter() - t
    print(_rss_mb("VmHWM") - base, el)


# ----------------------------------------------------------------------------------------------- Taichi
def bench_taichi(x0, v0, vol, S, threads):
    """(fwd, fb, x_final, dL/dE, dL/dv0, compile s) of one Taichi run (:func:`make_taichi`)."""
    return make_taichi(x0, v0, vol, S, threads)[1]


def make_taichi(x0, v0, vol, S, threads):
    """Compile the Taichi MLS-MPM of the scene; returns (again, first): ``again()`` times one more forward and
    one more forward+backward run (fwd, fb substeps/s), ``first`` = (fwd, fb, x_final, dL/dE, dL/dv0,
    compile s) of the first run."""
    import taichi as ti

    ti.init(arch=ti.cpu, default_fp=ti.f64, cpu_max_num_threads=threads, offline_cache=True, log_level=ti.WARN)
    n = len(x0)
    G = RES + 7  # same padded grid as physar: 3 nodes of padding, origin at -3 dx
    dx, inv_dx = SIZE / RES, RES / SIZE
    origin = -3 * dx
    p_mass, p_vol = vol * RHO, vol
    lo_w, hi_w = 3, 3 + RES
    x = ti.Vector.field(3, ti.f64, shape=(S + 1, n), needs_grad=True)
    v = ti.Vector.field(3, ti.f64, shape=(S + 1, n), needs_grad=True)
    C = ti.Matrix.field(3, 3, ti.f64, shape=(S + 1, n), needs_grad=True)
    F = ti.Matrix.field(3, 3, ti.f64, shape=(S + 1, n), needs_grad=True)
    Ef = ti.field(ti.f64, shape=n, needs_grad=True)
    gvi = ti.Vector.field(3, ti.f64, shape=(G, G, G), needs_grad=True)
    gm = ti.field(ti.f64, shape=(G, G, G), needs_grad=True)
    gvo = ti.Vector.field(3, ti.f64, shape=(G, G, G), needs_grad=True)
    grav = ti.Vector([0.0, 0.0, -9.81])

    @ti.kernel
    def clear_grid():
        for I in ti.grouped(gm):
            gvi[I] = ti.Vector.zero(ti.f64, 3)
            gm[I] = 0.0
            gvo[I] = ti.Vector.zero(ti.f64, 3)
            gvi.grad[I] = ti.Vector.zero(ti.f64, 3)
            gm.grad[I] = 0.0
            gvo.grad[I] = ti.Vector.zero(ti.f64, 3)

    @ti.kernel
    def p2g(s: ti.i32):
        for p in range(n):
            g = (x[s, p] - origin) * inv_dx
            base = ti.floor(g - 0.5, ti.i32)
            fx = g - base
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            mu = Ef[p] / (2.0 * (1.0 + NU))
            la = Ef[p] * NU / ((1.0 + NU) * (1.0 - 2.0 * NU))
            Fp = F[s, p]
            J = Fp.determinant()
            tau = mu * (Fp @ Fp.transpose() - ti.Matrix.identity(ti.f64, 3)) + la * ti.log(J) * ti.Matrix.identity(
                ti.f64, 3)
            affine = (-DT * p_vol * 4.0 * inv_dx * inv_dx) * tau + p_mass * C[s, p]
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                off = ti.Vector([i, j, k])
                dpos = (off - fx) * dx
                wt = w[i][0] * w[j][1] * w[k][2]
                gvi[base + off] += wt * (p_mass * v[s, p] + affine @ dpos)
                gm[base + off] += wt * p_mass

    @ti.kernel
    def grid_op():
        for i, j, k in gm:
            vv = ti.Vector.zero(ti.f64, 3)
            if gm[i, j, k] > 1e-14:
                vv = gvi[i, j, k] / gm[i, j, k] + DT * grav
                if i <= lo_w and vv[0] < 0:
                    vv[0] = 0.0
                if i >= hi_w and vv[0] > 0:
                    vv[0] = 0.0
                if j <= lo_w and vv[1] < 0:
                    vv[1] = 0.0
                if j >= hi_w and vv[1] > 0:
                    vv[1] = 0.0
                if k <= lo_w and vv[2] < 0:
                    vv[2] = 0.0
                if k >= hi_w and vv[2] > 0:
                    vv[2] = 0.0
            gvo[i, j, k] = vv

    @ti.kernel
    def g2p(s: ti.i32):
        for p in range(n):
            g = (x[s, p] - origin) * inv_dx
            base = ti.floor(g - 0.5, ti.i32)
            fx = g - base
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            nv = ti.Vector.zero(ti.f64, 3)
            nC = ti.Matrix.zero(ti.f64, 3, 3)
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                off = ti.Vector([i, j, k])
                dpos = (off - fx) * dx
                wt = w[i][0] * w[j][1] * w[k][2]
                gv = gvo[base + off]
                nv += wt * gv
                nC += 4.0 * inv_dx * inv_dx * wt * gv.outer_product(dpos)
            v[s + 1, p] = nv
            C[s + 1, p] = nC
            F[s + 1, p] = (ti.Matrix.identity(ti.f64, 3) + DT * nC) @ F[s, p]
            x[s + 1, p] = x[s, p] + DT * nv

    @ti.kernel
    def init(xn: ti.types.ndarray(), vn: ti.types.ndarray()):
        for p in range(n):
            for d in ti.static(range(3)):
                x[0, p][d] = xn[p, d]
                v[0, p][d] = vn[p, d]
            C[0, p] = ti.Matrix.zero(ti.f64, 3, 3)
            F[0, p] = ti.Matrix.identity(ti.f64, 3)
            Ef[p] = E

    @ti.kernel
    def seed(wn: ti.types.ndarray()):
        for p in range(n):
            for d in ti.static(range(3)):
                x.grad[S, p][d] = wn[p, d]

    def forward(steps):
        for s in range(steps):
            clear_grid()
            p2g(s)
            grid_op()
            g2p(s)

    def backward(steps):
        for s in reversed(range(steps)):
            clear_grid()
            p2g(s)
            grid_op()
            g2p.grad(s)
            grid_op.grad()
            p2g.grad(s)

    init(x0, v0)
    t = time.perf_counter()
    forward(1)
    backward(1)
    compile_s = time.perf_counter() - t
    w = np.random.default_rng(0).standard_normal(x0.shape)

    def again():
        init(x0, v0)
        ti.sync()
        t = time.perf_counter()
        forward(S)
        ti.sync()
        fwd = S / (time.perf_counter() - t)
        init(x0, v0)
        for fld in (x, v, C, F):
            fld.grad.fill(0)
        Ef.grad.fill(0)
        ti.sync()
        t = time.perf_counter()
        forward(S)
        seed(w)
        backward(S)
        ti.sync()
        fb = S / (time.perf_counter() - t)
        return fwd, fb

    fwd, fb = again()
    xf = x.to_numpy()[S]
    gE, gv = Ef.grad.to_numpy(), v.grad.to_numpy()[0]
    return again, (fwd, fb, xf, gE, gv, compile_s)


def _uptime() -> str:
    try:
        with open("/proc/loadavg") as f:
            return " ".join(f.read().split()[:3])
    except OSError:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main():
    import sys

    if len(sys.argv) > 1 and sys.argv[1] == "--memory-child":
        a = sys.argv[2:]
        return _memory_child(int(a[0]), int(a[1]), int(a[2]), bool(int(a[3])))
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--particles", type=int, nargs="+", default=[8000, 64000])
    ap.add_argument("--substeps", type=int, default=50, help="substeps per timed run")
    ap.add_argument("--rounds", type=int, default=3,
                    help="timed rounds; each round runs every code once, in turn (the median is reported)")
    ap.add_argument("--no-taichi", action="store_true")
    ap.add_argument("--generic", action="store_true", help="also time the generic per-launch tape path")
    ap.add_argument("--dense", action="store_true", help="also time the dense-grid forward (previous)")
    ap.add_argument("--no-memory", action="store_true", help="skip the peak-memory runs")
    ap.add_argument("--memory-frames", type=int, default=100)
    ap.add_argument("--memory-substeps", type=int, default=5, help="substeps per frame in the memory runs")
    args = ap.parse_args()
    threads = os.cpu_count() or 1
    print(f"# bench_mpm  {time.strftime('%Y-%m-%d %H:%M')}  {platform.processor() or platform.machine()}, "
          f"{threads} cores, load average (1, 5, 15 min) {_uptime()} (start)")
    rows = []
    med = lambda a: float(np.median(a))
    rng = lambda a: f"{min(a):.1f}–{max(a):.1f}"
    for n_target in args.particles:
        x, v, vol = scene_arrays(n_target)
        S = args.substeps
        load0 = _uptime()
        t_size = time.strftime("%H:%M:%S")
        if args.dense:
            dense, _ = bench_physar_forward(x, v, vol, S, active_box=False)
            rows.append((len(x), "physar, dense-grid update (previous)", dense, float("nan"), ""))
        codes = {"1": {"threads": 1}, "2": {"threads": 2}, "auto": {"threads": None}}
        fw, ta_f, ta_fb = [], [], []
        res = {k: [] for k in codes}
        ta = None
        if not args.no_taichi:
            try:
                again, (_tf, _tfb, xt, tgE, tgv, comp) = make_taichi(x, v, vol, S, threads)
                ta = (xt, tgE, tgv, comp)
            except ImportError:
                rows.append((len(x), "Taichi: not installed (`pip install taichi`)", float("nan"), float("nan"), ""))
        grads = {}
        for r in range(args.rounds):
            fw.append(bench_physar_forward(x, v, vol, S)[0])
            for k, kw in codes.items():
                fb, gE, gv = bench_physar_backward(x, v, vol, S, **kw)
                res[k].append(fb)
                grads[k] = (gE, gv)
            if ta is not None:
                a, b = again()
                ta_f.append(a)
                ta_fb.append(b)
        _, xp = bench_physar_forward(x, v, vol, S)
        gE, gv = grads["2"]
        load1 = _uptime()
        tag = f"load {load0} → {load1} ({t_size}–{time.strftime('%H:%M:%S')})"
        rows.append((len(x), "physar forward (1 thread) / fwd+bwd fused adjoint, 1 thread", med(fw), med(res["1"]),
                     f"fwd+bwd rounds {rng(res['1'])}; {tag}"))
        rows.append((len(x), "physar fwd+bwd fused adjoint, 2 threads", float("nan"), med(res["2"]),
                     f"rounds {rng(res['2'])}"))
        rows.append((len(x), "physar fwd+bwd fused adjoint, default (threads chosen by measurement)", float("nan"),
                     med(res["auto"]), f"rounds {rng(res['auto'])}"))
        if args.generic:
            fbg, _gEg, gvg = bench_physar_backward(x, v, vol, S, fused=False)
            d_fg = np.abs(gv - gvg).max() / np.abs(gvg).max()  # dL/dE is ~roundoff here (F stays ~I in free fall)
            rows.append((len(x), "physar fwd+bwd generic per-launch tape (previous)", float("nan"), fbg,
                         f"dL/dv0 rel. diff fused vs generic {d_fg:.1e}"))
        if ta is not None:
            xt, tgE, tgv, comp = ta
            dx_err = np.abs(xt - xp).max()
            gerr = max(np.abs(tgE - gE).max() / np.abs(gE).max(), np.abs(tgv - gv).max() / np.abs(gv).max())
            rows.append((len(x), f"Taichi 1.7 CPU ({threads} threads), dense grid", med(ta_f), med(ta_fb),
                         (f"fwd+bwd rounds {rng(ta_fb)}; max |x_ti - x_physar| = {dx_err:.1e} m, grad rel. diff "
                          f"{gerr:.1e}, first fwd+bwd incl. compile {comp:.0f} s")))
            import taichi as ti

            ti.reset()
            for k in codes:
                print(f"# {len(x)} particles: fwd+bwd physar {k} / Taichi = {med(res[k]) / med(ta_fb):.2f}  "
                      f"(per round: {', '.join(f'{a / b:.2f}' for a, b in zip(res[k], ta_fb))})")
    print(f"\nScene: neo-Hookean cube falling, {RES}^3 grid, dt = {DT:g} s, float64, {args.substeps} substeps "
          f"timed (after warm-up), median of {args.rounds} rounds\n")
    print("| particles | code | forward substeps/s | forward+backward substeps/s | notes |")
    print("|---|---|---|---|---|")
    for n, name, f, b, note in rows:
        fb_s = "-" if np.isnan(b) else f"{b:.1f}"
        f_s = "-" if np.isnan(f) else f"{f:.1f}"
        print(f"| {n} | {name} | {f_s} | {fb_s} | {note} |")
    from physar.mpm import adjoint

    print(f"\nthread chooser state (kind, particle-count octave, threads): mean s/substep, samples, calls: "
          f"{ {k: (round(v[0], 4), v[1], v[2]) for k, v in adjoint.CHOOSER.est.items()} }")
    if not args.no_memory:
        x, v, vol = scene_arrays(args.particles[0])
        F_, T_ = args.memory_frames, args.memory_substeps
        mem_ck, t_ck = bench_memory(args.particles[0], F_, T_, checkpoint=True)
        mem_nc, t_nc = bench_memory(args.particles[0], 10, T_, checkpoint=False)
        print(f"\nPeak memory of a backward pass ({len(x)} particles, {T_} substeps/frame, loss on every frame's "
              "positions; resident set above the pre-run level):\n")
        print("| run | frames | peak extra memory (MB) | time (s) |")
        print("|---|---|---|---|")
        print(f"| per-frame checkpointing | {F_} | {mem_ck:.0f} | {t_ck:.1f} |")
        print(f"| no checkpointing | 10 | {mem_nc:.0f} | {t_nc:.1f} |")
        print(f"| no checkpointing (extrapolated x{F_ // 10}) | {F_} | ~{mem_nc * F_ / 10:.0f} | - |")
    print(f"\nload average at the end: {_uptime()}")


if __name__ == "__main__":
    main()
