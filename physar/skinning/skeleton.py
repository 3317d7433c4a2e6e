r"""Skeletons with bone transforms in SE(3) and forward kinematics (seed 002, §3.1, Eq. 1).

Transforms are 4x4 homogeneous matrices :math:`\begin{bmatrix} R & t \\ 0 & 1 \end{bmatrix}`
(:math:`R \in SO(3)`, :math:`t` in m) as torch tensors. A skeleton has :math:`B` bones with ``parents[k] < k``
(-1 for roots) and rest-pose bone frames :math:`G_k^\text{rest}` (world :math:`\leftarrow` bone). A pose gives
local joint rotations; forward kinematics composes them down the hierarchy,
:math:`G_k = G_{\mathrm{parent}(k)} L_k`, and the skinning transform of Eq. 1 is
:math:`B_k(\theta) = G_k(\theta)\, (G_k^\text{rest})^{-1}`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from physar.errors import PhysarError


def rigid(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Homogeneous transforms (..., 4, 4) from rotations (..., 3, 3) and translations (..., 3), m."""
    T = torch.zeros(*R.shape[:-2], 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_rigid(T: torch.Tensor) -> torch.Tensor:
    r"""Inverse of rigid transforms (..., 4, 4): :math:`[R^\top, -R^\top t]`."""
    Rt = T[..., :3, :3].transpose(-1, -2)
    return rigid(Rt, -(Rt @ T[..., :3, 3:4])[..., 0])


def axis_angle_to_matrix(aa: torch.Tensor) -> torch.Tensor:
    r"""Rotation matrices (..., 3, 3) from axis-angle vectors (..., 3) (angle = norm, rad), Rodrigues'
    formula :math:`R = I + \sin(a) K + (1 - \cos(a)) K^2` with a Taylor branch near :math:`a = 0`
    (differentiable)."""
    a2 = (aa * aa).sum(-1, keepdim=True)[..., None]
    small = a2 < 1e-12
    a2s = torch.where(small, torch.ones_like(a2), a2)
    a = torch.sqrt(a2s)
    s = torch.where(small, 1 - a2 / 6, torch.sin(a) / a)
    c = torch.where(small, 0.5 - a2 / 24, (1 - torch.cos(a)) / a2s)
    x, y, z = aa.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*aa.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand_as(K)
    return eye + s * K + c * (K @ K)


def hierarchy_levels(parents: torch.Tensor) -> list[torch.Tensor]:
    """Bone indices grouped by depth in the tree (roots first), for level-wise vectorised FK."""
    p = parents.tolist()
    depth = [0] * len(p)
    for k, pk in enumerate(p):
        if pk >= k:
            raise PhysarError(f"skeleton: parent of bone {k} is {pk}; parents must precede their children")
        depth[k] = 0 if pk < 0 else depth[pk] + 1
    d = torch.tensor(depth, dtype=torch.long)
    return [torch.nonzero(d == lvl).squeeze(1) for lvl in range(int(d.max()) + 1 if len(p) else 0)]


def forward_kinematics(parents: torch.Tensor, local: torch.Tensor,
                       levels: list[torch.Tensor] | None = None) -> torch.Tensor:
    r"""Global bone frames (..., B, 4, 4): :math:`G_k = G_{\mathrm{parent}(k)} L_k`,
    :math:`G_\text{root} = L_\text{root}`, from local transforms :math:`L` (..., B, 4, 4) relative to the
    parent frame. Vectorised over bones of equal depth."""
    levels = hierarchy_levels(parents) if levels is None else levels
    glob = local.clone()
    for idx in levels[1:] if levels else []:
        par = parents[idx]
        glob[..., idx, :, :] = glob[..., par, :, :] @ local[..., idx, :, :]
    return glob


@dataclass
class Skeleton:
    r"""Bone hierarchy with rest-pose frames.

    Attributes:
        parents: (B,) long, parent index (-1 for a root), parents[k] < k.
        rest_global: (B, 4, 4) rest-pose bone frames :math:`G_k^\text{rest}` (world :math:`\leftarrow` bone), m.
        names: bone names.
    """

    parents: torch.Tensor
    rest_global: torch.Tensor
    names: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.parents = torch.as_tensor(self.parents, dtype=torch.long)
        b = self.parents.shape[0]
        if tuple(self.rest_global.shape) != (b, 4, 4):
            raise PhysarError(f"Skeleton: rest_global must have shape ({b}, 4, 4), got "
                              f"{tuple(self.rest_global.shape)}")
        if not self.names:
            self.names = [f"bone{k}" for k in range(b)]
        if len(self.names) != b:
            raise PhysarError(f"Skeleton: {len(self.names)} names for {b} bones")
        self._levels = hierarchy_levels(self.parents)

    @property
    def n_bones(self) -> int:
        return self.parents.shape[0]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise PhysarError(f"Skeleton: no bone named {name!r}; bones are {self.names}") from None

    def rest_local(self) -> torch.Tensor:
        r"""(B, 4, 4) rest transforms relative to the parent:
        :math:`L_k = (G_{\mathrm{parent}(k)}^\text{rest})^{-1} G_k^\text{rest}`."""
        par = self.parents.clamp_min(0)
        inv_par = invert_rigid(self.rest_global[par])
        loc = inv_par @ self.rest_global
        return torch.where((self.parents < 0)[:, None, None], self.rest_global, loc)

    def pose(self, rotations: torch.Tensor, root_translation: torch.Tensor | None = None) -> torch.Tensor:
        r"""Posed global bone frames (..., B, 4, 4) for local joint rotations (..., B, 3, 3) applied in each
        bone's rest frame
        (:math:`L_k(\theta) = L_k^\text{rest} \begin{bmatrix} R_k & 0 \\ 0 & 1 \end{bmatrix}`) and a
        translation (..., 3) (m, world) of the roots."""
        loc = self.rest_local().to(rotations.dtype) @ rigid(rotations, torch.zeros_like(rotations[..., 0]))
        glob = forward_kinematics(self.parents, loc, self._levels)
        if root_translation is not None:
            shift = rigid(torch.eye(3, dtype=glob.dtype).expand(*root_translation.shape[:-1], 3, 3),
                          root_translation)
            glob = shift[..., None, :, :] @ glob
        return glob

    def bone_transforms(self, posed_global: torch.Tensor) -> torch.Tensor:
        r"""Skinning transforms :math:`B_k = G_k(\theta)\, (G_k^\text{rest})^{-1}` in SE(3) (seed 002, Eq. 1),
        (..., B, 4, 4)."""
        return posed_global @ invert_rigid(self.rest_global.to(posed_global.dtype))
