r"""Deformation gradients of the physics-aware fine-tuning of seed 002 §4.1 (Eq. 4-5).

The canonical Gaussians are learned on the spin clip with fixed skinning; before the dynamic stage their
appearance is fine-tuned under the deformation gradients that the simulator itself would produce. For each
frame :math:`n` of the spin clip the particles are put at their LBS means :math:`x_n` with the
central-difference velocities :math:`v_n = (x_{n+1} - x_{n-1}) / (2\, dt)` (Eq. 4), and Alg. 1 is run with the
stress fixed to :math:`\sigma = 0` and the plasticity :math:`F = F_\text{trial}`, i.e. one frame of
``substeps`` MLS-MPM substeps (quadratic B-splines, APIC) of:

.. math::

    \text{P2G:} \quad & m_i = \sum_p w_{ip} m_p, \qquad
        m_i v_i = \sum_p w_{ip} m_p \big(v_p + C_p (x_i - x_p)\big) \\
    \text{G2P:} \quad & v_p = \sum_i w_{ip} v_i, \qquad
        C_p = \frac{4}{dx^2} \sum_i w_{ip} v_i (x_i - x_p)^\top \\
    & F_p \leftarrow (I + dt\, C_p) F_p, \qquad x_p \leftarrow x_p + dt\, v_p

with no force (:math:`\sigma = 0`, no gravity). :math:`F` is carried over from frame to frame; :math:`x, v`
are reset to the LBS values at every frame. The grid is a dense box around the particles (no walls), so any
pose can be used.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch

_OFFSETS = torch.tensor(list(itertools.product(range(3), repeat=3)), dtype=torch.long)  # (27, 3)


def _p2g2p(x: torch.Tensor, v: torch.Tensor, C: torch.Tensor, mass: torch.Tensor, dx: float,
           lo: torch.Tensor, shape: tuple[int, int, int]):
    """One force-free APIC transfer: returns grid-interpolated (v_p, C_p)."""
    xi = (x - lo) / dx
    base = torch.floor(xi - 0.5).long()
    fx = xi - base
    w = torch.stack([0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2], 1)  # (N, 3, 3)
    off = _OFFSETS
    wk = w[:, off[:, 0], 0] * w[:, off[:, 1], 1] * w[:, off[:, 2], 2]  # (N, 27)
    dpos = (off[None].to(x.dtype) - fx[:, None, :]) * dx  # (N, 27, 3) node - particle
    node = base[:, None, :] + off[None]
    nid = (node[..., 0] * shape[1] + node[..., 1]) * shape[2] + node[..., 2]  # (N, 27)
    n_nodes = shape[0] * shape[1] * shape[2]
    mp = wk * mass[:, None]
    affine = v[:, None, :] + (C[:, None] @ dpos[..., None])[..., 0]
    gm = torch.zeros(n_nodes, dtype=x.dtype).index_add_(0, nid.reshape(-1), mp.reshape(-1))
    gmv = torch.zeros(n_nodes, 3, dtype=x.dtype).index_add_(0, nid.reshape(-1), (mp[..., None] * affine).reshape(-1, 3))
    gv = gmv / gm.clamp_min(1e-30)[:, None]
    vi = gv[nid]  # (N, 27, 3)
    v_new = (wk[..., None] * vi).sum(1)
    C_new = 4.0 / dx**2 * (wk[..., None, None] * vi[..., :, None] * dpos[..., None, :]).sum(1)
    return v_new, C_new


def zero_stress_deformation(x: np.ndarray | torch.Tensor, dt: float, substeps: int, dx: float,
                            mass: np.ndarray | None = None) -> torch.Tensor:
    r"""Deformation gradients :math:`F` (F, N, 3, 3) of particles following the trajectories ``x`` (F, N, 3)
    (m), frames ``dt`` (s) apart, by Alg. 1 with :math:`\sigma = 0` (module docstring); :math:`F_0 = I`.
    ``dx`` is the grid spacing (m), ``mass`` (N,) the particle masses (default 1)."""
    if isinstance(x, np.ndarray) and not x.flags.writeable:
        x = np.array(x, dtype=np.float64)  # a read-only view (e.g. broadcast): torch needs writable memory
    x = torch.as_tensor(x, dtype=torch.float64)
    nf, n = x.shape[:2]
    m = torch.ones(n, dtype=torch.float64) if mass is None else torch.as_tensor(mass, dtype=torch.float64)
    v = torch.zeros_like(x)
    if nf > 2:
        v[1:-1] = (x[2:] - x[:-2]) / (2 * dt)  # Eq. 4
    if nf > 1:
        v[0], v[-1] = (x[1] - x[0]) / dt, (x[-1] - x[-2]) / dt
    ds = dt / substeps
    reach = float(v.abs().max()) * dt + 3 * dx
    lo = x.reshape(-1, 3).min(0).values - reach
    shape = tuple(int(s) for s in torch.ceil((x.reshape(-1, 3).max(0).values + reach - lo) / dx).long() + 1)
    F = torch.eye(3, dtype=torch.float64).repeat(n, 1, 1)
    C = torch.zeros(n, 3, 3, dtype=torch.float64)
    out = [F.clone()]
    eye = torch.eye(3, dtype=torch.float64)
    for f in range(nf - 1):
        xp, vp = x[f].clone(), v[f].clone()
        for _ in range(substeps):
            vp, C = _p2g2p(xp, vp, C, m, dx, lo, shape)
            F = (eye + ds * C) @ F
            xp = xp + ds * vp
        out.append(F.clone())
    return torch.stack(out)


__all__ = ["zero_stress_deformation"]
