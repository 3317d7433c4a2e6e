r"""Ground-truth renderer of the synthetic scenes: z-buffered shaded sphere impostors (numpy).

This is deliberately *not* the Gaussian rasteriser of :mod:`physar.gaussians` (no inverse crime, issue 8
part 4): every point (a fine MPM particle or a body sample) is drawn as an opaque sphere of radius r (m),
i.e. a screen-space disc of radius :math:`f r / z` (px), at the depth of the sphere surface
:math:`z - r \sqrt{1 - d^2}` (:math:`d` = normalised distance to the disc centre), with Lambert shading of the
sphere normal :math:`n = (d_x, d_y, -\sqrt{1 - d^2})` (camera frame) by a directional light, and a hard
z-buffer.  The image is
rendered at ``supersample`` times the resolution and box-filtered down (anti-aliased edges); the mask is
the covered fraction >= 0.5.  Camera: pinhole, OpenCV convention (x right, y down, z forward), pixel
(i, j) centred at (i + 0.5, j + 0.5), the convention of :class:`physar.gaussians.Camera`.
"""

from __future__ import annotations

import numpy as np


def render_spheres(points: np.ndarray, colors: np.ndarray, radius: float | np.ndarray, K: np.ndarray,
                   R: np.ndarray, t: np.ndarray, width: int, height: int, background=(0.3, 0.3, 0.35),
                   light=(-0.3, 0.5, 0.8), ambient: float = 0.35, supersample: int = 2):
    """Render points (N, 3) (m, world) with colours (N, 3) in [0, 1] as shaded spheres.

    ``K`` (3, 3) intrinsics (px) of the *output* resolution, ``R``, ``t`` world -> camera.  ``light`` is the
    direction the light travels in camera coordinates.  Returns (rgb (H, W, 3) float32 in [0, 1],
    mask (H, W) bool).
    """
    s = int(supersample)
    W, H = width * s, height * s
    pts = np.asarray(points, dtype=np.float64)
    col = np.asarray(colors, dtype=np.float64)
    rad = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(pts),))
    p = pts @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64)
    z = p[:, 2]
    ok = z > 1e-3
    p, col, rad, z = p[ok], col[ok], rad[ok], z[ok]
    fx, fy, cx, cy = K[0, 0] * s, K[1, 1] * s, K[0, 2] * s, K[1, 2] * s
    u = fx * p[:, 0] / z + cx
    v = fy * p[:, 1] / z + cy
    rpx = fx * rad / z
    vis = (u + rpx > 0) & (u - rpx < W) & (v + rpx > 0) & (v - rpx < H)
    u, v, rpx, z, col, rad = u[vis], v[vis], rpx[vis], z[vis], col[vis], rad[vis]
    L = np.asarray(light, dtype=np.float64)
    L = L / np.linalg.norm(L)
    img = np.empty((H, W, 3))
    img[:] = np.asarray(background, dtype=np.float64)
    cover = np.zeros((H, W))
    if len(u):
        k = int(np.ceil(rpx.max())) + 1
        off = np.arange(-k, k + 1)
        oi, oj = np.meshgrid(off, off, indexing="xy")
        oi, oj = oi.reshape(-1), oj.reshape(-1)
        i = np.floor(u)[:, None].astype(np.int64) + oi[None]
        j = np.floor(v)[:, None].astype(np.int64) + oj[None]
        dx = (i + 0.5 - u[:, None]) / rpx[:, None]
        dy = (j + 0.5 - v[:, None]) / rpx[:, None]
        d2 = dx * dx + dy * dy
        keep = (d2 <= 1.0) & (i >= 0) & (i < W) & (j >= 0) & (j < H)
        pid = np.nonzero(keep)[0]
        dx, dy, d2, i, j = dx[keep], dy[keep], d2[keep], i[keep], j[keep]
        nz = -np.sqrt(np.clip(1.0 - d2, 0.0, 1.0))
        depth = z[pid] + rad[pid] * nz
        pix = j * W + i
        order = np.lexsort((depth, pix))  # by pixel, then nearest first
        first = np.ones(len(order), dtype=bool)
        first[1:] = pix[order][1:] != pix[order][:-1]
        sel = order[first]
        shade = ambient + (1 - ambient) * np.clip(-(dx[sel] * L[0] + dy[sel] * L[1] + nz[sel] * L[2]), 0, 1)
        flat = img.reshape(-1, 3)
        flat[pix[sel]] = np.clip(col[pid[sel]] * shade[:, None], 0, 1)
        cover.reshape(-1)[pix[sel]] = 1.0
    rgb = img.reshape(height, s, width, s, 3).mean(axis=(1, 3))
    mask = cover.reshape(height, s, width, s).mean(axis=(1, 3)) >= 0.5
    return rgb.astype(np.float32), mask
