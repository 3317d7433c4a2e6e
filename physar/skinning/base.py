r"""The one body interface of seed 002 (§4.1-4.2) that the reconstruction uses, implemented by the capsule figure
(:class:`physar.skinning.CapsuleBody`, unit tests and the synthetic scenes) and by mesh bodies
(:class:`physar.skinning.BodyModel`: anny, SMPL from a user's model file).

A body is a skeleton (bone frames :math:`G_k^\text{rest}`, Eq. 1) with a volume and a rig:

* ``inside(x)`` and ``signed_distance(x)`` (m, < 0 inside): the body volume, whose interior receives the gated
  PD force (:math:`\omega_i = 0` outside, Eq. 7);
* ``skinning_weights(x)``: :math:`W_k(x)` of Eq. 1 (dense (N, B) or sparse (indices, values)), rows summing to 1;
* ``owner(x)``: the bone :math:`\arg\max_k W_k(x)` a point belongs to (the particles of a bone are the lattice
  points inside the body that it owns);
* ``lattice_points(bones, h)``: rest-pose particles of ``bones`` on a cell-centred lattice of spacing ``h``;
* ``clearance(B, boxes)``: per bone, the smallest distance (m) between the bone's skinned surface and a union of
  axis-aligned boxes over a sequence of skinning transforms :math:`B_k` (F, B, 4, 4): the LBS-impact reach of
  seed §4.2;
* ``smpl_map`` (bone :math:`\leftarrow` SMPL joint whose rotation it takes) and ``tpose`` (bone :math:`\to`
  (end bone, direction in T-pose)) for retargeting SMPL poses (:func:`physar.recon.importer.retarget`).

Shared here: the skinning transforms :math:`B_k(\theta) = G_k(\theta) (G_k^\text{rest})^{-1}` of a pose and
LBS of points (Eq. 1).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import torch

from physar.skinning.lbs import Weights, lbs
from physar.skinning.skeleton import Skeleton


def box_distance(points: np.ndarray, lo, hi) -> np.ndarray:
    r"""Euclidean distance (m) from points (..., 3) to the axis-aligned box [lo, hi] (0 inside):
    :math:`|\max(\text{lo} - p, 0, p - \text{hi})|`."""
    d = np.maximum(np.maximum(np.asarray(lo) - points, 0.0), points - np.asarray(hi))
    return np.linalg.norm(d, axis=-1)


def boxes_distance(points: np.ndarray, boxes) -> np.ndarray:
    """Distance (m) from points (..., 3) to the union of boxes [(min, max), ...] (0 inside one)."""
    return np.min([box_distance(points, lo, hi) for lo, hi in boxes], axis=0)


class Body(ABC):
    """A skinned body (module docstring). Subclasses are dataclasses holding at least ``skeleton``."""

    skeleton: Skeleton
    smpl_map: dict
    tpose: dict

    @abstractmethod
    def inside(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) bool: the point lies strictly inside the body at rest."""

    @abstractmethod
    def signed_distance(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) m: distance to the body's rest surface, negative inside."""

    @abstractmethod
    def skinning_weights(self, points: torch.Tensor) -> Weights:
        """Skinning weights of Eq. 1 for rest points (N, 3): dense (N, B) or sparse ((N, m) indices, values)."""

    @abstractmethod
    def owner(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) long: the bone of largest skinning weight at each point."""

    @abstractmethod
    def volume_bones(self) -> list[str]:
        """Names of the bones that own part of the body's volume, skeleton order."""

    @abstractmethod
    def lattice_points(self, bones, h: float, exclude=()) -> np.ndarray:
        """Rest points (N, 3) m on a cell-centred lattice of spacing ``h`` inside the body and owned by ``bones``
        (and outside the parts of ``exclude``)."""

    @abstractmethod
    def clearance(self, bone_transforms: torch.Tensor, boxes) -> np.ndarray:
        """(B,) m: per bone, the smallest distance over the frames between its skinned surface (skinning
        transforms (F, B, 4, 4), Eq. 1) and the union of boxes [(min, max), ...]; inf for bones without volume."""

    def bone_transforms(self, rotations: torch.Tensor, root_translation: torch.Tensor | None = None) -> torch.Tensor:
        r"""Skinning transforms :math:`B_k = G_k(\theta) (G_k^\text{rest})^{-1}` (..., B, 4, 4) for local joint
        rotations (..., B, 3, 3) and root translations (..., 3) m (Eq. 1)."""
        sk = self.skeleton
        return sk.bone_transforms(sk.pose(rotations, root_translation))

    def pose_points(self, points: torch.Tensor, rotations: torch.Tensor,
                    root_translation: torch.Tensor | None = None) -> torch.Tensor:
        """Rest points (N, 3) skinned to the pose (local joint rotations (B, 3, 3)) by Eq. 1."""
        B = self.bone_transforms(rotations.to(points.dtype),
                                 None if root_translation is None else root_translation.to(points.dtype))
        return lbs(points, self.skinning_weights(points), B.to(points.dtype))[0]
