"""Device check of physar's Warp MPM (and the integrators' Warp kernels) on a machine with a CUDA GPU.

Before every Warp allocation and launch named its device, physar's MPM used Warp's default device, ``cuda:0``
on a GPU machine, for some arrays while the torch bridge wrapped CPU tensors as CPU arrays: Warp's "trying to
launch on device='cuda:0', but input array ... is on device=cpu".  This script, on a scene built here (no file):
three 0.25 m blocks side by side, 8 particles per cell, float64 — an elastic block (fixed corotated, E = 1e5 Pa)
and a plastic one (Hencky + von Mises, yield 2 kPa) dropped 0.1 m onto the slip floor, and a PD-actuated block
(seed Eq. 6-7 as in physar.recon: gate omega = 1 inside, 0 on the surface layer; references 0.1 m above the
rest positions, the force held over each frame, Alg. 2):

(i)   runs it with ``device="cpu"`` while CUDA is visible (the bug: this raised before the fix);
(ii)  runs the same with ``device="cuda:0"``;
(iii) compares the positions after ``--frames`` frames: max |x_cpu - x_gpu| and that over the largest
      displacement (forward solver ``MPMSolver`` and the torch bridge's fused forward);
(iv)  back-propagates a loss on the final positions through ``torch_bridge.simulate`` (the fused frame adjoint
      and the generic Warp-tape path) on both devices, with CPU tensors in and out, and compares dL/dE
      (relative error, 2-norm);
(v)   times forward frames/s (``MPMSolver``, after a warm-up frame) and the fused forward and backward seconds
      of one frame (``torch_bridge.simulate``) on every device at ``--sizes`` particles;

plus the co-rotated tetrahedron kernels of physar.integrators.warp_kernels (forces, assembled stiffness,
matrix-free product, node frames) on both devices (loaded from its file: the package physar.integrators needs
scikit-fem and scikit-sparse).  Prints a compact table and writes everything to ``--out`` (JSON).

Imports: numpy, torch, warp, pydantic (physar.mpm's scene module) and the standard library; nothing else.

Usage (from the repository root)::

    python benchmarks/gpu_check_mpm.py --out gpu_check_mpm.json                # cpu and cuda:0
    python benchmarks/gpu_check_mpm.py --devices cpu --out /tmp/cpu_only.json  # a machine without a GPU

Exit code 0 when every comparison is within ``--tol`` (relative), 1 otherwise.
"""

import argparse
import importlib.util
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch
import warp as wp

from physar.mpm.model import Control, MPMModel, MPMSolver
from physar.mpm.torch_bridge import Params, simulate

SIDE, DROP, RHO, SUBSTEPS, FRAME_DT = 0.25, 0.1, 1000.0, 20, 0.02
KP, KD, LIFT = 200.0, 20.0, 0.1


def log(msg: str):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


# ------------------------------------------------------------------------------------------------ scene
def scene(n_target: int):
    """Positions (N, 3), per-particle material arrays, the gate and the PD references of the three blocks at
    about n_target particles (k^3 per block, 2 per cell and axis: resolution = 2k / (4 SIDE))."""
    k = max(4, round((n_target / 3) ** (1 / 3)))
    h = SIDE / k
    res = round(1.0 / (2 * h))
    ax = (np.arange(k) + 0.5) * h
    cube = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    xs, body = [], []
    for b, cx in enumerate((0.2, 0.5, 0.8)):
        xs.append(cube + [cx - SIDE / 2, 0.5 - SIDE / 2, DROP if b < 2 else 2 * h])
        body.append(np.full(len(cube), b))
    x, body = np.concatenate(xs), np.concatenate(body)
    n = len(x)
    elastic = np.where(body == 1, 3, 0)  # 3: Hencky (with von Mises), 0: fixed corotated
    plastic = np.where(body == 1, 1, 0)  # 1: von Mises
    pp = np.zeros((n, 4))
    pp[body == 1, 0] = 2.0e3
    act = body == 2
    c = x[act]
    inner = np.all((c - c.min(0) > h) & (c.max(0) - c > h), axis=1)  # the gate: 0 on the surface layer
    omega = np.zeros(n)
    omega[np.flatnonzero(act)[inner]] = 1.0
    x_ref = x + np.where(act[:, None], [0.0, 0.0, LIFT], 0.0)
    return {"x": x, "body": body, "elastic": elastic, "plastic": plastic, "pp": pp, "omega": omega,
            "x_ref": x_ref, "res": res, "vol": h**3}


def model_of(s: dict, device: str) -> MPMModel:
    n = len(s["x"])
    return MPMModel(size=1.0, resolution=s["res"], dt=FRAME_DT / SUBSTEPS, substeps=SUBSTEPS,
                    mass=np.full(n, s["vol"] * RHO), volume=np.full(n, s["vol"]),
                    E=np.where(s["body"] == 1, 2.0e5, 1.0e5), nu=np.full(n, 0.3), elastic=s["elastic"],
                    plastic=s["plastic"], plastic_params=s["pp"], body=s["body"], device=device)


def sync(device: str):
    if device != "cpu":
        wp.synchronize_device(device)


# ------------------------------------------------------------------------------------------------ checks
def forward(s: dict, device: str, frames: int) -> tuple[np.ndarray, float]:
    """MPMSolver run (PD force held per frame): final positions and frames/s (after one warm-up frame)."""
    m = model_of(s, device)
    ctrl = Control(s["omega"], s["x_ref"], np.zeros_like(s["x"]), kp=KP, kd=KD, hold=True)
    solver = MPMSolver(m)
    a, b = m.state(s["x"]), m.state(s["x"])
    a, b = solver.simulate_frame(a, b, ctrl)  # warm-up (kernel compilation on first use)
    solver.time = 0.0
    a, b = m.state(s["x"]), m.state(s["x"])
    sync(device)
    t = time.perf_counter()
    for _ in range(frames):
        a, b = solver.simulate_frame(a, b, ctrl)
    sync(device)
    return a.x.numpy().copy(), frames / (time.perf_counter() - t)


def grad_run(s: dict, device: str, frames: int, fused: bool) -> dict:
    """torch_bridge.simulate with CPU tensors in: final x, dL/dE (L = sum(w * x_final), fixed w) and the
    seconds of the forward and backward passes."""
    m = model_of(s, device)
    n = len(s["x"])
    E = torch.tensor(m.E, requires_grad=True)
    p = Params(E=E, nu=torch.tensor(m.nu), omega=torch.tensor(s["omega"]), x_ref=torch.tensor(s["x_ref"]),
               v_ref=torch.zeros(n, 3, dtype=torch.float64), kp=KP, kd=KD, hold=True)
    w = torch.tensor(np.random.default_rng(0).standard_normal((n, 3)))
    t0 = time.perf_counter()
    xs, _ = simulate(m, s["x"], np.zeros((n, 3)), p, frames, fused=fused)
    loss = (w * xs[-1]).sum()
    t1 = time.perf_counter()
    loss.backward()
    t2 = time.perf_counter()
    assert xs[-1].device.type == "cpu" and E.grad.device.type == "cpu", "results not on the caller's device"
    return {"x": xs[-1].detach().numpy(), "gE": E.grad.numpy().copy(), "fwd_s": t1 - t0, "bwd_s": t2 - t1}


def rel(a, b) -> float:
    d = np.linalg.norm(np.ravel(a) - np.ravel(b))
    return float(d / max(np.linalg.norm(np.ravel(a)), 1e-300))


def pos_diff(x_ref: np.ndarray, x: np.ndarray, x0: np.ndarray) -> dict:
    disp = float(np.abs(x_ref - x0).max())
    mad = float(np.abs(x_ref - x).max())
    return {"max_abs_m": mad, "max_displacement_m": disp, "relative": mad / disp}


def load_warp_kernels():
    """physar/integrators/warp_kernels.py as a module of its own (only numpy and warp)."""
    spec = importlib.util.spec_from_file_location("physar_warp_kernels", ROOT / "physar/integrators/warp_kernels.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def tet_mesh(k: int = 4):
    """A unit cube of k^3 cells, 6 tetrahedra each: nodes (n, 3), cells (m, 4), gradients G (m, 4, 3), volumes."""
    g = np.arange(k + 1)
    nodes = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) / k
    idx = lambda i, j, l: (i * (k + 1) + j) * (k + 1) + l
    tets = []
    for i in range(k):
        for j in range(k):
            for l in range(k):
                c = [idx(i + a, j + b, l + d) for a, b, d in
                     ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1))]
                for t in ((0, 1, 2, 6), (0, 2, 3, 6), (0, 3, 7, 6), (0, 7, 4, 6), (0, 4, 5, 6), (0, 5, 1, 6)):
                    tets.append([c[q] for q in t])
    cells = np.array(tets, dtype=np.int32)
    X = nodes[cells]  # (m, 4, 3)
    D = (X[:, 1:] - X[:, :1]).transpose(0, 2, 1)  # columns x_a - x_0
    vol = np.abs(np.linalg.det(D)) / 6
    Dinv = np.linalg.inv(D)  # rows: gradients of the barycentric coordinates 1..3
    G = np.concatenate([-Dinv.sum(1, keepdims=True), Dinv], axis=1)
    return nodes, cells, G, vol


def integrator_kernels(device: str) -> dict:
    wk = load_warp_kernels()
    nodes, cells, G, vol = tet_mesh()
    n = len(nodes)
    rng = np.random.default_rng(1)
    u = 0.05 * rng.standard_normal(3 * n)
    w = wk.WarpCorotatedP1(cells, G, vol, 4.0e5, 2.0e5, n, device=device)
    _F, _R, fe, flagged = (np.array(a) for a in w.stress_forces(u))
    slots = np.empty((len(cells), 144), dtype=np.int32)  # dense (3n)^2 pattern
    for a in range(4):
        for i in range(3):
            for b in range(4):
                for kk in range(3):
                    slots[:, (a * 3 + i) * 12 + b * 3 + kk] = (3 * cells[:, a] + i) * 3 * n + 3 * cells[:, b] + kk
    w.set_slots("dense", slots, (3 * n) ** 2)
    K = w.warped_assemble("dense").copy()
    y = w.warped_matvec(rng.standard_normal(3 * n))
    Rn = w.node_frames()[0].copy()
    return {"fe": fe, "K": K, "y": y, "Rn": Rn, "flagged": len(flagged)}


# ------------------------------------------------------------------------------------------------ main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--devices", default="cpu,cuda:0", help="comma-separated Warp devices; the first is the reference")
    ap.add_argument("--sizes", type=int, nargs="+", default=[5000, 100000], help="particle counts timed")
    ap.add_argument("--check-size", type=int, default=5000, help="particles of the comparison runs (iii, iv)")
    ap.add_argument("--frames", type=int, default=10, help="frames of the forward comparison (iii)")
    ap.add_argument("--grad-frames", type=int, default=3, help="frames of the backward comparison (iv)")
    ap.add_argument("--time-frames", type=int, default=3, help="frames timed per device and size (v)")
    ap.add_argument("--tol", type=float, default=1e-6, help="largest relative difference accepted")
    ap.add_argument("--out", required=True, help="JSON output path")
    args = ap.parse_args(argv)
    devices = [d.strip() for d in args.devices.split(",") if d.strip()]

    wp.init()
    env = {"python": platform.python_version(), "torch": torch.__version__, "warp": wp.config.version,
           "torch_cuda": torch.cuda.is_available(), "warp_devices": [d.alias for d in wp.get_devices()],
           "warp_default_device": str(wp.get_device()), "devices": devices,
           "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}
    log(f"env: {env}")
    res = {"env": env, "args": vars(args), "forward": {}, "grad": {}, "integrators": {}, "timing": [],
           "errors": {}, "pass": True}

    def fail(key: str, exc: Exception):
        res["errors"][key] = f"{type(exc).__name__}: {exc}"
        res["pass"] = False
        log(f"FAILED {key}: {type(exc).__name__}: {exc}")

    s = scene(args.check_size)
    log(f"check scene: {len(s['x'])} particles, grid {s['res']}^3, {SUBSTEPS} substeps/frame")
    # (i)-(iii) forward
    runs = {}
    for d in devices:
        try:
            log(f"forward {args.frames} frames on {d} (MPMSolver)")
            runs[d] = forward(s, d, args.frames)[0]
        except Exception as exc:  # noqa: BLE001 - reported, the other checks go on
            fail(f"forward[{d}]", exc)
    ref = devices[0]
    for d in devices[1:]:
        if ref in runs and d in runs:
            res["forward"][d] = pos_diff(runs[ref], runs[d], s["x"])
            log(f"forward {d} vs {ref}: {res['forward'][d]}")
    # (iv) gradients, fused and generic
    for fused in (True, False):
        tag = "fused" if fused else "generic"
        g = {}
        for d in devices:
            try:
                log(f"backward ({tag}, {args.grad_frames} frames) on {d}")
                g[d] = grad_run(s, d, args.grad_frames, fused)
            except Exception as exc:  # noqa: BLE001
                fail(f"grad_{tag}[{d}]", exc)
        for d in devices[1:]:
            if ref in g and d in g:
                res["grad"][f"{tag}:{d}"] = {"dE_rel": rel(g[ref]["gE"], g[d]["gE"]),
                                             "x": pos_diff(g[ref]["x"], g[d]["x"], s["x"])["relative"],
                                             "dE_norm": float(np.linalg.norm(g[ref]["gE"]))}
                log(f"grad {tag} {d} vs {ref}: {res['grad'][f'{tag}:{d}']}")
    # integrators' kernels
    ik = {}
    for d in devices:
        try:
            log(f"integrator kernels on {d}")
            ik[d] = integrator_kernels(d)
        except Exception as exc:  # noqa: BLE001
            fail(f"integrators[{d}]", exc)
    for d in devices[1:]:
        if ref in ik and d in ik:
            res["integrators"][d] = {k: rel(ik[ref][k], ik[d][k]) for k in ("fe", "K", "y", "Rn")}
            log(f"integrator kernels {d} vs {ref}: {res['integrators'][d]}")
    # (v) timing
    for n in args.sizes:
        st = scene(n)
        for d in devices:
            row = {"device": d, "particles": len(st["x"]), "grid": st["res"]}
            try:
                log(f"timing {len(st['x'])} particles on {d}")
                row["fwd_frames_per_s"] = forward(st, d, args.time_frames)[1]
                g = grad_run(st, d, 1, True)  # kernels compiled by (iv) already
                row["fused_fwd_s_per_frame"] = g["fwd_s"]
                row["fused_bwd_s_per_frame"] = g["bwd_s"]
            except Exception as exc:  # noqa: BLE001
                fail(f"timing[{d},{n}]", exc)
            res["timing"].append(row)

    comps = [v["relative"] for v in res["forward"].values()]
    comps += [v["dE_rel"] for v in res["grad"].values()] + [v["x"] for v in res["grad"].values()]
    comps += [e for v in res["integrators"].values() for e in v.values()]
    res["worst_relative"] = max(comps) if comps else None
    if comps and max(comps) > args.tol:
        res["pass"] = False
    print("\n== comparisons against", ref, flush=True)
    for d, v in res["forward"].items():
        print(f"  forward x   {d:>8}: max |dx| {v['max_abs_m']:.3e} m / max displacement {v['max_displacement_m']:.3f} m"
              f" = {v['relative']:.3e}", flush=True)
    for k, v in res["grad"].items():
        print(f"  dL/dE {k:>16}: rel {v['dE_rel']:.3e}   (x rel {v['x']:.3e})", flush=True)
    for d, v in res["integrators"].items():
        print(f"  tet kernels {d:>8}: " + ", ".join(f"{k} {e:.1e}" for k, e in v.items()), flush=True)
    print("== timing (float64)", flush=True)
    print(f"  {'device':>8} {'particles':>9} {'grid':>5} {'fwd frames/s':>12} {'fused fwd s':>11} {'fused bwd s':>11}",
          flush=True)
    for r in res["timing"]:
        c = [f"{r[k]:.4g}" if k in r else "-" for k in ("fwd_frames_per_s", "fused_fwd_s_per_frame",
                                                        "fused_bwd_s_per_frame")]
        print(f"  {r['device']:>8} {r['particles']:>9} {r['grid']:>5} {c[0]:>12} {c[1]:>11} {c[2]:>11}", flush=True)
    print(f"== {'PASS' if res['pass'] else 'FAIL'} (worst relative difference {res['worst_relative']}, "
          f"tol {args.tol}; errors: {list(res['errors']) or 'none'})", flush=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    log(f"wrote {args.out}")
    return 0 if res["pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
