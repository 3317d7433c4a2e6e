"""Vision layer (seed 000 §2.1): camera model and calibration, fiducial markers and pose, dot tracking,
back-projection onto the object's plane, and the observation operator C of the assimilation."""
from physar.vision.calibration import (
           CharucoSpec,
           aruco_dictionary,
           calibrate_charuco,
           detect_charuco,
           render_plane,
)
from physar.vision.camera import Camera, Pose
from physar.vision.dots import DotObservation, DotTracker
from physar.vision.markers import MarkerBoard, MarkerTracker, PoseEstimate
from physar.vision.observation import closest_on_triangles, surface_observation_matrix

__all__ = [
           "Camera",
           "CharucoSpec",
           "DotObservation",
           "DotTracker",
           "MarkerBoard",
           "MarkerTracker",
           "Pose",
           "PoseEstimate",
           "aruco_dictionary",
           "calibrate_charuco",
           "closest_on_triangles",
           "detect_charuco",
           "render_plane",
           "surface_observation_matrix",
]
