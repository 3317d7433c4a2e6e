r"""Differentiable Gaussian splatting on the CPU (vectorised PyTorch), with gsplat on CUDA.

Pipeline (Kerbl et al. 2023, 3DGS; Zwicker et al. 2002, EWA splatting), seed 002 §3.1:

1. Projection. Camera coordinates :math:`p = R \mu + t`; pixel mean
   :math:`m = (f_x p_x / p_z + c_x,\ f_y p_y / p_z + c_y)`; 2-D covariance
   :math:`\Sigma' = J R \Sigma R^\top J^\top + \epsilon_\text{2d} I` with the Jacobian of the perspective map
   :math:`J = \begin{bmatrix} f_x / z & 0 & -f_x x / z^2 \\ 0 & f_y / z & -f_y y / z^2 \end{bmatrix}`
   (:math:`(x, y, z) = p`); conic :math:`Q = \Sigma'^{-1}`.
2. Per pixel :math:`p`, per Gaussian :math:`i`:
   :math:`\alpha_i = \min(0.99,\ \eta_i \exp(-\tfrac12 d^\top Q d))`, :math:`d = p - m_i`; contributions with
   :math:`\alpha_i < 1/255` are skipped (as in 3DGS).
3. Front-to-back compositing in increasing :math:`p_z`: :math:`C = \sum_i c_i \alpha_i T_i`,
   :math:`T_i = \prod_{j<i} (1 - \alpha_j)`, stopping (without the stopping Gaussian) once
   :math:`T_i (1 - \alpha_i) < 10^{-4}` (3DGS early termination). Outputs RGB
   (:math:`+\ \mathrm{background} \cdot T_\text{final}`), alpha
   :math:`A = 1 - T_\text{final} = \sum_i \alpha_i T_i`, and expected depth
   :math:`D = \sum_i z_i \alpha_i T_i / A` (m, 0 where :math:`A = 0`).

Tile-based version (``backend="torch"``): each Gaussian is bucketed into the square pixel tiles its
support touches (``tile_size`` 4 by default: fastest of 2/4/8/16 in benchmarks/bench_gaussians.py on
the CPU, since a tile's pixels are evaluated densely). The support is the ellipse
:math:`d^\top Q d \le k_i^2`, :math:`k_i^2 = 2 \ln(255\, \eta_i)`, beyond which :math:`\alpha_i < 1/255` is
skipped anyway; it is bucketed by its axis-aligned bounding box, half-widths :math:`k_i \sqrt{\Sigma'_{xx}}`,
:math:`k_i \sqrt{\Sigma'_{yy}}` (at most the radius :math:`r_i = k_i \sqrt{\lambda_\max(\Sigma'_i)}` of the
enclosing circle; :math:`\le 3.33\, \sigma`), so the bucketing is exact (no 3-sigma truncation error).
The (tile, Gaussian) pairs are sorted by tile then depth, every pair evaluates all its tile's pixels, and
the transmittance is a segmented cumulative sum of :math:`\log(1 - \alpha)` (in float64). Early termination
is the exact rule above (a pair contributes iff :math:`T_i (1 - \alpha_i) \ge 10^{-4}`). Everything after the
pair list is differentiable by autograd. When gradients are needed, a first pass without autograd drops the
pairs that cannot matter: those with, at every pixel of their tile, :math:`\alpha = 0`
(:math:`\log(1 - \alpha) = 0` changes no product) or compositing already terminated before them
(:math:`T_i < 10^{-4}`: every later pair at that pixel is terminated too, with or without them); the second
pass, with autograd, composites the rest and gives the same image and gradients (the dropped pairs' gradients
are exactly zero). ``backend="dense"`` evaluates all Gaussians at all pixels (the naive reference used by the
benchmark); ``backend="gsplat"`` calls ``gsplat.rasterization`` (CUDA only; checked against this backend on a
lent GPU by benchmarks/gpu_check_gsplat.py, never in the test suite).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import torch

from physar.errors import PhysarError
from physar.gaussians.camera import Camera
from physar.gaussians.model import Gaussians, _check_finite, _first_bad, _floating
from physar.gaussians.sh import _eval_sh

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4


@dataclass
class RenderResult:
    """Rendered image: rgb (H, W, 3), alpha (H, W) in [0, 1], depth (H, W) expected depth, m."""

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    n_pairs: int = 0  # (tile, Gaussian) pairs bucketed (tile backend), for diagnostics
    n_composited: int = 0  # of those, pairs composited by the differentiable pass (fewer when culled)


@dataclass
class Projected:
    r"""Screen-space Gaussians: means2d (N, 2) px, conics (N, 3) = :math:`(Q_{00}, Q_{01}, Q_{11})`
    :math:`\mathrm{px}^{-2}`, depths (N,) m, radii (N,) px (0 = culled), opacities (N,), colours (N, 3);
    extents (N, 2) px: half-widths of the support's bounding box (None: the radius in both directions)."""

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor
    extents: torch.Tensor | None = None


# ---- input checks (once per call, on whole arrays; never inside the per-tile code) -------------------------
def _whole(value, name: str, where: str, minimum: int = 1, none: bool = False) -> int | None:
    """``value`` as an int >= ``minimum`` (None passes when ``none``), else a PhysarError naming it."""
    if value is None and none:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) \
            or value != int(value) or value < minimum:
        raise PhysarError(f"{where}: {name} must be a whole number >= {minimum}{' or None' if none else ''}, "
                          f"got {value!r}")
    return int(value)


def _check_options(where: str, eps2d=0.3, near=0.01, max_elements=2e8) -> None:
    """eps2d finite >= 0 (px^2), near finite > 0 (m), max_elements > 0."""
    for name, v, ok, want in (("eps2d", eps2d, lambda x: 0 <= x < math.inf, "a finite number >= 0 (px^2)"),
                              ("near", near, lambda x: 0 < x < math.inf, "a finite number > 0 (m)"),
                              ("max_elements", max_elements, lambda x: x > 0, "a number > 0")):
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not ok(v):
            raise PhysarError(f"{where}: {name} must be {want}, got {v!r}")


def _check_camera(cam, where: str) -> None:
    if not isinstance(cam, Camera):
        raise PhysarError(f"{where}: cam must be a physar.gaussians.Camera, got {type(cam).__name__}")


def _background(background, where: str, width: int, height: int) -> torch.Tensor | None:
    """``background`` as a finite tensor of shape (3,) or (height, width, 3) (a list is converted), or None."""
    if background is None:
        return None
    try:
        bg = torch.as_tensor(background)
    except (TypeError, ValueError, RuntimeError):
        raise PhysarError(f"{where}: background must be an RGB triple (3,) or an image ({height}, {width}, 3), "
                          f"got {type(background).__name__}") from None
    if tuple(bg.shape) not in ((3,), (height, width, 3)):
        raise PhysarError(f"{where}: background must have shape (3,) or ({height}, {width}, 3), got "
                          f"{tuple(bg.shape)}")
    if not bool(torch.isfinite(bg).all()):
        raise PhysarError(f"{where}: background contains NaN or infinite values")
    return bg


def _per_gaussian(t, name: str, where: str, shape: tuple, dtype: torch.dtype) -> None:
    """``t`` a floating tensor of exactly ``shape`` and ``dtype`` with finite values (PhysarError naming it)."""
    _floating(t, name, where)
    if tuple(t.shape) != shape:
        raise PhysarError(f"{where}: {name} must have shape {shape}, got {tuple(t.shape)}")
    if t.dtype != dtype:
        raise PhysarError(f"{where}: {name} is {t.dtype}, the means {dtype}; give them one dtype (use .to())")
    _check_finite(t, name, where)


def _check_cov3d(cov3d: torch.Tensor, where: str) -> None:
    r"""Each (3, 3) a covariance: symmetric and positive semi-definite within :math:`10^{-4}` of its largest
    eigenvalue (float32 products such as :math:`F R S S^\top R^\top F^\top` pass)."""
    with torch.no_grad():
        c = cov3d.detach()
        scale = c.abs().amax((-1, -2))
        tol = 1e-4 * scale
        sym = (c - c.transpose(-1, -2)).abs().amax((-1, -2)) <= tol
        ev = torch.linalg.eigvalsh(0.5 * (c + c.transpose(-1, -2))) if c.numel() else c.new_zeros(0, 3)
        bad = _first_bad(sym & (ev[:, 0] >= -tol))
    if bad is not None:
        raise PhysarError(f"{where}: cov3d[{bad}] is not a covariance (symmetric positive semi-definite): "
                          f"eigenvalues {[round(v, 9) for v in ev[bad].tolist()]} m^2, "
                          f"{[[round(v, 9) for v in r] for r in c[bad].tolist()]}")


def project(means: torch.Tensor, cov3d: torch.Tensor, opacities: torch.Tensor, colors: torch.Tensor,
            cam: Camera, eps2d: float = 0.3, near: float = 0.01) -> Projected:
    """EWA projection of 3-D Gaussians (means m, cov3d m^2) to the image plane (see module docstring).

    ``means`` (N, 3), ``cov3d`` (N, 3, 3) symmetric positive semi-definite, ``opacities`` (N,) in [0, 1],
    ``colors`` (N, 3), one floating dtype, finite; ``eps2d`` >= 0, ``near`` > 0. A PhysarError names the first
    argument (and Gaussian) that is not."""
    where = "project"
    _check_camera(cam, where)
    _check_options(where, eps2d, near)
    _floating(means, "means", where, (3,))
    n = means.shape[0]
    _per_gaussian(means, "means", where, (n, 3), means.dtype)
    _per_gaussian(cov3d, "cov3d", where, (n, 3, 3), means.dtype)
    _check_cov3d(cov3d, where)
    _per_gaussian(opacities, "opacities", where, (n,), means.dtype)
    if not bool(((opacities >= 0) & (opacities <= 1)).all()):
        raise PhysarError(f"{where}: opacities must lie in [0, 1]")
    _per_gaussian(colors, "colors", where, (n, 3), means.dtype)
    return _project(means, cov3d, opacities, colors, cam, eps2d, near)


def _project(means, cov3d, opacities, colors, cam: Camera, eps2d: float, near: float) -> Projected:
    """:func:`project` without the input checks."""
    R, t = cam.R.to(means.device, means.dtype), cam.t.to(means.device, means.dtype)
    p = means @ R.T + t
    x, y, z = p.unbind(-1)
    valid = z > near
    zs = torch.where(valid, z, torch.ones_like(z))
    u = cam.fx * x / zs + cam.cx
    v = cam.fy * y / zs + cam.cy
    # as in 3DGS/gsplat, the Jacobian of Gaussians far outside the view is evaluated at x/z, y/z clamped
    # to 1.3 times the half field of view (keeps their footprints bounded); no effect on visible means
    tx, ty = 0.5 * cam.width / cam.fx, 0.5 * cam.height / cam.fy
    xz = torch.clamp(x / zs, -(cam.cx / cam.fx + 0.3 * tx), (cam.width - cam.cx) / cam.fx + 0.3 * tx)
    yz = torch.clamp(y / zs, -(cam.cy / cam.fy + 0.3 * ty), (cam.height - cam.cy) / cam.fy + 0.3 * ty)
    zero = torch.zeros_like(zs)
    J = torch.stack([cam.fx / zs, zero, -cam.fx * xz / zs, zero, cam.fy / zs, -cam.fy * yz / zs],
                    -1).reshape(-1, 2, 3)
    M = J @ R
    cov2d = M @ cov3d @ M.transpose(-1, -2)
    a = cov2d[:, 0, 0] + eps2d
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + eps2d
    det = a * c - b * b
    valid = valid & (det > 0)
    det = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det, -b / det, a / det], -1)
    with torch.no_grad():
        lam = 0.5 * (a + c) + torch.sqrt(torch.clamp_min(0.25 * (a - c) ** 2 + b * b, 0.0))
        o = opacities.detach()
        k2 = 2.0 * torch.log(torch.clamp_min(o * 255.0, 1.0))
        radii = torch.sqrt(k2 * torch.clamp_min(lam, 0.0))
        radii = torch.where(valid & (o > ALPHA_MIN), radii, torch.zeros_like(radii))
        # bounding box of the ellipse d^T Q d <= k2 (Q^-1 = [[a, b], [b, c]]): half-widths sqrt(k2 a),
        # sqrt(k2 c); 1e-3 relative margin for the rounding of Q (float32) against a, c; never above r
        ext = torch.stack([torch.minimum(radii, 1.001 * torch.sqrt(k2 * torch.clamp_min(a, 0.0))),
                           torch.minimum(radii, 1.001 * torch.sqrt(k2 * torch.clamp_min(c, 0.0)))], -1)
        inside = (u + ext[:, 0] > 0) & (u - ext[:, 0] < cam.width) & (v + ext[:, 1] > 0) & (v - ext[:, 1] < cam.height)
        radii = torch.where(inside, radii, torch.zeros_like(radii))
        ext = torch.where(inside[:, None], ext, torch.zeros_like(ext))
    return Projected(torch.stack([u, v], -1), conics, z, radii, opacities, colors, ext)


def _alpha(dx: torch.Tensor, dy: torch.Tensor, conic: torch.Tensor, opac: torch.Tensor) -> torch.Tensor:
    r""":math:`\alpha = \min(0.99,\ \eta \exp(-d^\top Q d / 2))`, zeroed where :math:`< 1/255` (broadcast over
    pixels)."""
    power = -0.5 * (conic[..., 0:1] * dx * dx + conic[..., 2:3] * dy * dy) - conic[..., 1:2] * dx * dy
    alpha = torch.clamp_max(opac[..., None] * torch.exp(torch.clamp_max(power, 0.0)), ALPHA_MAX)
    keep = (power <= 0) & (alpha >= ALPHA_MIN)
    return torch.where(keep, alpha, torch.zeros_like(alpha))


def _log_transmittance(alpha: torch.Tensor, seg_start: torch.Tensor | None, seg_of: torch.Tensor | None):
    r"""(:math:`\log(1 - \alpha)`, inclusive and exclusive cumulative sums of it along dim 0 in float64):
    :math:`\log T` after and before each element; with ``seg_start``/``seg_of`` the sums restart at every
    segment (tile) start."""
    log1m = torch.log1p(-alpha)
    cs = torch.cumsum(log1m.double(), 0)
    incl = cs
    if seg_start is not None:
        base = torch.cat([torch.zeros_like(cs[:1]), cs])[seg_start]  # cs before each segment start
        incl = cs - base[seg_of]
    return log1m, incl, incl - log1m.double()


def _composite_weights(alpha: torch.Tensor, seg_start: torch.Tensor | None, seg_of: torch.Tensor | None):
    r"""Front-to-back weights :math:`w_i = \alpha_i T_i` with 3DGS early termination, along dim 0.

    With ``seg_start``/``seg_of`` the products restart at every segment (tile) start.
    """
    _, incl, excl = _log_transmittance(alpha, seg_start, seg_of)
    keep = incl >= math.log(T_MIN)
    T = torch.exp(excl).to(alpha.dtype)
    return torch.where(keep, alpha * T, torch.zeros_like(alpha))


def _sh_colors(g: Gaussians, cam: Camera) -> torch.Tensor:
    dirs = g.means - cam.center.to(g.means.device, g.means.dtype)
    return _eval_sh(g.sh, dirs)


def rasterize_tiles(pr: Projected, width: int, height: int, background: torch.Tensor | None = None,
                    tile_size: int = 4, max_elements: float = 2e8, cull: bool = True) -> RenderResult:
    """Tile-bucketed rasterisation of projected Gaussians (see module docstring). Differentiable.

    Memory grows with (pairs x tile pixels), about the total footprint area; more than ``max_elements``
    raises a PhysarError instead of exhausting memory. ``cull``: with autograd, drop the pairs that cannot
    contribute before the differentiable pass (exact; see the module docstring). ``width``, ``height``,
    ``tile_size`` positive whole numbers, ``background`` (3,) or (height, width, 3)."""
    where = "rasterize_tiles"
    if not isinstance(pr, Projected):
        raise PhysarError(f"{where}: pr must be the Projected of project(), got {type(pr).__name__}")
    width, height = _whole(width, "width", where), _whole(height, "height", where)
    tile_size = _whole(tile_size, "tile_size", where)
    _check_options(where, max_elements=max_elements)
    background = _background(background, where, width, height)
    return _rasterize_tiles(pr, width, height, background, tile_size, max_elements, cull)


def _rasterize_tiles(pr: Projected, width: int, height: int, background, tile_size: int, max_elements: float,
                     cull: bool) -> RenderResult:
    """:func:`rasterize_tiles` without the input checks."""
    dtype, dev = pr.means2d.dtype, pr.means2d.device
    ts = tile_size
    tx, ty = -(-width // ts), -(-height // ts)
    grads = torch.is_grad_enabled() and any(
        t.requires_grad for t in (pr.means2d, pr.conics, pr.opacities, pr.colors, pr.depths))
    with torch.no_grad():
        vis = torch.nonzero(pr.radii > 0).squeeze(1)
        m = pr.means2d.detach()[vis]
        ext = pr.radii[vis, None].expand(-1, 2) if pr.extents is None else pr.extents[vis]
        rx, ry = ext[:, 0], ext[:, 1]
        # pixel i (centre i + 0.5) can be touched iff |i + 0.5 - u| <= rx (rows: ry)
        x0 = torch.clamp(torch.floor((m[:, 0] - rx - 0.5) / ts), 0, tx - 1).long()
        x1 = torch.clamp(torch.floor((m[:, 0] + rx - 0.5) / ts), 0, tx - 1).long()
        y0 = torch.clamp(torch.floor((m[:, 1] - ry - 0.5) / ts), 0, ty - 1).long()
        y1 = torch.clamp(torch.floor((m[:, 1] + ry - 0.5) / ts), 0, ty - 1).long()
        nx, ny = x1 - x0 + 1, y1 - y0 + 1
        cnt = nx * ny
        gid = torch.repeat_interleave(torch.arange(vis.numel(), device=dev), cnt)
        first = torch.cumsum(cnt, 0) - cnt
        k = torch.arange(gid.numel(), device=dev) - first[gid]
        tile = (y0[gid] + k // nx[gid]) * tx + x0[gid] + k % nx[gid]
        # sort by (tile, depth); depth rank from a global stable sort
        order_d = torch.argsort(pr.depths.detach()[vis], stable=True)
        rank = torch.empty_like(order_d)
        rank[order_d] = torch.arange(order_d.numel(), device=dev)
        key = tile * max(vis.numel(), 1) + rank[gid]
        perm = torch.argsort(key)
        tile, g_local = tile[perm], gid[perm]
        gsel = vis[g_local]
        n_pairs = int(tile.numel())
        if n_pairs * ts * ts > max_elements:
            raise PhysarError(
                f"render: {n_pairs} (tile, Gaussian) pairs x {ts * ts} pixels exceed max_elements="
                f"{max_elements:.0e} (memory); the Gaussians' footprints are too large for this image size: "
                "lower the resolution, prune large or near-camera Gaussians, or raise max_elements")
        loc = torch.arange(ts, dtype=dtype, device=dev) + 0.5
        ly, lx = torch.meshgrid(loc, loc, indexing="ij")
        lx, ly = lx.reshape(1, -1), ly.reshape(1, -1)

        def segments(tile):  # tile starts, the tile of every pair, pixel centres of every pair's tile
            seg_start = torch.searchsorted(tile, tile.unique_consecutive())
            seg_of = torch.searchsorted(seg_start, torch.arange(tile.numel(), device=dev), right=True) - 1
            return seg_start, seg_of, (tile % tx).to(dtype)[:, None] * ts + lx, (tile // tx).to(dtype)[:, None] * ts + ly

        seg_start, seg_of, px, py = segments(tile)
        if cull and grads and n_pairs:
            mean0 = pr.means2d.detach()[gsel]
            a0 = _alpha(px - mean0[:, 0:1], py - mean0[:, 1:2], pr.conics.detach()[gsel], pr.opacities.detach()[gsel])
            _, _, excl0 = _log_transmittance(a0, seg_start, seg_of)
            need = ((a0 > 0) & (excl0 >= math.log(T_MIN))).any(1)
            del a0, excl0
            tile, gsel = tile[need], gsel[need]
            seg_start, seg_of, px, py = segments(tile)
    mean = pr.means2d[gsel]
    alpha = _alpha(px - mean[:, 0:1], py - mean[:, 1:2], pr.conics[gsel], pr.opacities[gsel])
    w = _composite_weights(alpha, seg_start, seg_of)
    n_tiles = tx * ty
    npx = ts * ts
    feat = torch.cat([pr.colors[gsel], pr.depths[gsel, None]], 1)  # (P, 4)
    acc = torch.zeros(n_tiles, npx, 5, dtype=dtype, device=dev)
    acc = acc.index_add(0, tile, torch.cat([w[..., None] * feat[:, None, :], w[..., None]], -1))
    img = acc.reshape(ty, tx, ts, ts, 5).permute(0, 2, 1, 3, 4).reshape(ty * ts, tx * ts, 5)
    img = img[:height, :width]
    return _finish(img[..., :3], img[..., 3], img[..., 4], background, n_pairs, int(tile.numel()))


def _finish(rgb, dsum, alpha, background, n_pairs=0, n_composited=0) -> RenderResult:
    if background is not None:
        rgb = rgb + (1.0 - alpha)[..., None] * background.to(rgb.device, rgb.dtype)
    depth = torch.where(alpha > 0, dsum / torch.clamp_min(alpha, 1e-12), torch.zeros_like(dsum))
    return RenderResult(rgb, alpha, depth, n_pairs, n_composited)


def rasterize_dense(pr: Projected, width: int, height: int, background: torch.Tensor | None = None,
                    pixel_chunk: int | None = None, max_elements: float = 2e8) -> RenderResult:
    """Naive reference: every visible Gaussian evaluated at every pixel, sorted by depth (no tiles).

    ``pixel_chunk`` bounds memory (pixels per chunk, a whole number >= 1; None: all at once); differentiable by
    autograd. ``max_elements`` is not used (kept for the signature of :func:`rasterize_tiles`).
    """
    where = "rasterize_dense"
    if not isinstance(pr, Projected):
        raise PhysarError(f"{where}: pr must be the Projected of project(), got {type(pr).__name__}")
    width, height = _whole(width, "width", where), _whole(height, "height", where)
    pixel_chunk = _whole(pixel_chunk, "pixel_chunk", where, none=True)
    background = _background(background, where, width, height)
    return _rasterize_dense(pr, width, height, background, pixel_chunk)


def _rasterize_dense(pr: Projected, width: int, height: int, background, pixel_chunk) -> RenderResult:
    """:func:`rasterize_dense` without the input checks."""
    dtype, dev = pr.means2d.dtype, pr.means2d.device
    vis = torch.nonzero(pr.radii > 0).squeeze(1)
    vis = vis[torch.argsort(pr.depths.detach()[vis], stable=True)]
    jj, ii = torch.meshgrid(torch.arange(height, dtype=dtype, device=dev) + 0.5,
                            torch.arange(width, dtype=dtype, device=dev) + 0.5, indexing="ij")
    pxa, pya = ii.reshape(-1), jj.reshape(-1)
    mean, conic, opac = pr.means2d[vis], pr.conics[vis], pr.opacities[vis]
    feat = torch.cat([pr.colors[vis], pr.depths[vis, None]], 1)
    chunk = pixel_chunk or pxa.numel()
    outs = []
    for s in range(0, pxa.numel(), chunk):
        px, py = pxa[s:s + chunk][None], pya[s:s + chunk][None]
        alpha = _alpha(px - mean[:, 0:1], py - mean[:, 1:2], conic, opac)
        w = _composite_weights(alpha, None, None)
        outs.append(torch.cat([w.T @ feat, w.sum(0)[:, None]], 1))
    img = torch.cat(outs, 0).reshape(height, width, 5)
    return _finish(img[..., :3], img[..., 3], img[..., 4], background)


def _render_gsplat(g: Gaussians, cam: Camera, cov3d, colors, background, eps2d, near) -> RenderResult:
    r"""gsplat backend (CUDA): ``gsplat.rasterization`` in "classic" mode with render_mode "RGB+ED".

    gsplat's kernels are float32: inputs are cast to float32 and the outputs back to the means' dtype, so
    autograd reaches the caller's tensors of any dtype. gsplat takes the activated values (scales in m,
    opacities in (0, 1)), quaternions in (w, x, y, z) order (normalised by gsplat), SH coefficients (N, K, 3)
    with the 3DGS ``+ 0.5`` convention, or post-activation colours (N, 3), and a (N, 3, 3) covariance
    (``covars``) in place of quaternions and scales when given. One convention differs from the torch backend:
    gsplat caps :math:`\alpha` at 0.999 instead of 0.99, so pixels under a Gaussian of peak opacity
    :math:`\eta > 0.99` differ (measured on a lent H200: benchmarks/RESULTS.md, "Gaussians and MPM on CUDA")."""
    try:
        import gsplat
    except ImportError:
        raise PhysarError("backend='gsplat' needs the gsplat package (CUDA only); use backend='torch'") from None
    if g.means.device.type != "cuda":
        raise PhysarError(f"backend='gsplat' needs the Gaussians on a CUDA device, got {g.means.device}; "
                          "use backend='torch' or move them with g.to('cuda')")
    return _gsplat_rasterize(gsplat, g, cam, cov3d, colors, background, eps2d, near)


def _gsplat_rasterize(gsplat, g: Gaussians, cam: Camera, cov3d, colors, background, eps2d, near) -> RenderResult:
    """The call of ``gsplat.rasterization`` and the conversion of its outputs (see :func:`_render_gsplat`)."""
    dev, dt = g.means.device, g.means.dtype
    f32 = lambda t: t.to(dev, torch.float32)
    kwargs = {}
    if colors is None:
        colors, kwargs["sh_degree"] = g.sh, g.sh_degree
    if cov3d is not None:
        kwargs["covars"] = f32(cov3d)
    out, alphas, _ = gsplat.rasterization(
        f32(g.means), f32(g.quats), f32(g.scales), f32(g.opacities), f32(colors),
        f32(cam.viewmat)[None], f32(cam.K)[None], cam.width, cam.height,
        near_plane=near, eps2d=eps2d, render_mode="RGB+ED", rasterize_mode="classic", **kwargs)
    rgb, alpha = out[0, ..., :3].to(dt), alphas[0, ..., 0].to(dt)
    if background is not None:  # composited here: gsplat 1.5.3's shape check refuses a (1, 3) background (packed)
        rgb = rgb + (1.0 - alpha)[..., None] * background.to(dev, dt)
    return RenderResult(rgb, alpha, out[0, ..., 3].to(dt))


def render(g: Gaussians, cam: Camera, *, F: torch.Tensor | None = None, cov3d: torch.Tensor | None = None,
           colors: torch.Tensor | None = None, background: torch.Tensor | None = None,
           backend: str = "auto", tile_size: int = 4, eps2d: float = 0.3, near: float = 0.01,
           pixel_chunk: int | None = None, max_elements: float = 2e8) -> RenderResult:
    r"""Render Gaussians ``g`` seen by ``cam``: RGB, alpha mask and expected depth (m).

    ``F`` (N, 3, 3): deformation gradients, giving :math:`\Sigma = F R S S^\top R^\top F^\top` (seed 002,
    Eq. 3); ``cov3d`` (N, 3, 3) overrides the covariance; ``colors`` (N, 3) overrides the SH colour (otherwise
    SH evaluated in the direction camera centre :math:`\to` mean). ``eps2d`` (:math:`\mathrm{px}^2`) is the
    3DGS screen-space low-pass filter (0.3); ``near`` (m) culls Gaussians with :math:`p_z \le \mathtt{near}`.
    ``backend``: "torch" (tiles, CPU/any device), "dense" (naive reference), "gsplat" (CUDA; see
    :func:`_render_gsplat`), "auto" (gsplat when the tensors are on CUDA and gsplat imports, torch otherwise).
    ``max_elements``: memory guard of the tile backend (pairs x tile pixels), see :func:`rasterize_tiles`.

    Checked once per call (a PhysarError names the argument, and the Gaussian): ``g`` a :class:`Gaussians`
    with finite values (:meth:`Gaussians.check_finite`), ``cam`` a :class:`Camera`, ``F`` / ``cov3d``
    (N, 3, 3) and ``colors`` (N, 3) finite and of the means' dtype (``cov3d`` symmetric positive
    semi-definite), ``background`` (3,) or (H, W, 3) finite, ``tile_size`` and ``pixel_chunk`` whole numbers
    >= 1, ``eps2d`` >= 0, ``near`` > 0.
    """
    where = "render"
    if not isinstance(g, Gaussians):
        raise PhysarError(f"{where}: g must be physar.gaussians.Gaussians, got {type(g).__name__}")
    _check_camera(cam, where)
    tile_size = _whole(tile_size, "tile_size", where)
    pixel_chunk = _whole(pixel_chunk, "pixel_chunk", where, none=True)
    _check_options(where, eps2d, near, max_elements)
    background = _background(background, where, cam.width, cam.height)
    g.check_finite(where)
    if backend == "auto":
        backend = "torch"
        if g.means.is_cuda:
            try:
                import gsplat  # noqa: F401

                backend = "gsplat"
            except ImportError:
                pass
    if backend not in ("torch", "dense", "gsplat"):
        raise PhysarError(f"render: unknown backend {backend!r}; use 'auto', 'torch', 'dense' or 'gsplat'")
    if F is not None and cov3d is not None:
        raise PhysarError("render: give either F or cov3d, not both")
    n, dt = len(g), g.means.dtype
    if F is not None:
        _per_gaussian(F, "F", where, (n, 3, 3), dt)
        cov3d = g.covariance(F)
    elif cov3d is not None:
        _per_gaussian(cov3d, "cov3d", where, (n, 3, 3), dt)
        _check_cov3d(cov3d, where)
    if colors is not None:
        _per_gaussian(colors, "colors", where, (n, 3), dt)
    if backend == "gsplat":
        return _render_gsplat(g, cam, cov3d, colors, background, eps2d, near)
    if cov3d is None:
        cov3d = g.covariance()
    if colors is None:
        colors = _sh_colors(g, cam)
    pr = _project(g.means, cov3d, g.opacities, colors, cam, eps2d, near)
    if backend == "dense":
        return _rasterize_dense(pr, cam.width, cam.height, background, pixel_chunk)
    return _rasterize_tiles(pr, cam.width, cam.height, background, tile_size, max_elements, True)
