r"""A tiny procedural humanoid made of capsules, for fast tests and synthetic scenes (seed 002, §4.1-4.2).

Each bone :math:`k` carries a capsule: the set of points within radius :math:`r_k` (m) of the segment
:math:`[a_k, b_k]` (its rest-pose head and tail). The body volume is the union of the capsules; the inside
test gives the gating mask of seed 002, Eq. 7 (:math:`\omega_i = 0` for particles outside the body). Skinning
weights come from the distances :math:`d_k(x)` to the bone segments:
:math:`W_k(x) = \operatorname{softmax}_k\big(-d_k(x)^2 / (2 \sigma^2)\big)` (so they sum to 1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from physar.errors import PhysarError
from physar.skinning.base import Body, boxes_distance
from physar.skinning.skeleton import Skeleton, rigid

#: bone of :func:`procedural_humanoid` <- SMPL joint whose rotation it takes (its rest pose is SMPL's T-pose)
HUMANOID_SMPL_MAP = {"root": "pelvis", "pelvis": "pelvis", "spine": "spine3", "head": "head",
                     "upperarm.L": "left_shoulder", "forearm.L": "left_elbow",
                     "upperarm.R": "right_shoulder", "forearm.R": "right_elbow",
                     "thigh.L": "left_hip", "shin.L": "left_knee", "thigh.R": "right_hip", "shin.R": "right_knee"}


def segment_distance(points: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Distances (N, B) from points (N, 3) to segments :math:`[a_k, b_k]` ((B, 3) each), m."""
    ab = b - a  # (B, 3)
    ap = points[:, None, :] - a[None]  # (N, B, 3)
    denom = torch.clamp_min((ab * ab).sum(-1), 1e-30)
    s = torch.clamp((ap * ab[None]).sum(-1) / denom, 0.0, 1.0)
    return torch.linalg.vector_norm(ap - s[..., None] * ab[None], dim=-1)


@dataclass
class CapsuleBody(Body):
    """Skeleton + one capsule (head, tail, radius) per bone; radius 0 = bone without volume
    (:class:`physar.skinning.Body`)."""

    skeleton: Skeleton
    heads: torch.Tensor  # (B, 3) m
    tails: torch.Tensor  # (B, 3) m
    radii: torch.Tensor  # (B,) m
    sigma: float = 0.05  # m, width of the skinning-weight falloff
    smpl_map: dict = field(default_factory=dict)  # bone <- SMPL joint (retargeting)
    tpose: dict = field(default_factory=dict)  # bone -> (end bone, T-pose direction): none, the rest is a T

    def __post_init__(self) -> None:
        b = self.skeleton.n_bones
        for name, shape in (("heads", (b, 3)), ("tails", (b, 3)), ("radii", (b,))):
            if tuple(getattr(self, name).shape) != shape:
                raise PhysarError(f"CapsuleBody: {name} must have shape {shape}")
        if torch.any(self.radii < 0):
            raise PhysarError("CapsuleBody: radii must be >= 0")

    def _active(self) -> torch.Tensor:
        return self.radii > 0

    def signed_distance(self, points: torch.Tensor) -> torch.Tensor:
        r""":math:`\min_k (d_k(x) - r_k)` over bones with volume (m): < 0 inside the body; exact outside."""
        act = self._active()
        d = segment_distance(points, self.heads[act].to(points.dtype), self.tails[act].to(points.dtype))
        return (d - self.radii[act].to(points.dtype)).min(-1).values

    def inside(self, points: torch.Tensor) -> torch.Tensor:
        r"""(N,) bool: point strictly inside the union of capsules (rest pose) — the :math:`\omega` gating
        mask."""
        return self.signed_distance(points) < 0

    def skinning_weights(self, points: torch.Tensor) -> torch.Tensor:
        """Dense weights (N, B), rows sum to 1; zero on bones without volume."""
        act = self._active()
        d = segment_distance(points, self.heads.to(points.dtype), self.tails.to(points.dtype))
        logits = -(d * d) / (2 * self.sigma**2)
        logits = torch.where(act[None], logits, torch.full_like(logits, -torch.inf))
        return torch.softmax(logits, dim=-1)

    def owner(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) long: bone of largest weight (the nearest capsule axis among bones with volume)."""
        return self.skinning_weights(points).argmax(-1)

    def volume_bones(self) -> list[str]:
        """Bones with a capsule (radius > 0)."""
        return [b for b, r in zip(self.skeleton.names, self.radii.tolist()) if r > 0]

    def lattice_points(self, bones, h: float, exclude=()) -> np.ndarray:
        """Rest-pose lattice points (spacing h, from the bones' bounding box) inside the capsules of ``bones`` and
        outside those of ``exclude``."""
        idx = [self.skeleton.index(b) for b in bones]
        heads, tails, radii = self.heads[idx].double(), self.tails[idx].double(), self.radii[idx].double()
        lo = torch.minimum(heads, tails).min(0).values - radii.max()
        hi = torch.maximum(heads, tails).max(0).values + radii.max()
        axes = [torch.arange(float(lo[i]) + h / 2, float(hi[i]), h, dtype=torch.float64) for i in range(3)]
        P = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        keep = (segment_distance(P, heads, tails) < radii).any(1)
        if exclude:
            ex = [self.skeleton.index(b) for b in exclude]
            keep &= ~(segment_distance(P, self.heads[ex].double(), self.tails[ex].double())
                      < self.radii[ex].double()).any(1)
        return P[keep].numpy()

    def clearance(self, bone_transforms: torch.Tensor, boxes, samples: int = 17) -> np.ndarray:
        r"""Per bone, :math:`\min_{f, s} d(B_k^f a_k(s), \text{boxes}) - r_k` (m): the capsule posed rigidly by its
        own transform (the LBS of Eq. 1 where :math:`W_k = 1`), its axis :math:`a_k(s)` sampled at ``samples``
        points; inf for bones without volume."""
        B = bone_transforms.detach().double().cpu().numpy()  # (F, K, 4, 4)
        s = np.linspace(0.0, 1.0, samples)[:, None]
        out = np.full(self.skeleton.n_bones, np.inf)
        for k in range(self.skeleton.n_bones):
            r = float(self.radii[k])
            if r <= 0:
                continue
            a, b = self.heads[k].double().numpy(), self.tails[k].double().numpy()
            P = a + s * (b - a)  # (S, 3) rest axis
            Pw = np.einsum("fij,sj->fsi", B[:, k, :3, :3], P) + B[:, k, None, :3, 3]
            out[k] = float(boxes_distance(Pw, boxes).min()) - r
        return out

    def sample_volume(self, n: int, generator: torch.Generator | None = None,
                      dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """``n`` points uniformly distributed inside the body (rejection sampling in the bounding box)."""
        act = self._active()
        r = self.radii[act, None]
        lo = torch.minimum(self.heads[act] - r, self.tails[act] - r).min(0).values.to(dtype)
        hi = torch.maximum(self.heads[act] + r, self.tails[act] + r).max(0).values.to(dtype)
        out, have = [], 0
        while have < n:
            p = lo + (hi - lo) * torch.rand(4 * n, 3, generator=generator, dtype=dtype)
            p = p[self.inside(p)]
            out.append(p)
            have += p.shape[0]
        return torch.cat(out)[:n]


def procedural_humanoid(height: float = 1.7, dtype: torch.dtype = torch.float32) -> CapsuleBody:
    """A 12-bone capsule humanoid standing on :math:`z = 0`, facing :math:`-y`, height ``height`` (m).

    Bones: root (no volume), pelvis, spine, head, upper/lower arms and legs (left and right). Bone
    frames have identity rotation at the rest pose and sit at the bone heads (the joints).
    """
    if isinstance(height, bool) or not isinstance(height, (int, float, np.number)) or not np.isfinite(height) \
            or not 0.3 <= height <= 3.0:
        raise PhysarError(f"procedural_humanoid: height = {height!r} must be a person's height in metres, "
                          "0.3 to 3.0")
    h = float(height) / 1.7
    P = lambda *v: [h * c for c in v]
    bones = [  # name, parent, head, tail, radius
        ("root", -1, P(0, 0, 0.95), P(0, 0, 0.95), 0.0),
        ("pelvis", 0, P(0, 0, 0.95), P(0, 0, 1.05), 0.13),
        ("spine", 1, P(0, 0, 1.05), P(0, 0, 1.40), 0.14),
        ("head", 2, P(0, 0, 1.50), P(0, 0, 1.60), 0.10),
        ("upperarm.L", 2, P(0.20, 0, 1.42), P(0.48, 0, 1.42), 0.05),
        ("forearm.L", 4, P(0.48, 0, 1.42), P(0.74, 0, 1.42), 0.04),
        ("upperarm.R", 2, P(-0.20, 0, 1.42), P(-0.48, 0, 1.42), 0.05),
        ("forearm.R", 6, P(-0.48, 0, 1.42), P(-0.74, 0, 1.42), 0.04),
        ("thigh.L", 1, P(0.10, 0, 0.90), P(0.10, 0, 0.50), 0.07),
        ("shin.L", 8, P(0.10, 0, 0.50), P(0.10, 0, 0.08), 0.05),
        ("thigh.R", 1, P(-0.10, 0, 0.90), P(-0.10, 0, 0.50), 0.07),
        ("shin.R", 10, P(-0.10, 0, 0.50), P(-0.10, 0, 0.08), 0.05),
    ]
    heads = torch.tensor([b[2] for b in bones], dtype=dtype)
    tails = torch.tensor([b[3] for b in bones], dtype=dtype)
    rest = rigid(torch.eye(3, dtype=dtype).expand(len(bones), 3, 3), heads)
    sk = Skeleton(torch.tensor([b[1] for b in bones]), rest, [b[0] for b in bones])
    return CapsuleBody(sk, heads, tails, torch.tensor([b[4] * h for b in bones], dtype=dtype), sigma=0.05 * h,
                       smpl_map=dict(HUMANOID_SMPL_MAP))
