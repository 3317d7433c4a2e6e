r"""Fused, hand-scheduled reverse mode for frames of expert-law MLS-MPM substeps (seed 002, Alg. 1-2).

The generic bridge (:mod:`physar.mpm.torch_bridge`) wraps every Warp launch in its own autograd function and
replays it on a ``wp.Tape``; with per-frame checkpointing a substep is then run three times forward plus once
in reverse, with fresh allocations per launch.  Without neural residuals the whole frame is one
:class:`torch.autograd.Function` here:

* two fused kernels per substep: stress + P2G (:math:`\tau = \tau(F, E, \nu) + \tau_f(F, a_0, E_f)`, the fibre
  term of :func:`physar.mpm.constitutive.fiber_stress`, inside the scatter) and G2P + return map
  (:math:`F \leftarrow \mathcal{P}\big((I + \Delta t\, C) F\big)` inside the gather); the grid update is the
  shared ``grid_update_kernel``;
* forward: the last K substeps of the frame keep their states and grids, as many as a memory budget allows
  (``FusedFrame.keep_bytes``, over all frames alive in the graph); the first :math:`T - K` store only the
  states at segment boundaries (every :math:`k \approx \sqrt{T - K}` substeps);
* backward: the kept substeps are reversed directly; then per segment (last first) the :math:`k` substeps are
  recomputed with their states and grids stored and reversed; memory is
  :math:`O\big((K + (T - K)/k + k)\, N\big)`, cost :math:`2 - K/T` forward sweeps + 1 adjoint sweep;
* the reverse of a substep, per particle (issue 19: hand-written where Warp's generated adjoint of the
  27-node loops was 3-4x slower than the forward): the return map and position update by Warp's adjoints of
  small per-particle kernels (:func:`trial_plastic_kernel`, :func:`advect_kernel`; by hand in
  :func:`g2p_gather_adjoint_kernel` when there is no collider and no plastic law), the APIC gather by hand
  (a scatter of the grid velocity adjoints), the grid update by Warp, the MLS-MPM scatter by hand as a gather
  of the grid adjoints (no atomics), the stress and external force by Warp's adjoint of
  :func:`stress_force_kernel`;
* both CPU cores: each per-particle launch can be split into two halves run concurrently (Warp's CPU kernels
  run outside the GIL); the P2G halves scatter into separate grids that are summed, the G2P adjoint halves into
  separate grid adjoints that are summed.  By default one or two threads are chosen per sweep from measured
  wall times (:class:`ThreadChooser`): under load two threads can be slower than one.

Devices: every array and launch is on ``model.device`` (:class:`physar.mpm.model.MPMModel`); tensors are moved
there and the results returned on the device of the caller's ``x``.  On a GPU each launch runs whole (one
"thread" in the sense above: the split into halves is for the CPU's cores).

Gradients equal the generic Warp-tape path's to round-off and central differences; see tests/mpm/test_fused.py
and tests/mpm/test_fused_paths.py.
"""

from __future__ import annotations

import math
import os
import threading
import time
import weakref
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
import warp as wp

from physar.mpm.actuation import pd_force
from physar.mpm.constitutive import hardening_factor, kirchhoff_stress_fiber
from physar.mpm.model import (
    MPMModel,
    _base,
    _frac,
    _weights,
    advect_particle,
    g2p_particle,
    grid_update_kernel,
    p2g_particle,
    plastic_update,
)

_f = wp.float64

_POOL: ThreadPoolExecutor | None = None
MIN_PARTICLES_PER_THREAD = 2048


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="physar-mpm")
    return _POOL


@wp.kernel
def p2g_fused_kernel(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    C: wp.array(dtype=wp.mat33d),
    F: wp.array(dtype=wp.mat33d),
    Jp: wp.array(dtype=wp.float64),
    E: wp.array(dtype=wp.float64),
    nu: wp.array(dtype=wp.float64),
    elastic: wp.array(dtype=wp.int32),
    plastic: wp.array(dtype=wp.int32),
    pp: wp.array(dtype=wp.vec4d),
    fiber: wp.array(dtype=wp.vec3d),
    fiber_E: wp.array(dtype=wp.float64),
    mass: wp.array(dtype=wp.float64),
    vol: wp.array(dtype=wp.float64),
    omega: wp.array(dtype=wp.float64),
    x_ref: wp.array(dtype=wp.vec3d),
    v_ref: wp.array(dtype=wp.vec3d),
    f_hold: wp.array(dtype=wp.vec3d),
    kp: wp.float64,
    kd: wp.float64,
    origin: wp.float64,
    dx: wp.float64,
    dt: wp.float64,
    nmax: wp.int32,
    off: wp.vec3i,
    p0: wp.int32,
    grid_mv: wp.array3d(dtype=wp.vec3d),
    grid_m: wp.array3d(dtype=wp.float64),
):
    """Steps 1-2 of Alg. 1 for particle p0 + tid: Kirchhoff stress (expert law + fibre term), then the scatter."""
    p = wp.tid() + p0
    h = hardening_factor(Jp[p], plastic[p], pp[p])
    tau = kirchhoff_stress_fiber(F[p], E[p], nu[p], elastic[p], h, fiber[p], fiber_E[p])
    f = f_hold[p] + pd_force(mass[p], omega[p], x[p], v[p], x_ref[p], v_ref[p], kp, kd)
    p2g_particle(x[p], v[p], C[p], tau, mass[p], vol[p], f, origin, dx, dt, nmax, off, grid_mv, grid_m)


@wp.kernel
def g2p_fused_kernel(
    grid_v: wp.array3d(dtype=wp.vec3d),
    x: wp.array(dtype=wp.vec3d),
    F: wp.array(dtype=wp.mat33d),
    Jp: wp.array(dtype=wp.float64),
    E: wp.array(dtype=wp.float64),
    nu: wp.array(dtype=wp.float64),
    plastic: wp.array(dtype=wp.int32),
    pp: wp.array(dtype=wp.vec4d),
    origin: wp.float64,
    dx: wp.float64,
    dt: wp.float64,
    nmax: wp.int32,
    x_lo: wp.float64,
    x_hi: wp.float64,
    off: wp.vec3i,
    nc: wp.int32,
    ckind: wp.array(dtype=wp.int32),
    ccenter: wp.array(dtype=wp.vec3d),
    cvel: wp.array(dtype=wp.vec3d),
    csize: wp.array(dtype=wp.vec3d),
    caxis: wp.array(dtype=wp.vec3d),
    p0: wp.int32,
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
    C_out: wp.array(dtype=wp.mat33d),
    F_out: wp.array(dtype=wp.mat33d),
    Jp_out: wp.array(dtype=wp.float64),
):
    """Steps 4-5 of Alg. 1 for particle p0 + tid: APIC gather, F_trial = (I + dt C) F, return map."""
    p = wp.tid() + p0
    nv, nC, xn = g2p_particle(grid_v, x[p], origin, dx, dt, nmax, x_lo, x_hi, off, nc, ckind, ccenter, cvel, csize,
                              caxis)
    Ft = (wp.identity(n=3, dtype=wp.float64) + dt * nC) * F[p]
    Fn, J = plastic_update(Ft, Jp[p], E[p], nu[p], plastic[p], pp[p])
    x_out[p] = xn
    v_out[p] = nv
    C_out[p] = nC
    F_out[p] = Fn
    Jp_out[p] = J


@wp.func
def _dweights(fx: wp.vec3d) -> wp.mat33d:
    """d w_r / d fx of :func:`physar.mpm.model._weights` (row r, per axis): fx - 3/2, -2 (fx - 1), fx - 1/2."""
    return wp.matrix_from_rows(fx - wp.vec3d(_f(1.5), _f(1.5), _f(1.5)),
                               _f(-2.0) * (fx - wp.vec3d(_f(1.0), _f(1.0), _f(1.0))),
                               fx - wp.vec3d(_f(0.5), _f(0.5), _f(0.5)))


@wp.kernel
def trial_plastic_kernel(
    nC: wp.array(dtype=wp.mat33d),
    F: wp.array(dtype=wp.mat33d),
    Jp: wp.array(dtype=wp.float64),
    E: wp.array(dtype=wp.float64),
    nu: wp.array(dtype=wp.float64),
    plastic: wp.array(dtype=wp.int32),
    pp: wp.array(dtype=wp.vec4d),
    dt: wp.float64,
    p0: wp.int32,
    F_out: wp.array(dtype=wp.mat33d),
    Jp_out: wp.array(dtype=wp.float64),
):
    """Step 5 alone (the tail of :func:`g2p_fused_kernel`): F = P((I + dt C_new) F); launched in reverse only."""
    p = wp.tid() + p0
    Ft = (wp.identity(n=3, dtype=wp.float64) + dt * nC[p]) * F[p]
    Fn, J = plastic_update(Ft, Jp[p], E[p], nu[p], plastic[p], pp[p])
    F_out[p] = Fn
    Jp_out[p] = J


@wp.kernel
def advect_kernel(
    x: wp.array(dtype=wp.vec3d),
    nv: wp.array(dtype=wp.vec3d),
    dt: wp.float64,
    x_lo: wp.float64,
    x_hi: wp.float64,
    nc: wp.int32,
    ckind: wp.array(dtype=wp.int32),
    ccenter: wp.array(dtype=wp.vec3d),
    cvel: wp.array(dtype=wp.vec3d),
    csize: wp.array(dtype=wp.vec3d),
    caxis: wp.array(dtype=wp.vec3d),
    p0: wp.int32,
    x_out: wp.array(dtype=wp.vec3d),
):
    """The position update of step 4 alone (collider projection, clamp); launched in reverse only."""
    p = wp.tid() + p0
    x_out[p] = advect_particle(x[p], nv[p], dt, x_lo, x_hi, nc, ckind, ccenter, cvel, csize, caxis)


@wp.kernel
def stress_force_kernel(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    F: wp.array(dtype=wp.mat33d),
    Jp: wp.array(dtype=wp.float64),
    E: wp.array(dtype=wp.float64),
    nu: wp.array(dtype=wp.float64),
    elastic: wp.array(dtype=wp.int32),
    plastic: wp.array(dtype=wp.int32),
    pp: wp.array(dtype=wp.vec4d),
    fiber: wp.array(dtype=wp.vec3d),
    fiber_E: wp.array(dtype=wp.float64),
    mass: wp.array(dtype=wp.float64),
    omega: wp.array(dtype=wp.float64),
    x_ref: wp.array(dtype=wp.vec3d),
    v_ref: wp.array(dtype=wp.vec3d),
    f_hold: wp.array(dtype=wp.vec3d),
    kp: wp.float64,
    kd: wp.float64,
    p0: wp.int32,
    tau_out: wp.array(dtype=wp.mat33d),
    f_out: wp.array(dtype=wp.vec3d),
):
    """Step 1 and the external force of :func:`p2g_fused_kernel` alone; launched in reverse only."""
    p = wp.tid() + p0
    h = hardening_factor(Jp[p], plastic[p], pp[p])
    tau_out[p] = kirchhoff_stress_fiber(F[p], E[p], nu[p], elastic[p], h, fiber[p], fiber_E[p])
    f_out[p] = f_hold[p] + pd_force(mass[p], omega[p], x[p], v[p], x_ref[p], v_ref[p], kp, kd)


@wp.kernel
def g2p_gather_adjoint_kernel(
    grid_v: wp.array3d(dtype=wp.vec3d),
    x: wp.array(dtype=wp.vec3d),
    adj_nv: wp.array(dtype=wp.vec3d),
    adj_nC: wp.array(dtype=wp.mat33d),
    origin: wp.float64,
    dx: wp.float64,
    nmax: wp.int32,
    off: wp.vec3i,
    p0: wp.int32,
    tail: wp.int32,
    nv: wp.array(dtype=wp.vec3d),
    nC: wp.array(dtype=wp.mat33d),
    F: wp.array(dtype=wp.mat33d),
    dt: wp.float64,
    x_lo: wp.float64,
    x_hi: wp.float64,
    adj_xo: wp.array(dtype=wp.vec3d),
    adj_Fo: wp.array(dtype=wp.mat33d),
    adj_Jpo: wp.array(dtype=wp.float64),
    adj_x: wp.array(dtype=wp.vec3d),
    adj_gv: wp.array3d(dtype=wp.vec3d),
    adj_F: wp.array(dtype=wp.mat33d),
    adj_Jp: wp.array(dtype=wp.float64),
):
    r"""Reverse of the APIC gather (:func:`physar.mpm.model.g2p_gather`), written out by hand.

    With :math:`K = 4/dx^2`, :math:`f_x = (x - \mathrm{origin})/dx - \mathrm{base}`,
    :math:`\Delta_i = (i - f_x)\, dx` and given :math:`\bar v_p = \partial L / \partial v_p` (``adj_nv``),
    :math:`\bar C_p = \partial L / \partial C_p` (``adj_nC``):

    .. math::

        \frac{\partial L}{\partial v_i} \mathrel{+}= w_{ip} \big(\bar v_p + K \bar C_p \Delta_i\big)
        \quad \text{(scattered into adj\_gv)},

        \frac{\partial L}{\partial x_p} \mathrel{+}= \frac{1}{dx} \sum_i \Big[ \nabla w_{ip}\,
        \big(v_i \cdot (\bar v_p + K \bar C_p \Delta_i)\big) - w_{ip}\, dx\, K \bar C_p^\top v_i \Big].

    ``tail`` = 1 (no colliders, no plastic law): the rest of the substep's reverse is done here as well, for
    :math:`x_\text{new} = \operatorname{clamp}(x + dt\, v_p)` and :math:`F_\text{new} = (I + dt\, C_p) F`,
    :math:`J_{p,\text{new}} = J_p` (``adj_nv``, ``adj_nC`` are then the adjoints of the stored :math:`v_p`,
    :math:`C_p` only; the clamp passes the adjoint where :math:`\mathrm{lo} \le x \le \mathrm{hi}`, as Warp's
    ``clamp`` does); ``tail`` = 0: ``adj_nv``, ``adj_nC`` are the totals (the tail was reversed by Warp's
    adjoints of :func:`advect_kernel` and :func:`trial_plastic_kernel`)."""
    p = wp.tid() + p0
    xp = x[p]
    inv_dx = _f(1.0) / dx
    b = _base(xp, origin, inv_dx, nmax)
    fx = _frac(xp, origin, inv_dx, b)
    W = _weights(fx)
    D = _dweights(fx)
    anv = adj_nv[p]
    aCp = adj_nC[p]
    axp = wp.vec3d()
    if tail == 1:
        xu = xp + dt * nv[p]
        ax = adj_xo[p]
        for d in range(3):
            if xu[d] < x_lo or xu[d] > x_hi:
                ax[d] = _f(0.0)
        anv = anv + dt * ax
        axp = ax
        aFt = adj_Fo[p]
        Fp = F[p]
        aCp = aCp + dt * (aFt * wp.transpose(Fp))
        adj_F[p] = adj_F[p] + wp.transpose(wp.identity(n=3, dtype=wp.float64) + dt * nC[p]) * aFt
        adj_Jp[p] = adj_Jp[p] + adj_Jpo[p]
    aC = (_f(4.0) * inv_dx * inv_dx) * aCp
    aCt = wp.transpose(aC)
    afx = wp.vec3d()
    for i in range(3):
        for j in range(3):
            for k in range(3):
                ii = b[0] + wp.int32(i) - off[0]
                jj = b[1] + wp.int32(j) - off[1]
                kk = b[2] + wp.int32(k) - off[2]
                dpos = (wp.vec3d(wp.float64(i), wp.float64(j), wp.float64(k)) - fx) * dx
                wgt = W[i, 0] * W[j, 1] * W[k, 2]
                gw = wp.vec3d(D[i, 0] * W[j, 1] * W[k, 2], W[i, 0] * D[j, 1] * W[k, 2], W[i, 0] * W[j, 1] * D[k, 2])
                gv = grid_v[ii, jj, kk]
                a = anv + aC * dpos
                wp.atomic_add(adj_gv, ii, jj, kk, wgt * a)
                afx = afx + wp.dot(gv, a) * gw - (wgt * dx) * (aCt * gv)
    adj_x[p] = adj_x[p] + axp + inv_dx * afx


@wp.kernel
def p2g_scatter_adjoint_kernel(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    C: wp.array(dtype=wp.mat33d),
    tau: wp.array(dtype=wp.mat33d),
    f: wp.array(dtype=wp.vec3d),
    mass: wp.array(dtype=wp.float64),
    vol: wp.array(dtype=wp.float64),
    adj_mv: wp.array3d(dtype=wp.vec3d),
    adj_m: wp.array3d(dtype=wp.float64),
    origin: wp.float64,
    dx: wp.float64,
    dt: wp.float64,
    nmax: wp.int32,
    off: wp.vec3i,
    p0: wp.int32,
    adj_x: wp.array(dtype=wp.vec3d),
    adj_v: wp.array(dtype=wp.vec3d),
    adj_C: wp.array(dtype=wp.mat33d),
    adj_tau: wp.array(dtype=wp.mat33d),
    adj_f: wp.array(dtype=wp.vec3d),
):
    r"""Reverse of the MLS-MPM scatter (:func:`physar.mpm.model.p2g_particle`) as a gather, written out by
    hand.

    Forward: :math:`(m v)_i \mathrel{+}= w_{ip} (\mathrm{mom} + A \Delta_i)`,
    :math:`m_i \mathrel{+}= w_{ip} m_p` with :math:`\mathrm{mom} = m_p v_p + dt\, f_p` and
    :math:`A = -dt\, V_p K \tau_p + m_p C_p` (:math:`K = 4/dx^2`, :math:`\Delta_i` and :math:`f_x` as in
    :func:`g2p_gather_adjoint_kernel`).  Given :math:`\overline{mv}_i = \partial L / \partial (m v)_i` and
    :math:`\bar m_i = \partial L / \partial m_i`:

    .. math::

        \bar a_\mathrm{mom} = \sum_i w_{ip}\, \overline{mv}_i, \qquad
        \bar a_A = \sum_i w_{ip}\, \overline{mv}_i \Delta_i^\top,

        \frac{\partial L}{\partial f_x} = \sum_i \Big[ \nabla w_{ip} \big(\overline{mv}_i \cdot
        (\mathrm{mom} + A \Delta_i) + \bar m_i m_p\big) - w_{ip}\, dx\, A^\top \overline{mv}_i \Big];

    then :math:`\partial L / \partial x_p \mathrel{+}= (\partial L / \partial f_x) / dx`,
    :math:`\partial L / \partial v_p \mathrel{+}= m_p \bar a_\mathrm{mom}`,
    :math:`\partial L / \partial C_p \mathrel{+}= m_p \bar a_A`,
    :math:`\partial L / \partial \tau_p = -dt\, V_p K \bar a_A`,
    :math:`\partial L / \partial f_p = dt\, \bar a_\mathrm{mom}` (the last two are written, not
    accumulated)."""
    p = wp.tid() + p0
    xp = x[p]
    m = mass[p]
    inv_dx = _f(1.0) / dx
    b = _base(xp, origin, inv_dx, nmax)
    fx = _frac(xp, origin, inv_dx, b)
    W = _weights(fx)
    D = _dweights(fx)
    K = _f(4.0) * inv_dx * inv_dx
    A = (-dt * vol[p] * K) * tau[p] + m * C[p]
    At = wp.transpose(A)
    mom = m * v[p] + dt * f[p]
    a_mom = wp.vec3d()
    a_A = wp.mat33d()
    afx = wp.vec3d()
    for i in range(3):
        for j in range(3):
            for k in range(3):
                ii = b[0] + wp.int32(i) - off[0]
                jj = b[1] + wp.int32(j) - off[1]
                kk = b[2] + wp.int32(k) - off[2]
                dpos = (wp.vec3d(wp.float64(i), wp.float64(j), wp.float64(k)) - fx) * dx
                wgt = W[i, 0] * W[j, 1] * W[k, 2]
                gw = wp.vec3d(D[i, 0] * W[j, 1] * W[k, 2], W[i, 0] * D[j, 1] * W[k, 2], W[i, 0] * W[j, 1] * D[k, 2])
                amv = adj_mv[ii, jj, kk]
                u = At * amv
                a_mom = a_mom + wgt * amv
                a_A = a_A + wgt * wp.outer(amv, dpos)
                afx = afx + (wp.dot(amv, mom) + wp.dot(u, dpos) + adj_m[ii, jj, kk] * m) * gw - (wgt * dx) * u
    adj_x[p] = adj_x[p] + inv_dx * afx
    adj_v[p] = adj_v[p] + m * a_mom
    adj_C[p] = adj_C[p] + m * a_A
    adj_tau[p] = (-dt * vol[p] * K) * a_A
    adj_f[p] = dt * a_mom


@wp.kernel
def add_grid_kernel(a_mv: wp.array3d(dtype=wp.vec3d), a_m: wp.array3d(dtype=wp.float64),
                    b_mv: wp.array3d(dtype=wp.vec3d), b_m: wp.array3d(dtype=wp.float64)):
    i, j, k = wp.tid()
    a_mv[i, j, k] = a_mv[i, j, k] + b_mv[i, j, k]
    a_m[i, j, k] = a_m[i, j, k] + b_m[i, j, k]


@wp.kernel
def add_vec_grid_kernel(a: wp.array3d(dtype=wp.vec3d), b: wp.array3d(dtype=wp.vec3d)):
    i, j, k = wp.tid()
    a[i, j, k] = a[i, j, k] + b[i, j, k]


_STATE = (("x", wp.vec3d), ("v", wp.vec3d), ("C", wp.mat33d), ("F", wp.mat33d), ("Jp", wp.float64))


def _alloc_state(n: int, device: str, zero: bool = True) -> list:
    """Buffers (x, v, C, F, Jp) of n particles on the Warp ``device`` (zeroed, or left uninitialised)."""
    if zero:
        return [wp.zeros(n, dtype=t, device=device) for _, t in _STATE]
    return [wp.empty(n, dtype=t, device=device) for _, t in _STATE]


def _usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _default_keep_bytes() -> int:
    """min(512 MiB, 1/8 of the memory available now)."""
    cap = 1 << 29
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return min(cap, int(line.split()[1]) * 1024 // 8)
    except OSError:
        pass
    return cap // 4


class ThreadChooser:
    """Picks 1 or 2 threads per sweep from the wall time of the sweeps already run (per process).

    Two threads split every per-particle launch in halves and join after each; on a loaded machine one half can
    wait for a core while the other is done, and two threads then run slower than one (issue 19).  So each
    kind of sweep (``"fwd"``: a forward substep, ``"adj"``: a reverse substep) keeps an exponential mean
    (weight 0.3) of its seconds per substep for 1 and for 2 threads, per particle-count octave; the first
    call of each mode is not counted (kernel loading), the two modes alternate until each has two samples,
    then the faster is used and the other is tried once after every m calls of the faster, so that a change
    of the machine's load is followed.  m = max(``probe_every``, ceil((r - 1) / ``overhead``)), at most 256,
    with r >= 1 the ratio of the two means: the probes cost at most ``overhead`` (5 %) of the time while the
    means hold."""

    def __init__(self, probe_every: int = 8, overhead: float = 0.05):
        self.probe_every = probe_every
        self.overhead = overhead
        self._lock = threading.Lock()
        self.est: dict = {}  # (kind, octave, mode) -> [mean seconds, samples, calls]
        self._since: dict = {}  # (kind, octave) -> calls of the faster mode since the last probe

    def interval(self, fast: float, slow: float) -> int:
        r = slow / fast if fast > 0 else 1.0
        return int(min(256, max(self.probe_every, math.ceil((r - 1.0) / self.overhead - 1e-9))))

    def pick(self, kind: str, n: int) -> int:
        key = (kind, int(n).bit_length())
        with self._lock:
            st = [self.est.setdefault((*key, mode), [0.0, 0, 0]) for mode in (1, 2)]
            if st[0][1] < 2 or st[1][1] < 2:
                mode = 1 if st[0][2] <= st[1][2] else 2
            else:
                best = 1 if st[0][0] <= st[1][0] else 2
                since = self._since.get(key, 0)
                if since >= self.interval(st[best - 1][0], st[2 - best][0]):
                    mode, self._since[key] = 3 - best, 0
                else:
                    mode, self._since[key] = best, since + 1
            st[mode - 1][2] += 1
            return mode

    def record(self, kind: str, n: int, mode: int, seconds: float):
        with self._lock:
            e = self.est[(kind, int(n).bit_length(), mode)]
            if e[2] <= 1:  # first call of this mode: kernel loading, not counted
                return
            e[0] = seconds if e[1] == 0 else 0.7 * e[0] + 0.3 * seconds
            e[1] += 1


CHOOSER = ThreadChooser()


class FusedFrame:
    """Forward and reverse sweeps of one frame of ``model.substeps`` substeps (see module docstring).

    ``threads``: 1, 2, or None (default): 1 on a single usable core or below 2 x 2048 particles, else chosen per
    sweep by :class:`ThreadChooser` from measured wall times (so two threads are used only while they are
    faster); always 1 on a GPU (``model.device`` "cuda:N").  ``keep_bytes``: memory (bytes, over all frames
    alive in the graph) that the forward may use to keep the states and grids of a frame's last K substeps so
    that the backward does not run them again (default :func:`_default_keep_bytes`: min(512 MiB, 1/8 of the
    available memory); 0 = pure checkpointing); the first T - K substeps are checkpointed every
    ceil(sqrt(T - K)) substeps and recomputed in the backward.
    """

    def __init__(self, model: MPMModel, threads: int | None = None, keep_bytes: int | None = None):
        self.model = model
        self.device = model.device
        n = model.n_particles
        few = _usable_cores() < 2 or n < 2 * MIN_PARTICLES_PER_THREAD
        if not wp.get_device(self.device).is_cpu or (threads is None and few):
            threads = 1
        self.threads = None if threads is None else max(1, min(2, int(threads)))
        h = n // 2
        self._parts = {1: [(0, n)], 2: [(0, h), (h, n - h)]}
        # reverse of the G2P tail by hand when no particle has a plastic law (F_new = F_trial, J_p constant)
        self.simple_tail = not bool(np.any(np.asarray(model.plastic) != 0))
        self.keep_bytes = _default_keep_bytes() if keep_bytes is None else int(keep_bytes)
        self._held = 0
        self._held_lock = threading.Lock()

    # -- memory kept for the backward
    def reserve(self, T: int) -> tuple[int, int]:
        """(K, bytes): how many of a frame's T substeps the forward may keep (states: 200 bytes per particle,
        grids: 88 bytes per node of the last box seen), within what is left of ``keep_bytes``; reserved."""
        per = self.model.n_particles * 200 + 88 * getattr(self, "_last_box", 0)
        with self._held_lock:
            K = min(T, (self.keep_bytes - self._held) // per - 1)
            if K < 1:
                return 0, 0
            nbytes = (K + 1) * per
            self._held += nbytes
            return int(K), int(nbytes)

    def release(self, nbytes: int):
        with self._held_lock:
            self._held -= nbytes

    # -- helpers
    def _mode(self, kind: str) -> int:
        return self.threads if self.threads is not None else CHOOSER.pick(kind, self.model.n_particles)

    def _timed(self, kind: str, mode: int, t0: float):
        if self.threads is None:
            CHOOSER.record(kind, self.model.n_particles, mode, time.perf_counter() - t0)

    @staticmethod
    def _par(fns):
        """Run the callables concurrently (the first on this thread)."""
        if len(fns) == 1:
            fns[0]()
            return
        futs = [_pool().submit(f) for f in fns[1:]]
        fns[0]()
        for f in futs:
            f.result()

    def _consts(self):
        m = self.model
        a = m.warp_arrays()
        lo, hi = m.clamp_range
        return m, a, lo, hi, m.n_grid - 3

    # -- one substep forward; returns what the reverse sweep needs
    def substep(self, s_in: list, s_out: list, P: dict, t: float, keep: bool = False, box=None):
        """One substep s_in -> s_out.  ``box`` (corner, shape, threads) is the active node box of s_in and the
        thread count when already known (the backward recompute reuses those of the forward sweep: same states,
        same summation order, no host round trip).  Returns that triple, or with ``keep`` what the reverse
        sweep needs."""
        t_start = time.perf_counter()
        m, a, lo, hi, nmax = self._consts()
        x, v, C, F, Jp = s_in
        if box is not None:
            corner, shape, mode = box
        else:
            corner, shape = m.active_box(x.numpy())
            mode = self._mode("fwd")
        self._last_box = shape[0] * shape[1] * shape[2]
        parts = self._parts[mode]
        off = wp.vec3i(*corner)
        d = self.device
        grids = [(wp.zeros(shape, dtype=wp.vec3d, device=d), wp.zeros(shape, dtype=wp.float64, device=d))
                 for _ in parts]
        col = a["colliders"].at(t, m.dt)
        cin = col.inputs()

        def p2g(k):
            p0, cnt = parts[k]
            return lambda: wp.launch(
                p2g_fused_kernel, cnt,
                inputs=[x, v, C, F, Jp, P["E"], P["nu"], a["elastic"], a["plastic"], a["pp"], a["fiber"],
                        P["fiber_E"], a["mass"], a["volume"], P["omega"], P["x_ref"], P["v_ref"], P["f_hold"],
                        P["kp"], P["kd"], m.origin, m.dx, m.dt, nmax, off, p0],
                outputs=list(grids[k]), device=d)

        self._par([p2g(k) for k in range(len(parts))])
        mv, gm = grids[0]
        for k in range(1, len(grids)):
            wp.launch(add_grid_kernel, shape, inputs=[mv, gm, grids[k][0], grids[k][1]], device=d)
        gv = wp.zeros(shape, dtype=wp.vec3d, device=d)
        g_in = [mv, gm, wp.vec3d(*m.gravity), m.dt, m.pad, m.pad + m.resolution, a["bc"], a["friction"],
                wp.vec3i(0, 0, 0), off, m.origin, m.dx, *cin]
        wp.launch(grid_update_kernel, shape, inputs=g_in, outputs=[gv], device=d)

        def g2p(k):
            p0, cnt = parts[k]
            return lambda: wp.launch(
                g2p_fused_kernel, cnt,
                inputs=[gv, x, F, Jp, P["E"], P["nu"], a["plastic"], a["pp"], m.origin, m.dx, m.dt, nmax, lo, hi,
                        off, cin[0], cin[1], cin[4], cin[5], cin[6], cin[7], p0],
                outputs=list(s_out), device=d)

        self._par([g2p(k) for k in range(len(parts))])
        if box is None:
            self._timed("fwd", mode, t_start)
        if keep:
            return {"shape": shape, "off": off, "grids": grids, "gv": gv, "g_in": g_in, "t": t}
        return corner, shape, mode

    def _scratch(self) -> dict:
        if getattr(self, "_scr", None) is None:
            n, d = self.model.n_particles, self.device
            types = {"tau": wp.mat33d, "f": wp.vec3d, "adj_tau": wp.mat33d, "adj_f": wp.vec3d, "x": wp.vec3d,
                     "F": wp.mat33d, "Jp": wp.float64}
            self._scr = {k: wp.zeros(n, dtype=t, device=d) for k, t in types.items()}
        return self._scr

    def adjoint_substep(self, s_in: list, s_out: list, adj_in: list, adj_out: list, P: dict, adjP: dict, rec: dict):
        """Accumulate into adj_in (state s) and adjP the adjoints given adj_out (state s + 1); adj_out's v and C
        entries are overwritten (they become the total adjoints of the gathered v_p, C_p).

        Per particle range, in reverse order of the substep: return map (Warp's adjoint of
        :func:`trial_plastic_kernel`), position update (of :func:`advect_kernel`), the APIC gather
        (:func:`g2p_gather_adjoint_kernel`, by hand), the grid update (Warp), the scatter
        (:func:`p2g_scatter_adjoint_kernel`, by hand: a gather of the grid adjoints, no atomics) and the stress
        and external force (Warp's adjoint of :func:`stress_force_kernel`)."""
        t_start = time.perf_counter()
        mode = self._mode("adj")
        parts = self._parts[mode]
        m, a, lo, hi, nmax = self._consts()
        x, v, C, F, Jp = s_in
        shape, off, gv = rec["shape"], rec["off"], rec["gv"]
        col = a["colliders"].at(rec["t"], m.dt)
        cin = col.inputs()
        scr = self._scratch()
        tail = self.simple_tail and cin[0] == 0
        d = self.device
        adj_gvs = [wp.zeros(shape, dtype=wp.vec3d, device=d) for _ in parts]

        def g2p_adj(k):
            p0, cnt = parts[k]
            pl_in = [s_out[2], F, Jp, P["E"], P["nu"], a["plastic"], a["pp"], m.dt, p0]
            pl_adj = _adj(pl_in, {0: adj_out[2], 1: adj_in[3], 2: adj_in[4], 3: adjP["E"], 4: adjP["nu"]})
            ad_in = [x, s_out[1], m.dt, lo, hi, cin[0], cin[1], cin[4], cin[5], cin[6], cin[7], p0]
            ad_adj = _adj(ad_in, {0: adj_in[0], 1: adj_out[1]})

            def run():
                if not tail:
                    wp.launch(trial_plastic_kernel, cnt, inputs=pl_in, outputs=[scr["F"], scr["Jp"]],
                              adj_inputs=pl_adj, adj_outputs=[adj_out[3], adj_out[4]], adjoint=True, device=d)
                    wp.launch(advect_kernel, cnt, inputs=ad_in, outputs=[scr["x"]], adj_inputs=ad_adj,
                              adj_outputs=[adj_out[0]], adjoint=True, device=d)
                wp.launch(g2p_gather_adjoint_kernel, cnt,
                          inputs=[gv, x, adj_out[1], adj_out[2], m.origin, m.dx, nmax, off, p0, int(tail), s_out[1],
                                  s_out[2], F, m.dt, lo, hi, adj_out[0], adj_out[3], adj_out[4]],
                          outputs=[adj_in[0], adj_gvs[k], adj_in[3], adj_in[4]], device=d)
            return run

        self._par([g2p_adj(k) for k in range(len(parts))])
        adj_gv = adj_gvs[0]
        for k in range(1, len(adj_gvs)):
            wp.launch(add_vec_grid_kernel, shape, inputs=[adj_gv, adj_gvs[k]], device=d)
        adj_mv = wp.zeros(shape, dtype=wp.vec3d, device=d)
        adj_m = wp.zeros(shape, dtype=wp.float64, device=d)
        g_in = rec["g_in"]
        g_adj = _adj(g_in, {0: adj_mv, 1: adj_m})
        wp.launch(grid_update_kernel, shape, inputs=g_in, outputs=[gv], adj_inputs=g_adj, adj_outputs=[adj_gv],
                  adjoint=True, device=d)

        def p2g_adj(k):
            p0, cnt = parts[k]
            sf_in = [x, v, F, Jp, P["E"], P["nu"], a["elastic"], a["plastic"], a["pp"], a["fiber"], P["fiber_E"],
                     a["mass"], P["omega"], P["x_ref"], P["v_ref"], P["f_hold"], P["kp"], P["kd"], p0]
            sf_adj = _adj(sf_in, {0: adj_in[0], 1: adj_in[1], 2: adj_in[3], 3: adj_in[4], 4: adjP["E"],
                                  5: adjP["nu"], 10: adjP["fiber_E"], 12: adjP["omega"], 13: adjP["x_ref"],
                                  14: adjP["v_ref"], 15: adjP["f_hold"]})

            def run():
                wp.launch(stress_force_kernel, cnt, inputs=sf_in, outputs=[scr["tau"], scr["f"]], device=d)
                wp.launch(p2g_scatter_adjoint_kernel, cnt,
                          inputs=[x, v, C, scr["tau"], scr["f"], a["mass"], a["volume"], adj_mv, adj_m, m.origin,
                                  m.dx, m.dt, nmax, off, p0],
                          outputs=[adj_in[0], adj_in[1], adj_in[2], scr["adj_tau"], scr["adj_f"]], device=d)
                wp.launch(stress_force_kernel, cnt, inputs=sf_in, outputs=[scr["tau"], scr["f"]], adj_inputs=sf_adj,
                          adj_outputs=[scr["adj_tau"], scr["adj_f"]], adjoint=True, device=d)
            return run

        self._par([p2g_adj(k) for k in range(len(parts))])
        self._timed("adj", mode, t_start)


def _adj(inputs: list, given: dict) -> list:
    """Adjoint argument list for ``inputs``: ``given[i]`` where set, a zero value for Warp value types (vec3i …),
    None otherwise (arrays without gradient, Python scalars)."""
    out = []
    for i, a in enumerate(inputs):
        if i in given:
            out.append(given[i])
        elif wp._src.types.is_native_type(type(a)):
            out.append(type(a)())
        else:
            out.append(None)
    return out


def _wp(t: torch.Tensor, dtype, device: str):
    """A Warp view of ``t`` on the Warp ``device`` (moved there first: a copy only when it is elsewhere)."""
    return wp.from_torch(t.detach().to(wp.device_to_torch(device)).contiguous(), dtype=dtype)


def _params(runner: FusedFrame, E, nu, omega, x_ref, v_ref, f_hold, fiber_E, kp: float, kd: float) -> dict:
    """The per-particle parameters as Warp arrays on the runner's device, and the gains."""
    d = runner.device
    return {"E": _wp(E, wp.float64, d), "nu": _wp(nu, wp.float64, d), "omega": _wp(omega, wp.float64, d),
            "x_ref": _wp(x_ref, wp.vec3d, d), "v_ref": _wp(v_ref, wp.vec3d, d), "f_hold": _wp(f_hold, wp.vec3d, d),
            "fiber_E": _wp(fiber_E, wp.float64, d), "kp": float(kp), "kd": float(kd)}


def _host(t: torch.Tensor) -> np.ndarray:
    """A NumPy array of a tensor's values (a view for a contiguous CPU tensor, a host copy of a GPU one)."""
    return t.detach().cpu().contiguous().numpy()


class _Kept:
    """The states and grids of a frame kept by the forward for the backward; their bytes count against the
    runner's ``keep_bytes`` until the backward has used them or the graph is dropped."""

    def __init__(self, runner, nbytes: int, states: list, recs: list, start: int):
        self.states, self.recs, self.start = states, recs, start
        self._fin = weakref.finalize(self, runner.release, nbytes)

    def release(self):
        self.states = self.recs = None
        self._fin()


class FusedFrameFunction(torch.autograd.Function):
    """(x, v, C, F, Jp, E, nu, omega, x_ref, v_ref, f_hold, fiber_E) at the start of a frame -> state at its end.

    f_hold (N, 3) N is the external force held over the frame (seed Alg. 2); omega, x_ref, v_ref, kp, kd give
    the per-substep PD force (zeros when the force is held).  The fibre directions are the model's
    (``model.fiber``, constant); fiber_E (N,) Pa is differentiable."""

    @staticmethod
    def forward(ctx, runner: FusedFrame, t0: float, kp: float, kd: float, x, v, C, F, Jp, E, nu, omega, x_ref, v_ref,
                f_hold, fiber_E):
        m = runner.model
        n, T = m.n_particles, m.substeps
        P = _params(runner, E, nu, omega, x_ref, v_ref, f_hold, fiber_E, kp, kd)
        dev = runner.device
        cur = [wp.array(_host(t), dtype=d, device=dev) for t, (_, d) in zip((x, v, C, F, Jp), _STATE)]
        ctx.runner, ctx.t0, ctx.kp, ctx.kd, ctx.caller = runner, t0, kp, kd, x.device
        ctx.kept, ctx.kept_released = None, False
        # the last K substeps keep their states and grids (as many as runner.keep_bytes allows): the backward
        # runs those substeps only in reverse; the first T - K are checkpointed every ceil(sqrt(T - K))
        # substeps and recomputed segment by segment
        K, nbytes = runner.reserve(T) if any(ctx.needs_input_grad[4:]) else (0, 0)
        tail0 = T - K
        seg = max(1, math.ceil(math.sqrt(tail0)))
        nxt = _alloc_state(n, dev, zero=False)
        bounds = {0: [a.numpy().copy() for a in cur]}
        boxes = []
        for s in range(tail0):
            boxes.append(runner.substep(cur, nxt, P, t0 + s * m.dt))
            cur, nxt = nxt, cur
            if (s + 1) % seg == 0 and s + 1 < tail0:
                bounds[s + 1] = [a.numpy().copy() for a in cur]
        if K > 0:
            states, recs = [cur], []
            for s in range(tail0, T):
                out = _alloc_state(n, dev, zero=False)
                recs.append(runner.substep(states[-1], out, P, t0 + s * m.dt, keep=True))
                states.append(out)
            ctx.kept = _Kept(runner, nbytes, states, recs, tail0)
            cur = states[-1]
            if tail0 == 0:
                bounds = {}
        ctx.bounds, ctx.boxes = bounds, boxes
        ctx.save_for_backward(E, nu, omega, x_ref, v_ref, f_hold, fiber_E)
        return tuple(torch.from_numpy(a.numpy().copy()).to(ctx.caller) for a in cur)

    @staticmethod
    def backward(ctx, *grads):
        runner = ctx.runner
        m = runner.model
        n, T = m.n_particles, m.substeps
        E, nu, omega, x_ref, v_ref, f_hold, fiber_E = ctx.saved_tensors
        P = _params(runner, E, nu, omega, x_ref, v_ref, f_hold, fiber_E, ctx.kp, ctx.kd)
        dev = runner.device
        types = {"E": wp.float64, "nu": wp.float64, "omega": wp.float64, "x_ref": wp.vec3d, "v_ref": wp.vec3d,
                 "f_hold": wp.vec3d, "fiber_E": wp.float64}
        adjP = {k: wp.zeros(n, dtype=t, device=dev) for k, t in types.items()}
        shapes = [(n, 3), (n, 3), (n, 3, 3), (n, 3, 3), (n,)]
        adj_next = [wp.array(np.ascontiguousarray(_host(g) if g is not None else np.zeros(sh)), dtype=d, device=dev)
                    for g, (_, d), sh in zip(grads, _STATE, shapes)]
        adj_cur = _alloc_state(n, dev)
        if ctx.kept is None and ctx.kept_released:
            raise RuntimeError("this MPM frame kept its last substeps for one backward pass, which has run: "
                               "back-propagating it again (retain_graph) needs FusedFrame(model, keep_bytes=0)")
        starts = sorted(ctx.bounds)
        end = T if ctx.kept is None else ctx.kept.start
        segments = [(s0, starts[i + 1] if i + 1 < len(starts) else end, None, None) for i, s0 in enumerate(starts)]
        if ctx.kept is not None:
            segments.append((ctx.kept.start, T, ctx.kept.states, ctx.kept.recs))
        for s0, s1, states, recs in reversed(segments):
            if states is None:
                states = [[wp.array(a, dtype=d, device=dev) for a, (_, d) in zip(ctx.bounds[s0], _STATE)]]
                recs = []
                for s in range(s0, s1):
                    out = _alloc_state(n, dev, zero=False)
                    recs.append(runner.substep(states[-1], out, P, ctx.t0 + s * m.dt, keep=True, box=ctx.boxes[s]))
                    states.append(out)
            for j in reversed(range(s1 - s0)):
                for a in adj_cur:
                    a.zero_()
                runner.adjoint_substep(states[j], states[j + 1], adj_cur, adj_next, P, adjP, recs[j])
                adj_cur, adj_next = adj_next, adj_cur
        if ctx.kept is not None:
            ctx.kept.release()
            ctx.kept, ctx.kept_released = None, True
        to_t = lambda a: torch.from_numpy(a.numpy().copy()).to(ctx.caller)
        g_state = [to_t(a) for a in adj_next]
        g_par = [to_t(adjP[k]) for k in ("E", "nu", "omega", "x_ref", "v_ref", "f_hold", "fiber_E")]
        return (None, None, None, None, *g_state, *g_par)
