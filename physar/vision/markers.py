r"""Fiducial markers and camera pose (seed 000 §2.1, §5.1: fiducial markers locate the camera).

ArUco markers are found with ``cv2.aruco.ArucoDetector`` inside regions of interest predicted from the
previous pose (a full-frame search only when the pose is unknown), their corners are refined to sub-pixel
accuracy, and the pose minimises the reprojection error :math:`\sum_k \|p_k - \Pi(R, t; X_k)\|^2` (IPPE for
the planar board, then Levenberg-Marquardt). A constant-velocity filter on :math:`(\log R, t)` predicts the next
pose, smooths measurements within their noise, gates outliers and holds the pose while the markers are occluded.

A marker whose corners disagree with the pose the other markers give (a ``[[marker]]`` table with a wrong
centre, normal, up, size or id) is left out of the pose (:meth:`MarkerTracker._consistent`): the markers are
dropped one at a time, each time the one whose removal lets the rest agree best, until the rest agree within
``max_reproj_px``. A marker found disagreeing with at least two others in ``confirm`` frames (and in more frames
than it agreed) is left out for good, with one warning line saying what disagrees.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np

from physar.errors import ConfigError, PhysarWarning
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
        r"""Square markers of side `size` [m] centred at plane coordinates `centres_uv` (m, 2).

        The plane is :math:`\mathtt{origin} + a\, \mathtt{axis\_u} + b\, \mathtt{axis\_v}`; axis_u points
        right and axis_v down in the marker image.
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


@dataclass(repr=False)
class PoseEstimate:
    """The camera pose of one frame (:meth:`MarkerTracker.update`).

    Attributes:
        pose: the filtered camera pose (world -> camera), or None while no pose is known.
        status: "measured", "predicted" (held by the constant-velocity filter under occlusion) or "lost".
        n_markers: markers found in the frame.
        reprojection_px: RMS reprojection error of the measured pose, px (nan unless measured).
        ids: ids of the markers the pose was measured from.
        image_corners: (4k, 2) refined image corners of those markers, four per marker in ``ids``' order,
            px; None unless measured.
        full_search: whether the whole frame was searched (no predicted pose).
        rotation_std: (3,) standard deviation of the pose's rotation about the world axes, rad.
    """

    pose: Pose | None
    status: str  # "measured", "predicted" (held under occlusion) or "lost"
    n_markers: int = 0
    reprojection_px: float = float("nan")
    ids: list = field(default_factory=list)
    image_corners: np.ndarray | None = None
    full_search: bool = False
    rotation_std: np.ndarray | None = None  # (3,) std of the pose's rotation about the world axes [rad]

    def __repr__(self) -> str:
        """One line: status, marker count (and the first 4 ids), RMS reprojection error [px], the largest
        rotation std [deg], ``full search`` when set, and the pose (:class:`Pose`'s one line); no arrays."""
        ids = [int(i) for i in self.ids]
        text = f"PoseEstimate({self.status}, {self.n_markers} marker{'' if self.n_markers == 1 else 's'}"
        if ids:
            text += f" (ids {', '.join(map(str, ids[:4]))}{', ...' if len(ids) > 4 else ''})"
        if np.isfinite(self.reprojection_px):
            text += f", rms {self.reprojection_px:.3g} px"
        rot = np.ravel(self.rotation_std) if self.rotation_std is not None else np.zeros(0)
        if np.isfinite(rot).any():
            text += f", rotation std {np.degrees(np.max(rot[np.isfinite(rot)])):.2g} deg"
        if self.full_search:
            text += ", full search"
        return text + f", {'no pose' if self.pose is None else repr(self.pose)})"


def rotation_std(camera: Camera, pose: Pose, points, sigma_px: float, centre=None) -> np.ndarray:
    r"""Standard deviations [rad] of the camera pose's rotation about the world axes through ``centre`` that
    PnP on ``points`` (m, 3) with pixel noise ``sigma_px`` leaves: Gauss-Newton covariance
    :math:`\sigma^2 (J^\top J)^{-1}` (:math:`\sigma` = ``sigma_px``) of the 6 pose parameters (3 small world
    rotations :math:`\delta\theta`, 3 translations :math:`\delta t`),
    :math:`X \mapsto c + \exp(\delta\theta)(X - c) + \delta t` (:math:`c` = ``centre``), :math:`J` by central
    differences of the projection."""
    X = np.asarray(points, float).reshape(-1, 3)
    c = X.mean(0) if centre is None else np.asarray(centre, float)
    h = 1e-6
    D = X - c
    zero = np.zeros(len(X))
    # directions of the 6 parameters: δθ_j e_j x (X - c) (exp(δθ) = I + [δθ]x + O(h²), the O(h²) term is even
    # in h and cancels in the central difference) and δt_j e_j
    dirs = np.stack([np.stack(v, 1) for v in ((zero, -D[:, 2], D[:, 1]), (D[:, 2], zero, -D[:, 0]),
                                              (-D[:, 1], D[:, 0], zero))] + [np.tile(np.eye(3)[j], (len(X), 1))
                                                                            for j in range(3)])
    Xs = X[None, None] + h * np.array([1.0, -1.0])[None, :, None, None] * dirs[:, None]  # (6, 2, m, 3)
    p = camera.project(Xs.reshape(-1, 3), pose).reshape(6, 2, -1)
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


EDGE_MIN_FRACTION = 0.6
"""Fraction of an edge's profiles that must show one clean step for :func:`refine_corners_by_edges` to fit it."""

EDGE_MAX_RMS_PX = 0.35
"""Largest RMS distance [px] of an edge's step points from their fitted line (else the marker keeps its corners)."""


def refine_corners_by_edges(gray, corners: np.ndarray, cells: int, K=None, dist=None) -> np.ndarray:
    r"""Marker corners (m, 4, 2) re-measured as the intersections of their four edges' lines.

    ``cv2.cornerSubPix`` (the ArUco detector's refinement) solves :math:`\sum_q (\nabla I_q^\top (p - q))^2 = 0`
    over a window around the corner; at the outer corner of a marker's black border the blurred (rounded) corner
    pulls it inside the marker, by 0.1-0.25 px on a rendered 960 x 540 clip (the markers then look smaller and the
    pose is biased). Here each edge between two corners is sampled by profiles across it, from 15 % to 85 % of
    its length (away from the rounded corners), over :math:`\pm h`, :math:`h = \min(4, 0.35\,c)` px
    (:math:`c` the border cell's width across that edge, the mean length of the two edges beside it over
    ``cells``, the cells per side including the border, so the profile stays in the black border and the white
    margin, also on the short edges of a foreshortened marker). The step of each profile is where it crosses
    :math:`(I_{in} + I_{out}) / 2` (the means of its two ends), linearly interpolated; a profile with no single
    crossing or a contrast under 20 grey levels is skipped. A line is fitted to each edge's step points (total
    least squares after undistorting them with ``K``, ``dist`` when given: the edges are straight only without
    lens distortion), adjacent lines are intersected, and the intersections distorted back.

    A marker keeps its given corners when an edge has too few clean steps (:data:`EDGE_MIN_FRACTION`: occluded,
    no white margin), its steps scatter from their line (:data:`EDGE_MAX_RMS_PX`), or a corner would move more
    than max(1 px, c / 4). ``gray``: uint8 (h, w); ``corners`` in ArUco order (TL, TR, BR, BL)."""
    c = np.asarray(corners, float).reshape(-1, 4, 2)
    out = c.copy()
    if len(c) == 0:
        return out
    g = np.asarray(gray, np.float32)
    a, b = c, np.roll(c, -1, axis=1)                                     # (m, 4, 2) edge k: corner k -> k + 1
    length = np.linalg.norm(b - a, axis=2)                               # (m, 4)
    cell = length.mean(1) / cells                                        # (m,)
    # the border cell across edge k is as wide as the two edges beside it / cells (foreshortened views: the
    # mean cell would reach into the data bits across the short edges)
    across = (np.roll(length, 1, axis=1) + np.roll(length, -1, axis=1)) / (2 * cells)   # (m, 4)
    half = np.clip(0.35 * across, 1.0, 4.0)
    n_s = int(np.clip(length.mean() / 2, 8, 32))
    s = np.linspace(0.15, 0.85, n_s)
    o = np.linspace(-1.0, 1.0, 17)                                       # offsets / half
    d = (b - a) / np.maximum(length, 1e-9)[..., None]
    nrm = np.stack([-d[..., 1], d[..., 0]], -1)
    P = a[:, :, None] + s[None, None, :, None] * (b - a)[:, :, None]    # (m, 4, n_s, 2)
    off = o[None, None, None, :] * half[:, :, None, None]                # (m, 4, 1, 17)
    S = P[..., None, :] + off[..., None] * nrm[:, :, None, None, :]      # (m, 4, n_s, 17, 2)
    v = cv2.remap(g, S[..., 0].reshape(-1, 17).astype(np.float32), S[..., 1].reshape(-1, 17).astype(np.float32),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan).reshape(S.shape[:-1])
    lo, hi = v[..., :2].mean(-1), v[..., -2:].mean(-1)
    mid = (lo + hi) / 2
    cross = np.diff(v > mid[..., None], axis=-1)                         # (m, 4, n_s, 16)
    one = (cross.sum(-1) == 1) & (np.abs(hi - lo) >= 20) & np.all(np.isfinite(v), -1)
    j = np.argmax(cross, -1)
    v0 = np.take_along_axis(v, j[..., None], -1)[..., 0]
    v1 = np.take_along_axis(v, j[..., None] + 1, -1)[..., 0]
    f = np.where(v1 != v0, (mid - v0) / np.where(v1 != v0, v1 - v0, 1.0), 0.5)
    t = (o[j] + f * (o[1] - o[0])) * half[:, :, None]                    # step offset along the normal [px]
    Q = P + t[..., None] * nrm[:, :, None, :]                            # (m, 4, n_s, 2) step points
    undistort = K is not None and dist is not None and np.any(np.asarray(dist) != 0)
    if undistort:
        K = np.asarray(K, float)
        dist = np.asarray(dist, float)
        Q = cv2.undistortPoints(Q.reshape(-1, 1, 2), K, dist, P=K).reshape(Q.shape)
    for m in range(len(c)):
        if not (np.all(one[m].mean(-1) >= EDGE_MIN_FRACTION) and np.all(one[m].sum(-1) >= 5)):
            continue
        lines, ok = [], True
        for k in range(4):
            q = Q[m, k][one[m, k]]
            mean = q.mean(0)
            _, sv, vt = np.linalg.svd(q - mean, full_matrices=False)
            if sv[-1] / np.sqrt(len(q)) > EDGE_MAX_RMS_PX:
                ok = False
                break
            lines.append((mean, vt[0]))
        if not ok:
            continue
        new = np.empty((4, 2))
        for k in range(4):                    # corner k: the lines of edge k - 1 (into it) and edge k (out of it)
            (m1, d1), (m2, d2) = lines[k - 1], lines[k]
            A = np.column_stack([d1, -d2])
            if abs(np.linalg.det(A)) < 1e-6:
                ok = False
                break
            u = np.linalg.solve(A, m2 - m1)
            new[k] = m1 + u[0] * d1
        if not ok:
            continue
        if undistort:
            x = cv2.undistortPoints(new.reshape(-1, 1, 2), K, None).reshape(-1, 2)   # ideal normalised coordinates
            new = cv2.projectPoints(np.column_stack([x, np.ones(4)]), np.zeros(3), np.zeros(3), K,
                                    dist)[0].reshape(-1, 2)
        if np.all(np.isfinite(new)) and np.linalg.norm(new - c[m], axis=1).max() <= max(1.0, cell[m] / 4):
            out[m] = new
    return out


class MarkerTracker:
    r"""Per-frame marker detection (ROI-predicted) and filtered camera pose.

    ``alpha`` (0..1]: weight of a measurement whose change from the prediction is within the noise
    (``noise_px`` of reprojection); larger changes pass through (:math:`\alpha \to 1`), so camera motion does
    not lag. ``hold_frames``: how long the pose is predicted (velocity decaying) when no marker is visible;
    while it is held the predicted regions are searched in every frame, the full frame every
    ``full_search_every``.

    ``track``: follow the markers between detections instead of detecting them in every frame: the corners
    predicted by the pose filter are refined by ``cv2.cornerSubPix`` (the same refinement, window and stopping
    rule the detector applies to its corners, so the same corners to ~0.002 px on scene (a)), and a marker is
    accepted only if every corner moved less than ``track_px`` from its prediction and the marker's
    :math:`(n+2)^2` cells sampled through the homography of the refined corners reproduce its dictionary bits
    (every white cell brighter than every black cell, see :meth:`_verify`). A marker that fails (occluded, the
    prediction off after a hold) falls back to ArUco detection in its region of interest, and every
    ``redetect_every`` frames (0: never) all markers are detected again.

    Markers that disagree with the others are left out of the pose (see the module doc and
    :meth:`_consistent`); ``rejected`` maps the board index of each marker left out for good (after
    ``confirm`` frames) to the reason, also given once as a :class:`physar.errors.PhysarWarning` starting with
    ``source`` (the project file).
    """

    def __init__(self, camera: Camera, board: MarkerBoard, roi_margin: float = 0.3, min_markers: int = 1,
                 alpha: float = 0.6, noise_px: float = 0.15, hold_frames: int = 150, max_reproj_px: float = 3.0,
                 gate_px: float = 40.0, track: bool = True, track_px: float = 2.5, redetect_every: int = 30,
                 full_search_every: int = 4, confirm: int = 3, source: str | None = None, edges: bool = True):
        self.camera, self.board = camera, board
        self.confirm, self.source = max(1, int(confirm)), source
        self.edges = edges
        self.rejected: dict[int, str] = {}              # board index -> why it is left out of the pose
        self._agreed = np.zeros(len(board.ids), int)   # frames each marker agreed with at least one other
        self._disagreed = np.zeros(len(board.ids), int)  # frames it disagreed with at least two others
        self._searched = np.zeros(len(board.ids), int)   # whole-frame searches for it while it was suspect
        self.n_left_out = 0                             # markers left out of a frame's pose (statistics)
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
        self.track, self.track_px, self.redetect_every = track, track_px, redetect_every
        self.full_search_every = max(1, int(full_search_every))
        self._subpix = ((params.cornerRefinementWinSize,) * 2,
                        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, params.cornerRefinementMaxIterations,
                         params.cornerRefinementMinAccuracy))
        dic = aruco_dictionary(board.dictionary)
        n = dic.markerSize + 2  # bits and a one-cell black border
        self._n_cells = n
        self._bits = np.array([cv2.aruco.generateImageMarker(dic, int(i), n) > 127 for i in board.ids])  # (m, n, n)
        g = (np.arange(3) + 1) / 4  # 3x3 samples inside each cell, away from the cell edges
        cy, cx, sy, sx = np.meshgrid(np.arange(n), np.arange(n), g, g, indexing="ij")
        self._cells = np.stack([(cx + sx) / n, (cy + sy) / n], -1).reshape(-1, 2)  # unit-square coordinates
        self.n_tracked = self.n_detected = 0  # markers found by tracking / by detection (statistics)
        self.reset()

    def reset(self):
        self._w = None  # log rotation
        self._t = None
        self._vw = np.zeros(3)
        self._vt = np.zeros(3)
        self._missed = 0
        self._frame = 0

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

    def _verify(self, gray, corners: dict) -> dict:
        """The markers of ``corners`` {k: (4, 2)} whose image shows their dictionary bits: the :math:`(n+2)^2`
        cells (:math:`n^2` bits and the black border) are sampled (3x3 bilinear samples per cell) through the homography
        that maps the unit square to the corners (TL, TR, BR, BL), and every cell that is white in the
        marker must be brighter than every black cell, by at least a quarter of the white-black mean
        difference and 10 grey levels."""
        ks = list(corners)
        if not ks:
            return {}
        sq = np.float32([[0, 0], [1, 0], [1, 1], [0, 1]])
        pts = [cv2.perspectiveTransform(self._cells[None].astype(np.float32),
                                        cv2.getPerspectiveTransform(sq, corners[k].astype(np.float32)))[0] for k in ks]
        pts = np.stack(pts)  # (len(ks), cells * 9, 2)
        v = cv2.remap(gray, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR).astype(np.float32)
        n = self._bits.shape[1]
        cell = v.reshape(len(ks), n * n, 9).mean(-1)
        out = {}
        for j, k in enumerate(ks):
            white = self._bits[k].ravel()
            if white.all() or not white.any():
                continue
            lo, hi = cell[j][~white], cell[j][white]
            gap = hi.min() - lo.max()
            if gap > max(10.0, 0.25 * (hi.mean() - lo.mean())):
                out[k] = corners[k]
        return out

    def _track(self, gray, proj) -> dict:
        """{board index: (4, 2) corners} of the markers followed from their predicted corners ``proj``
        (m, 4, 2): sub-pixel refinement, motion gate ``track_px`` and bit check (:meth:`_verify`)."""
        h, w = gray.shape[:2]
        win = self._subpix[0][0] + 2
        ok = np.all(np.isfinite(proj), (1, 2))
        ok &= np.all((proj[..., 0] > win) & (proj[..., 0] < w - 1 - win) & (proj[..., 1] > win)
                     & (proj[..., 1] < h - 1 - win), 1)
        ok &= np.linalg.norm(proj[:, 0] - proj[:, 2], axis=1) > 24  # too small to refine and verify
        ks = np.flatnonzero(ok)
        if ks.size == 0:
            return {}
        p0 = proj[ks].reshape(-1, 1, 2).astype(np.float32)
        p1 = cv2.cornerSubPix(gray, p0.copy(), self._subpix[0], (-1, -1), self._subpix[1]).reshape(-1, 4, 2)
        moved = np.abs(p1 - p0.reshape(-1, 4, 2)).max((1, 2))
        cand = {int(k): p1[j].astype(float) for j, k in enumerate(ks) if moved[j] < self.track_px}
        return self._verify(gray, cand)

    def detect(self, gray, prediction: Pose | None):
        """{board index: (4, 2) corners}; ROI search around the predicted markers, else the full frame."""
        h, w = gray.shape[:2]
        found = {}
        if prediction is not None:
            proj = self.camera.project(self.board.corners.reshape(-1, 3), prediction).reshape(-1, 4, 2)
            if self.rejected:   # markers left out for good are not looked for (their predicted place is wrong)
                proj[list(self.rejected)] = np.nan
            periodic = self.redetect_every > 0 and self._frame % self.redetect_every == 0
            # corner tracking only from a measured pose: after a hold the prediction has drifted too far for
            # the sub-pixel refinement to converge fully (2-3.5 px overlay error in the first frames after a
            # one-second full occlusion), so the markers are detected again in their ROIs
            if self.track and not periodic and self._missed == 0:
                found = self._track(gray, proj)
                self.n_tracked += len(found)
            for k, p in enumerate(proj):
                if k in found or not np.all(np.isfinite(p)):
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
                    self.n_detected += 1
            if self.track and periodic and self._missed == 0 and len(found) < len(proj) - len(self.rejected):
                # a marker that the periodic re-detection misses (ArUco rejects its candidate now and then while
                # it is in plain view) is followed from its prediction as in the other frames, not dropped from
                # this frame's pose: a pose from fewer markers moves every estimate of that one frame
                rest = proj.copy()
                rest[list(found)] = np.nan
                more = self._track(gray, rest)
                self.n_tracked += len(more)
                found.update(more)
            if len(found) >= self.min_markers and (self._missed == 0 or len(found) == len(proj) - len(self.rejected)):
                return found, False
            # markers back after a hold: the drifted prediction's ROIs may miss some of them, so the frame is
            # searched in full (once: the pose is measured again from then on)
            if found:
                return self._detect(gray), True
            if self._missed % self.full_search_every:  # held pose: full-frame search every few frames
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
        # Levenberg-Marquardt from the candidate with the smallest reprojection error (the others only if
        # that one does not converge to an acceptable pose)
        def rms(pose):
            if np.any(pose.apply(obj)[:, 2] <= 0):
                return np.inf
            return float(np.sqrt(np.mean(np.sum((self.camera.project(obj, pose) - img) ** 2, 1))))

        start = sorted((rms(Pose.from_rvec(r, t)), j) for j, (r, t) in enumerate(cands))
        best = None
        for e0, j in start:
            if not np.isfinite(e0):
                continue
            r, t = cands[j]
            r, t = cv2.solvePnPRefineLM(obj, img, self.K, self.dist, r.reshape(3, 1).copy(), t.reshape(3, 1).copy(),
                                        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-12))
            pose = Pose.from_rvec(r, t)
            err = rms(pose)
            if best is None or err < best[1] - 1e-6:
                best = (pose, err)
            if best[1] <= self.max_reproj_px:
                break
        return best, img

    def _marker_rms(self, pose: Pose, found: dict, ks) -> np.ndarray:
        """RMS reprojection error [px] of each marker ``ks`` of ``found`` under ``pose`` (inf behind it)."""
        X = self.board.corners[list(ks)].reshape(-1, 3)
        img = np.concatenate([found[k] for k in ks]).reshape(-1, 2)
        if np.any(pose.apply(X)[:, 2] <= 0):
            return np.full(len(ks), np.inf)
        d2 = np.sum((self.camera.project(X, pose) - img) ** 2, 1).reshape(len(ks), 4)
        return np.sqrt(d2.mean(1))

    def _consistent(self, found: dict, prediction: Pose | None):
        """(best, image corners, the markers used) of the pose from the markers of ``found`` that agree.

        Markers left out for good (``rejected``) are dropped first. When every marker's corners lie within
        max_reproj_px / 2 of the joint pose, all are used (one solve, the usual case). Otherwise markers are
        dropped one at a time, each time the one whose removal gives the smallest worst per-marker error of the
        rest (a solve without it: its own corners cannot pull that pose), as long as its corners are more than
        max_reproj_px from that pose. A dropped marker farther than max_reproj_px from the pose of at least two
        others that agree counts as disagreeing (``confirm`` such frames, more than it agreed with another:
        left out for good, one warning, :meth:`explain`). Two markers that
        disagree: the one with more disagreeing frames goes, else the one farther from the predicted pose; with
        neither to tell them apart, no pose is measured."""
        if self.rejected:
            found = {k: c for k, c in found.items() if k not in self.rejected}
        if len(found) < self.min_markers or not found:
            return None, None, found
        best, img = self._solve(found, prediction)
        ks = sorted(found)
        if len(ks) < 2:
            return best, img, found
        thr = self.max_reproj_px
        if best is not None and self._marker_rms(best[0], found, ks).max() <= 0.5 * thr:
            self._agreed[ks] += 1
            return best, img, found
        keep, dropped = list(ks), []
        while len(keep) > 2:
            trials = []
            for k in keep:
                rest = [j for j in keep if j != k]
                b, _ = self._solve({j: found[j] for j in rest}, prediction)
                if b is not None:
                    trials.append((float(self._marker_rms(b[0], found, rest).max()), k, b))
            if not trials:
                break
            worst_rest, k, b = min(trials, key=lambda t: t[0])
            if self._marker_rms(b[0], found, [k])[0] <= thr:
                break      # the least helpful marker agrees with the others' pose: nothing to drop
            keep.remove(k)
            dropped.append(k)
            if worst_rest <= thr:
                break
        if len(keep) == 2:
            b, _ = self._solve({j: found[j] for j in keep}, prediction)
            if b is None or self._marker_rms(b[0], found, keep).max() > thr:
                k = self._odd_one_out(found, keep, prediction)
                if k is None:
                    return None, None, {}
                keep.remove(k)
                dropped.append(k)
        if not dropped:
            return best, img, found
        kept = {j: found[j] for j in keep}
        best, img = self._solve(kept, prediction)
        if best is not None and self._marker_rms(best[0], found, keep).max() <= thr:
            self.n_left_out += len(dropped)
            if len(keep) >= 2:      # the others agree: each dropped marker far from their pose disagreed
                self._agreed[keep] += 1
                for k in dropped:
                    if self._marker_rms(best[0], found, [k])[0] > thr:
                        self._disagreed[k] += 1
                        if self._disagreed[k] >= self.confirm and self._disagreed[k] > self._agreed[k]:
                            self._reject(k, found[k], best[0], keep)
        return best, img, kept

    def _odd_one_out(self, found, pair, prediction) -> int | None:
        """Which of two disagreeing markers to drop: the one that disagreed with others in more frames, else
        the one whose corners are farther from the predicted pose (by more than max_reproj_px); None when
        neither tells."""
        a, b = pair
        if self._disagreed[a] != self._disagreed[b]:
            return a if self._disagreed[a] > self._disagreed[b] else b
        if prediction is not None:
            ea, eb = self._marker_rms(prediction, found, pair)
            if abs(ea - eb) > self.max_reproj_px:
                return a if ea > eb else b
        return None

    def _reject(self, k: int, corners: np.ndarray, pose: Pose, rest: list):
        """Leave marker ``k`` out for good and say so once (see :meth:`explain`)."""
        why = self.explain(k, corners, pose, rest)
        self.rejected[k] = why
        warnings.warn(PhysarWarning(f"{self.source}: {why}" if self.source else why), stacklevel=3)

    def explain(self, k: int, corners: np.ndarray, pose: Pose, rest) -> str:
        """One line saying how the image corners ``corners`` (4, 2) of marker ``k`` disagree with ``pose``, the
        camera pose the markers ``rest`` give: seen where another marker should be (ids swapped), turned about its
        normal (its up), mirrored (its normal), at another scale (its size, e.g. given in mm), else how far
        (mm) and how much turned (degrees) it is from where the others put it (its centre, normal)."""
        ids = self.board.ids
        cfg = self.board.corners[k]
        thr = self.max_reproj_px
        name = f"[[marker]] id {ids[k]}"
        by = (f"[[marker]] id {ids[rest[0]]}" if len(rest) == 1
              else f"[[marker]] ids {', '.join(str(ids[j]) for j in rest)}")
        tail = "; it is left out of the camera pose"

        def fits(X):    # the corners X (4, 3) project onto the image corners under the others' pose
            return bool(np.all(pose.apply(X)[:, 2] > 0)
                        and np.sqrt(np.mean(np.sum((self.camera.project(X, pose) - corners) ** 2, 1))) <= thr)

        for j in range(len(ids)):
            if j != k and fits(self.board.corners[j]):
                return (f"{name} is seen where {by} put [[marker]] id {ids[j]}: are the two ids swapped? Check its "
                        f"id{tail}")
        for r, turn in ((1, "90°"), (2, "180°"), (3, "90°")):
            if fits(np.roll(cfg, r, axis=0)):
                return f"{name} is seen turned by {turn} about its normal from where {by} put it: check its up{tail}"
        if fits(cfg[[1, 0, 3, 2]]):
            return (f"{name} is seen mirrored where {by} put it: check its normal (outward from the face it is "
                    f"stuck on){tail}")
        c = cfg.mean(0)
        side = float(np.linalg.norm(cfg[1] - cfg[0]))
        own, _ = self._solve({k: corners}, None)
        if own is None:
            return f"{name} disagrees with where {by} put it: check its center, normal, up and size{tail}"
        zk, z = own[0].apply(c[None])[0, 2], pose.apply(c[None])[0, 2]
        sigma = z / zk if zk > 0 else np.nan
        if np.isfinite(sigma) and abs(sigma - 1) > 0.05 and fits(c + sigma * (cfg - c)):
            return (f"{name} fits where {by} put it only with a side of {sigma * side:.3g} m, not size = "
                    f"{side:.4g}: check its size (metres){tail}")
        X = pose.inverse().apply(own[0].apply(cfg))     # where it is if its size is right, object frame
        d = float(np.linalg.norm(X.mean(0) - c))
        n0 = np.cross(cfg[1] - cfg[0], cfg[3] - cfg[0])
        n1 = np.cross(X[1] - X[0], X[3] - X[0])
        ang = float(np.degrees(np.arccos(np.clip(n0 @ n1 / (np.linalg.norm(n0) * np.linalg.norm(n1)), -1, 1))))
        return (f"{name} is {d * 1e3:.0f} mm / {ang:.0f}° away from where {by} put it: check its center, normal, "
                f"up and size{tail}")

    def update(self, gray) -> PoseEstimate:
        """Process one grey frame (uint8 (h, w)); returns the filtered pose and its status."""
        pred = self.predicted()
        found, full = self.detect(gray, pred)
        if not full and self._disagreed.any():
            # a marker that disagreed and is not confirmed yet is looked for in the whole frame (its predicted
            # place is wrong when its table is), at most 2 * confirm times each, until it agrees or is confirmed
            sus = [k for k in np.flatnonzero((self._disagreed > self._agreed) & (self._searched < 2 * self.confirm))
                   if k not in found and k not in self.rejected]
            if sus:
                self._searched[sus] += 1
                for k, c in self._detect(gray).items():
                    found.setdefault(k, c)
                full = True
        self._frame += 1
        if found and self.edges:
            ks = list(found)
            refined = refine_corners_by_edges(gray, np.stack([found[k] for k in ks]), self._n_cells, self.K, self.dist)
            found = {k: refined[j] for j, k in enumerate(ks)}
        best = None
        if len(found) >= self.min_markers:
            best, img, found = self._consistent(found, pred)
        if best is not None and best[1] <= self.max_reproj_px:
            pose, err = best
            if pred is not None and self._missed == 0:
                # gate: a jump larger than gate_px at the markers is an outlier unless the full search agrees
                # (a corner behind the camera in either pose projects to NaN: that is a jump, not a NaN gain)
                d = np.abs(self.camera.project(self.board.corners.reshape(-1, 3), pose)
                           - self.camera.project(self.board.corners.reshape(-1, 3), pred))
                d = float(d.max()) if np.isfinite(d).all() else np.inf
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
