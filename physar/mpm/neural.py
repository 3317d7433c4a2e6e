r"""Neural residual constitutive laws of seed 002, Eq. (8), with the regulariser of Eq. (11).

.. math::

    \sigma = \mathcal{E}(F, E, \nu) + \mathcal{E}_\theta(F, l_e), \qquad
    F = \mathcal{P}(F_\text{trial}) + \mathcal{P}_\theta(F_\text{trial}, l_p) \qquad \text{(Eq. 8)}

Both residuals are NCLaw-style MLPs (13 -> 64 -> 64 -> 9, seed 002 App. A) on the rotation-invariant features
[singular values of :math:`F` (3), :math:`F^\top F` (9), :math:`\det F` (1)]; the per-particle latent (64) is
added to the output of the first hidden layer.  The last layer is zero-initialised, so a fresh network returns
0 and training starts from the expert law.  Output scaling (physar's choice, so that the unit network output
is meaningful):

* :math:`\mathcal{E}_\theta`: Cauchy stress residual
  :math:`\sigma_\theta = s_\sigma J^{-1} F \operatorname{sym}(O) F^\top` (Pa), :math:`O` =
  reshape(out, 3, 3), :math:`s_\sigma` = ``stress_scale``: the network gives a second Piola-Kirchhoff stress
  in the material frame, pushed forward; it enters the MPM force as the Kirchhoff stress
  :math:`J \sigma_\theta = s_\sigma F \operatorname{sym}(O) F^\top` (symmetric, so angular momentum stays
  conserved);
* :math:`\mathcal{P}_\theta`: deformation-gradient residual
  :math:`s_F\, F_\text{trial} \operatorname{sym}(O)` (dimensionless), :math:`s_F` = ``F_scale``: a flow in
  the material frame (below), added to the expert return map's :math:`\mathcal{P}(F_\text{trial})`.

Both are frame-indifferent: the features are invariant under a rotation :math:`Q` of the deformed state
(:math:`F \to QF`) and the outputs turn with it, :math:`\sigma_\theta(QF) = Q \sigma_\theta(F) Q^\top`,
:math:`\mathcal{P}_\theta(QF) = Q \mathcal{P}_\theta(F)`. Seed §4.3 calls its modules "physics-aware" and
takes NCLaw's architecture (App. A.2); NCLaw's public code turns its outputs with the polar rotation
:math:`R` (:math:`P = R \operatorname{sym}(O)`, :math:`\Delta F = \alpha R \operatorname{sym}(O)`); the push-
forward by :math:`F` here is physar's choice (no SVD gradients, and a symmetric Kirchhoff stress). The plastic
form generalises, to first order, an isotropic return map :math:`F = F_\text{trial} V e^{\Delta\epsilon}
V^\top`. ``objective=False`` keeps physar's form before 2026-11-29 (:math:`s_\sigma \operatorname{sym}(O)`
and :math:`s_F O` in the world frame, which a rigid rotation of the deformed body does not turn), only for
models fitted with it; the two forms differ already at first order about :math:`F = I` unless
:math:`O(I) = 0` and :math:`O` is symmetric.

The singular values come from Warp's ``svd3`` (finite gradients at :math:`F = I`, unlike
``torch.linalg.svd``).

Undeformed-state equilibrium (``rest_free``, off by default; physar's option, not in the seed): each network's
output at :math:`F = I` (same latent) is subtracted, :math:`O(F, l) - O(I, l)`, so that a residual cannot
stress the undeformed material (:math:`\mathcal{E}_\theta(I, l_e) = 0`) nor drift an undeformed deformation
gradient (:math:`\mathcal{P}_\theta(I, l_p) = 0`): without it, an unloaded object with a learned residual moves on
its own (measured on the quick C-pillow, issue 17: a residual freed of the Eq. 11 term learned a rest stress of
about 1 kPa).  Truncation (below) applies to the difference.

Activation truncation at inference (seed App. A.2, Eq. 12): :math:`O = 0` where
:math:`\lVert O \rVert_\text{Fro} < \epsilon` (:math:`\epsilon = 10^{-3}`), :math:`O` the (3, 3) output matrix
of a network.  physar applies it to the network's own (unit) output, before the output scaling above, so that
:math:`\epsilon` keeps the seed's meaning of "a negligible network output" whatever the scale.
"""

from __future__ import annotations

import torch
from torch import nn


def invariant_features(F: torch.Tensor, sv: torch.Tensor) -> torch.Tensor:
    r"""(N, 13) features :math:`[\sigma_1, \sigma_2, \sigma_3, F^\top F \text{ (row-major)}, \det F]` of
    deformation gradients :math:`F` (N, 3, 3)."""
    C = F.transpose(1, 2) @ F
    return torch.cat([sv, C.reshape(-1, 9), torch.linalg.det(F)[:, None]], dim=1)


class ResidualMLP(nn.Module):
    """13 -> hidden -> hidden -> 9 MLP with the per-particle latent added after the first layer."""

    def __init__(self, latent_dim: int = 64, hidden: int = 64, scale: float = 1.0):
        super().__init__()
        self.latent_dim = latent_dim
        self.scale = float(scale)
        self.l1 = nn.Linear(13, hidden, dtype=torch.float64)
        self.l2 = nn.Linear(hidden, hidden, dtype=torch.float64)
        self.l3 = nn.Linear(hidden, 9, dtype=torch.float64)
        if latent_dim != hidden:
            raise ValueError(f"latent_dim ({latent_dim}) must equal the hidden width ({hidden}) (seed 002 App. A)")
        nn.init.zeros_(self.l3.weight)
        nn.init.zeros_(self.l3.bias)
        self.act = nn.GELU()

    def raw(self, feat: torch.Tensor, latent: torch.Tensor | None) -> torch.Tensor:
        """The (N, 3, 3) network output O (unscaled, untruncated)."""
        h = self.l1(feat)
        if latent is not None:
            h = h + latent
        h = self.act(h)
        h = self.act(self.l2(h))
        return self.l3(h).reshape(-1, 3, 3)

    def forward(self, feat: torch.Tensor, latent: torch.Tensor | None, eps: float | None = None,
                rest_free: bool = False) -> torch.Tensor:
        """scale * O with O the (N, 3, 3) network output; ``rest_free``: O(feat) - O(features of F = I) (same
        latent); ``eps``: O truncated by Eq. 12 first."""
        out = self.raw(feat, latent)
        if rest_free:
            out = out - self.raw(REST_FEATURES.to(feat).expand(feat.shape[0], 13), latent)
        return self.scale * (out if eps is None else truncate(out, eps))


# invariant_features of F = I: singular values 1, F^T F = I, det 1
REST_FEATURES = torch.tensor([1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0], dtype=torch.float64)


def truncate(O: torch.Tensor, eps: float) -> torch.Tensor:
    """Seed Eq. 12: O (N, 3, 3) with every matrix of Frobenius norm < eps set to 0."""
    keep = torch.linalg.matrix_norm(O) >= eps
    return torch.where(keep[:, None, None], O, torch.zeros_like(O))


class NeuralResidual(nn.Module):
    """The pair (E_theta, P_theta) of Eq. (8); either may be disabled (None)."""

    def __init__(self, elastic: bool = True, plastic: bool = True, latent_dim: int = 64,
                 stress_scale: float = 1.0e4, F_scale: float = 1.0e-3, eps: float = 1.0e-3, rest_free: bool = False,
                 objective: bool = True):
        super().__init__()
        self.objective = bool(objective)  # outputs in the material frame, pushed forward by F (module docstring)
        self.eps = float(eps)  # Eq. 12 threshold on the unit network output
        self.rest_free = bool(rest_free)  # O(F) - O(I): no residual on undeformed material
        self.elastic = ResidualMLP(latent_dim, latent_dim, stress_scale) if elastic else None
        self.plastic = ResidualMLP(latent_dim, latent_dim, F_scale) if plastic else None
        self.latent_dim = latent_dim

    def _sym_elastic(self, F, sv, l_e, truncate: bool):
        """s sym(O) (N, 3, 3), Pa: the elastic network's output at F, symmetrised; ``truncate``: Eq. 12."""
        out = self.elastic(invariant_features(F, sv), l_e, self.eps if truncate else None, self.rest_free)
        return 0.5 * (out + out.transpose(1, 2))

    def kirchhoff(self, F, sv, l_e, truncate: bool = False):
        """Kirchhoff residual J sigma_theta (N, 3, 3), Pa (module docstring): s F sym(O) F^T, or J s sym(O) for
        the world-frame form; ``truncate``: Eq. 12 (inference). No division by J (finite for any F)."""
        out = self._sym_elastic(F, sv, l_e, truncate)
        if not self.objective:
            return torch.linalg.det(F)[:, None, None] * out
        return F @ out @ F.transpose(1, 2)

    def stress(self, F, sv, l_e, truncate: bool = False):
        """Cauchy residual sigma_theta = kirchhoff / J (N, 3, 3), Pa; ``truncate``: Eq. 12 (inference)."""
        if not self.objective:  # s sym(O) itself, without a J / J round trip
            return self._sym_elastic(F, sv, l_e, truncate)
        return self.kirchhoff(F, sv, l_e, truncate) / torch.linalg.det(F)[:, None, None]

    def deformation(self, F_trial, sv, l_p, truncate: bool = False):
        """Residual added to the projected deformation gradient, (N, 3, 3) (module docstring); ``truncate``:
        Eq. 12 (inference)."""
        out = self.plastic(invariant_features(F_trial, sv), l_p, self.eps if truncate else None, self.rest_free)
        if not self.objective:
            return out
        return F_trial @ (0.5 * (out + out.transpose(1, 2)))


def regulariser(nets: NeuralResidual | None, omega: torch.Tensor | None, F=None, l_e=None, F_trial=None, l_p=None,
                lam_law: float = 10.0, lam_omega: float = 0.1, lam_feat: float = 1.0) -> torch.Tensor:
    r"""The regulariser of Eq. (11) plus the latent term :math:`R_\text{feat}` of seed 002 App. A:

    .. math::

        R = \lambda_\text{law} \big(\lVert \mathcal{E}_\theta(F, l_e) \rVert_2
        + \lVert \mathcal{P}_\theta(F_\text{trial}, l_p) \rVert_2\big)
        + \lambda_\omega \lVert \omega \rVert_2
        + \lambda_\text{feat} \big(\lVert l_e \rVert_2 + \lVert l_p \rVert_2\big),

    with :math:`\lambda_\text{law}, \lambda_\omega, \lambda_\text{feat}` = ``lam_law``, ``lam_omega``,
    ``lam_feat``.  Defaults are the seed's weights.

    :math:`\lVert \cdot \rVert_2` is the 2-norm of all entries (over particles).  F, F_trial (N, 3, 3):
    deformation gradients where the residuals are evaluated (their singular values enter as features only,
    without gradient); a residual that is absent (``nets`` None or its network None) or has no F contributes
    nothing."""
    r = lam_omega * torch.linalg.vector_norm(omega) if omega is not None else torch.zeros((), dtype=torch.float64)
    if nets is None:
        return r
    sv = lambda A: torch.linalg.svdvals(A.detach())
    if nets.elastic is not None and F is not None:
        r = r + lam_law * torch.linalg.vector_norm(nets.stress(F, sv(F), l_e))
        if l_e is not None:
            r = r + lam_feat * torch.linalg.vector_norm(l_e)
    if nets.plastic is not None and F_trial is not None:
        r = r + lam_law * torch.linalg.vector_norm(nets.deformation(F_trial, sv(F_trial), l_p))
        if l_p is not None:
            r = r + lam_feat * torch.linalg.vector_norm(l_p)
    return r
