r"""Gated PD actuation of seed 002, Eq. (6)-(7).

.. math::

    f_\text{PD} = k_p (x_\text{ref} - x) + k_d (v_\text{ref} - v) \quad \text{(Eq. 6)}, \qquad
    f_\text{ex} = \omega f_\text{PD} \quad \text{(Eq. 7)}.

physar scales the force by the particle mass,
:math:`f_\text{ex} = m_p \omega_p \big[k_p (x_\text{ref} - x) + k_d (v_\text{ref} - v)\big]`, so that the
gains do not depend on the particle sampling: :math:`k_p` is in :math:`1/\mathrm{s}^2` and :math:`k_d` in
:math:`1/\mathrm{s}` (seed 002 App. uses :math:`k_p = 2 \cdot 10^2`, :math:`k_d = 2 \cdot 10^1`).
:math:`\omega_p = 0` outside the actuated volume.  The force is transferred to the grid with the P2G weights
(seed 002, §4.2) as the impulse :math:`dt\, f_\text{ex}`.

When the force is evaluated (seed 002 Alg. 2): lines 2-4 compute :math:`f_\text{ex}^n` from the state
:math:`s_n` at the start of frame :math:`n` and the :math:`T` substeps of lines 5-8 all apply that same force
(:func:`held_force`, the default of :class:`physar.mpm.model.Control` and
:class:`physar.mpm.torch_bridge.Params`).  The per-substep variant (:func:`pd_force` inside the P2G kernel,
evaluated on each substep's state) is kept for stiff tracking (``hold=False``): held over a frame of length
:math:`h`, the explicit PD update is stable only for about :math:`\omega k_d h < 2` and
:math:`\omega k_p h^2 < 2` (the velocity factor :math:`1 - \omega k_d h` of one frame), e.g. the seed's gains
at 30 fps, not :math:`k_d = 110\ \mathrm{s}^{-1}`.
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
    r""":math:`f_\text{ex} = m \omega \big[k_p (x_\text{ref} - x) + k_d (v_\text{ref} - v)\big]` (N),
    Eq. (6)-(7), for NumPy arrays or torch tensors (differentiable): m, omega (N,), x, v, x_ref, v_ref (N, 3)
    at the start of a frame (Alg. 2, lines 2-4)."""
    return (m * omega)[:, None] * (kp * (x_ref - x) + kd * (v_ref - v))


def pd_force_np(m, omega, x, v, x_ref, v_ref, kp, kd):
    """NumPy version of :func:`pd_force` for arrays (N,), (N,), (N, 3) ... (N)."""
    return held_force(np.asarray(m, dtype=np.float64), np.asarray(omega, dtype=np.float64), x, v, x_ref, v_ref,
                      kp, kd)
