"""Benchmark of the CPU Gaussian rasteriser (physar.gaussians.render, backend "torch", tile-bucketed)
against the naive dense PyTorch rasteriser (every Gaussian at every pixel, backend "dense") in the same run.

Scene: N random anisotropic Gaussians (sigma 1-4 cm, opacity 0.05-0.95, SH degree 1) in a 2 m cube seen
from 4 m with a 40 degree field of view (footprints of a few pixels, most pixels covered). Loss for the
backward pass: sum(rgb * w1) + sum(alpha * w2) with fixed random weights; gradients w.r.t. all parameters.
The dense backward runs pixel chunk by pixel chunk (backward per chunk, gradients accumulated) to bound
memory; its forward is timed without autograd, like the tile forward in the first column.

Usage: python benchmarks/bench_gaussians.py [--n 10000] [--res 128 256] [--repeats 3] [--no-dense]
"""

from __future__ import annotations

import argparse
import platform
import time

import torch

from physar.gaussians import Camera, Gaussians, eval_sh, project, rasterize_dense, render
from physar.gaussians.rasterize import Projected

PARAMS = ["means", "quats", "log_scales", "opacity_logits", "sh"]


def scene(n: int, res: int, seed: int = 0):
    g_ = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g_) - 0.5) * 2.0
    g = Gaussians.from_values(means, 0.01 + 0.03 * torch.rand(n, 3, generator=g_),
                              0.05 + 0.9 * torch.rand(n, generator=g_), torch.rand(n, 3, generator=g_),
                              quats=torch.randn(n, 4, generator=g_), sh_degree=1)
    g.sh[:, 1:] = 0.05 * torch.randn(n, 3, 3, generator=g_)
    cam = Camera.look_at((0.0, 0.0, -4.0), (0.0, 0.0, 0.0), width=res, height=res, fov_y_deg=40)
    w1 = torch.rand(res, res, 3, generator=g_)
    w2 = torch.rand(res, res, generator=g_)
    return g, cam, w1, w2


def _best(fn, repeats):
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return min(ts), out


def tile_times(g, cam, w1, w2, repeats, tile_size=4):
    with torch.no_grad():
        t_fwd, out = _best(lambda: render(g, cam, tile_size=tile_size), repeats)
    gg = g.detach().requires_grad_()
    tf, tb = [], []
    for _ in range(repeats):
        for p in PARAMS:
            getattr(gg, p).grad = None
        t0 = time.perf_counter()
        o = render(gg, cam, tile_size=tile_size)
        loss = (o.rgb * w1).sum() + (o.alpha * w2).sum()
        t1 = time.perf_counter()
        loss.backward()
        t2 = time.perf_counter()
        tf.append(t1 - t0)
        tb.append(t2 - t1)
    grads = {p: getattr(gg, p).grad.clone() for p in PARAMS}
    return t_fwd, min(tf), min(tb), out, grads


def dense_times(g, cam, w1, w2, chunk=2048):
    with torch.no_grad():
        t0 = time.perf_counter()
        out = render(g, cam, backend="dense", pixel_chunk=chunk)
        t_fwd = time.perf_counter() - t0
    gg = g.detach().requires_grad_()
    t0 = time.perf_counter()
    pr = project(gg.means, gg.covariance(), gg.opacities, eval_sh(gg.sh, gg.means - cam.center), cam)
    H, W = cam.height, cam.width
    rows = max(1, chunk // W)
    for r0 in range(0, H, rows):
        r1 = min(H, r0 + rows)
        # render the band of rows [r0, r1) by shifting the principal point (same projection otherwise)
        band = _shift_rows(pr, r0)
        o = rasterize_dense(band, W, r1 - r0)
        loss = (o.rgb * w1[r0:r1]).sum() + (o.alpha * w2[r0:r1]).sum()
        loss.backward(retain_graph=True)
    t_fb = time.perf_counter() - t0
    grads = {p: getattr(gg, p).grad.clone() for p in PARAMS}
    return t_fwd, t_fb, out, grads


def _shift_rows(pr, r0):
    m = pr.means2d - torch.tensor([0.0, float(r0)])
    return Projected(m, pr.conics, pr.depths, pr.radii, pr.opacities, pr.colors)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--res", type=int, nargs="+", default=[128, 256])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-dense", action="store_true")
    ap.add_argument("--tile-sweep", action="store_true", help="also time tile sizes 2, 4, 8, 16")
    args = ap.parse_args()
    torch.set_num_threads(torch.get_num_threads())
    print(f"# physar.gaussians rasteriser benchmark: N={args.n}, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads, {platform.processor() or platform.machine()}")
    print("| res | pairs | tile fwd (no grad) s | tile fwd (graph) s | tile bwd s | dense fwd s | "
          "dense fwd+bwd s | fwd ratio | fwd+bwd ratio | max abs diff rgb | max rel diff grad |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for res in args.res:
        g, cam, w1, w2 = scene(args.n, res)
        t_fwd, t_f, t_b, out, grads = tile_times(g, cam, w1, w2, args.repeats)
        row = f"| {res}² | {out.n_pairs} | {t_fwd:.3f} | {t_f:.3f} | {t_b:.3f} |"
        if args.no_dense:
            print(row + " - | - | - | - | - | - |")
            continue
        d_fwd, d_fb, dout, dgrads = dense_times(g, cam, w1, w2)
        diff = (dout.rgb - out.rgb).abs().max().item()
        gdiff = max(((grads[p] - dgrads[p]).norm() / dgrads[p].norm()).item() for p in PARAMS)
        print(row + f" {d_fwd:.3f} | {d_fb:.3f} | {d_fwd / t_fwd:.1f}x | {d_fb / (t_f + t_b):.1f}x | "
              f"{diff:.1e} | {gdiff:.1e} |")
    if args.tile_sweep:
        print("\n| res | tile size | pairs | fwd (graph) s | bwd s |")
        print("|---|---|---|---|---|")
        for res in args.res:
            g, cam, w1, w2 = scene(args.n, res)
            for ts in (2, 4, 8, 16):
                _, t_f, t_b, out, _ = tile_times(g, cam, w1, w2, args.repeats, tile_size=ts)
                print(f"| {res}² | {ts} | {out.n_pairs} | {t_f:.3f} | {t_b:.3f} |")


if __name__ == "__main__":
    main()
