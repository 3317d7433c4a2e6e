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

#: largest :math:`\max |R^\top R - I|` that :func:`rotmat_to_quat` accepts (float32 products of rotations pass;
#: a scaled, sheared or blended matrix does not).
ROTATION_TOL = 1e-2


def _floating(x, name: str, where: str, last: tuple = ()) -> torch.Tensor:
    """``x`` itself when it is a floating torch tensor whose trailing dimensions are ``last``, else a
    PhysarError naming ``where``, ``name``, the shape or type found and the one expected."""
    want = "(..., " + ", ".join(map(str, last)) + ")" if last else ""
    if not isinstance(x, torch.Tensor):
        raise PhysarError(f"{where}: {name} must be a torch tensor{' ' + want if want else ''}, got "
                          f"{type(x).__name__}")
    if not x.is_floating_point():
        raise PhysarError(f"{where}: {name} must be a floating tensor, got {x.dtype}")
    if last and (x.ndim < len(last) or tuple(x.shape[x.ndim - len(last):]) != last):
        raise PhysarError(f"{where}: {name} must have shape {want}, got {tuple(x.shape)}")
    return x


def _first_bad(ok: torch.Tensor) -> int | None:
    """Index (along dim 0) of the first row of the boolean ``ok`` with a False, None when all are True (one
    reduction over the whole array)."""
    if bool(ok.all()):
        return None
    return int(torch.nonzero(~ok.reshape(ok.shape[0], -1).all(1))[0, 0]) if ok.ndim else 0


def _check_finite(x: torch.Tensor, name: str, where: str) -> None:
    """PhysarError naming the first row of ``x`` (dim 0) with a NaN or infinite value."""
    bad = _first_bad(torch.isfinite(x.detach()))
    if bad is not None:
        raise PhysarError(f"{where}: {name}[{bad}] contains NaN or infinite values")


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    """DC SH coefficient that renders to the colour ``rgb`` in [0, 1] (inverse of ``C0 * f + 0.5``); a list or
    array is converted to a tensor."""
    if not isinstance(rgb, torch.Tensor):
        rgb = torch.as_tensor(rgb, dtype=torch.get_default_dtype())
    return (rgb - 0.5) / SH_C0


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in (w, x, y, z) order.

    The quaternion is normalised first, so any non-zero finite 4-vector is accepted (as in 3DGS); a zero or
    non-finite one (no rotation) raises a PhysarError naming its index.
    """
    _floating(q, "quaternions", "quat_to_rotmat", (4,))
    norm = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    bad = _first_bad(((norm > 0) & torch.isfinite(norm)).detach().reshape(-1))
    if bad is not None:
        raise PhysarError(f"quat_to_rotmat: quaternion {bad} (flattened) is zero or not finite "
                          f"({q.detach().reshape(-1, 4)[bad].tolist()}): no rotation")
    q = q / norm
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
    r"""Unit quaternions (..., 4), (w, x, y, z) with w >= 0, from rotation matrices (..., 3, 3).

    Shepperd's method, branch chosen per matrix by the largest of (trace, r00, r11, r22); vectorised.
    Each matrix must be a rotation: finite, :math:`\max |R^\top R - I| \le` :data:`ROTATION_TOL` and
    det > 0 (anything else has no quaternion; a PhysarError names the first such matrix).
    """
    _floating(r, "r", "rotmat_to_quat", (3, 3))
    with torch.no_grad():
        rd = r.detach().reshape(-1, 3, 3)
        err = (rd.transpose(-1, -2) @ rd - torch.eye(3, dtype=rd.dtype, device=rd.device)).abs().amax((-1, -2))
        bad = _first_bad((err <= ROTATION_TOL) & (torch.linalg.det(rd) > 0))  # NaN fails both
    if bad is not None:
        raise PhysarError(f"rotmat_to_quat: matrix {bad} (flattened) is not a rotation (|R^T R - I| = "
                          f"{float(err[bad]):.3g}, det {float(torch.linalg.det(rd[bad])):.3g}; expected "
                          f"orthonormal with det +1): {[[round(v, 6) for v in row] for row in rd[bad].tolist()]}")
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
    :math:`R S S^\top R^\top`). All three must share the dtype; shapes are checked (a PhysarError names the
    argument), and ``scales`` and ``F`` must be finite.
    """
    _floating(quats, "quats", "covariance", (4,))
    lead = tuple(quats.shape[:-1])
    _floating(scales, "scales", "covariance")
    if tuple(scales.shape) != lead + (3,):
        raise PhysarError(f"covariance: scales must have shape {lead + (3,)} (one per quaternion), got "
                          f"{tuple(scales.shape)}")
    if F is not None:
        _floating(F, "F", "covariance")
        if tuple(F.shape) != lead + (3, 3):
            raise PhysarError(f"covariance: F must have shape {lead + (3, 3)} (one per quaternion), got "
                              f"{tuple(F.shape)}")
    for name, t in (("scales", scales), ("F", F)):
        if t is not None and t.dtype != quats.dtype:
            raise PhysarError(f"covariance: {name} is {t.dtype}, quats {quats.dtype}; give them one dtype")
        if t is not None:
            _check_finite(t, name, "covariance")
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

    The constructor checks shapes, floating dtypes and that all five share dtype and device (a PhysarError
    names the tensor); values (NaN, inf, zero quaternions) are checked by :meth:`check_finite`, which
    :func:`~physar.gaussians.render` and :func:`~physar.gaussians.save_ply` call.
    """

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor

    def __post_init__(self) -> None:
        for f in fields(self):
            _floating(getattr(self, f.name), f.name, "Gaussians")
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
        for f in fields(self):
            t = getattr(self, f.name)
            if t.dtype != self.means.dtype or t.device != self.means.device:
                raise PhysarError(f"Gaussians: {f.name} is {t.dtype} on {t.device}, means {self.means.dtype} on "
                                  f"{self.means.device}; all tensors must share dtype and device (use .to())")

    def check_finite(self, where: str = "Gaussians") -> None:
        r"""PhysarError naming the first tensor and Gaussian with a NaN or infinite value, or whose scale
        :math:`\exp(\text{log\_scales})` overflows, or whose quaternion is zero (one pass per tensor; the
        constructor checks shapes and dtypes only, as it runs inside optimisation loops)."""
        for f in fields(self):
            _check_finite(getattr(self, f.name), f.name, where)
        bad = _first_bad(torch.isfinite(torch.exp(self.log_scales.detach())))
        if bad is not None:
            raise PhysarError(f"{where}: log_scales[{bad}] = {self.log_scales[bad].tolist()} overflows exp() in "
                              f"{self.log_scales.dtype} (scale above {torch.finfo(self.log_scales.dtype).max:.3g} m)")
        bad = _first_bad(torch.linalg.vector_norm(self.quats.detach(), dim=-1) > 0)
        if bad is not None:
            raise PhysarError(f"{where}: quats[{bad}] is zero (no rotation)")

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
        """Build from activated values: scales s (m, (N, 3) or (N,) isotropic), opacities in (0, 1) ((N,)),
        colours in [0, 1] (N, 3) (DC term; higher SH bands zero), rotations (N, 4) (identity when None),
        ``sh_degree`` 0..3. Tensors, arrays or lists; the dtype is the means' (the default dtype for integer
        means). Every value must be finite, scales > 0, colours within [0, 1], quaternions non-zero; a
        PhysarError names the first offending argument and Gaussian. (The stored SH coefficients ``sh`` are
        not bounded: higher bands may take a rendered colour out of [0, 1]; the renderer clamps it at 0, as
        3DGS does.)"""
        where = "Gaussians.from_values"
        means = torch.as_tensor(means)
        dt = means.dtype if means.is_floating_point() else torch.get_default_dtype()
        means = means.to(dt)
        if means.ndim != 2 or means.shape[1] != 3:
            raise PhysarError(f"{where}: means must have shape (N, 3), got {tuple(means.shape)}")
        n = means.shape[0]
        scales = torch.as_tensor(scales, dtype=dt, device=means.device)
        if scales.ndim == 1 and scales.shape[0] == n:
            scales = scales[:, None].expand(n, 3)
        if tuple(scales.shape) != (n, 3):
            raise PhysarError(f"{where}: scales must have shape ({n},) or ({n}, 3), got {tuple(scales.shape)}")
        opacities = torch.as_tensor(opacities, dtype=dt, device=means.device)
        if tuple(opacities.shape) != (n,):
            raise PhysarError(f"{where}: opacities must have shape ({n},), got {tuple(opacities.shape)}")
        colors = torch.as_tensor(colors, dtype=dt, device=means.device)
        if tuple(colors.shape) != (n, 3):
            raise PhysarError(f"{where}: colors must have shape ({n}, 3), got {tuple(colors.shape)}")
        if quats is None:
            quats = torch.zeros(n, 4, dtype=dt, device=means.device)
            quats[:, 0] = 1.0
        quats = torch.as_tensor(quats, dtype=dt, device=means.device)
        if tuple(quats.shape) != (n, 4):
            raise PhysarError(f"{where}: quats must have shape ({n}, 4), got {tuple(quats.shape)}")
        for name, t in (("means", means), ("scales", scales), ("opacities", opacities), ("colors", colors),
                        ("quats", quats)):
            _check_finite(t, name, where)
        if torch.any(scales <= 0):
            raise PhysarError(f"{where}: scales must be > 0")
        if torch.any((opacities <= 0) | (opacities >= 1)):
            raise PhysarError(f"{where}: opacities must lie strictly between 0 and 1")
        bad = _first_bad((colors >= 0) & (colors <= 1))
        if bad is not None:
            raise PhysarError(f"{where}: colors[{bad}] = {colors[bad].detach().tolist()} must lie in [0, 1] (RGB; not 0-255)")
        bad = _first_bad(torch.linalg.vector_norm(quats, dim=-1) > 0)
        if bad is not None:
            raise PhysarError(f"{where}: quats[{bad}] is zero (no rotation)")
        if sh_degree not in (0, 1, 2, 3) or isinstance(sh_degree, bool):
            raise PhysarError(f"{where}: sh_degree must be 0..3, got {sh_degree!r}")
        sh = torch.zeros(n, (int(sh_degree) + 1) ** 2, 3, dtype=dt, device=means.device)
        sh[:, 0] = rgb_to_sh0(colors)
        return cls(means.clone(), quats.clone(), torch.log(scales).clone(), torch.logit(opacities), sh)

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
        Eq. 1); scales, opacity, SH unchanged. ``rot`` may also be one (3, 3) or (1, 3, 3) and ``trans`` one
        (3,) for all; both of the means' dtype and finite, ``rot`` rotations (see :func:`rotmat_to_quat`)."""
        n = len(self)
        for name, t, shape in (("rot", rot, (n, 3, 3)), ("trans", trans, (n, 3))):
            _floating(t, name, "Gaussians.transformed")
            if t.ndim not in (len(shape) - 1, len(shape)) or tuple(t.shape[t.ndim - len(shape) + 1:]) != shape[1:] \
                    or (t.ndim == len(shape) and t.shape[0] not in (1, n)):
                raise PhysarError(f"Gaussians.transformed: {name} must have shape {shape} (or one for all), got "
                                  f"{tuple(t.shape)}")
            if t.dtype != self.means.dtype:
                raise PhysarError(f"Gaussians.transformed: {name} is {t.dtype}, the Gaussians {self.means.dtype}; "
                                  "give them one dtype")
            _check_finite(t, name, "Gaussians.transformed")
        means = (rot @ self.means[..., None])[..., 0] + trans
        quats = rotmat_to_quat(rot @ self.rotations)
        return replace(self, means=means, quats=quats)
