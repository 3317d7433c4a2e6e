"""Skeletons, bone transforms in SE(3) and linear blend skinning (seed 002, Eq. 1); one body interface
(:class:`Body`) implemented by a procedural capsule humanoid and by mesh bodies (the ``anny`` body model, cached,
and SMPL-family npz templates, :func:`load_body`); inside tests for the gating mask omega (seed 002, Eq. 7)."""

from physar.skinning.base import Body, box_distance, boxes_distance
from physar.skinning.body import (
    SMPL_JOINTS,
    SMPL_PARENTS,
    SMPL_TO_BODY,
    BodyModel,
    anny_body,
    load_anny,
    load_body,
    load_smpl_npz,
    ray_crossings,
    smpl_body,
    surface_distance,
    winding_number,
)
from physar.skinning.capsule import CapsuleBody, procedural_humanoid, segment_distance
from physar.skinning.lbs import blend_transforms, lbs, lbs_gaussians, normalize_weights
from physar.skinning.skeleton import (
    Skeleton,
    axis_angle_to_matrix,
    forward_kinematics,
    invert_rigid,
    rigid,
)

__all__ = ["SMPL_JOINTS", "SMPL_PARENTS", "SMPL_TO_BODY", "Body", "BodyModel", "CapsuleBody", "Skeleton", "anny_body",
           "axis_angle_to_matrix", "blend_transforms", "box_distance", "boxes_distance", "forward_kinematics",
           "invert_rigid", "lbs", "lbs_gaussians", "load_anny", "load_body", "load_smpl_npz", "normalize_weights",
           "procedural_humanoid", "ray_crossings", "rigid", "segment_distance", "smpl_body", "surface_distance",
           "winding_number"]
