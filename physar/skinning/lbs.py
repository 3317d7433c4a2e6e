r"""Linear blend skinning (seed 002, Eq. 1).

:math:`A^i = \sum_k W_k^i B_k` (a 4x4 affine blend of the bone transforms :math:`B_k` in SE(3));
:math:`\mu_\text{lbs}^i = A_\text{rot}^i \mu_c^i + A_t^i` and :math:`R_\text{lbs}^i = A_\text{rot}^i R_c^i`.
:math:`A_\text{rot}` is a blend of rotations, in general not orthogonal; for Gaussians it therefore enters the
covariance like a deformation gradient,
:math:`\Sigma = A_\text{rot} R_c S S^\top R_c^\top A_\text{rot}^\top` (seed 002, Eq. 3 with
:math:`F = A_\text{rot}`), which
:func:`lbs_gaussians` returns for :func:`physar.gaussians.render` (``F=``).
"""

from __future__ import annotations

import torch

from physar.errors import PhysarError

Weights = torch.Tensor | tuple[torch.Tensor, torch.Tensor]


def blend_transforms(weights: Weights, bone_transforms: torch.Tensor) -> torch.Tensor:
    r"""The blended transforms :math:`A^i = \sum_k W_k^i B_k`, (N, 4, 4). ``weights`` is dense (N, B) or
    sparse (indices (N, m), w (N, m)); ``bone_transforms`` (B, 4, 4)."""
    if isinstance(weights, tuple):
        idx, w = weights
        if idx.shape != w.shape:
            raise PhysarError(f"lbs: sparse weight indices {tuple(idx.shape)} and values {tuple(w.shape)} "
                              "must have the same shape")
        return (w[..., None, None] * bone_transforms[idx]).sum(-3)
    if weights.ndim != 2 or weights.shape[1] != bone_transforms.shape[-3]:
        raise PhysarError(f"lbs: weights must have shape (N, {bone_transforms.shape[-3]}), "
                          f"got {tuple(weights.shape)}")
    return torch.einsum("nk,kij->nij", weights, bone_transforms)


def lbs(points: torch.Tensor, weights: Weights, bone_transforms: torch.Tensor,
        rotations: torch.Tensor | None = None):
    r"""Skin points (N, 3) (m) and optionally per-point rotations (N, 3, 3) by Eq. 1 (seed 002):

    .. math:: A^i = \sum_k W_k^i B_k, \qquad \mu_\text{lbs}^i = A_\text{rot}^i \mu^i + A_t^i, \qquad
              R_\text{lbs}^i = A_\text{rot}^i R^i.

    Returns (mu_lbs (N, 3), R_lbs (N, 3, 3) or None, A (N, 4, 4)).
    """
    A = blend_transforms(weights, bone_transforms)
    mu = (A[:, :3, :3] @ points[..., None])[..., 0] + A[:, :3, 3]
    R = None if rotations is None else A[:, :3, :3] @ rotations
    return mu, R, A


def lbs_gaussians(g, weights: Weights, bone_transforms: torch.Tensor):
    r"""Skinned copy of Gaussians ``g`` (means moved by Eq. 1) and the per-Gaussian :math:`A_\text{rot}`
    (N, 3, 3) to pass as ``F`` to the renderer so that
    :math:`\Sigma = A_\text{rot} R S S^\top R^\top A_\text{rot}^\top`."""
    mu, _, A = lbs(g.means, weights, bone_transforms)
    return g.replace(means=mu), A[:, :3, :3]


def normalize_weights(w: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Weights rescaled to sum to 1 along ``dim``; raises PhysarError if any row has zero total."""
    s = w.sum(dim, keepdim=True)
    if torch.any(s <= 0):
        raise PhysarError("skinning weights: a point has no positive weight on any bone")
    return w / s
