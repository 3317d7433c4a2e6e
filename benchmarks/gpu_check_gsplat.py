"""Check of the rasteriser's CUDA paths on a lent GPU machine (issue 17, part 3): never run by the tests.

What it measures, on one scene of anisotropic Gaussians with SH degree 1 (peak opacities in (0.05, 0.95),
where gsplat's alpha cap 0.999 and ours, 0.99, cannot differ; a second run with opacities up to 0.999
shows that difference):

1. ``backend="torch"`` on CUDA (float32) against the same backend on the CPU in float64: image, alpha,
   depth and the gradients of a fixed scalar loss w.r.t. means, log-scales, quaternions, opacity logits
   and SH, and w.r.t. a deformation gradient F (seed 002, Eq. 3).
2. ``backend="gsplat"`` (``gsplat.rasterization``, compiled at first use) against the CPU float64
   reference, the same quantities.
3. Forward and forward + backward time per frame of both CUDA backends and of the CPU torch backend, at
   several image sizes and Gaussian counts (median of repeated runs, ``torch.cuda.synchronize``).

Usage (on the GPU machine, physar's source tree as the working directory):

    PYTHONPATH=. python3 benchmarks/gpu_check_gsplat.py --out result.json

It imports only torch, numpy and physar.gaussians; ``--device cpu --skip-gsplat`` runs part 1's code path on
the CPU alone (a smoke test of the script).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
import traceback

import torch

from physar.gaussians.camera import Camera
from physar.gaussians.model import Gaussians
from physar.gaussians.rasterize import render


def scene(n: int, seed: int = 0, max_opacity: float = 0.95) -> Gaussians:
    """n anisotropic Gaussians on a torus (flattened along the surface normal), SH degree 1, float64."""
    gen = torch.Generator().manual_seed(seed)
    u = 2 * math.pi * torch.rand(n, generator=gen, dtype=torch.float64)
    v = 2 * math.pi * torch.rand(n, generator=gen, dtype=torch.float64)
    R0, r0 = 0.25, 0.09
    means = torch.stack([(R0 + r0 * torch.cos(v)) * torch.cos(u), (R0 + r0 * torch.cos(v)) * torch.sin(u),
                         r0 * torch.sin(v)], -1)
    spacing = math.sqrt(4 * math.pi ** 2 * R0 * r0 / n)
    scales = spacing * torch.exp(0.3 * torch.randn(n, 3, generator=gen, dtype=torch.float64))
    scales[:, 2] *= 0.2
    q = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    opac = 0.05 + (max_opacity - 0.05) * torch.rand(n, generator=gen, dtype=torch.float64)
    col = torch.rand(n, 3, generator=gen, dtype=torch.float64)
    g = Gaussians.from_values(means, scales, opac, col, quats=q / q.norm(dim=1, keepdim=True), sh_degree=1)
    sh = g.sh.clone()
    sh[:, 1:] = 0.3 * torch.randn(n, 3, 3, generator=gen, dtype=torch.float64)
    return g.replace(sh=sh)


def camera(width: int, height: int) -> Camera:
    return Camera.look_at((0.15, -0.55, 0.45), (0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov_y_deg=50.0,
                          width=width, height=height)


def loss_weights(width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(7)
    return (torch.rand(height, width, 3, generator=gen, dtype=torch.float64),
            torch.rand(height, width, generator=gen, dtype=torch.float64))


def render_and_grads(g: Gaussians, cam: Camera, backend: str, device: str, dtype: torch.dtype, F=None):
    """Render on (device, dtype); return images and d(loss)/d(parameters) as float64 CPU tensors."""
    gd = g.to(device=device, dtype=dtype).detach().requires_grad_(True)
    Fd = None if F is None else F.to(device=device, dtype=dtype).detach().requires_grad_(True)
    cam_d = cam.to(dtype)
    res = render(gd, cam_d, F=Fd, backend=backend, background=torch.tensor([0.1, 0.2, 0.3]))
    wr, wa = loss_weights(cam.width, cam.height)
    wr, wa = wr.to(device, dtype), wa.to(device, dtype)
    # depth weighted by alpha (the depth of empty pixels is a convention, not an observable)
    loss = (wr * res.rgb).sum() + (wa * res.alpha).sum() + (wa * res.alpha * res.depth).sum()
    loss.backward()
    out = {k: getattr(res, k).detach().double().cpu() for k in ("rgb", "alpha", "depth")}
    for k, t in gd.tensors().items():
        out["grad_" + k] = t.grad.detach().double().cpu()
    if Fd is not None:
        out["grad_F"] = Fd.grad.detach().double().cpu()
    return out


def compare(ref: dict, got: dict) -> dict:
    """Max / mean absolute image differences and relative gradient errors ||g - g_ref|| / ||g_ref||."""
    res = {}
    for k in ("rgb", "alpha"):
        d = (got[k] - ref[k]).abs()
        res[k] = {"max_abs": float(d.max()), "mean_abs": float(d.mean())}
    m = (ref["alpha"] > 0.5) & (got["alpha"] > 0.5)
    d = (got["depth"] - ref["depth"])[m].abs()
    res["depth_alpha>0.5"] = {"max_abs_m": float(d.max()) if d.numel() else 0.0,
                              "mean_abs_m": float(d.mean()) if d.numel() else 0.0}
    for k, r in ref.items():
        if k.startswith("grad_"):
            den = float(r.norm())
            res[k + "_rel_err"] = float((got[k] - r).norm()) / den if den > 0 else float(got[k].norm())
            res[k + "_cosine"] = float(torch.nn.functional.cosine_similarity(got[k].flatten(), r.flatten(), dim=0))
    return res


def timed(fn, reps: int, device: str) -> float:
    """Median wall time of fn() in ms (after one warm-up call)."""
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    fn()
    sync()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        sync()
        ts.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(ts)


def timing(g: Gaussians, cam: Camera, backend: str, device: str, reps: int) -> dict:
    gd = g.to(device=device, dtype=torch.float32).detach()
    cam32 = cam.to(torch.float32)
    fwd = lambda: render(gd, cam32, backend=backend)

    gg = gd.requires_grad_(True)

    def fwd_bwd():
        r = render(gg, cam32, backend=backend)
        (r.rgb.sum() + r.alpha.sum()).backward()
        for t in gg.tensors().values():
            t.grad = None

    with torch.no_grad():
        t_f = timed(fwd, reps, device)
    return {"forward_ms": t_f, "forward_backward_ms": timed(fwd_bwd, reps, device)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=None, help="JSON file for the results")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--skip-gsplat", action="store_true")
    ap.add_argument("--n", type=int, default=20000, help="Gaussians in the agreement check")
    ap.add_argument("--size", type=int, nargs=2, default=(320, 240), help="width height of the agreement check")
    ap.add_argument("--time-n", type=int, nargs="*", default=(20000, 200000))
    ap.add_argument("--time-sizes", type=int, nargs="*", default=(256, 512, 1024))
    ap.add_argument("--time-cpu", action="store_true", help="also time the torch backend on the CPU")
    ap.add_argument("--reps", type=int, default=10)
    a = ap.parse_args(argv)
    result: dict = {"torch": torch.__version__, "device": a.device}
    if a.device.startswith("cuda"):
        result["gpu"] = torch.cuda.get_device_name(0)
    result["cpu_threads"] = torch.get_num_threads()

    def save():
        if a.out:
            with open(a.out, "w") as fh:
                json.dump(result, fh, indent=1)

    def log(*msg):
        print(*msg, flush=True)

    backends = ["torch"] + ([] if a.skip_gsplat else ["gsplat"])
    if "gsplat" in backends:
        try:
            t0 = time.perf_counter()
            import gsplat
            from gsplat.cuda._backend import _C  # noqa: F401  (JIT build at first import)

            result["gsplat"] = {"version": gsplat.__version__, "import_and_build_s": time.perf_counter() - t0}
            log("gsplat", gsplat.__version__, f"ready in {time.perf_counter() - t0:.0f} s")
        except Exception as exc:  # noqa: BLE001 - recorded, then the torch checks go on
            result["gsplat_error"] = "".join(traceback.format_exception(exc))[-4000:]
            log("gsplat unavailable:", result["gsplat_error"])
            backends = ["torch"]
        save()

    W, H = a.size
    cam = camera(W, H)
    for label, max_op in (("opacity<=0.95", 0.95), ("opacity<=0.999", 0.999)):
        g = scene(a.n, max_opacity=max_op)
        gen = torch.Generator().manual_seed(3)
        F = torch.eye(3, dtype=torch.float64) + 0.05 * torch.randn(a.n, 3, 3, generator=gen, dtype=torch.float64)
        for use_F in (False, True):
            key = f"agreement {label}{' with F' if use_F else ''}"
            ref = render_and_grads(g, cam, "torch", "cpu", torch.float64, F if use_F else None)
            result[key] = {"covered_px": int((ref["alpha"] > 0.5).sum()), "pixels": W * H}
            for be in backends:
                try:
                    got = render_and_grads(g, cam, be, a.device, torch.float32, F if use_F else None)
                    result[key][be] = compare(ref, got)
                except Exception as exc:  # noqa: BLE001
                    result[key][be] = {"error": "".join(traceback.format_exception(exc))[-3000:]}
                log(key, be, json.dumps(result[key][be])[:900])
                save()
    result["timing"] = []
    for n in a.time_n:
        g = scene(n)
        for s in a.time_sizes:
            cam_s = camera(s, s)
            runs = [(be, a.device) for be in backends]
            if a.time_cpu and s <= 512:
                runs.append(("torch", "cpu"))
            for be, dev in runs:
                row = {"n": n, "px": s, "backend": be, "device": dev}
                try:
                    row.update(timing(g, cam_s, be, dev, a.reps if dev != "cpu" else 3))
                except Exception as exc:  # noqa: BLE001
                    row["error"] = f"{type(exc).__name__}: {exc}"[:500]
                result["timing"].append(row)
                log("timing", json.dumps(row))
                save()
    save()
    return 0


if __name__ == "__main__":
    sys.exit(main())
