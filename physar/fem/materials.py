"""Hyperelastic materials, vectorised over quadrature points.

Each material gives the strain energy density W(F) [J/m^3], the first Piola-Kirchhoff stress
P = dW/dF [Pa] and the tangent A_iJkL = dP_iJ/dF_kL, all for F of shape (q, 3, 3).
Lamé constants: lambda = E nu / ((1 + nu)(1 - 2 nu)), mu = E / (2 (1 + nu)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physar.errors import ConfigError

I3 = np.eye(3)
# identity tensors as (3,3,3,3) arrays in the index order (i, J, k, L)
_DIK_DJL = np.einsum("ik,jl->ijkl", I3, I3)
_DIJ_DKL = np.einsum("ij,kl->ijkl", I3, I3)
_DIL_DJK = np.einsum("il,jk->ijkl", I3, I3)


def lame(E: float, nu: float) -> tuple[float, float]:
    r"""Lamé constants :math:`(\lambda, \mu)` [Pa] from Young's modulus E [Pa] and Poisson ratio nu."""
    for what, v in (("Young's modulus E", E), ("Poisson ratio nu", nu)):
        if np.ndim(v) != 0 or np.asarray(v).dtype.kind not in "iuf":
            raise ConfigError(f"{what} must be a number, got {v!r}")
    if not (np.isfinite(E) and E > 0):
        raise ConfigError(f"Young's modulus E must be positive, got {E}")
    if not (-1.0 < nu < 0.5):
        raise ConfigError(f"Poisson ratio nu must be in (-1, 0.5), got {nu}")
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def _det(F):
    return np.linalg.det(F)


class Material:
    """Base class. Subclasses implement energy_density, stress and stress_tangent."""

    name = "material"
    linear = False

    def energy_density(self, F: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def stress(self, F: np.ndarray) -> np.ndarray:
        return self.stress_tangent(F)[0]

    def stress_tangent(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
        raise NotImplementedError

    @property
    def params(self) -> dict:
        return dict(self.__dict__)


@dataclass(frozen=True)
class LinearElastic(Material):
    r"""Small-strain linear elasticity, with the strain :math:`\varepsilon = \operatorname{sym}(F - I)`:

    .. math::

        W = \mu\, \varepsilon : \varepsilon + \frac{\lambda}{2} (\operatorname{tr} \varepsilon)^2, \qquad
        \sigma = \lambda \operatorname{tr}(\varepsilon)\, I + 2 \mu\, \varepsilon.
    """

    E: float
    nu: float
    name = "linear"
    linear = True

    def __post_init__(self):
        lame(self.E, self.nu)

    def energy_density(self, F):
        lam, mu = lame(self.E, self.nu)
        H = F - I3
        eps = 0.5 * (H + np.swapaxes(H, -1, -2))
        tr = np.trace(eps, axis1=-2, axis2=-1)
        return mu * np.einsum("...ij,...ij->...", eps, eps) + 0.5 * lam * tr**2

    def stress_tangent(self, F):
        lam, mu = lame(self.E, self.nu)
        H = F - I3
        eps = 0.5 * (H + np.swapaxes(H, -1, -2))
        tr = np.trace(eps, axis1=-2, axis2=-1)
        P = lam * tr[..., None, None] * I3 + 2 * mu * eps
        A = lam * _DIJ_DKL + mu * (_DIK_DJL + _DIL_DJK)
        return P, np.broadcast_to(A, F.shape[:-2] + (3, 3, 3, 3))


@dataclass(frozen=True)
class StVK(Material):
    r"""Kirchhoff–Saint Venant (seed 000 §5.2), with the strain :math:`E = \tfrac12 (F^\top F - I)`:

    .. math::

        W = \mu\, E : E + \frac{\lambda}{2} (\operatorname{tr} E)^2, \qquad
        P = F S, \quad S = \lambda \operatorname{tr}(E)\, I + 2 \mu E.
    """

    E: float
    nu: float
    name = "stvk"

    def __post_init__(self):
        lame(self.E, self.nu)

    def _green(self, F):
        return 0.5 * (np.einsum("...ki,...kj->...ij", F, F) - I3)

    def energy_density(self, F):
        lam, mu = lame(self.E, self.nu)
        Eg = self._green(F)
        tr = np.trace(Eg, axis1=-2, axis2=-1)
        return mu * np.einsum("...ij,...ij->...", Eg, Eg) + 0.5 * lam * tr**2

    def stress_tangent(self, F):
        lam, mu = lame(self.E, self.nu)
        Eg = self._green(F)
        tr = np.trace(Eg, axis1=-2, axis2=-1)
        S = lam * tr[..., None, None] * I3 + 2 * mu * Eg
        P = F @ S
        FFt = F @ np.swapaxes(F, -1, -2)
        A = (
            np.einsum("ik,...jl->...ijkl", I3, S)
            + lam * np.einsum("...ij,...kl->...ijkl", F, F)
            + mu * np.einsum("...ik,jl->...ijkl", FFt, I3)
            + mu * np.einsum("...il,...kj->...ijkl", F, F)
        )
        return P, A


@dataclass(frozen=True)
class NeoHookean(Material):
    r"""Compressible neo-Hookean, with :math:`I_1 = \operatorname{tr}(F^\top F)` and :math:`J = \det F`:

    .. math::

        W = \frac{\mu}{2} (I_1 - 3) - \mu \ln J + \frac{\lambda}{2} (\ln J)^2, \qquad
        P = \mu F + (\lambda \ln J - \mu) F^{-\top}.
    """

    E: float
    nu: float
    name = "neohookean"

    def __post_init__(self):
        lame(self.E, self.nu)

    def energy_density(self, F):
        lam, mu = lame(self.E, self.nu)
        J = _det(F)
        I1 = np.einsum("...ij,...ij->...", F, F)
        with np.errstate(invalid="ignore", divide="ignore"):
            lnJ = np.where(J > 0, np.log(np.where(J > 0, J, 1.0)), np.nan)
        W = 0.5 * mu * (I1 - 3) - mu * lnJ + 0.5 * lam * lnJ**2
        return np.where(J > 0, W, np.inf)

    def stress_tangent(self, F):
        lam, mu = lame(self.E, self.nu)
        J = _det(F)
        G = np.swapaxes(np.linalg.inv(F), -1, -2)  # F^{-T}
        lnJ = np.log(np.abs(J))
        c = (lam * lnJ - mu)[..., None, None]
        P = mu * F + c * G
        A = (
            mu * _DIK_DJL
            + lam * np.einsum("...ij,...kl->...ijkl", G, G)
            - c[..., None, None] * np.einsum("...il,...kj->...ijkl", G, G)
        )
        return P, A


@dataclass(frozen=True)
class NeoHookeanIncompressible(Material):
    r"""Nearly incompressible neo-Hookean (seed 000 §5.3):

    .. math::

        W = C_1 (\bar I_1 - 3) + \frac{\kappa}{2} (J - 1)^2, \qquad \bar I_1 = J^{-2/3} I_1,

    with :math:`\bar I_1` the isochoric first invariant and :math:`\kappa` [Pa] the bulk penalty
    (:math:`\kappa \gg C_1` approaches the incompressible law :math:`W = C_1 (I_1 - 3)` of the seed).
    Small strain: :math:`\mu = 2 C_1`.
    """

    C1: float
    kappa: float
    name = "neohookean_incompressible"

    def __post_init__(self):
        if not (np.isfinite(self.C1) and self.C1 > 0):
            raise ConfigError(f"C1 must be positive, got {self.C1}")
        if not (np.isfinite(self.kappa) and self.kappa > 0):
            raise ConfigError(f"kappa must be positive, got {self.kappa}")

    @classmethod
    def from_E_nu(cls, E: float, nu: float) -> NeoHookeanIncompressible:
        lam, mu = lame(E, nu)
        return cls(C1=mu / 2, kappa=lam + 2 * mu / 3)

    def energy_density(self, F):
        J = _det(F)
        I1 = np.einsum("...ij,...ij->...", F, F)
        with np.errstate(invalid="ignore"):
            W = self.C1 * (np.cbrt(J) ** -2 * I1 - 3) + 0.5 * self.kappa * (J - 1) ** 2
        return np.where(J > 0, W, np.inf)

    def stress_tangent(self, F):
        C1, k = self.C1, self.kappa
        J = _det(F)
        G = np.swapaxes(np.linalg.inv(F), -1, -2)
        I1 = np.einsum("...ij,...ij->...", F, F)
        a = np.cbrt(J) ** -2
        a_, I1_, J_ = a[..., None, None], I1[..., None, None], J[..., None, None]
        P = C1 * a_ * (2 * F - (2.0 / 3.0) * I1_ * G) + k * (J_ - 1) * J_ * G
        a4, I14, J4 = a_[..., None, None], I1_[..., None, None], J_[..., None, None]
        GG = np.einsum("...ij,...kl->...ijkl", G, G)
        GGt = np.einsum("...il,...kj->...ijkl", G, G)
        FG = np.einsum("...ij,...kl->...ijkl", F, G)
        GF = np.einsum("...ij,...kl->...ijkl", G, F)
        A = (
            2 * C1 * a4 * (_DIK_DJL - (2.0 / 3.0) * FG)
            - (2.0 / 3.0) * C1 * a4 * (-(2.0 / 3.0) * I14 * GG + 2 * GF - I14 * GGt)
            + k * ((2 * J4**2 - J4) * GG - (J4**2 - J4) * GGt)
        )
        return P, A


def polar(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Polar decomposition :math:`F = R S` with :math:`R` a proper rotation (:math:`\det R = +1`),
    vectorised via SVD.

    For :math:`\det F < 0` the sign of the smallest singular value is flipped so that :math:`R` stays a
    rotation.
    """
    U, s, Vt = np.linalg.svd(F)
    d = np.sign(np.linalg.det(U @ Vt))
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    s = s.copy()
    s[..., 2] *= d
    R = U @ Vt
    S = np.einsum("...ki,...k,...kj->...ij", Vt, s, Vt)
    return R, S


def _skew_axial(M):
    return np.stack([M[..., 2, 1], M[..., 0, 2], M[..., 1, 0]], axis=-1)


def _hat(w):
    z = np.zeros_like(w[..., 0])
    return np.stack(
        [
            np.stack([z, -w[..., 2], w[..., 1]], -1),
            np.stack([w[..., 2], z, -w[..., 0]], -1),
            np.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


@dataclass(frozen=True)
class Corotated(Material):
    r"""Co-rotated linear elasticity, with the polar decomposition :math:`F = R S`:

    .. math::

        W = \mu \lVert S - I \rVert^2 + \frac{\lambda}{2} (\operatorname{tr} S - 3)^2, \qquad
        P = 2 \mu (F - R) + \lambda (\operatorname{tr} S - 3) R.

    The tangent is exact, including :math:`dR = R [w]_\times` with
    :math:`(\operatorname{tr}(S)\, I - S)\, w = \operatorname{axial}(R^\top dF - dF^\top R)`.
    """

    E: float
    nu: float
    name = "corotated"

    def __post_init__(self):
        lame(self.E, self.nu)

    def energy_density(self, F):
        lam, mu = lame(self.E, self.nu)
        _, S = polar(F)
        D = S - I3
        return mu * np.einsum("...ij,...ij->...", D, D) + 0.5 * lam * np.trace(D, axis1=-2, axis2=-1) ** 2

    def stress(self, F):
        lam, mu = lame(self.E, self.nu)
        R, S = polar(F)
        trD = (np.trace(S, axis1=-2, axis2=-1) - 3)[..., None, None]
        return 2 * mu * (F - R) + lam * trD * R

    def stress_tangent(self, F):
        lam, mu = lame(self.E, self.nu)
        R, S = polar(F)
        trS = np.trace(S, axis1=-2, axis2=-1)
        P = 2 * mu * (F - R) + lam * (trS - 3)[..., None, None] * R
        Minv = np.linalg.inv(trS[..., None, None] * I3 - S)
        A = np.empty(F.shape[:-2] + (3, 3, 3, 3))
        Rt = np.swapaxes(R, -1, -2)
        for k in range(3):
            for L in range(3):
                E = np.zeros((3, 3))
                E[k, L] = 1.0
                RtE = Rt @ E
                w = np.einsum("...ij,...j->...i", Minv, _skew_axial(RtE - np.swapaxes(RtE, -1, -2)))
                dR = R @ _hat(w)
                A[..., :, :, k, L] = (
                    2 * mu * (E - dR)
                    + lam * R[..., k, L][..., None, None] * R
                    + lam * (trS - 3)[..., None, None] * dR
                )
        return P, A


#: Material classes by the name a FEM problem file gives in ``[material] model``.
MATERIALS = {
    "linear": LinearElastic,
    "stvk": StVK,
    "neohookean": NeoHookean,
    "neohookean_incompressible": NeoHookeanIncompressible,
    "corotated": Corotated,
}


def make_material(name: str, **params) -> Material:
    r"""Material by name: linear | stvk | neohookean | neohookean_incompressible | corotated.

    `neohookean_incompressible` takes C1 and kappa, or E and nu (:math:`C_1 = \mu/2`, :math:`\kappa` = bulk
    modulus).
    """
    if name not in MATERIALS:
        raise ConfigError(f"unknown material {name!r}; choose one of {', '.join(MATERIALS)}")
    if name == "neohookean_incompressible":
        if "C1" in params or "kappa" in params:
            if "C1" not in params or "kappa" not in params:
                raise ConfigError("neohookean_incompressible needs both C1 and kappa (or E and nu)")
            return NeoHookeanIncompressible(C1=float(params["C1"]), kappa=float(params["kappa"]))
        return NeoHookeanIncompressible.from_E_nu(float(params["E"]), float(params["nu"]))
    missing = [k for k in ("E", "nu") if k not in params]
    if missing:
        raise ConfigError(f"material {name!r} needs {' and '.join(missing)}")
    return MATERIALS[name](E=float(params["E"]), nu=float(params["nu"]))
