r"""Tracking of small coloured dots on the object and their displacements (seed 000 §2.1, §5.1: "small blue
dots adhered to the beam for the determination of the beam deflection").

Per frame: the dots are predicted by projecting their last 3-D positions with the current pose, or by pyramidal
Lucas-Kanade (KLT) optical flow from the previous frame (``flow``: always, never, or "auto": only when the
projection missed the measured dots by more than ``flow_px`` in the previous frame, i.e. when the object
deforms fast; blob detection (connected components of the colour mask) finds dots without a track); each
prediction is refined by the colour-weighted centroid of the blob in a small window,

.. math::

    p = \frac{\sum_i w_i x_i}{\sum_i w_i}, \qquad w_i = \max(0, c_i - \tau), \qquad c = B - \max(R, G)

(:math:`c_i` the "blueness" of pixel :math:`i`).
The refined pixels are back-projected onto the object's plane (ray-plane intersection, :class:`Camera`),
giving 3-D positions :math:`x` and displacements :math:`u^* = x - X_{\mathrm{ref}}`.
A dot whose projection is NaN (behind the camera, :meth:`Camera.project`) or farther than ``FAR_PX`` from the
image origin (just in front of the camera's centre plane) is not visible in that frame: it is neither searched
nor measured, and comes out invalid (NaN); the other dots are tracked as if it were not there.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from physar.errors import ConfigError
from physar.vision.camera import Camera, Pose

FAR_PX = 1e7  # |pixel| beyond which a projected dot counts as not visible (keeps the integer crops in range)


def _visible(pixels) -> np.ndarray:
    """(n,) bool: rows of `pixels` (n, 2) that are finite and within ``FAR_PX`` (False for NaN, no warning)."""
    return np.all(np.abs(pixels) < FAR_PX, axis=1)


@dataclass(repr=False)
class DotObservation:
    r"""The dots of one frame (:meth:`DotTracker.update`).

    Attributes:
        pixels: (n, 2) refined image positions (NaN where not seen), px.
        valid: (n,) bool, the dot was seen.
        world: (n, 3) positions back-projected onto the object's plane (NaN where not seen), m.
        displacement: (n, 3) ``world`` minus the reference positions, :math:`u^* = x - X_\mathrm{ref}`, m.
    """

    pixels: np.ndarray        # (n, 2) refined image positions (NaN where not seen)
    valid: np.ndarray         # (n,) bool
    world: np.ndarray         # (n, 3) back-projected positions [m] (NaN where not seen)
    displacement: np.ndarray  # (n, 3) world - reference [m] (NaN where not seen)

    def __repr__(self) -> str:
        """One line: how many dots were seen, and the mean and largest displacement norm of those [m]; no arrays."""
        seen = np.asarray(self.valid, bool)
        n = len(seen)
        text = f"DotObservation({int(seen.sum())} of {n} dot{'' if n == 1 else 's'} seen"
        d = np.asarray(self.displacement, float)
        u = np.linalg.norm(d[seen], axis=1) if d.ndim == 2 and len(d) == n else np.zeros(0)
        u = u[np.isfinite(u)]
        if len(u):
            text += f", |displacement| mean {u.mean():.3g} m, max {u.max():.3g} m"
        return text + ")"


class DotTracker:
    """Track dots with reference positions ``reference`` (n, 3) [m] lying on the plane (point, normal)."""

    def __init__(self, camera: Camera, reference, plane_point, plane_normal, radius_px: float = 6.0,
                 threshold: float = 30.0, min_mass: float = 4.0, gate_px: float = 6.0, colour: str = "blue", luma: bool = True,
                 flow: bool | str = True, flow_px: float = 1.5):
        ref = np.asarray(reference, float)
        if ref.ndim != 2 or ref.shape[1] != 3 or len(ref) == 0:
            raise ConfigError(f"dot reference positions must have shape (n, 3), got {ref.shape}")
        if colour not in ("blue", "red", "green"):
            raise ConfigError(f"dot colour must be blue, red or green, got {colour!r}")
        self.camera, self.reference = camera, ref
        self.plane = (np.asarray(plane_point, float), np.asarray(plane_normal, float))
        self.r = max(2, int(round(radius_px * 1.6)))  # noqa: RUF046 - numpy 1.x round
        self.threshold, self.min_mass, self.gate_px, self.luma = threshold, min_mass, gate_px, luma
        self.channel = {"blue": 0, "green": 1, "red": 2}[colour]
        if flow not in (True, False, "auto"):
            raise ConfigError(f"dot flow must be true, false or 'auto', got {flow!r}")
        self.flow, self.flow_px = flow, flow_px
        self._need_flow = True
        self.n_flow = 0  # frames that ran KLT (statistics)
        self._prev_gray = None
        self._prev_px = None
        self._prev_valid = None
        self.displacement = np.zeros_like(ref)  # last known displacement, for predictions
        off = np.arange(-self.r, self.r + 1)
        self._oy, self._ox = np.meshgrid(off, off, indexing="ij")
        self._lk = {"winSize": (15, 15), "maxLevel": 2,
                    "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)}

    def reset(self):
        self._prev_gray = None

    def _window_centre(self, pred, shape):
        h, w = shape[:2]
        return np.column_stack([np.clip(np.round(pred[:, 0]).astype(int), self.r, w - self.r - 1),
                                np.clip(np.round(pred[:, 1]).astype(int), self.r, h - self.r - 1)])

    def _centroid(self, frame, pred, gray=None):
        r"""Centroids around predictions (n, 2); returns (pixels, mass).

        The colour ("blueness" :math:`c = B - \max(R, G)`) finds the blob and gives its mass, but the position
        is the centroid of the luma contrast :math:`d = |Y_{\mathrm{bg}} - Y|` above half its peak, inside the
        (dilated) colour mask: video is stored as 4:2:0, so colour has half the resolution of luma and a colour
        centroid locks to the 2-pixel chroma grid (±0.06 px here, slowly varying as the camera moves), while the
        luma centroid does not (measured on scene (a): 0.063 px vs 0.123 px rms vertically).
        """
        cx, cy = self._window_centre(pred, frame.shape).T
        ys, xs = cy[:, None, None] + self._oy, cx[:, None, None] + self._ox
        win = frame[ys, xs].astype(np.float32)  # (n, k, k, 3)
        others = [c for c in range(3) if c != self.channel]
        c = win[..., self.channel] - np.maximum(win[..., others[0]], win[..., others[1]])
        wgt = np.maximum(c - self.threshold, 0.0)
        mass = wgt.sum((1, 2))
        if gray is not None and self.luma:
            g = gray[ys, xs].astype(np.float32)
            sup = c > self.threshold / 2
            sup = self._dilate(sup) & self._dilate(wgt > 0)  # around the blob, not isolated coloured noise
            border = np.concatenate([g[:, 0, :], g[:, -1, :], g[:, :, 0], g[:, :, -1]], 1)
            d = g - np.median(border, 1)[:, None, None]
            sign = np.sign(np.where(wgt > 0, d, 0.0).sum((1, 2)))  # dots darker (or brighter) than around
            d = sign[:, None, None] * d * sup
            peak = d.max((1, 2))[:, None, None]
            lw = np.maximum(d - 0.5 * peak, 0.0)
            ok = (lw.sum((1, 2)) > 0) & (peak.ravel() > 0)
            wgt = np.where(ok[:, None, None], lw, wgt)
        with np.errstate(invalid="ignore", divide="ignore"):
            m = wgt.sum((1, 2))
            px = np.column_stack([(wgt * xs).sum((1, 2)) / m, (wgt * ys).sum((1, 2)) / m])
        return px, mass / max(self.threshold, 1.0)

    @staticmethod
    def _dilate(mask, r: int = 2):
        """Binary dilation of (n, k, k) masks by a :math:`(2r+1)^2` square (one OpenCV call on the stacked
        masks, separated by :math:`r` empty rows)."""
        n, k, _ = mask.shape
        pad = np.zeros((n, k + r, k), np.uint8)
        pad[:, :k] = mask
        out = cv2.dilate(pad.reshape(n * (k + r), k), np.ones((2 * r + 1, 2 * r + 1), np.uint8))
        return out.reshape(n, k + r, k)[:, :k].astype(bool)

    def detect_blobs(self, frame, pred, search_px):
        """Blob detection: connected components of the colour mask in the region around `pred` (n, 2);
        each prediction takes the nearest blob centroid within `search_px` (else stays NaN). Rows of `pred` that
        are not visible (NaN, or beyond ``FAR_PX``) stay NaN, as do all rows when `search_px` is not in
        (0, ``FAR_PX``)."""
        h, w = frame.shape[:2]
        pred = np.asarray(pred, float)
        out = np.full_like(pred, np.nan)
        seen = _visible(pred)
        if not (seen.any() and 0 < search_px < FAR_PX):
            return out
        q = pred[seen]
        lo = np.floor(q.min(0) - search_px).astype(int)
        hi = np.ceil(q.max(0) + search_px).astype(int)
        x0, y0, x1, y1 = max(lo[0], 0), max(lo[1], 0), min(hi[0], w), min(hi[1], h)
        if x1 <= x0 or y1 <= y0:
            return out
        roi = frame[y0:y1, x0:x1].astype(np.int16)
        others = [c for c in range(3) if c != self.channel]
        c = roi[..., self.channel] - np.maximum(roi[..., others[0]], roi[..., others[1]])
        mask = (c > self.threshold).astype(np.uint8)
        _n, _, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
        area = stats[1:, cv2.CC_STAT_AREA]
        cents = cents[1:][(area >= 3) & (area <= 4 * (2 * self.r + 1) ** 2)] + (x0, y0)
        if len(cents) == 0:
            return out
        d = np.linalg.norm(q[:, None, :] - cents[None], axis=2)
        j = np.argmin(d, axis=1)
        ok = d[np.arange(len(q)), j] < search_px
        found = np.full_like(q, np.nan)
        found[ok] = cents[j[ok]]
        out[seen] = found
        return out

    def _spacing(self, proj):
        """Smallest distance between consecutive projected dots (n, 2) (reference order), skipping the pairs
        with a dot that is not visible (NaN); ``4 r`` without such a pair."""
        gaps = np.linalg.norm(np.diff(proj, axis=0), axis=1)  # NaN where one of the pair is not visible
        gaps = gaps[np.isfinite(gaps)]
        return gaps.min() if gaps.size else 4 * self.r

    def _measure(self, frame, pred, gray):
        """Centroids around visible predictions (m, 2), re-centred once on the blob (only the dots whose window
        moved: the others would give the same result); returns (pixels, mass, bad), `bad` where no centroid
        was found (its pixel is then the prediction)."""
        px, mass = self._centroid(frame, pred, gray)
        bad = ~np.isfinite(px).all(1)
        px[bad] = pred[bad]
        moved = np.any(self._window_centre(px, frame.shape) != self._window_centre(pred, frame.shape), 1)
        if moved.any():
            px2, mass[moved] = self._centroid(frame, px[moved], gray)
            bad2 = ~np.isfinite(px2).all(1)
            px2[bad2] = pred[moved][bad2]
            px[moved], bad[moved] = px2, bad2
        return px, mass, bad

    def update(self, frame, gray, pose: Pose | None, use_flow: bool = True) -> DotObservation:
        """Track the dots in a BGR frame (uint8 (h, w, 3)) with its grey image and the camera pose."""
        n = len(self.reference)
        nan = np.full((n, 3), np.nan)
        if pose is None:
            self._prev_gray = None
            return DotObservation(np.full((n, 2), np.nan), np.zeros(n, bool), nan, nan.copy())
        proj = self.camera.project(self.reference + self.displacement, pose)
        seen = _visible(proj)  # not visible this frame: NaN (behind the camera) or far beyond the image
        proj[~seen] = np.nan
        proj0, pred = proj.copy(), proj.copy()
        if self.flow == "auto":
            use_flow = use_flow and self._need_flow
        elif not self.flow:
            use_flow = False
        track = np.zeros(n, bool) if self._prev_gray is None else self._prev_valid & seen
        if use_flow and track.any():
            self.n_flow += 1
            idx = np.flatnonzero(track)
            p0 = self._prev_px[idx].astype(np.float32).reshape(-1, 1, 2)
            # pyramids of the region around the dots only (not the whole frame); the crop holds p0, which
            # lies inside the image (a valid dot), so it is never empty
            h, w = gray.shape[:2]
            m = 3 * self.r + 20
            both = np.vstack([p0.reshape(-1, 2), proj[seen]])
            x0, y0 = np.maximum(np.floor(both.min(0) - m).astype(int), 0)
            x1, y1 = np.ceil(both.max(0) + m).astype(int)
            x1, y1 = min(x1, w), min(y1, h)
            p1, st, _ = cv2.calcOpticalFlowPyrLK(self._prev_gray[y0:y1, x0:x1], gray[y0:y1, x0:x1],
                                                 p0 - np.float32([x0, y0]), None, **self._lk)
            p1 = p1.reshape(-1, 2) + (x0, y0)
            ok = (st.ravel() == 1) & (np.linalg.norm(p1 - proj[idx], axis=1) < self.gate_px)
            pred[idx[ok]] = p1[ok]
        # dots without a flow track: blob detection within half the dot spacing of their projection
        lost = np.ones(n, bool) if self._prev_gray is None else ~self._prev_valid
        if lost.any():
            found = self.detect_blobs(frame, proj[lost], 0.45 * self._spacing(proj))
            ok = np.isfinite(found).all(1)
            idx = np.flatnonzero(lost)[ok]
            pred[idx] = found[ok]
            proj[idx] = found[ok]  # accept the blob as the new prediction (gate below)
        # measure the visible dots, then re-centre the window on the blob and measure again
        px, mass, bad = np.full((n, 2), np.nan), np.zeros(n), ~seen
        valid = np.zeros(n, bool)
        if seen.any():
            px[seen], mass[seen], bad[seen] = self._measure(frame, pred[seen], gray)
            valid[seen] = ((mass[seen] >= self.min_mass) & ~bad[seen]
                           & (np.linalg.norm(px[seen] - proj[seen], axis=1) < self.gate_px))
        h, w = gray.shape[:2]
        valid &= (px[:, 0] > self.r) & (px[:, 0] < w - self.r - 1) & (px[:, 1] > self.r) & (px[:, 1] < h - self.r - 1)
        world = nan.copy()
        if valid.any():
            world[valid] = self.camera.backproject_to_plane(px[valid], pose, *self.plane)
        disp = world - self.reference
        # KLT for the next frame ("auto") if the projection of the last displacements missed a measured dot
        miss = np.linalg.norm(px[valid] - proj0[valid], axis=1)
        self._need_flow = bool(miss.size == 0 or miss.max() > self.flow_px)
        self.displacement[valid] = disp[valid]
        self._prev_gray, self._prev_px, self._prev_valid = gray, px, valid
        px = px.copy()
        px[~valid] = np.nan
        return DotObservation(px, valid, world, disp)
