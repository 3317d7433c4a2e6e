"""Fiducial markers and camera pose (seed 000 §2.1, §5.1: fiducial markers locate the camera).

ArUco markers are found with ``cv2.aruco.ArucoDetector`` inside regions of interest predicted from the
previous pose (a full-frame search only when the pose is unknown), their corners are refined to sub-pixel
accuracy, and the pose minimises the reprojection error Σ_k ||p_k - Π(R, t; X_k)||² (IPPE for the planar
board, then Levenberg-Marquardt). A constant-velocity filter on (log R, t) predicts the next pose, smooths
measurements within their noise, gates outliers and holds the pose while the markers are occluded.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from physar.errors import ConfigError
from physar.vision.calibration import aruco_dictionary
from physar.vision.camera import Camera, Pose


@dataclass(frozen=True)
class MarkerBoard:
    """Markers fixed to the world: ids (m,) and corners (m, 4, 3) [m] in ArUco order (TL, TR, BR, BL)."""

    ids: np.ndarray
    corners: np.ndarray
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self):
        ids = np.asarray(self.ids, int).ravel()
        c = np.asarray(self.corners, float)
        if c.shape != (ids.size, 4, 3):
            raise ConfigError(f"marker corners must have shape ({ids.size}, 4, 3), got {c.shape}")
        if len(set(ids.tolist())) != ids.size:
            raise ConfigError(f"marker ids must be distinct, got {ids.tolist()}")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "corners", c)

    @classmethod
    def on_plane(cls, ids, centres_uv, size, origin, axis_u, axis_v, dictionary="DICT_4X4_50"):
        """Square markers of side `size` [m] centred at plane coordinates `centres_uv` (m, 2).

        The plane is origin + a axis_u + b axis_v; axis_u points right and axis_v down in the marker image.
        """
        o, eu, ev = (np.asarray(v, float) for v in (origin, axis_u, axis_v))
        h = size / 2
        offs = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
        uv = np.asarray(centres_uv, float)[:, None, :] + offs[None]
        return cls(ids, o + uv[..., :1] * eu + uv[..., 1:] * ev, dictionary)

    @property
    def planar(self) -> bool:
        X = self.corners.reshape(-1, 3)
        s = np.linalg.svd(X - X.mean(0), compute_uv=False)
        return s[-1] < 1e-9 * max(s[0], 1e-300)

    def index(self, marker_id: int) -> int | None:
        k = np.flatnonzero(self.ids == marker_id)
        return int(k[0]) if k.size else None


@dataclass
class PoseEstimate:
    pose: Pose | None
    status: str  # "measured", "predicted" (held under occlusion) or "lost"
    n_markers: int = 0
    reprojection_px: float = float("nan")
    ids: list = field(default_factory=list)
    image_corners: np.ndarray | None = None
    full_search: bool = False
    rotation_std: np.ndarray | None = None  # (3,) std of the pose's rotation about the world axes [rad]


def rotation_std(camera: Camera, pose: Pose, points, sigma_px: float, centre=None) -> np.ndarray:
    """Standard deviations [rad] of the camera pose's rotation about the world axes through ``centre`` that
    PnP on ``points`` (m, 3) with pixel noise ``sigma_px`` leaves: Gauss-Newton covariance
    sigma² (J^T J)^-1 of the 6 pose parameters (3 small world rotations δθ, 3 translations δt),
    X -> c + exp(δθ)(X - c) + δt, J by central differences of the projection."""
    X = np.asarray(points, float).reshape(-1, 3)
    c = X.mean(0) if centre is None else np.asarray(centre, float)
    h = 1e-6
    Xs = []
    for j in range(6):
        for sgn in (1.0, -1.0):
            d = np.zeros(6)
            d[j] = sgn * h
            Xs.append(c + (X - c) @ _exp_rot(d[:3]).T + d[3:])
    p = camera.project(np.concatenate(Xs), pose).reshape(6, 2, -1)
    J = ((p[:, 0] - p[:, 1]) / (2 * h)).T  # (2m, 6)
    try:
        cov = np.linalg.inv(J.T @ J) * sigma_px ** 2
    except np.linalg.LinAlgError:
        return np.full(3, np.inf)
    return np.sqrt(np.abs(np.diag(cov)[:3]))


def _log_rot(R):
    return cv2.Rodrigues(R)[0].ravel()


def _exp_rot(w):
    return cv2.Rodrigues(np.asarray(w, float).reshape(3, 1))[0]


class MarkerTracker:
    """Per-frame marker detection (ROI-predicted) and filtered camera pose.

    ``alpha`` (0..1]: weight of a measurement whose change from the prediction is within the noise
    (``noise_px`` of reprojection); larger changes pass through (alpha -> 1), so camera motion does not lag.
    ``hold_frames``: how long the pose is predicted (velocity decaying) when no marker is visible.
    """

    def __init__(self, camera: Camera, board: MarkerBoard, roi_margin: float = 0.3, min_markers: int = 1,
                 alpha: float = 0.6, noise_px: float = 0.15, hold_frames: int = 150, max_reproj_px: float = 3.0,
                 gate_px: float = 40.0):
        self.camera, self.board = camera, board
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        params.cornerRefinementWinSize = 4
        params.cornerRefinementMaxIterations = 50
        params.cornerRefinementMinAccuracy = 0.005
        self._params = params
        self.detector = cv2.aruco.ArucoDetector(aruco_dictionary(board.dictionary), params)
        self._roi_detectors = {}
        self.roi_margin, self.min_markers, self.alpha, self.noise_px = roi_margin, min_markers, alpha, noise_px
        self.hold_frames, self.max_reproj_px, self.gate_px = hold_frames, max_reproj_px, gate_px
        self.K, self.dist = camera.to_opencv()
        self.reset()

    def reset(self):
        self._w = None  # log rotation
        self._t = None
        self._vw = np.zeros(3)
        self._vt = np.zeros(3)
        self._missed = 0

    # --- prediction --------------------------------------------------------------------------------
    def predicted(self) -> Pose | None:
        if self._w is None:
            return None
        return Pose(_exp_rot(self._w + self._vw), self._t + self._vt)

    # --- detection ---------------------------------------------------------------------------------
    def _roi_detector(self, size_px: float):
        """Detector for a region of interest around a marker of predicted side ``size_px``: one adaptive
        threshold window of about a seventh of the marker (a module and a half), instead of the three-window
        sweep of the full-frame search (half the time, same corners)."""
        win = max(3, int(size_px / 7) | 1)
        det = self._roi_detectors.get(win)
        if det is None:
            p = cv2.aruco.DetectorParameters()
            for name in ("cornerRefinementMethod", "cornerRefinementWinSize", "cornerRefinementMaxIterations",
                         "cornerRefinementMinAccuracy"):
                setattr(p, name, getattr(self._params, name))
            p.adaptiveThreshWinSizeMin = p.adaptiveThreshWinSizeMax = win
            det = self._roi_detectors[win] = cv2.aruco.ArucoDetector(aruco_dictionary(self.board.dictionary), p)
        return det

    def _detect(self, gray, x0=0, y0=0, detector=None):
        corners, ids, _ = (detector or self.detector).detectMarkers(gray)
        out = {}
        if ids is None:
            return out
        for c, i in zip(corners, ids.ravel()):
            k = self.board.index(int(i))
            if k is not None:
                out[k] = c.reshape(4, 2) + (x0, y0)
        return out

    def detect(self, gray, prediction: Pose | None):
        """{board index: (4, 2) corners}; ROI search around the predicted markers, else the full frame."""
        h, w = gray.shape[:2]
        found = {}
        if prediction is not None:
            proj = self.camera.project(self.board.corners.reshape(-1, 3), prediction).reshape(-1, 4, 2)
            for k, p in enumerate(proj):
                if not np.all(np.isfinite(p)):
                    continue
                lo, hi = p.min(0), p.max(0)
                m = self.roi_margin * (hi - lo).max() + 8
                x0, y0 = int(max(lo[0] - m, 0)), int(max(lo[1] - m, 0))
                x1, y1 = int(min(hi[0] + m, w)), int(min(hi[1] + m, h))
                if x1 - x0 < 16 or y1 - y0 < 16:
                    continue
                det = self._detect(gray[y0:y1, x0:x1], x0, y0, self._roi_detector((hi - lo).max()))
                if k in det:
                    found[k] = det[k]
            if len(found) >= self.min_markers:
                return found, False
        return self._detect(gray), True

    # --- pose ----------------------------------------------------------------------------------------
    def _solve(self, found, prediction):
        ks = sorted(found)
        obj = self.board.corners[ks].reshape(-1, 3)
        img = np.concatenate([found[k] for k in ks]).reshape(-1, 2)
        cands = []
        if prediction is not None:
            cands.append((prediction.rvec, prediction.t))
        if self.board.planar:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, self.K, self.dist, flags=cv2.SOLVEPNP_IPPE)
            cands += [(r.ravel(), t.ravel()) for r, t in zip(rvecs[:n], tvecs[:n])]
        else:
            ok, r, t = cv2.solvePnP(obj, img, self.K, self.dist, flags=cv2.SOLVEPNP_SQPNP)
            if ok:
                cands.append((r.ravel(), t.ravel()))
        best = None
        for r, t in cands:
            r, t = cv2.solvePnPRefineLM(obj, img, self.K, self.dist, r.reshape(3, 1).copy(), t.reshape(3, 1).copy(),
                                        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-12))
            pose = Pose.from_rvec(r, t)
            if np.any(pose.apply(obj)[:, 2] <= 0):
                continue
            err = float(np.sqrt(np.mean(np.sum((self.camera.project(obj, pose) - img) ** 2, 1))))
            if best is None or err < best[1] - 1e-6:
                best = (pose, err)
        return best, img

    def update(self, gray) -> PoseEstimate:
        """Process one grey frame (uint8 (h, w)); returns the filtered pose and its status."""
        pred = self.predicted()
        found, full = self.detect(gray, pred)
        best = None
        if len(found) >= self.min_markers:
            best, img = self._solve(found, pred)
        if best is not None and best[1] <= self.max_reproj_px:
            pose, err = best
            if pred is not None and self._missed == 0:
                # gate: a jump larger than gate_px at the markers is an outlier unless the full search agrees
                d = np.abs(self.camera.project(self.board.corners.reshape(-1, 3), pose)
                           - self.camera.project(self.board.corners.reshape(-1, 3), pred)).max()
                a = float(np.clip(d / (3 * self.noise_px), self.alpha, 1.0))
            else:
                a = 1.0
            w_meas, t_meas = _log_rot(pose.R), pose.t
            if self._w is None or self._missed > 0 and a == 1.0:
                w_new, t_new = w_meas, t_meas
                vw, vt = (np.zeros(3), np.zeros(3)) if self._w is None else (self._vw * 0, self._vt * 0)
            else:
                wp, tp = self._w + self._vw, self._t + self._vt
                dw = _log_rot(_exp_rot(w_meas) @ _exp_rot(wp).T)
                w_new = _log_rot(_exp_rot(a * dw) @ _exp_rot(wp))
                t_new = tp + a * (t_meas - tp)
                vw = 0.7 * self._vw + 0.3 * (w_new - self._w)
                vt = 0.7 * self._vt + 0.3 * (t_new - self._t)
            self._w, self._t, self._vw, self._vt = w_new, t_new, vw, vt
            self._missed = 0
            ks = sorted(found)
            rstd = rotation_std(self.camera, pose, self.board.corners[ks].reshape(-1, 3),
                                max(err, self.noise_px), self.board.corners.reshape(-1, 3).mean(0))
            return PoseEstimate(Pose(_exp_rot(w_new), t_new), "measured", len(found), err,
                                [int(self.board.ids[k]) for k in ks], img, full, rstd)
        # no usable measurement: hold (decaying velocity)
        if self._w is None:
            return PoseEstimate(None, "lost", len(found), full_search=full)
        self._missed += 1
        self._w, self._t = self._w + self._vw, self._t + self._vt
        self._vw *= 0.5
        self._vt *= 0.5
        status = "predicted" if self._missed <= self.hold_frames else "lost"
        return PoseEstimate(Pose(_exp_rot(self._w), self._t), status, len(found), full_search=full)
