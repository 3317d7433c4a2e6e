r"""Real spherical harmonics up to degree 3 for view-dependent colour (3DGS convention).

:math:`\mathrm{colour}(d) = \sum_{l \le \mathrm{deg},\, m} c_{lm} Y_{lm}(d) + 0.5`, clamped at 0, with
:math:`d` the unit direction from the camera
centre to the Gaussian mean. The constants are those of the real SH basis used by 3DGS / gsplat.
"""

from __future__ import annotations

import torch

from physar.errors import PhysarError

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
      0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    r"""Real SH basis values (N, :math:`(\mathrm{degree}+1)^2`) at unit directions ``dirs`` (N, 3)."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [C2[0] * xy, C2[1] * yz, C2[2] * (2 * zz - xx - yy), C2[3] * xz, C2[4] * (xx - yy)]
    if degree >= 3:
        out += [
            C3[0] * y * (3 * xx - yy),
            C3[1] * xy * z,
            C3[2] * y * (4 * zz - xx - yy),
            C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            C3[4] * x * (4 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, dim=-1)


def eval_sh(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    r"""RGB (N, 3) from SH coefficients ``sh`` (N, K, 3) at view directions ``dirs`` (N, 3, need not be unit).

    :math:`\mathrm{rgb} = \max\big(\sum_k Y_k(d)\, \mathtt{sh}[:, k] + 0.5, 0\big)` (3DGS convention),
    :math:`K = (\mathrm{degree} + 1)^2 \in \{1, 4, 9, 16\}`. A zero direction (a mean at the camera centre)
    gives the DC colour, the mean over all directions (every band :math:`l \ge 1` is a homogeneous polynomial
    of degree :math:`l` in :math:`d`). Shapes, floating dtypes and finite values are checked (a PhysarError
    names the argument).
    """
    for name, t in (("sh", sh), ("dirs", dirs)):
        if not isinstance(t, torch.Tensor) or not t.is_floating_point():
            raise PhysarError(f"eval_sh: {name} must be a floating torch tensor, got "
                              f"{getattr(t, 'dtype', type(t).__name__)}")
    if sh.ndim != 3 or sh.shape[2] != 3 or sh.shape[1] not in _DEGREE:
        raise PhysarError(f"eval_sh: sh must have shape (N, K, 3) with K in (1, 4, 9, 16) (degree <= 3), got "
                          f"{tuple(sh.shape)}")
    if tuple(dirs.shape) != (sh.shape[0], 3):
        raise PhysarError(f"eval_sh: dirs must have shape ({sh.shape[0]}, 3) (one per sh row), got "
                          f"{tuple(dirs.shape)}")
    for name, t in (("sh", sh), ("dirs", dirs)):
        if not bool(torch.isfinite(t.detach()).all()):
            raise PhysarError(f"eval_sh: {name} contains NaN or infinite values")
    return _eval_sh(sh, dirs)


_DEGREE = {1: 0, 4: 1, 9: 2, 16: 3}


def _eval_sh(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """:func:`eval_sh` without the input checks (the renderer checks its Gaussians once per call)."""
    degree = _DEGREE[sh.shape[1]]
    if degree == 0:
        return torch.clamp_min(C0 * sh[:, 0] + 0.5, 0.0)
    norm = torch.linalg.vector_norm(dirs, dim=-1, keepdim=True)
    d = dirs / torch.clamp_min(norm, torch.finfo(norm.dtype).tiny)  # zero direction -> 0: the DC colour
    basis = sh_basis(degree, d)  # (N, K)
    return torch.clamp_min((basis[..., None] * sh).sum(1) + 0.5, 0.0)
