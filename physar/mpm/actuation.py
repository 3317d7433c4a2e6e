"""Gated PD actuation of seed 002, Eq. (6)-(7).

f_PD = k_p (x_ref - x) + k_d (v_ref - v)   (Eq. 6),   f_ex = omega f_PD   (Eq. 7).

physar scales the force by the particle mass, f_ex = m_p omega_p [k_p (x_ref - x) + k_d (v_ref - v)], so that
the gains do not depend on the particle sampling: k_p is in 1/s^2 and k_d in 1/s (seed 002 App. uses
k_p = 2e2, k_d = 2e1).  omega_p = 0 outside the actuated volume.  The force is transferred to the grid with
the P2G weights (seed 002, §4.2) as the impulse dt f_ex.
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


def pd_force_np(m, omega, x, v, x_ref, v_ref, kp, kd):
    """NumPy version of :func:`pd_force` for arrays (N,), (N,), (N, 3) ... (N)."""
    return (np.asarray(m) * np.asarray(omega))[:, None] * (kp * (x_ref - x) + kd * (v_ref - v))
