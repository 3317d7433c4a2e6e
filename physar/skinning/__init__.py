"""Skeletons, bone transforms in SE(3) and linear blend skinning (seed 002, Eq. 1); a procedural capsule
humanoid, the ``anny`` body model (cached) and SMPL-family npz templates; inside tests for the gating
mask omega (seed 002, Eq. 7)."""

from physar.skinning.body import BodyModel, load_anny, load_smpl_npz, winding_number
from physar.skinning.capsule import CapsuleBody, procedural_humanoid, segment_distance
from physar.skinning.lbs import blend_transforms, lbs, lbs_gaussians, normalize_weights
from physar.skinning.skeleton import (
    Skeleton,
    axis_angle_to_matrix,
    forward_kinematics,
    invert_rigid,
    rigid,
)

__all__ = ["BodyModel", "CapsuleBody", "Skeleton", "axis_angle_to_matrix", "blend_transforms",
           "forward_kinematics", "invert_rigid", "lbs", "lbs_gaussians", "load_anny", "load_smpl_npz",
           "normalize_weights", "procedural_humanoid", "rigid", "segment_distance", "winding_number"]
