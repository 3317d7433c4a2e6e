r"""Expert constitutive laws and plastic return maps as Warp functions (seed 002, §3.2, Alg. 1 lines 3 and 5).

All functions work in float64 and return the **Kirchhoff** stress :math:`\tau = J \sigma = P F^\top` (Pa); the
MLS-MPM force of Alg. 1 uses :math:`\tau` directly (Hu et al. 2018, Eq. 18).  The Cauchy stress of the seed
is :math:`\sigma = \tau / J`.

Elastic laws (``ELASTIC_*`` codes), with Lamé parameters :math:`\mu = E / (2 (1 + \nu))`,
:math:`\lambda = E \nu / ((1 + \nu)(1 - 2 \nu))`:

* fixed-corotated (Stomakhin et al. 2012):
  :math:`\tau = 2 \mu (F - R) F^\top + \lambda (J - 1) J I`, :math:`R = \operatorname{polar}(F)`, evaluated as
  :math:`2 \mu (B - \sqrt{B}) + \dots`, :math:`B = F F^\top` (valid for :math:`J > 0`), with a Newton matrix
  square root;
* Kirchhoff–Saint Venant (StVK): :math:`\tau = F (2 \mu G + \lambda \operatorname{tr}(G) I) F^\top`,
  :math:`G = (F^\top F - I) / 2`;
* compressible neo-Hookean: :math:`\tau = \mu (F F^\top - I) + \lambda \log(J) I`;
* Hencky (StVK in logarithmic strain, used with the Hencky-strain return maps):
  :math:`\tau = U (2 \mu \log S + \lambda \operatorname{tr}(\log S) I) U^\top` for :math:`F = U S V^\top`.

Plastic return maps (``PLASTIC_*`` codes), :math:`F = \mathcal{P}(F_\text{trial})` of Alg. 1 line 5, acting on
the singular values :math:`S` of :math:`F_\text{trial} = U S V^\top`:

* identity: :math:`F = F_\text{trial}`;
* von Mises (metal): Hencky strain :math:`e = \log S`, deviatoric part
  :math:`\hat e = e - \operatorname{tr}(e)/3`; if :math:`2 \mu \lVert \hat e \rVert > \sqrt{2/3}\, \sigma_Y`
  the deviatoric strain is scaled back onto the yield surface;
* Drucker–Prager (sand, Klar et al. 2016, Alg. 2): :math:`\operatorname{tr}(e) > 0 \Rightarrow S = I`; else

  .. math::

      \delta\gamma = \lVert \hat e \rVert + \frac{3 \lambda + 2 \mu}{2 \mu} \operatorname{tr}(e)\, \alpha,
      \qquad \alpha = \sqrt{2/3}\, \frac{2 \sin\phi}{3 - \sin\phi};

  if :math:`\delta\gamma > 0`, :math:`e \leftarrow e - \delta\gamma\, \hat e / \lVert \hat e \rVert`;
* snow (Stomakhin et al. 2013): :math:`S` clamped to :math:`[1 - \theta_c, 1 + \theta_s]`, the removed volume
  goes into the plastic Jacobian :math:`J_p`, and the Lamé parameters harden as :math:`\exp(\xi (1 - J_p))`.

Anisotropic fibre term (physar's choice of an anisotropic ground-truth law, not part of seed 002): every
elastic law above may be augmented per particle by a standard fibre-reinforced :math:`I_4` term
(Holzapfel-style fibre family, here with a quadratic instead of an exponential fibre energy), with :math:`a_0`
the unit fibre direction in the rest configuration and :math:`E_f \ge 0` (Pa) the fibre modulus:

.. math::

    \Psi_f = \frac{E_f}{8} (I_4 - 1)^2, \qquad I_4 = |F a_0|^2, \qquad
    \tau_f = \frac{\partial \Psi_f}{\partial F} F^\top = \frac{E_f}{2} (I_4 - 1) (F a_0)(F a_0)^\top

(:func:`fiber_stress`).  Its small-strain uniaxial stiffness along :math:`a_0` is :math:`E_f` (on top of the
isotropic law); it acts in tension and in compression, is smooth in :math:`F` and objective.  It is not scaled
by the snow hardening and, for the plastic materials, acts on the elastic part :math:`F` of Alg. 1 (after the
return map), like the isotropic law.

Per-particle plastic parameters are packed into a vec4d ``pp``: von Mises (:math:`\sigma_Y` [Pa], -, -, -),
Drucker–Prager (:math:`\alpha` [-], -, -, -), snow (:math:`\theta_c`, :math:`\theta_s`, :math:`\xi`, -).
"""

from __future__ import annotations

import math

import warp as wp

ELASTIC_FIXED_COROTATED = 0
ELASTIC_STVK = 1
ELASTIC_NEOHOOKEAN = 2
ELASTIC_HENCKY = 3

PLASTIC_IDENTITY = 0
PLASTIC_VON_MISES = 1
PLASTIC_DRUCKER_PRAGER = 2
PLASTIC_SNOW = 3

ELASTIC_CODES = {
    "fixed_corotated": ELASTIC_FIXED_COROTATED,
    "stvk": ELASTIC_STVK,
    "neohookean": ELASTIC_NEOHOOKEAN,
    "hencky": ELASTIC_HENCKY,
}
PLASTIC_CODES = {
    "identity": PLASTIC_IDENTITY,
    "von_mises": PLASTIC_VON_MISES,
    "drucker_prager": PLASTIC_DRUCKER_PRAGER,
    "snow": PLASTIC_SNOW,
}

_f = wp.float64
SV_MIN = wp.constant(wp.float64(1.0e-6))  # smallest singular value fed to log (guards inverted elements)


def drucker_prager_alpha(friction_angle_deg: float) -> float:
    r""":math:`\alpha = \sqrt{2/3}\, 2 \sin\phi / (3 - \sin\phi)` of Klar et al. 2016 for a friction angle
    :math:`\phi` (degrees)."""
    s = math.sin(math.radians(friction_angle_deg))
    return math.sqrt(2.0 / 3.0) * 2.0 * s / (3.0 - s)


@wp.func
def lame(E: wp.float64, nu: wp.float64):
    mu = E / (_f(2.0) * (_f(1.0) + nu))
    la = E * nu / ((_f(1.0) + nu) * (_f(1.0) - _f(2.0) * nu))
    return mu, la


@wp.func
def sym_sqrt(B: wp.mat33d) -> wp.mat33d:
    r"""Square root of a symmetric positive-definite matrix by 10 Newton steps
    :math:`Y \leftarrow (Y + Y^{-1} B) / 2` from :math:`Y_0 = \sqrt{\operatorname{tr} B / 3}\, I`.  Smooth in
    :math:`B` (no eigen/SVD), so its derivative is exact at repeated eigenvalues."""
    a = wp.sqrt(wp.trace(B) / _f(3.0))
    Y = a * wp.identity(n=3, dtype=wp.float64)
    for _ in range(10):
        Y = _f(0.5) * (Y + wp.inverse(Y) * B)
    return _f(0.5) * (Y + wp.transpose(Y))


@wp.func
def kirchhoff_stress(
    F: wp.mat33d, E: wp.float64, nu: wp.float64, elastic: wp.int32, hardening: wp.float64
) -> wp.mat33d:
    """Kirchhoff stress tau(F) (Pa) of the elastic law ``elastic``; Lamé parameters scaled by ``hardening``."""
    mu, la = lame(E, nu)
    mu = mu * hardening
    la = la * hardening
    I = wp.identity(n=3, dtype=wp.float64)
    J = wp.determinant(F)
    tau = wp.mat33d()
    if elastic == 0:
        # (F - R) F^T = F F^T - R S R^T = B - sqrt(B) with B = F F^T (F = R S); no SVD, exact gradient at F = I
        B = F * wp.transpose(F)
        tau = _f(2.0) * mu * (B - sym_sqrt(B)) + la * (J - _f(1.0)) * J * I
    elif elastic == 1:
        G = _f(0.5) * (wp.transpose(F) * F - I)
        S = _f(2.0) * mu * G + la * wp.trace(G) * I
        tau = F * S * wp.transpose(F)
    elif elastic == 2:
        Jc = wp.max(J, SV_MIN)
        tau = mu * (F * wp.transpose(F) - I) + la * wp.log(Jc) * I
    else:
        U = wp.mat33d()
        s = wp.vec3d()
        V = wp.mat33d()
        wp.svd3(F, U, s, V)
        e = wp.vec3d(
            wp.log(wp.max(s[0], SV_MIN)), wp.log(wp.max(s[1], SV_MIN)), wp.log(wp.max(s[2], SV_MIN))
        )
        tr = e[0] + e[1] + e[2]
        d = _f(2.0) * mu * e + la * tr * wp.vec3d(_f(1.0), _f(1.0), _f(1.0))
        tau = U * wp.diag(d) * wp.transpose(U)
    return tau


@wp.func
def fiber_stress(F: wp.mat33d, a0: wp.vec3d, Ef: wp.float64) -> wp.mat33d:
    r"""Kirchhoff stress of the fibre energy :math:`\Psi_f = (E_f/8)(I_4 - 1)^2`, :math:`I_4 = |F a_0|^2`
    (:math:`a_0` unit, rest frame): :math:`\tau_f = (E_f/2)(I_4 - 1) (F a_0)(F a_0)^\top` (Pa).  Zero for
    :math:`E_f = 0` or :math:`a_0 = 0`."""
    fa = F * a0
    I4 = wp.dot(fa, fa)
    return (_f(0.5) * Ef * (I4 - _f(1.0))) * wp.outer(fa, fa)


@wp.func
def kirchhoff_stress_fiber(
    F: wp.mat33d, E: wp.float64, nu: wp.float64, elastic: wp.int32, hardening: wp.float64, a0: wp.vec3d,
    Ef: wp.float64,
) -> wp.mat33d:
    """Expert law of seed 002 §3.2 (:func:`kirchhoff_stress`) plus the fibre term (:func:`fiber_stress`)."""
    return kirchhoff_stress(F, E, nu, elastic, hardening) + fiber_stress(F, a0, Ef)


@wp.func
def singular_values(F: wp.mat33d) -> wp.vec3d:
    U = wp.mat33d()
    s = wp.vec3d()
    V = wp.mat33d()
    wp.svd3(F, U, s, V)
    return s


@wp.func
def hencky_project(
    F: wp.mat33d, E: wp.float64, nu: wp.float64, plastic: wp.int32, pp: wp.vec4d
) -> wp.mat33d:
    """Return map of von Mises (plastic == 1) or Drucker–Prager (plastic == 2) on the Hencky strain."""
    U = wp.mat33d()
    s = wp.vec3d()
    V = wp.mat33d()
    wp.svd3(F, U, s, V)
    mu, la = lame(E, nu)
    e = wp.vec3d(wp.log(wp.max(s[0], SV_MIN)), wp.log(wp.max(s[1], SV_MIN)), wp.log(wp.max(s[2], SV_MIN)))
    tr = e[0] + e[1] + e[2]
    ones = wp.vec3d(_f(1.0), _f(1.0), _f(1.0))
    eh = e - tr / _f(3.0) * ones
    nrm = wp.sqrt(wp.dot(eh, eh) + _f(1.0e-30))
    out = F
    if plastic == 1:
        sy = pp[0] * wp.sqrt(_f(2.0) / _f(3.0))
        if _f(2.0) * mu * nrm > sy:
            e2 = e - (nrm - sy / (_f(2.0) * mu)) / nrm * eh
            out = U * wp.diag(wp.vec3d(wp.exp(e2[0]), wp.exp(e2[1]), wp.exp(e2[2]))) * wp.transpose(V)
    else:
        alpha = pp[0]
        if tr > _f(0.0):
            out = U * wp.transpose(V)
        else:
            dg = nrm + (_f(3.0) * la + _f(2.0) * mu) / (_f(2.0) * mu) * tr * alpha
            if dg > _f(0.0):
                e2 = e - dg / nrm * eh
                out = U * wp.diag(wp.vec3d(wp.exp(e2[0]), wp.exp(e2[1]), wp.exp(e2[2]))) * wp.transpose(V)
    return out


@wp.func
def snow_project(F: wp.mat33d, pp: wp.vec4d) -> wp.mat33d:
    """Snow return map: singular values clamped to [1 - theta_c, 1 + theta_s] (Stomakhin et al. 2013)."""
    U = wp.mat33d()
    s = wp.vec3d()
    V = wp.mat33d()
    wp.svd3(F, U, s, V)
    lo = _f(1.0) - pp[0]
    hi = _f(1.0) + pp[1]
    c = wp.vec3d(wp.clamp(s[0], lo, hi), wp.clamp(s[1], lo, hi), wp.clamp(s[2], lo, hi))
    return U * wp.diag(c) * wp.transpose(V)


@wp.func
def hardening_factor(Jp: wp.float64, plastic: wp.int32, pp: wp.vec4d) -> wp.float64:
    h = _f(1.0)
    if plastic == 3:
        h = wp.exp(pp[2] * (_f(1.0) - Jp))
    return h
