r"""MLS-MPM with APIC transfers and quadratic B-splines in 3-D (seed 002, §3.2, Alg. 1), in NVIDIA Warp.

Newton-style split: :class:`MPMModel` holds the constants (grid, particle masses/volumes, materials,
boundaries, gravity, time step), :class:`MPMState` the per-particle state :math:`s = \{x, v, C, F\}` (+ the
plastic Jacobian :math:`J_p` of the snow law), and :class:`MPMSolver` advances
``step(state_in, state_out, control, dt)`` by one substep of Alg. 1:

1. :math:`\sigma = \mathcal{E}(F, E, \nu)` + fibre term (:func:`stress_kernel`, Kirchhoff stress
   :math:`\tau = J \sigma`; the optional anisotropic fibre term is
   :func:`physar.mpm.constitutive.fiber_stress`);
2. P2G (MLS-MPM, Hu et al. 2018, Eq. 29; :math:`f_\text{ex}` of seed Eq. 7):

   .. math::

       m_i = \sum_p w_{ip} m_p, \qquad
       (m v)_i = \sum_p w_{ip} \Big[m_p v_p + \Big(m_p C_p - dt\, V_p \frac{4}{dx^2} \tau_p\Big)(x_i - x_p)
       + dt\, f_{\text{ex},p}\Big];

3. grid: :math:`v_i = (m v)_i / m_i + dt\, g`, then wall/ground boundary conditions;
4. G2P (APIC, Jiang et al. 2015):

   .. math::

       v_p = \sum_i w_{ip} v_i, \qquad C_p = \frac{4}{dx^2} \sum_i w_{ip} v_i (x_i - x_p)^\top, \qquad
       F_\text{trial} = (I + dt\, C_p) F_p, \qquad x_p \mathrel{+}= dt\, v_p;

   a particle that would end inside a kinematic collider is projected onto its surface,
   :math:`x_p \mathrel{-}= \phi\, n` (:mod:`physar.mpm.colliders`);
5. :math:`F = \mathcal{P}(F_\text{trial})` (:mod:`physar.mpm.constitutive`).

Units: SI (m, s, kg, Pa).  All arrays are float64 and live on the Warp device of the model
(:attr:`MPMModel.device`, "cpu" by default, or "cuda:N"): every allocation and launch names it, so that a
machine with a GPU does not put some arrays on Warp's default device (``cuda:0``) and others on the CPU.
The grid covers the cube :math:`[0, \mathrm{size}]^3` with ``pad`` extra nodes on each side; walls sit at the
faces of the cube (the ground is the face :math:`z = 0`).  Particles are clamped to the padded grid so that they
can never index outside it (a NaN state is reported by :meth:`MPMSolver.simulate_frame` as a
:class:`physar.errors.SolverError`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from physar.errors import ConfigError, SolverError
from physar.mpm.actuation import held_force, pd_force
from physar.mpm.colliders import MAX_COLLIDERS, Collider, ColliderArrays, collider_sdf
from physar.mpm.constitutive import (
    hardening_factor,
    hencky_project,
    kirchhoff_stress_fiber,
    singular_values,
    snow_project,
)
from physar.output import native_stderr_without

wp.config.quiet = True  # warp < 1.10
wp.config.log_level = 30  # warp >= 1.10: no init banner or module-load lines on stdout (keeps --json clean)
with native_stderr_without("Could not find or load the NVIDIA CUDA driver"):  # a CPU-only machine: no noise
    wp.init()

_f = wp.float64

BC_NONE, BC_STICKY, BC_SLIP, BC_SEPARATE = 0, 1, 2, 3
BC_CODES = {"none": BC_NONE, "sticky": BC_STICKY, "slip": BC_SLIP, "separate": BC_SEPARATE}
WALLS = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")  # z_min is the ground
_DEVICE_NAME = re.compile(r"cpu|cuda(:\d+)?")


def _span(a, unit: str = "") -> str:
    """``5e+04 Pa`` (one value) or ``1e+04..5e+04 Pa`` (min..max) of an array, for a summary (one pass each)."""
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return "none"
    lo, hi = float(a.min()), float(a.max())
    text = f"{lo:.4g}" if lo == hi else f"{lo:.4g}..{hi:.4g}"
    return f"{text} {unit}" if unit else text


def _box(x) -> str:
    """``[0, 1] x [0, 0.5] x [0.2, 0.3] m``: the bounding box of positions x (N, 3) (``empty`` for none)."""
    x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    if len(x) == 0:
        return "empty"
    return " x ".join(f"[{a:.4g}, {b:.4g}]" for a, b in zip(x.min(axis=0).tolist(), x.max(axis=0).tolist())) + " m"


def _count(n: int, word: str, many: str | None = None) -> str:
    """``1 particle``, ``2 particles`` (``many``: the plural when it is not `word` + s)."""
    return f"{n} {word}" if n == 1 else f"{n} {many or word + 's'}"


def device_name(value: str) -> str:
    """``value`` when it is a device name ('cpu', 'cuda' or 'cuda:N'), else ValueError (the check of the configuration
    fields that name a device; whether this machine has it is checked where it is used, :func:`resolve_device`)."""
    if not _DEVICE_NAME.fullmatch(value):
        raise ValueError(f"{value!r} is not a device: use 'cpu', 'cuda' or 'cuda:N'")
    return value


def resolve_device(device) -> str:
    """The Warp device alias ("cpu", "cuda:N") that ``device`` ("cpu", "cuda" = Warp's current CUDA device, or
    "cuda:N") names; a :class:`ConfigError` naming the value and Warp's devices (``wp.get_devices()``) when it
    is not one of those or Warp does not have it."""
    available = [d.alias for d in wp.get_devices()]
    name = device if isinstance(device, str) else None
    if name == "cuda" and any(a.startswith("cuda") for a in available):
        name = wp.get_device("cuda").alias
    if name is None or not _DEVICE_NAME.fullmatch(name) or name not in available:
        raise ConfigError(f"MPM device {device!r} is not available: Warp has {', '.join(available)} (a device is "
                          "'cpu', 'cuda' or 'cuda:N')")
    return name


# ----------------------------------------------------------------------------------------------- kernels
@wp.func
def _base(xp: wp.vec3d, origin: wp.float64, inv_dx: wp.float64, nmax: wp.int32) -> wp.vec3i:
    """Lower-left node of the 3x3x3 quadratic B-spline stencil, clamped to the grid."""
    g = (xp - wp.vec3d(origin, origin, origin)) * inv_dx
    return wp.vec3i(
        wp.clamp(wp.int32(wp.floor(g[0] - _f(0.5))), 0, nmax),
        wp.clamp(wp.int32(wp.floor(g[1] - _f(0.5))), 0, nmax),
        wp.clamp(wp.int32(wp.floor(g[2] - _f(0.5))), 0, nmax),
    )


@wp.func
def _frac(xp: wp.vec3d, origin: wp.float64, inv_dx: wp.float64, b: wp.vec3i) -> wp.vec3d:
    g = (xp - wp.vec3d(origin, origin, origin)) * inv_dx
    return g - wp.vec3d(wp.float64(b[0]), wp.float64(b[1]), wp.float64(b[2]))


@wp.func
def _weights(fx: wp.vec3d) -> wp.mat33d:
    """Quadratic B-spline weights; row r holds the weights of node offset r along x, y, z."""
    h = wp.vec3d(_f(1.5), _f(1.5), _f(1.5)) - fx
    a = fx - wp.vec3d(_f(1.0), _f(1.0), _f(1.0))
    b = fx - wp.vec3d(_f(0.5), _f(0.5), _f(0.5))
    w0 = _f(0.5) * wp.cw_mul(h, h)
    w1 = wp.vec3d(_f(0.75), _f(0.75), _f(0.75)) - wp.cw_mul(a, a)
    w2 = _f(0.5) * wp.cw_mul(b, b)
    return wp.matrix_from_rows(w0, w1, w2)


@wp.kernel
def stress_kernel(
    F: wp.array(dtype=wp.mat33d),
    Jp: wp.array(dtype=wp.float64),
    E: wp.array(dtype=wp.float64),
    nu: wp.array(dtype=wp.float64),
    elastic: wp.array(dtype=wp.int32),
    plastic: wp.array(dtype=wp.int32),
    pp: wp.array(dtype=wp.vec4d),
    fiber: wp.array(dtype=wp.vec3d),
    fiber_E: wp.array(dtype=wp.float64),
    tau: wp.array(dtype=wp.mat33d),
):
    r"""Step 1: :math:`\tau_p = \tau_\text{expert}(F_p; E_p, \nu_p) + (E_f/2)(I_4 - 1)(F a_0)(F a_0)^\top`
    (seed 002 §3.2 + fibre term)."""
    p = wp.tid()
    h = hardening_factor(Jp[p], plastic[p], pp[p])
    tau[p] = kirchhoff_stress_fiber(F[p], E[p], nu[p], elastic[p], h, fiber[p], fiber_E[p])


@wp.kernel
def singular_values_kernel(F: wp.array(dtype=wp.mat33d), s: wp.array(dtype=wp.vec3d)):
    p = wp.tid()
    s[p] = singular_values(F[p])


@wp.func
def p2g_particle(
    xp: wp.vec3d,
    vp: wp.vec3d,
    Cp: wp.mat33d,
    tau: wp.mat33d,
    m: wp.float64,
    V: wp.float64,
    f: wp.vec3d,
    origin: wp.float64,
    dx: wp.float64,
    dt: wp.float64,
    nmax: wp.int32,
    off: wp.vec3i,
    grid_mv: wp.array3d(dtype=wp.vec3d),
    grid_m: wp.array3d(dtype=wp.float64),
):
    """Scatter one particle (step 2 of the module docstring); array index = global node index - off."""
    inv_dx = _f(1.0) / dx
    b = _base(xp, origin, inv_dx, nmax)
    fx = _frac(xp, origin, inv_dx, b)
    W = _weights(fx)
    affine = (-dt * V * _f(4.0) * inv_dx * inv_dx) * tau + m * Cp
    mom = m * vp + dt * f
    for i in range(3):
        for j in range(3):
            for k in range(3):
                ii = b[0] + wp.int32(i) - off[0]
                jj = b[1] + wp.int32(j) - off[1]
                kk = b[2] + wp.int32(k) - off[2]
                dpos = (wp.vec3d(wp.float64(i), wp.float64(j), wp.float64(k)) - fx) * dx
                wgt = W[i, 0] * W[j, 1] * W[k, 2]
                wp.atomic_add(grid_mv, ii, jj, kk, wgt * (mom + affine * dpos))
                wp.atomic_add(grid_m, ii, jj, kk, wgt * m)


@wp.kernel
def p2g_kernel(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    C: wp.array(dtype=wp.mat33d),
    tau: wp.array(dtype=wp.mat33d),
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
    grid_mv: wp.array3d(dtype=wp.vec3d),
    grid_m: wp.array3d(dtype=wp.float64),
):
    """Step 2 with f_ex = f_hold (the force held over the frame, Alg. 2) + the per-substep PD force (zero when
    omega = 0 or k_p = k_d = 0)."""
    p = wp.tid()
    f = f_hold[p] + pd_force(mass[p], omega[p], x[p], v[p], x_ref[p], v_ref[p], kp, kd)
    p2g_particle(x[p], v[p], C[p], tau[p], mass[p], vol[p], f, origin, dx, dt, nmax, off, grid_mv, grid_m)


@wp.func
def _apply_bc(v: wp.vec3d, n: wp.vec3d, code: wp.int32, mu: wp.float64) -> wp.vec3d:
    """Wall condition for inward normal n: sticky v=0; slip v.n=0; separate v.n>=0; Coulomb friction mu."""
    out = v
    vn = wp.dot(v, n)
    if code == 1:
        out = wp.vec3d()
    elif code == 2 or (code == 3 and vn < _f(0.0)):
        vt = v - vn * n
        if vn < _f(0.0) and mu > _f(0.0):
            vtn = wp.length(vt)
            if vtn <= -mu * vn:
                vt = wp.vec3d()
            else:
                vt = vt * (_f(1.0) + mu * vn / vtn)
        out = vt
    return out


@wp.kernel
def grid_update_kernel(
    grid_mv: wp.array3d(dtype=wp.vec3d),
    grid_m: wp.array3d(dtype=wp.float64),
    gravity: wp.vec3d,
    dt: wp.float64,
    lo: wp.int32,
    hi: wp.int32,
    bc: wp.array(dtype=wp.int32),
    friction: wp.array(dtype=wp.float64),
    start: wp.vec3i,
    off: wp.vec3i,
    origin: wp.float64,
    dx: wp.float64,
    nc: wp.int32,
    ckind: wp.array(dtype=wp.int32),
    cbc: wp.array(dtype=wp.int32),
    cfric: wp.array(dtype=wp.float64),
    ccenter: wp.array(dtype=wp.vec3d),
    cvel: wp.array(dtype=wp.vec3d),
    csize: wp.array(dtype=wp.vec3d),
    caxis: wp.array(dtype=wp.vec3d),
    grid_v: wp.array3d(dtype=wp.vec3d),
):
    """Grid velocities on the box of array indices start + tid; global node index = array index + off.

    Walls first, then the ``nc`` kinematic colliders (:mod:`physar.mpm.colliders`) in the collider frame.
    """
    a0, a1, a2 = wp.tid()
    ai = a0 + start[0]
    aj = a1 + start[1]
    ak = a2 + start[2]
    i = ai + off[0]
    j = aj + off[1]
    k = ak + off[2]
    m = grid_m[ai, aj, ak]
    v = wp.vec3d()
    if m > _f(1.0e-14):
        v = grid_mv[ai, aj, ak] / m + dt * gravity
        if i <= lo:
            v = _apply_bc(v, wp.vec3d(_f(1.0), _f(0.0), _f(0.0)), bc[0], friction[0])
        if i >= hi:
            v = _apply_bc(v, wp.vec3d(_f(-1.0), _f(0.0), _f(0.0)), bc[1], friction[1])
        if j <= lo:
            v = _apply_bc(v, wp.vec3d(_f(0.0), _f(1.0), _f(0.0)), bc[2], friction[2])
        if j >= hi:
            v = _apply_bc(v, wp.vec3d(_f(0.0), _f(-1.0), _f(0.0)), bc[3], friction[3])
        if k <= lo:
            v = _apply_bc(v, wp.vec3d(_f(0.0), _f(0.0), _f(1.0)), bc[4], friction[4])
        if k >= hi:
            v = _apply_bc(v, wp.vec3d(_f(0.0), _f(0.0), _f(-1.0)), bc[5], friction[5])
        if nc > 0:
            xi = wp.vec3d(origin + dx * wp.float64(i), origin + dx * wp.float64(j), origin + dx * wp.float64(k))
            for c in range(MAX_COLLIDERS):  # unrolled (constant bound): exact adjoint, unlike a dynamic loop
                sd = wp.vec4d(_f(1.0), _f(0.0), _f(0.0), _f(1.0))
                if c < nc:
                    sd = collider_sdf(xi, ckind[c], ccenter[c], csize[c], caxis[c])
                if sd[0] < _f(0.0):
                    vc = cvel[c]
                    v = _apply_bc(v - vc, wp.vec3d(sd[1], sd[2], sd[3]), cbc[c], cfric[c]) + vc
    grid_v[ai, aj, ak] = v


@wp.kernel
def clear_grid_kernel(start: wp.vec3i, grid_mv: wp.array3d(dtype=wp.vec3d), grid_m: wp.array3d(dtype=wp.float64)):
    a0, a1, a2 = wp.tid()
    grid_mv[a0 + start[0], a1 + start[1], a2 + start[2]] = wp.vec3d()
    grid_m[a0 + start[0], a1 + start[1], a2 + start[2]] = _f(0.0)


@wp.func
def g2p_particle(
    grid_v: wp.array3d(dtype=wp.vec3d),
    xp: wp.vec3d,
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
):
    """Gather one particle (step 4): new v, C and position (collider projection, clamp to the padded grid)."""
    nv, nC = g2p_gather(grid_v, xp, origin, dx, nmax, off)
    xc = advect_particle(xp, nv, dt, x_lo, x_hi, nc, ckind, ccenter, cvel, csize, caxis)
    return nv, nC, xc


@wp.func
def g2p_gather(grid_v: wp.array3d(dtype=wp.vec3d), xp: wp.vec3d, origin: wp.float64, dx: wp.float64,
               nmax: wp.int32, off: wp.vec3i):
    r"""APIC gather of step 4: :math:`v_p = \sum_i w_{ip} v_i`,
    :math:`C_p = (4/dx^2) \sum_i w_{ip} v_i (x_i - x_p)^\top`."""
    inv_dx = _f(1.0) / dx
    b = _base(xp, origin, inv_dx, nmax)
    fx = _frac(xp, origin, inv_dx, b)
    W = _weights(fx)
    nv = wp.vec3d()
    nC = wp.mat33d()
    for i in range(3):
        for j in range(3):
            for k in range(3):
                ii = b[0] + wp.int32(i) - off[0]
                jj = b[1] + wp.int32(j) - off[1]
                kk = b[2] + wp.int32(k) - off[2]
                dpos = (wp.vec3d(wp.float64(i), wp.float64(j), wp.float64(k)) - fx) * dx
                wgt = W[i, 0] * W[j, 1] * W[k, 2]
                gv = grid_v[ii, jj, kk]
                nv = nv + wgt * gv
                nC = nC + (_f(4.0) * inv_dx * inv_dx * wgt) * wp.outer(gv, dpos)
    return nv, nC


@wp.func
def advect_particle(
    xp: wp.vec3d,
    nv: wp.vec3d,
    dt: wp.float64,
    x_lo: wp.float64,
    x_hi: wp.float64,
    nc: wp.int32,
    ckind: wp.array(dtype=wp.int32),
    ccenter: wp.array(dtype=wp.vec3d),
    cvel: wp.array(dtype=wp.vec3d),
    csize: wp.array(dtype=wp.vec3d),
    caxis: wp.array(dtype=wp.vec3d),
) -> wp.vec3d:
    """x_p + dt v_p, projected out of the colliders and clamped to the padded grid (end of step 4)."""
    xn = xp + dt * nv
    if nc > 0:  # a particle that ends inside a collider (at its end-of-substep position) is put back on its surface
        for c in range(MAX_COLLIDERS):
            sd = wp.vec4d(_f(1.0), _f(0.0), _f(0.0), _f(1.0))
            if c < nc:
                sd = collider_sdf(xn, ckind[c], ccenter[c] + dt * cvel[c], csize[c], caxis[c])
            if sd[0] < _f(0.0):
                xn = xn - sd[0] * wp.vec3d(sd[1], sd[2], sd[3])
    return wp.vec3d(wp.clamp(xn[0], x_lo, x_hi), wp.clamp(xn[1], x_lo, x_hi), wp.clamp(xn[2], x_lo, x_hi))


@wp.kernel
def g2p_kernel(
    grid_v: wp.array3d(dtype=wp.vec3d),
    x: wp.array(dtype=wp.vec3d),
    F: wp.array(dtype=wp.mat33d),
    origin: wp.float64,
    dx: wp.float64,
    dt: wp.float64,
    nmax: wp.int32,
    x_lo: wp.float64,
    x_hi: wp.float64,
    off: wp.vec3i,
    nc: wp.int32,
    ckind: wp.array(dtype=wp.int32),
    cbc: wp.array(dtype=wp.int32),
    cfric: wp.array(dtype=wp.float64),
    ccenter: wp.array(dtype=wp.vec3d),
    cvel: wp.array(dtype=wp.vec3d),
    csize: wp.array(dtype=wp.vec3d),
    caxis: wp.array(dtype=wp.vec3d),
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
    C_out: wp.array(dtype=wp.mat33d),
    F_trial: wp.array(dtype=wp.mat33d),
):
    p = wp.tid()
    nv, nC, xn = g2p_particle(grid_v, x[p], origin, dx, dt, nmax, x_lo, x_hi, off, nc, ckind, ccenter, cvel, csize,
                              caxis)
    v_out[p] = nv
    C_out[p] = nC
    F_trial[p] = (wp.identity(n=3, dtype=wp.float64) + dt * nC) * F[p]
    x_out[p] = xn


@wp.func
def plastic_update(Ft: wp.mat33d, Jp: wp.float64, E: wp.float64, nu: wp.float64, code: wp.int32, pp: wp.vec4d):
    """F = P(F_trial) (step 5) and the updated plastic Jacobian of the snow law."""
    Fn = Ft
    J = Jp
    if code == 1 or code == 2:
        Fn = hencky_project(Ft, E, nu, code, pp)
    elif code == 3:
        Fn = snow_project(Ft, pp)
        J = J * wp.determinant(Ft) / wp.determinant(Fn)
    return Fn, J


@wp.kernel
def plastic_kernel(
    F_trial: wp.array(dtype=wp.mat33d),
    Jp: wp.array(dtype=wp.float64),
    E: wp.array(dtype=wp.float64),
    nu: wp.array(dtype=wp.float64),
    plastic: wp.array(dtype=wp.int32),
    pp: wp.array(dtype=wp.vec4d),
    F_out: wp.array(dtype=wp.mat33d),
    Jp_out: wp.array(dtype=wp.float64),
):
    p = wp.tid()
    Fn, J = plastic_update(F_trial[p], Jp[p], E[p], nu[p], plastic[p], pp[p])
    F_out[p] = Fn
    Jp_out[p] = J


# ----------------------------------------------------------------------------------------------- objects
NU_MIN, NU_MAX = -1.0, 0.5  # open bounds of the Poisson ratio (the scene file's body.nu has the same)


def check_material(E, nu, where: str = "") -> None:
    r"""A :class:`ConfigError` naming the first particle whose Young's modulus ``E`` (N,) Pa is not a finite
    number > 0 or whose Poisson ratio ``nu`` (N,) is not in the open interval (-1, 0.5) (the limits of a scene's
    ``body.E`` and ``body.nu``: :math:`\lambda = E \nu / ((1 + \nu)(1 - 2 \nu))` is infinite at 0.5);
    ``where`` prefixes the message (e.g. ``"Params."``)."""
    E, nu = np.asarray(E, dtype=np.float64), np.asarray(nu, dtype=np.float64)
    bad = ~(np.isfinite(E) & (E > 0))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ConfigError(f"{where}E[{i}] = {E[i]:g} Pa: Young's modulus must be a finite number > 0")
    bad = ~(np.isfinite(nu) & (nu > NU_MIN) & (nu < NU_MAX))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ConfigError(f"{where}nu[{i}] = {nu[i]:g}: Poisson's ratio must be in ({NU_MIN:g}, {NU_MAX:g})")


@dataclass(repr=False)
class MPMModel:
    r"""Static description of an MPM scene (SI units).

    ``size`` (m) is the side of the simulated cube :math:`[0, \mathrm{size}]^3`, ``resolution`` the number of
    grid cells per side (:math:`dx = \mathrm{size} / \mathrm{resolution}`), ``dt`` the substep (s) and
    ``substeps`` the substeps per frame. Per-particle arrays: ``mass`` (kg), ``volume`` (m^3), ``E`` (Pa),
    ``nu``, ``elastic``/``plastic`` codes of :mod:`physar.mpm.constitutive`, ``plastic_params`` (N, 4),
    ``body`` (index of the body it came from). ``walls`` maps each of x_min … z_max to none | sticky | slip |
    separate and ``friction`` to a Coulomb coefficient (used for slip/separate walls).

    Optional anisotropy (physar's choice of an anisotropic ground-truth law on top of the expert laws of seed
    002 §3.2; a standard fibre-reinforced :math:`I_4` model, Holzapfel-style): ``fiber`` (N, 3) is the fibre
    direction :math:`a_0` of each particle in the rest configuration (normalised here; a zero row = no fibre)
    and ``fiber_E`` (N,) >= 0 the fibre modulus :math:`E_f` (Pa).  The strain energy per unit rest volume
    gains :math:`\Psi_f = (E_f / 8)(I_4 - 1)^2` with :math:`I_4 = |F a_0|^2`, i.e. the Kirchhoff stress gains
    :math:`\tau_f = (E_f / 2)(I_4 - 1)(F a_0)(F a_0)^\top`, and the small-strain uniaxial stiffness along
    :math:`a_0` grows by :math:`E_f`.
    ``None`` (default) = zeros = isotropic.

    ``device``: the Warp device of every array and launch of this model ("cpu", the default; "cuda" or
    "cuda:N"); checked by :func:`resolve_device` and stored as Warp's alias ("cuda" -> "cuda:0").  The torch
    bridge (:mod:`physar.mpm.torch_bridge`) moves its tensors there and its results back to the caller's device.
    """

    size: float
    resolution: int
    dt: float
    substeps: int
    mass: np.ndarray
    volume: np.ndarray
    E: np.ndarray
    nu: np.ndarray
    elastic: np.ndarray
    plastic: np.ndarray
    plastic_params: np.ndarray
    body: np.ndarray
    gravity: tuple = (0.0, 0.0, -9.81)
    walls: dict = field(default_factory=lambda: {w: "slip" for w in WALLS})
    friction: dict = field(default_factory=lambda: {w: 0.0 for w in WALLS})
    pad: int = 3
    colliders: list = field(default_factory=list)
    fiber: np.ndarray | None = None
    fiber_E: np.ndarray | None = None
    device: str = "cpu"

    def __post_init__(self):
        self.device = resolve_device(self.device)
        n = len(self.mass)
        if n == 0:
            raise ConfigError("MPM model has no particles (every body is empty or outside the domain)")
        if self.resolution < 4:
            raise ConfigError(f"grid.resolution = {self.resolution}: must be >= 4")
        if not (self.size > 0 and self.dt > 0 and self.substeps >= 1):
            raise ConfigError(f"size={self.size}, dt={self.dt}, substeps={self.substeps} must be positive")
        for name in ("mass", "volume", "E", "nu"):
            a = np.asarray(getattr(self, name), dtype=np.float64)
            if a.shape != (n,) or not np.all(np.isfinite(a)):
                raise ConfigError(f"MPM model: '{name}' must be {n} finite numbers")
            setattr(self, name, a)
        check_material(self.E, self.nu, "MPM model: ")
        for w in self.walls:
            if w not in WALLS or self.walls[w] not in BC_CODES:
                raise ConfigError(f"boundary wall '{w}' = '{self.walls[w]}': walls are {WALLS}, "
                                  f"types {sorted(BC_CODES)}")
        self.elastic = np.asarray(self.elastic, dtype=np.int32)
        self.plastic = np.asarray(self.plastic, dtype=np.int32)
        self.plastic_params = np.asarray(self.plastic_params, dtype=np.float64).reshape(n, 4)
        self.body = np.asarray(self.body, dtype=np.int32)
        self.colliders = list(self.colliders)
        for i, c in enumerate(self.colliders):
            if not isinstance(c, Collider):
                raise ConfigError(f"MPM model: colliders[{i}] is a {type(c).__name__}, not a Collider")
        self._set_fibers()
        self._wp = None

    def _set_fibers(self):
        """Validate and normalise ``fiber`` / ``fiber_E`` (None -> zeros)."""
        n = len(self.mass)
        if self.fiber is None:
            a = np.zeros((n, 3))
        else:
            a = np.asarray(self.fiber, dtype=np.float64)
            if a.shape != (n, 3) or not np.all(np.isfinite(a)):
                raise ConfigError(f"MPM model: 'fiber' must be an ({n}, 3) array of finite numbers "
                                  f"(got shape {a.shape})")
        if self.fiber_E is None:
            ef = np.zeros(n)
        else:
            ef = np.asarray(self.fiber_E, dtype=np.float64)
            if ef.shape != (n,) or not np.all(np.isfinite(ef)):
                raise ConfigError(f"MPM model: 'fiber_E' must be {n} finite numbers (got shape {ef.shape})")
            if np.any(ef < 0):
                i = int(np.argmin(ef))
                raise ConfigError(f"MPM model: 'fiber_E' must be >= 0 Pa (particle {i}: {ef[i]:g})")
        norm = np.linalg.norm(a, axis=1)
        bad = (ef > 0) & (norm == 0)
        if np.any(bad):
            i = int(np.argmax(bad))
            raise ConfigError(f"MPM model: particle {i} has fiber_E = {ef[i]:g} Pa but a zero 'fiber' direction")
        self.fiber = a / np.where(norm > 0, norm, 1.0)[:, None]
        self.fiber_E = ef

    @property
    def anisotropic(self) -> bool:
        """True if any particle has a fibre term (fiber_E > 0)."""
        return bool(np.any(self.fiber_E > 0))

    def __repr__(self) -> str:
        """One line: particles and bodies, total mass, E and nu ranges, grid, time step, colliders, device."""
        bodies = int(self.body.max()) + 1 if self.body.size else 0
        extra = (", anisotropic" if self.anisotropic else "") + (
            f", {_count(len(self.colliders), 'collider')}" if self.colliders else "")
        return (f"MPMModel({_count(self.n_particles, 'particle')} in {_count(bodies, 'body', 'bodies')}, "
                f"mass {float(self.mass.sum()):.4g} kg, E {_span(self.E, 'Pa')}, nu {_span(self.nu)}, "
                f"grid {self.resolution}^3 cells of {self.dx:.4g} m on [0, {self.size:g}]^3 m, "
                f"dt {self.dt:.4g} s x {self.substeps} substeps{extra}, device {self.device})")

    # grid geometry
    @property
    def n_particles(self) -> int:
        return len(self.mass)

    @property
    def dx(self) -> float:
        return self.size / self.resolution

    @property
    def n_grid(self) -> int:
        return self.resolution + 2 * self.pad + 1

    @property
    def origin(self) -> float:
        return -self.pad * self.dx

    @property
    def clamp_range(self) -> tuple[float, float]:
        r"""Particles are kept in :math:`[\mathrm{lo}, \mathrm{hi}]^3` so that their 3x3x3 stencil stays on
        the grid."""
        return self.origin + self.dx, self.origin + (self.n_grid - 2) * self.dx

    def active_box(self, x: np.ndarray) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        r"""Lower corner and shape (global node indices) of the box of grid nodes that particles at x (N, 3)
        touch.

        The 3x3x3 stencil of a particle starts at :math:`\lfloor (x - \mathrm{origin}) / dx - 1/2 \rfloor`
        (clamped to the grid); one node of margin on each side makes the box independent of rounding.  Only
        this box is allocated / updated (the grid phase costs :math:`O(\mathrm{box})` instead of
        :math:`O(\mathrm{resolution}^3)`).
        """
        x = np.asarray(x)
        # the map x -> floor((x - origin) / dx - 1/2) is monotone (also in floating point): apply it to the extremes
        gmin = np.floor((x.min(axis=0) - self.origin) / self.dx - 0.5)
        gmax = np.floor((x.max(axis=0) - self.origin) / self.dx - 0.5)
        if not (np.all(np.isfinite(gmin)) and np.all(np.isfinite(gmax))):
            raise SolverError("MPM simulation diverged (non-finite particle positions): reduce the substep "
                              "(more time.substeps) or the stiffness")
        lo = np.clip(gmin - 1, 0, self.n_grid - 3).astype(int)
        hi = np.clip(gmax + 1, 0, self.n_grid - 3).astype(int) + 3  # exclusive
        return tuple(int(v) for v in lo), tuple(int(v) for v in hi - lo)

    @property
    def frame_dt(self) -> float:
        return self.dt * self.substeps

    def warp_arrays(self) -> dict:
        """Constant per-particle arrays on the model's Warp device (built once, cached)."""
        d = self.device
        if self._wp is None:
            self._wp = {
                "mass": wp.array(self.mass, dtype=wp.float64, device=d),
                "volume": wp.array(self.volume, dtype=wp.float64, device=d),
                "E": wp.array(self.E, dtype=wp.float64, device=d),
                "nu": wp.array(self.nu, dtype=wp.float64, device=d),
                "elastic": wp.array(self.elastic, dtype=wp.int32, device=d),
                "plastic": wp.array(self.plastic, dtype=wp.int32, device=d),
                "pp": wp.array(self.plastic_params, dtype=wp.vec4d, device=d),
                "fiber": wp.array(self.fiber, dtype=wp.vec3d, device=d),
                "fiber_E": wp.array(self.fiber_E, dtype=wp.float64, device=d),
                "bc": wp.array([BC_CODES[self.walls.get(w, "slip")] for w in WALLS], dtype=wp.int32,
                               device=d),
                "friction": wp.array([float(self.friction.get(w, 0.0)) for w in WALLS], dtype=wp.float64,
                                     device=d),
                "zero_omega": wp.zeros(self.n_particles, dtype=wp.float64, device=d),
                "zero_vec": wp.zeros(self.n_particles, dtype=wp.vec3d, device=d),
                "colliders": ColliderArrays(self.colliders, d),
            }
        return self._wp

    def state(self, x: np.ndarray, v: np.ndarray | None = None) -> MPMState:
        """A state at positions x (N, 3) with velocities v, :math:`C = 0`, :math:`F = I`, :math:`J_p = 1`."""
        n = self.n_particles
        x = np.asarray(x, dtype=np.float64).reshape(n, 3)
        v = np.zeros((n, 3)) if v is None else np.broadcast_to(np.asarray(v, dtype=np.float64), (n, 3))
        return MPMState.from_numpy(x, v, np.zeros((n, 3, 3)), np.tile(np.eye(3), (n, 1, 1)), np.ones(n),
                                   device=self.device)


_STATE_SHAPES = {"x": (3,), "v": (3,), "C": (3, 3), "F": (3, 3), "Jp": ()}
_STATE_DTYPES = {"x": wp.vec3d, "v": wp.vec3d, "C": wp.mat33d, "F": wp.mat33d, "Jp": wp.float64}


@dataclass(repr=False)
class MPMState:
    r"""Per-particle state :math:`s = \{x\ (\mathrm{m}), v\ (\mathrm{m/s}), C\ (1/\mathrm{s}), F\ (-)\}` of
    Alg. 1, plus the plastic Jacobian :math:`J_p`.

    Fields are Warp arrays on the model's device: ``state.numpy()`` returns copies, while on the CPU
    ``state.x.numpy()`` is a view of the buffer that the next step overwrites (copy it to keep a frame; on a GPU
    it is a copy already)."""

    x: wp.array
    v: wp.array
    C: wp.array
    F: wp.array
    Jp: wp.array

    @staticmethod
    def from_numpy(x, v, C, F, Jp, device: str = "cpu") -> MPMState:
        """A state holding copies of the arrays, on the Warp ``device``: x, v (N, 3), C, F (N, 3, 3), Jp (N,),
        N = ``len(x)``; a :class:`ConfigError` naming the array whose shape is not that."""
        arrays = {"x": x, "v": v, "C": C, "F": F, "Jp": Jp}
        x = np.asarray(x, dtype=np.float64)
        n = len(x) if x.ndim == 2 else -1
        out = []
        for name, a in arrays.items():
            a = np.ascontiguousarray(a, dtype=np.float64)
            want = (n, *_STATE_SHAPES[name])
            if a.shape != want:
                shape = "(N, 3)" if name == "x" else str(want)
                raise ConfigError(f"MPMState: '{name}' must have shape {shape}, got {a.shape}")
            out.append(wp.array(a, dtype=_STATE_DTYPES[name], device=device))
        return MPMState(*out)

    @property
    def n_particles(self) -> int:
        return self.x.shape[0]

    def __repr__(self) -> str:
        """One line: particles, device, bounding box of the positions [m], largest speed [m/s] (no arrays)."""
        x, v = self.x.numpy(), self.v.numpy()  # views on the CPU, copies from a GPU
        speed = float(np.sqrt((v.reshape(-1, 3) ** 2).sum(axis=1)).max()) if len(v) else 0.0
        return (f"MPMState({_count(self.n_particles, 'particle')} on {self.x.device.alias}, bounds {_box(x)}, "
                f"max |v| {speed:.4g} m/s)")

    def check_fits(self, model: MPMModel, name: str = "state") -> None:
        """A :class:`ConfigError` unless every array holds one entry per particle of ``model`` (a shorter
        array would be read and written past its end by the kernels)."""
        n = model.n_particles
        for k in ("x", "v", "C", "F", "Jp"):
            m = getattr(self, k).shape[0]
            if m != n:
                raise ConfigError(f"MPM {name}.{k} holds {m} particles but the model has {n}")

    def numpy(self) -> dict:
        return {k: getattr(self, k).numpy().copy() for k in ("x", "v", "C", "F", "Jp")}  # numpy() is a view on CPU

    def copy(self) -> MPMState:
        d = self.numpy()
        return MPMState.from_numpy(d["x"], d["v"], d["C"], d["F"], d["Jp"], device=self.x.device.alias)


@dataclass(repr=False)
class Control:
    r"""PD actuation of seed Eq. (6)-(7): gate :math:`\omega` (N,), references :math:`x_\text{ref}`, :math:`v_\text{ref}`
    (N, 3), gains :math:`k_p`, :math:`k_d`,

    .. math::

        f_\text{ex} = m\, \omega \big[k_p (x_\text{ref} - x) + k_d (v_\text{ref} - v)\big].

    ``hold=True`` (seed Alg. 2): :meth:`MPMSolver.simulate_frame` evaluates :math:`f_\text{ex}` once from the
    state at the start of the frame and applies it at every substep; ``False``: recomputed from each substep's
    state (:mod:`physar.mpm.actuation` gives the stability bound of the held force)."""

    omega: np.ndarray
    x_ref: np.ndarray
    v_ref: np.ndarray
    kp: float = 2.0e2
    kd: float = 2.0e1
    hold: bool = True

    def __repr__(self) -> str:
        """One line: particles, how many are actuated (omega != 0), omega's range, gains, held or not."""
        omega = np.asarray(self.omega, dtype=np.float64).ravel()
        return (f"Control({_count(omega.size, 'particle')}, {int(np.count_nonzero(omega))} actuated, "
                f"omega {_span(omega)}, kp={self.kp:g} 1/s^2, kd={self.kd:g} 1/s, "
                f"{'held over a frame' if self.hold else 'per substep'})")

    def held_force(self, model: MPMModel, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        r""":math:`f_\text{ex}` (N, 3) of Eq. (6)-(7) at positions x and velocities v (N, 3) (Alg. 2,
        lines 2-4)."""
        return held_force(model.mass, np.asarray(self.omega, dtype=np.float64), x, v,
                          np.asarray(self.x_ref, dtype=np.float64), np.asarray(self.v_ref, dtype=np.float64),
                          self.kp, self.kd)

    def check_fits(self, model: MPMModel) -> None:
        """A :class:`ConfigError` unless omega is (N,) and x_ref, v_ref (N, 3), N = ``model.n_particles``."""
        n = model.n_particles
        for name, want in (("omega", (n,)), ("x_ref", (n, 3)), ("v_ref", (n, 3))):
            got = np.shape(getattr(self, name))
            if got != want:
                raise ConfigError(f"MPM Control.{name} must have shape {want} (one per particle), got {got}")

    def warp(self, device: str):
        """(omega, x_ref, v_ref) as Warp arrays on ``device`` (the model's)."""
        return (
            wp.array(np.asarray(self.omega, dtype=np.float64), dtype=wp.float64, device=device),
            wp.array(np.asarray(self.x_ref, dtype=np.float64), dtype=wp.vec3d, device=device),
            wp.array(np.asarray(self.v_ref, dtype=np.float64), dtype=wp.vec3d, device=device),
        )


class MPMSolver:
    """Forward MLS-MPM substeps on preallocated buffers (no autodiff; see :mod:`physar.mpm.torch_bridge`)."""

    def __init__(self, model: MPMModel, active_box: bool = True):
        """``active_box``: grid phase only on the box of nodes touched by particles (same result, faster)."""
        self.model = model
        self.active_box = active_box
        n, g, d = model.n_particles, model.n_grid, model.device
        self.tau = wp.zeros(n, dtype=wp.mat33d, device=d)
        self.F_trial = wp.zeros(n, dtype=wp.mat33d, device=d)
        self.grid_mv = wp.zeros((g, g, g), dtype=wp.vec3d, device=d)
        self.grid_m = wp.zeros((g, g, g), dtype=wp.float64, device=d)
        self.grid_v = wp.zeros((g, g, g), dtype=wp.vec3d, device=d)
        self._ctrl_cache = None
        self.time = 0.0  # s, start of the next substep (moves the kinematic colliders)

    def step(self, state_in: MPMState, state_out: MPMState, control: Control | None = None, dt: float | None = None,
             t: float | None = None, force: np.ndarray | None = None):
        r"""One substep of Alg. 1 from ``state_in`` into ``state_out`` (the two must not alias).

        ``t`` (s) is the time at the start of the substep (default: ``self.time``, which every step advances).
        ``force`` (N, 3), N: an external force :math:`f_\text{ex}` applied as is (the held PD force of
        Alg. 2); ``control`` adds the PD force evaluated on ``state_in`` (a one-substep frame;
        :meth:`simulate_frame` holds it).  A :class:`ConfigError` when a state, the control or the force does not
        hold one entry per particle of the model.
        """
        self._check_inputs(state_in, state_out, control)
        if force is not None and np.shape(force) != (self.model.n_particles, 3):
            raise ConfigError(f"MPM step: 'force' must have shape ({self.model.n_particles}, 3), "
                              f"got {np.shape(force)}")
        self._substep(state_in, state_out, control, dt, t, force)

    def _check_inputs(self, state: MPMState, scratch: MPMState, control: Control | None) -> None:
        """Shapes of the states and the control against the model (once per call, not per substep)."""
        state.check_fits(self.model, "state")
        scratch.check_fits(self.model, "scratch state")
        if control is not None:
            control.check_fits(self.model)

    def _substep(self, state_in: MPMState, state_out: MPMState, control: Control | None, dt: float | None,
                 t: float | None, force: np.ndarray | None):
        """:meth:`step` on inputs already checked."""
        m = self.model
        a = m.warp_arrays()
        dt = float(m.dt if dt is None else dt)
        t = self.time if t is None else float(t)
        self.time = t + dt
        col = a["colliders"].at(t, dt)
        n, g = m.n_particles, m.n_grid
        if control is None:
            omega, x_ref, v_ref, kp, kd = a["zero_omega"], a["zero_vec"], a["zero_vec"], 0.0, 0.0
        else:
            if self._ctrl_cache is None or self._ctrl_cache[0] is not control:
                self._ctrl_cache = (control, control.warp(m.device))
            omega, x_ref, v_ref = self._ctrl_cache[1]
            kp, kd = control.kp, control.kd
        dev = m.device
        f_hold = (a["zero_vec"] if force is None
                  else wp.array(np.asarray(force, dtype=np.float64), dtype=wp.vec3d, device=dev))
        nmax = g - 3
        zero = wp.vec3i(0, 0, 0)
        lo_box, shape = m.active_box(state_in.x.numpy()) if self.active_box else ((0, 0, 0), (g, g, g))
        start = wp.vec3i(*lo_box)
        wp.launch(stress_kernel, n, inputs=[state_in.F, state_in.Jp, a["E"], a["nu"], a["elastic"],
                                                  a["plastic"], a["pp"], a["fiber"], a["fiber_E"]],
                  outputs=[self.tau], device=dev)
        wp.launch(p2g_kernel, n, inputs=[state_in.x, state_in.v, state_in.C, self.tau, a["mass"], a["volume"],
                                         omega, x_ref, v_ref, f_hold, kp, kd, m.origin, m.dx, dt, nmax, zero],
                  outputs=[self.grid_mv, self.grid_m], device=dev)
        wp.launch(grid_update_kernel, shape,
                  inputs=[self.grid_mv, self.grid_m, wp.vec3d(*m.gravity), dt, m.pad, m.pad + m.resolution,
                          a["bc"], a["friction"], start, zero, m.origin, m.dx, *col.inputs()], outputs=[self.grid_v],
                  device=dev)
        lo, hi = m.clamp_range
        wp.launch(g2p_kernel, n, inputs=[self.grid_v, state_in.x, state_in.F, m.origin, m.dx, dt, nmax, lo, hi, zero,
                                         *col.inputs()],
                  outputs=[state_out.x, state_out.v, state_out.C, self.F_trial], device=dev)
        wp.launch(plastic_kernel, n, inputs=[self.F_trial, state_in.Jp, a["E"], a["nu"], a["plastic"], a["pp"]],
                  outputs=[state_out.F, state_out.Jp], device=dev)
        wp.launch(clear_grid_kernel, shape, inputs=[start], outputs=[self.grid_mv, self.grid_m],
                  device=dev)  # grid all-zero again

    def simulate_frame(self, state: MPMState, scratch: MPMState, control: Control | None = None,
                       check: bool = True) -> tuple[MPMState, MPMState]:
        """:math:`T` = ``model.substeps`` substeps; returns (new state, scratch) — the two buffers swap roles.

        With ``control.hold`` the PD force is evaluated once on ``state`` and held over the :math:`T` substeps
        (seed 002 Alg. 2, lines 2-4); otherwise it is recomputed at every substep."""
        self._check_inputs(state, scratch, control)
        a, b = state, scratch
        force, ctrl = None, control
        if control is not None and control.hold:
            force, ctrl = control.held_force(self.model, state.x.numpy(), state.v.numpy()), None
        for _ in range(self.model.substeps):
            self._substep(a, b, ctrl, None, None, force)
            a, b = b, a
        if check:
            check_state(self.model, a.x.numpy(), a.v.numpy(), a.F.numpy())
        return a, b


F_MAX = 1.0e3  # |F_ij| above this is taken as a blow-up (no material law here is meaningful there)


def check_state(model: MPMModel, x, v, F, where: str = "") -> None:
    """Raise :class:`SolverError` if the state has blown up: non-finite x, v or F, |F_ij| > F_MAX, or a particle
    faster than one cell per substep (|v| dt > dx, the CFL bound of the explicit update).  Particles that leave
    the grid are not an error: G2P clamps them to the padded grid (``model.clamp_range``)."""
    vmax = float(np.abs(v).max()) if np.all(np.isfinite(v)) else np.inf
    fmax = float(np.abs(F).max()) if np.all(np.isfinite(F)) else np.inf
    if not np.all(np.isfinite(x)) or not np.isfinite(vmax) or fmax > F_MAX or vmax * model.dt > model.dx:
        raise SolverError(f"MPM simulation diverged{where} (max |v| = {vmax:.3g} m/s, max |F_ij| = {fmax:.3g}): "
                          f"increase time.substeps (dt = {model.dt:.3g} s) or lower the stiffness")


# ----------------------------------------------------------------------------------------------- diagnostics
def _lame_np(E, nu):
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def elastic_energy_density(F: np.ndarray, E: np.ndarray, nu: np.ndarray, elastic: np.ndarray,
                           fiber: np.ndarray | None = None, fiber_E: np.ndarray | None = None) -> np.ndarray:
    r"""Strain energy density :math:`\psi(F)` (:math:`\mathrm{J/m^3}`, per unit rest volume) matching the
    stresses of :mod:`physar.mpm.constitutive` (without snow hardening).

    With ``fiber`` (N, 3, unit rest directions :math:`a_0`, zero rows allowed) and ``fiber_E`` (N,) the fibre
    energy :math:`\Psi_f = (E_f / 8)(|F a_0|^2 - 1)^2` is added (:class:`MPMModel`)."""
    mu, la = _lame_np(np.asarray(E), np.asarray(nu))
    s = np.linalg.svd(F, compute_uv=False)
    J = np.prod(s, axis=1)
    psi = np.zeros(len(F))
    fc = elastic == 0
    psi[fc] = mu[fc] * np.sum((s[fc] - 1) ** 2, axis=1) + 0.5 * la[fc] * (J[fc] - 1) ** 2
    sv = elastic == 1
    G = 0.5 * (s[sv] ** 2 - 1)
    psi[sv] = mu[sv] * np.sum(G**2, axis=1) + 0.5 * la[sv] * np.sum(G, axis=1) ** 2
    nh = elastic == 2
    lJ = np.log(np.maximum(J[nh], 1e-6))
    psi[nh] = 0.5 * mu[nh] * (np.sum(s[nh] ** 2, axis=1) - 3) - mu[nh] * lJ + 0.5 * la[nh] * lJ**2
    hk = elastic == 3
    e = np.log(np.maximum(s[hk], 1e-6))
    psi[hk] = mu[hk] * np.sum(e**2, axis=1) + 0.5 * la[hk] * np.sum(e, axis=1) ** 2
    if fiber is not None and fiber_E is not None:
        fa = np.einsum("nij,nj->ni", F, np.asarray(fiber, dtype=np.float64))
        I4 = np.sum(fa * fa, axis=1)
        psi = psi + np.asarray(fiber_E, dtype=np.float64) / 8.0 * (I4 - 1.0) ** 2
    return psi


def diagnostics(model: MPMModel, st: dict) -> dict:
    r"""Centre of mass (m), linear momentum (kg m/s), APIC angular momentum (kg m^2/s) and energies (J).

    The angular momentum includes the affine part,
    :math:`L = \sum_p m_p \big[x_p \times v_p + (dx^2/4)\, \varepsilon : C_p^\top\big]`, which is what APIC
    conserves exactly (Jiang et al. 2015).
    """
    m = model.mass
    x, v, C, F = st["x"], st["v"], st["C"], st["F"]
    M = m.sum()
    D = model.dx**2 / 4.0
    aff = np.stack([C[:, 2, 1] - C[:, 1, 2], C[:, 0, 2] - C[:, 2, 0], C[:, 1, 0] - C[:, 0, 1]], axis=1)
    L = np.sum(m[:, None] * (np.cross(x, v) + D * aff), axis=0)
    g = np.asarray(model.gravity)
    ke = 0.5 * np.sum(m * np.sum(v * v, axis=1))
    pe = -np.sum(m * (x @ g))
    ee = np.sum(model.volume * elastic_energy_density(F, model.E, model.nu, model.elastic,
                                                          model.fiber, model.fiber_E))
    return {
        "com": (m[:, None] * x).sum(0) / M,
        "momentum": (m[:, None] * v).sum(0),
        "angular_momentum": L,
        "kinetic_energy": ke,
        "potential_energy": pe,
        "elastic_energy": ee,
        "total_energy": ke + pe + ee,
    }
