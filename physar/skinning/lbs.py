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

WEIGHT_SUM_TOL = 1e-3  # accepted |sum_k W_k - 1| per point (float16 or rounded weights pass, a lost bone does not)


def _check_weight_shapes(weights: Weights, n_bones: int, n_points: int | None, name: str) -> torch.Tensor:
    """The shape part of :func:`check_weights` (no pass over the values); returns the weight values."""
    sparse = isinstance(weights, tuple)
    if sparse:
        if len(weights) != 2 or not all(isinstance(t, torch.Tensor) for t in weights):
            raise PhysarError(f"{name}: sparse weights must be a tuple (indices, values) of tensors")
        idx, w = weights
        if idx.shape != w.shape or w.ndim != 2:
            raise PhysarError(f"{name}: sparse indices {tuple(idx.shape)} and values {tuple(w.shape)} must have "
                              "one shape (N, m)")
        if idx.dtype.is_floating_point or idx.dtype.is_complex or idx.dtype == torch.bool:
            raise PhysarError(f"{name}: sparse indices must be integers, got {idx.dtype}")
    else:
        if not isinstance(weights, torch.Tensor):
            raise PhysarError(f"{name}: must be a tensor (N, {n_bones}) or a tuple (indices, values), "
                              f"got {type(weights).__name__}")
        w = weights
        if w.ndim != 2 or w.shape[1] != n_bones:
            raise PhysarError(f"{name}: must have shape (N, {n_bones}) for {n_bones} bones, got {tuple(w.shape)}")
    if n_points is not None and w.shape[0] != n_points:
        raise PhysarError(f"{name}: {w.shape[0]} rows for {n_points} points")
    return w


def check_weights(weights: Weights, n_bones: int, n_points: int | None = None, name: str = "lbs: weights") -> None:
    r"""Refuse skinning weights that Eq. 1 cannot use, in one PhysarError line starting with ``name`` and naming
    the first bad point (row) and value: dense weights not of shape (N, ``n_bones``), sparse (indices, values)
    not of one shape (N, m) or with an index outside ``0..n_bones-1``, N differing from ``n_points`` (when
    given), a weight that is NaN, infinite or negative, or a row whose sum is not 1 within ``WEIGHT_SUM_TOL``
    (:math:`\sum_k W_k = 1` keeps a point on its bones; a row of zeros would move it to the origin).
    Good weights cost a minimum and a row sum of (N, m) (and the indices' range) and one host synchronisation."""
    w = _check_weight_shapes(weights, n_bones, n_points, name)
    sparse = isinstance(weights, tuple)
    if sparse:
        idx = weights[0]
    w = w.detach()
    if w.numel() == 0:
        if len(w):
            raise PhysarError(f"{name}: row 0 has no weight on any bone (Eq. 1 would move the point to the origin)")
        return
    # fast pass: the minimum is NaN or < 0 for a NaN, -inf or negative weight; a row sum is off 1 (or NaN) for
    # +inf and for rows not summing to 1
    sums_ok = (w.sum(1) - 1).abs() <= WEIGHT_SUM_TOL
    ok = (w.min() >= 0) & sums_ok.all()
    if sparse:
        lo, hi = torch.aminmax(idx)
        ok &= (lo >= 0) & (hi < n_bones)
    if bool(ok):
        return
    if sparse:
        out = (idx < 0) | (idx >= n_bones)
        if bool(out.any()):
            i, k = torch.nonzero(out)[0].tolist()
            raise PhysarError(f"{name}: row {i} has bone index {int(idx[i, k])}, outside 0..{n_bones - 1}")
    bad_val = ~torch.isfinite(w) | (w < 0)
    if bool(bad_val.any()):
        i, k = torch.nonzero(bad_val)[0].tolist()
        what = "negative" if torch.isfinite(w[i, k]) else "not finite"
        raise PhysarError(f"{name}: row {i} has weight {float(w[i, k]):g} ({what}) in column {k}")
    i = int(torch.nonzero(~sums_ok)[0, 0])
    total = float(w[i].sum())
    if total == 0:
        raise PhysarError(f"{name}: row {i} has no weight on any bone (Eq. 1 would move the point to the origin)")
    raise PhysarError(f"{name}: row {i} sums to {total:.6g}, not 1 (within {WEIGHT_SUM_TOL:g}); "
                      "normalize_weights rescales the rows")


def blend_transforms(weights: Weights, bone_transforms: torch.Tensor, *, check_values: bool = True) -> torch.Tensor:
    r"""The blended transforms :math:`A^i = \sum_k W_k^i B_k`, (N, 4, 4). ``weights`` is dense (N, B) or
    sparse (indices (N, m), w (N, m)); ``bone_transforms`` (B, 4, 4). Weights that Eq. 1 cannot use (NaN,
    negative, rows not summing to 1, indices out of range, mismatched shapes) raise PhysarError
    (:func:`check_weights`). ``check_values=False`` (as scipy's ``check_finite=False``) keeps only the shape
    checks, for weights checked once already (a :class:`~physar.skinning.Body` checks its own when built): the
    value pass costs a reduction over (N, m) and, on a GPU, a host synchronisation per call."""
    if not isinstance(bone_transforms, torch.Tensor) or bone_transforms.ndim != 3 \
            or bone_transforms.shape[1:] != (4, 4):
        raise PhysarError(f"lbs: bone_transforms must have shape (B, 4, 4), got "
                          f"{tuple(getattr(bone_transforms, 'shape', ()))}")
    if check_values:
        check_weights(weights, bone_transforms.shape[0])
    else:
        _check_weight_shapes(weights, bone_transforms.shape[0], None, "lbs: weights")
    if isinstance(weights, tuple):
        idx, w = weights
        return (w[..., None, None] * bone_transforms[idx]).sum(-3)
    return torch.einsum("nk,kij->nij", weights, bone_transforms)


def lbs(points: torch.Tensor, weights: Weights, bone_transforms: torch.Tensor,
        rotations: torch.Tensor | None = None, *, check_values: bool = True):
    r"""Skin points (N, 3) (m) and optionally per-point rotations (N, 3, 3) by Eq. 1 (seed 002):

    .. math:: A^i = \sum_k W_k^i B_k, \qquad \mu_\text{lbs}^i = A_\text{rot}^i \mu^i + A_t^i, \qquad
              R_\text{lbs}^i = A_\text{rot}^i R^i.

    Returns (mu_lbs (N, 3), R_lbs (N, 3, 3) or None, A (N, 4, 4)). The weights must have one row per point
    (:func:`check_weights`; ``check_values=False`` keeps only the shape checks, see :func:`blend_transforms`).
    """
    A = blend_transforms(weights, bone_transforms, check_values=check_values)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) != len(A):
        raise PhysarError(f"lbs: points must have shape ({len(A)}, 3) (one per weight row), "
                          f"got {tuple(points.shape)}")
    if rotations is not None and tuple(rotations.shape) != (len(A), 3, 3):
        raise PhysarError(f"lbs: rotations must have shape ({len(A)}, 3, 3), got {tuple(rotations.shape)}")
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
    """Weights rescaled to sum to 1 along ``dim``; raises PhysarError naming the first bad entry if a weight is
    NaN, infinite or negative, or if a row has zero total (a point on no bone)."""
    bad = ~torch.isfinite(w) | (w < 0)
    if bool(bad.any()):
        at = tuple(torch.nonzero(bad)[0].tolist())
        raise PhysarError(f"skinning weights: entry {at} is {float(w[at]):g}; weights must be finite and >= 0")
    s = w.sum(dim, keepdim=True)
    if torch.any(s <= 0):
        at = tuple(torch.nonzero(s <= 0)[0].tolist())
        raise PhysarError(f"skinning weights: the row at {at} (dim {dim}) has no positive weight on any bone")
    return w / s
