"""Gated PD actuation of seed 002, Eq. (6)-(7).

f_PD = k_p (x_ref - x) + k_d (v_ref - v)   (Eq. 6),   f_ex = omega f_PD   (Eq. 7).

physar scales the force by the particle mass, f_ex = m_p omega_p [k_p (x_ref - x) + k_d (v_ref - v)], so that
the gains do not depend on the particle sampling: k_p is in 1/s^2 and k_d in 1/s (seed 002 App. uses
k_p = 2e2, k_d = 2e1).  omega_p = 0 outside the actuated volume.  The force is transferred to the grid with
the P2G weights (seed 002, §4.2) as the impulse dt f_ex.

When the force is evaluated (seed 002 Alg. 2): lines 2-4 compute f_ex^n from the state s_n at the start of
frame n and the T substeps of lines 5-8 all apply that same force (:func:`held_force`, the default of
:class:`physar.mpm.model.Control` and :class:`physar.mpm.torch_bridge.Params`).  The per-substep variant
(:func:`pd_force` inside the P2G kernel, evaluated on each substep's state) is kept for stiff tracking
(``hold=False``): held over a frame of length h, the explicit PD update is stable only for about
omega k_d h < 2 and omega k_p h^2 < 2 (the velocity factor 1 - omega k_d h of one frame), e.g. the seed's
gains at 30 fps, not k_d = 110 1/s.
"""

from __future__ import annotations

import numpy as np
import warp as wp


@wp.func
def pd_force(
    m: wp.float64,
    omega: wp.float64,
    x: wp.vec3d,
    v: wp.vec3d,
    x_ref: wp.vec3d,
    v_ref: wp.vec3d,
    kp: wp.float64,
    kd: wp.float64,
) -> wp.vec3d:
    """Mass-scaled gated PD force (N), seed 002 Eq. (6)-(7)."""
    return m * omega * (kp * (x_ref - x) + kd * (v_ref - v))


def held_force(m, omega, x, v, x_ref, v_ref, kp: float, kd: float):
    """f_ex = m omega [k_p (x_ref - x) + k_d (v_ref - v)] (N), Eq. (6)-(7), for NumPy arrays or torch tensors
    (differentiable): m, omega (N,), x, v, x_ref, v_ref (N, 3) at the start of a frame (Alg. 2, lines 2-4)."""
    return (m * omega)[:, None] * (kp * (x_ref - x) + kd * (v_ref - v))


def pd_force_np(m, omega, x, v, x_ref, v_ref, kp, kd):
    """NumPy version of :func:`pd_force` for arrays (N,), (N,), (N, 3) ... (N)."""
    return held_force(np.asarray(m, dtype=np.float64), np.asarray(omega, dtype=np.float64), x, v, x_ref, v_ref,
                      kp, kd)
