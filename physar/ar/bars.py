r"""A rigid bar turned by a rotation parameter, measured in each frame (seed 000 §5.3.2, Fig. 17).

The bar pivots about the parameter's rotation axis :math:`a` through its point :math:`p` (from the model's
build configuration); its visible face lies in the plane through :math:`P = p + \mathrm{face}\, a`
perpendicular to :math:`a`. With the pose of the frame, that plane is rectified around :math:`P`
(:math:`\mathrm{right} = a \times \mathrm{zero}`, the direction the bar turns to for a positive angle;
:math:`\mathrm{up} = \mathrm{zero}`, the bar's direction at parameter 0), the bar's colour (bright,
unsaturated) is segmented in an annulus about the pivot, and the angle of the segmented pixels' principal axis
from ``up`` towards ``right`` is the parameter (:func:`physar.vision.markerless.lever_angle`), in the parameter's unit.

A measurement is rejected (NaN) when the segmented area is not that of the bar (0.4 to 1.8 times the expected
area: a wrong pose, or something else of that colour) or the angle lies outside the parameter's range by more
than a tenth of the range.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from physar.vision.camera import Camera, Pose


class BarObserver:
    """Measures one ``[[bar]]`` of a project (see the module doc). ``param``: the model parameter as built
    (name, kind rotation, axis, point, unit, range)."""

    def __init__(self, bar, param: dict, index: int, camera: Camera):
        self.bar, self.index, self.camera = bar, index, camera
        a = np.asarray(param["axis"], float)
        self.axis = a / np.linalg.norm(a)
        z = np.asarray(bar.zero, float)
        self.zero = z / np.linalg.norm(z)
        self.right = np.cross(self.axis, self.zero)
        self.pivot = np.asarray(param["point"], float) + bar.face * self.axis
        self.deg = str(param.get("unit", "deg")).lower().startswith("deg")
        self.lo, self.hi = param["range"]
        r = bar.length
        self.rs = 210.0 / r                                 # rectified px per m: 420 px across the annulus
        self.origin = self.pivot - r * self.right + r * self.zero
        self.size = (int(2 * r * self.rs), int(1.15 * r * self.rs))
        self.pivot_px = np.array([r * self.rs - 0.5, r * self.rs - 0.5])
        self.r0, self.r1 = 0.24 * r, 0.95 * r
        self.expected = (self.r1 - self.r0) * bar.width * self.rs ** 2

    def measure(self, frame: np.ndarray, pose: Pose) -> tuple[float, int]:
        """(angle in the parameter's unit or NaN, segmented pixels)."""
        from physar.vision.markerless import lever_angle, plane_homography

        H = plane_homography(self.camera, pose, self.origin, self.right, -self.zero, self.rs)
        rect = cv2.warpPerspective(frame, H, self.size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        a, n = lever_angle(rect, self.pivot_px, self.r0 * self.rs, self.r1 * self.rs, sat_max=self.bar.saturation_max,
                           val_min=self.bar.value_min, min_pixels=max(8, int(0.1 * self.expected)))
        if not np.isfinite(a):
            return float("nan"), n
        a = math.degrees(a) if self.deg else a
        slack = 0.1 * (self.hi - self.lo)
        if not (0.4 * self.expected <= n <= 1.8 * self.expected) or not (self.lo - slack <= a <= self.hi + slack):
            return float("nan"), n
        return float(a), n


__all__ = ["BarObserver"]
