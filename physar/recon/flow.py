r"""Structure-preserving 3-D flow of seed 002 §4.4 (Eq. 9): the losses of the per-frame position optimisation.

.. math::

    L_\text{SP-Flow} = \lambda_\text{rgb} L_\text{rgb} + \lambda_\text{flow} L_\text{flow}
    + \lambda_\text{arap} L_\text{arap} \qquad \text{(Eq. 9)}

* :math:`L_\text{rgb}`: the image loss of the rendered frame (in :mod:`physar.recon.train`).
* :math:`L_\text{flow}` (:func:`flow_loss`): 2-D optical flow :math:`u` between consecutive observed frames,
  computed by OpenCV's DIS (Kroeger et al. 2016; RAFT weights are not reachable offline), compared with the
  image motion of the particles visible in frame :math:`n-1`,
  :math:`\operatorname{mean}_i \lVert \pi(x'_{n,i}) - \pi(x'_{n-1,i}) - u(\pi(x'_{n-1,i})) \rVert_1` (px),
  :math:`u` sampled bilinearly; visibility = the particle is no deeper than the rendered (alpha-normalised)
  depth + a tolerance and the pixel is covered.
* :math:`L_\text{arap}` (:func:`arap_energy`): as-rigid-as-possible energy (Sorkine & Alexa 2007) with respect
  to the rest (canonical) lattice,
  :math:`E = \operatorname{mean}_{(i, j)} \lVert (x_i - x_j) - R_i (X_i - X_j) \rVert^2` (m^2) over the edges,
  :math:`R_i` the rotation of the polar decomposition of :math:`S_i = \sum_j (x_i - x_j)(X_i - X_j)^\top` (the
  optimal local rotation). :math:`R_i` is held fixed when differentiating, which gives the exact gradient at
  the optimal rotations (envelope theorem).
* :math:`L_\text{ray}` (:func:`ray_motion`), **not in the seed**: the mean squared motion along the camera ray
  of each particle's previous position, :math:`\operatorname{mean}_i ((x'_{n,i} - x'_{n-1,i}) \cdot r_i)^2`
  (m^2), :math:`r_i` the unit ray from the camera centre through :math:`x'_{n-1,i}`.  A 2-D flow observes motion
  along the ray only through the change of scale (looming); with DIS's errors (0.2-0.3 px against 0.6-1.2 px of
  motion on the quick C-pillow) that signal is noise, and the flow term alone moved the object along the rays
  the wrong way (depth error 9.6 mm at the third frame against 5.7 mm for the object at rest, benchmarks/RESULTS.md
  "Why the Eq. 9 flow target was poor").  The term keeps the unobserved depth at the previous frame's unless
  ARAP (the hidden particles) asks for more.

:func:`sp_flow_prior` is the weighted sum of the three geometric terms that the image loss is added to.

The positions :math:`x'_n` it gives are the target of the Eq. 10 term
:math:`\lambda_\text{3Dflow} \lVert x_{n} - x'_{n} \rVert_1` of the physics stage (:func:`flow_target_loss`).
Only part of :math:`x'_n` is measured: the motion across the rays of the particles the optical flow saw; the
rest is ARAP's extrapolation (hidden particles, about 90 % on the C-pillow) and the ray term's prior (depth).
``TrainConfig.flow_target`` chooses what the physics stage compares: every coordinate of every particle (the
seed), the visible particles, or their motion across the rays ("observed", physar's default).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from physar.errors import PhysarError


def dis_flow(img0: np.ndarray, img1: np.ndarray, preset: str = "medium") -> np.ndarray:
    r"""Dense optical flow (H, W, 2) (px, (dx, dy)) from img0 to img1 (RGB float in [0, 1] or uint8) by DIS.

    Flow is sampled at pixel centres: :math:`\mathrm{img1}(p + u(p)) \approx \mathrm{img0}(p)`."""
    presets = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
    if preset not in presets:
        raise PhysarError(f"dis_flow: unknown preset {preset!r}; use {', '.join(presets)}")
    a, b = np.asarray(img0), np.asarray(img1)
    if a.shape != b.shape:
        raise PhysarError(f"dis_flow: image shapes differ {a.shape} vs {b.shape}")

    def gray(z):
        z = np.asarray(z)
        if z.dtype != np.uint8:
            z = (np.clip(z, 0, 1) * 255 + 0.5).astype(np.uint8)
        return cv2.cvtColor(z, cv2.COLOR_RGB2GRAY) if z.ndim == 3 else z

    dis = cv2.DISOpticalFlow_create(presets[preset])
    if min(a.shape[:2]) < 256:  # small frames: denser patches, down to the finest scale (sub-pixel motion)
        dis.setPatchStride(2)
        dis.setFinestScale(0)
        dis.setVariationalRefinementIterations(5)
    return dis.calc(gray(a), gray(b), None).astype(np.float32)


def project(x: torch.Tensor, K: torch.Tensor, R: torch.Tensor, t: torch.Tensor):
    """Pixel coordinates (N, 2) (pixel centres at :math:`i + 0.5`) and camera depths (N,) of world points x
    (N, 3)."""
    p = x @ R.T + t
    z = p[:, 2]
    uv = torch.stack([K[0, 0] * p[:, 0] / z + K[0, 2], K[1, 1] * p[:, 1] / z + K[1, 2]], 1)
    return uv, z


def sample_bilinear(img: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Values (N, C) of an (H, W, C) image at continuous pixel coordinates uv (N, 2) (centres at
    :math:`i + 0.5`), clamped at the border."""
    H, W = img.shape[:2]
    u = (uv[:, 0] - 0.5).clamp(0, W - 1)
    v = (uv[:, 1] - 0.5).clamp(0, H - 1)
    u0, v0 = u.floor().long().clamp(max=W - 2), v.floor().long().clamp(max=H - 2)
    a, b = (u - u0)[:, None], (v - v0)[:, None]
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
            + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])


def visible(uv: torch.Tensor, z: torch.Tensor, depth: torch.Tensor, alpha: torch.Tensor, tol: float,
            min_alpha: float = 0.5) -> torch.Tensor:
    """Particles inside the image, on a covered pixel, and at most ``tol`` (m) behind the rendered surface
    (depth normalised by alpha)."""
    H, W = alpha.shape
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H) & (z > 0)
    i = uv[:, 0].long().clamp(0, W - 1)
    j = uv[:, 1].long().clamp(0, H - 1)
    a = alpha[j, i]
    surf = depth[j, i] / a.clamp_min(1e-6)
    return inside & (a >= min_alpha) & (z <= surf + tol)


def flow_loss(x_prev: torch.Tensor, x_new: torch.Tensor, flow: torch.Tensor, vis: torch.Tensor, K, R, t):
    r""":math:`L_\text{flow}` of Eq. 9 (px):
    :math:`\operatorname{mean} \lVert \pi(x_\text{new}) - \pi(x_\text{prev}) - u(\pi(x_\text{prev})) \rVert_1`
    over the visible particles."""
    if not bool(vis.any()):
        return torch.zeros((), dtype=x_new.dtype)
    uv0, _ = project(x_prev[vis], K, R, t)
    uv1, _ = project(x_new[vis], K, R, t)
    u = sample_bilinear(flow, uv0.detach()).to(uv1.dtype)
    return (uv1 - uv0.detach() - u).abs().sum(1).mean()


def ray_motion(x_prev: torch.Tensor, x_new: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    r""":math:`L_\text{ray}` (m^2): mean over particles of the squared component of :math:`x_\text{new} -
    x_\text{prev}` along the unit ray from the camera centre (world, (3,)) through :math:`x_\text{prev}`."""
    ray = _unit_rays(x_prev, centre)
    return (((x_new - x_prev) * ray).sum(1) ** 2).mean()


def _unit_rays(points: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """Unit rays (N, 3) from the camera centre (3,) through ``points`` (N, 3), detached (held fixed when
    differentiating)."""
    ray = (points - centre).detach()
    return ray / torch.linalg.vector_norm(ray, dim=1, keepdim=True)


def sp_flow_prior(x: torch.Tensor, x_prev: torch.Tensor, flow: torch.Tensor, vis: torch.Tensor, K, R, t,
                  X_rest: torch.Tensor, pairs: torch.Tensor, lambda_of: float, lambda_arap: float,
                  lambda_ray: float) -> torch.Tensor:
    r"""The geometric part of the Eq. 9 objective for frame n (the image loss is added by the caller):
    :math:`\lambda_\text{of} L_\text{flow} + \lambda_\text{arap} L_\text{arap} + \lambda_\text{ray}
    L_\text{ray}` with ``x_prev`` = :math:`x'_{n-1}` and the camera (K, R, t) of :func:`project`."""
    out = lambda_of * flow_loss(x_prev, x, flow, vis, K, R, t) + lambda_arap * arap_energy(x, X_rest, pairs)
    if lambda_ray > 0:
        out = out + lambda_ray * ray_motion(x_prev, x, -(R.T @ t))
    return out


def flow_target_loss(x: torch.Tensor, target: torch.Tensor, sel: torch.Tensor | None = None,
                     centre: torch.Tensor | None = None) -> torch.Tensor:
    r"""The Eq. 10 3-D flow term without its weight (m): :math:`\operatorname{mean} |x_n - x'_n|` over the
    coordinates of the particles ``sel`` (all when None). With the camera centre (world, (3,)) given, only the
    part of :math:`x_n - x'_n` across the ray from the centre through :math:`x'_n` is compared,
    :math:`d - (d \cdot r) r`: the Eq. 9 target observes depth only through :math:`L_\text{ray}`'s prior.  The
    L1 norm is over the world coordinates, as in the seed's Eq. 10, so its weight per unit length depends on the
    direction: 1 to :math:`\sqrt{3}` for a vector in 3-D, up to :math:`\sqrt{3}` also for one across a ray."""
    if sel is not None:
        if not bool(sel.any()):
            return torch.zeros((), dtype=x.dtype)
        x, target = x[sel], target[sel]
    d = x - target
    if centre is not None:
        r = _unit_rays(target, centre)
        d = d - (d * r).sum(1, keepdim=True) * r
    return d.abs().mean()


def polar_rotation(S: torch.Tensor) -> torch.Tensor:
    r"""Rotation part (:math:`\det = +1`) of the polar decomposition of :math:`S` (..., 3, 3)."""
    U, _, Vh = torch.linalg.svd(S)
    d = torch.sign(torch.linalg.det(U @ Vh))
    D = torch.ones(*S.shape[:-2], 3, dtype=S.dtype)
    D[..., 2] = d
    return (U * D[..., None, :]) @ Vh


def arap_energy(x: torch.Tensor, X: torch.Tensor, pairs: torch.Tensor) -> torch.Tensor:
    """ARAP energy (m^2) of positions x (N, 3) w.r.t. rest positions X over undirected edges ``pairs`` (E, 2)
    (both directions summed, mean over edges); see the module docstring."""
    i, j = pairs[:, 0], pairs[:, 1]
    dX = X[i] - X[j]
    dx = x[i] - x[j]
    P = (dx[:, :, None] * dX[:, None, :]).detach()
    S = torch.zeros(len(X), 3, 3, dtype=x.dtype).index_add(0, i, P).index_add(0, j, P)
    Rm = polar_rotation(S)
    r_i = dx - (Rm[i] @ dX[:, :, None])[..., 0]
    r_j = dx - (Rm[j] @ dX[:, :, None])[..., 0]
    return 0.5 * ((r_i**2).sum(1) + (r_j**2).sum(1)).mean()


__all__ = ["arap_energy", "dis_flow", "flow_loss", "flow_target_loss", "polar_rotation", "ray_motion", "sp_flow_prior"]
