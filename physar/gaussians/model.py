r"""A set of 3-D Gaussians (seed 002, §3.1 and §4.1) and the physics-aware covariance (seed 002, Eq. 3).

Each Gaussian :math:`i` has a mean :math:`\mu_i` (m), a rotation :math:`R_i` stored as a unit quaternion
(w, x, y, z), a diagonal scale :math:`S_i = \operatorname{diag}(s_i)` stored as :math:`\log(s_i)` (:math:`s_i`
in m), an opacity :math:`\eta_i \in (0, 1)` stored as its logit, and spherical-harmonic (SH) colour
coefficients :math:`h_i` of degree :math:`\le 3`, shape (K, 3) with :math:`K = (\mathrm{degree} + 1)^2`.
These are the parameterisations of the standard 3DGS PLY layout (Kerbl et al. 2023), so a `Gaussians`
object round-trips through :mod:`physar.gaussians.ply` without conversion.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch

from physar.errors import PhysarError

#: SH band-0 constant Y_0^0 = 1 / (2 sqrt(pi)); colour = C0 * f_dc + 0.5 for degree 0.
SH_C0 = 0.28209479177387814


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    """DC SH coefficient that renders to the colour ``rgb`` in [0, 1] (inverse of ``C0 * f + 0.5``)."""
    return (rgb - 0.5) / SH_C0


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in (w, x, y, z) order.

    The quaternion is normalised first, so any non-zero 4-vector is accepted (as in 3DGS).
    """
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    r = torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return r.reshape(*q.shape[:-1], 3, 3)


def rotmat_to_quat(r: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (..., 4), (w, x, y, z) with w >= 0, from rotation matrices (..., 3, 3).

    Shepperd's method, branch chosen per matrix by the largest of (trace, r00, r11, r22); vectorised.
    """
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    tr = m00 + m11 + m22
    cand = torch.stack(
        [
            torch.stack([1 + tr, r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                         r[..., 1, 0] - r[..., 0, 1]], -1),
            torch.stack([r[..., 2, 1] - r[..., 1, 2], 1 + m00 - m11 - m22, r[..., 0, 1] + r[..., 1, 0],
                         r[..., 0, 2] + r[..., 2, 0]], -1),
            torch.stack([r[..., 0, 2] - r[..., 2, 0], r[..., 0, 1] + r[..., 1, 0], 1 - m00 + m11 - m22,
                         r[..., 1, 2] + r[..., 2, 1]], -1),
            torch.stack([r[..., 1, 0] - r[..., 0, 1], r[..., 0, 2] + r[..., 2, 0], r[..., 1, 2] + r[..., 2, 1],
                         1 - m00 - m11 + m22], -1),
        ],
        dim=-2,
    )  # (..., 4 candidates, 4)
    key = torch.stack([tr, m00, m11, m22], -1).argmax(-1)
    q = torch.take_along_dim(cand, key[..., None, None].expand(*key.shape, 1, 4), dim=-2).squeeze(-2)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def covariance(quats: torch.Tensor, scales: torch.Tensor, F: torch.Tensor | None = None) -> torch.Tensor:
    r"""Covariance matrices (N, 3, 3), unit m^2 (seed 002, Eq. 3):

    .. math:: \Sigma = F R S S^\top R^\top F^\top.

    ``quats`` (N, 4) give :math:`R`, ``scales`` (N, 3) are the standard deviations :math:`s` (m, not log)
    along the principal axes (:math:`S = \operatorname{diag}(s)`), ``F`` (N, 3, 3) is the deformation
    gradient of each particle (identity when None, which gives the 3DGS covariance
    :math:`R S S^\top R^\top`).
    """
    m = quat_to_rotmat(quats) * scales[..., None, :]  # R S
    if F is not None:
        m = F @ m
    return m @ m.transpose(-1, -2)


@dataclass
class Gaussians:
    r"""3-D Gaussians as torch tensors (unit m), in the 3DGS parameterisation.

    Attributes:
        means: (N, 3) centres :math:`\mu_i`, m.
        quats: (N, 4) rotations as quaternions (w, x, y, z); need not be normalised.
        log_scales: (N, 3) log of the standard deviations along the principal axes (log m).
        opacity_logits: (N,) logit of the peak opacity :math:`\eta_i`.
        sh: (N, K, 3) SH coefficients per colour channel,
            :math:`K = (\mathrm{degree} + 1)^2 \in \{1, 4, 9, 16\}`; sh[:, 0] is the DC term (f_dc in the PLY
            file), sh[:, 1:] the rest (f_rest).
    """

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        expect = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,)}
        if self.means.ndim != 2 or self.means.shape[1] != 3:
            raise PhysarError(f"Gaussians: means must have shape (N, 3), got {tuple(self.means.shape)}")
        for name, shape in expect.items():
            t = getattr(self, name)
            if tuple(t.shape) != shape:
                raise PhysarError(f"Gaussians: {name} must have shape {shape}, got {tuple(t.shape)}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3 or self.sh.shape[1] not in (
            1, 4, 9, 16
        ):
            raise PhysarError(
                f"Gaussians: sh must have shape (N, K, 3) with K in (1, 4, 9, 16) (degree <= 3), "
                f"got {tuple(self.sh.shape)}"
            )

    # ---- construction -------------------------------------------------------------------------------
    @classmethod
    def from_values(
        cls,
        means: torch.Tensor,
        scales: torch.Tensor,
        opacities: torch.Tensor,
        colors: torch.Tensor,
        quats: torch.Tensor | None = None,
        sh_degree: int = 0,
    ) -> Gaussians:
        """Build from activated values: scales s (m, (N, 3) or (N,) isotropic), opacities in (0, 1),
        colours in [0, 1] (N, 3) (DC term; higher SH bands zero), rotations (identity when None)."""
        means = torch.as_tensor(means)
        dt = means.dtype if means.is_floating_point() else torch.get_default_dtype()
        means = means.to(dt)
        n = means.shape[0]
        scales = torch.as_tensor(scales, dtype=dt)
        if scales.ndim == 1:
            scales = scales[:, None].expand(n, 3)
        opacities = torch.as_tensor(opacities, dtype=dt)
        if torch.any(scales <= 0):
            raise PhysarError("Gaussians.from_values: scales must be > 0")
        if torch.any((opacities <= 0) | (opacities >= 1)):
            raise PhysarError("Gaussians.from_values: opacities must lie strictly between 0 and 1")
        if quats is None:
            quats = torch.zeros(n, 4, dtype=dt)
            quats[:, 0] = 1.0
        if not 0 <= sh_degree <= 3:
            raise PhysarError(f"Gaussians.from_values: sh_degree must be 0..3, got {sh_degree}")
        sh = torch.zeros(n, (sh_degree + 1) ** 2, 3, dtype=dt)
        sh[:, 0] = rgb_to_sh0(torch.as_tensor(colors, dtype=dt))
        return cls(means.clone(), torch.as_tensor(quats, dtype=dt).clone(), torch.log(scales).clone(),
                   torch.logit(opacities), sh)

    # ---- activated values ---------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return {1: 0, 4: 1, 9: 2, 16: 3}[self.sh.shape[1]]

    @property
    def scales(self) -> torch.Tensor:
        """(N, 3) standard deviations, m."""
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> torch.Tensor:
        r"""(N,) peak opacities :math:`\eta \in (0, 1)`."""
        return torch.sigmoid(self.opacity_logits)

    @property
    def rotations(self) -> torch.Tensor:
        """(N, 3, 3) rotation matrices :math:`R`."""
        return quat_to_rotmat(self.quats)

    def covariance(self, F: torch.Tensor | None = None) -> torch.Tensor:
        r"""(N, 3, 3) covariances :math:`\Sigma = F R S S^\top R^\top F^\top`, m^2 (seed 002, Eq. 3)."""
        return covariance(self.quats, self.scales, F)

    # ---- utilities ----------------------------------------------------------------------------------
    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def to(self, *args, **kwargs) -> Gaussians:
        """Copy with every tensor converted by ``Tensor.to(*args, **kwargs)`` (dtype or device)."""
        return Gaussians(**{k: v.to(*args, **kwargs) for k, v in self.tensors().items()})

    def detach(self) -> Gaussians:
        return Gaussians(**{k: v.detach() for k, v in self.tensors().items()})

    def requires_grad_(self, flag: bool = True) -> Gaussians:
        for v in self.tensors().values():
            v.requires_grad_(flag)
        return self

    def replace(self, **changes: torch.Tensor) -> Gaussians:
        return replace(self, **changes)

    def __getitem__(self, idx) -> Gaussians:
        out = {k: v[idx] for k, v in self.tensors().items()}
        if out["means"].ndim == 1:
            out = {k: v.unsqueeze(0) for k, v in out.items()}
        return Gaussians(**out)

    def transformed(self, rot: torch.Tensor, trans: torch.Tensor) -> Gaussians:
        r"""Gaussians moved by per-Gaussian rigid motions (rot (N, 3, 3), trans (N, 3)):
        :math:`\mu' = \mathrm{rot}\, \mu + t`, :math:`R' = \mathrm{rot}\, R` (the LBS update of seed 002,
        Eq. 1); scales, opacity, SH unchanged."""
        means = (rot @ self.means[..., None])[..., 0] + trans
        quats = rotmat_to_quat(rot @ self.rotations)
        return replace(self, means=means, quats=quats)
