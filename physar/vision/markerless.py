r"""Markerless vision (seed 000 §5.2, §5.3): camera pose from ORB features of a rigid planar scene part,
in-plane deformation of a textured surface by feature tracking, lever angle by colour segmentation.

* :class:`PlanarMap` — ORB keypoints (Rublee et al., seed ref. [51]) with known 3-D positions on a world
  plane, built from a registered frame (pose from markers at frame 0, §5.2) or from a reference image of
  the plane (the support plate, §5.3). ``locate`` matches the frame's ORB descriptors (Hamming distance,
  Lowe ratio test), fits the plane-to-image homography by RANSAC (seed ref. [52]: the plane's features are
  the inliers, the rest of the scene the outliers, §5.3.2), and the pose from the inliers by IPPE + LM
  (minimising :math:`\sum_k \|p_k - \Pi(R, t; X_k)\|^2`).
* :class:`PlaneTextureTracker` — rectifies a planar surface patch of the object with the current pose
  (homography :math:`H = K\, [R e_u,\ R e_v,\ R o + t]\, A` from the patch's pixel grid to the image) and tracks the
  surface's own texture features (ORB keypoints of the reference view) by pyramidal Lucas-Kanade from the
  reference view to the current one, with a forward-backward check. The in-plane displacement of a
  material point :math:`X` of the patch is :math:`(p_k - p_k^0) / (\text{px per m})` along :math:`(e_u, e_v)`:
  the observations :math:`u^*` of
  seed 000 Eq. (2) without fiducials (§5.2, "some existing pattern in the solid").
* :func:`lever_angle` — white-colour segmentation (low saturation, high value) of a rectified plate view in
  an annulus about the pivot and the principal direction of the segmented pixels (§5.3.2, Fig. 17).

Lengths in m, angles in rad unless stated.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from physar.errors import ConfigError, PhysarError
from physar.vision.camera import Camera, Pose


def _orb(n_features: int, fast_threshold: int = 12):
    return cv2.ORB_create(nfeatures=int(n_features), scaleFactor=1.2, nlevels=6, edgeThreshold=19,
                          patchSize=19, fastThreshold=fast_threshold)


def plane_homography(camera: Camera, pose: Pose, origin, axis_u, axis_v, px_per_m: float) -> np.ndarray:
    r"""3x3 map from rectified pixel :math:`(c, r)` of the plane patch :math:`o + a e_u + b e_v`
    (:math:`o` = origin, :math:`a = (c + 1/2)/s`, :math:`b = (r + 1/2)/s`, :math:`s` = px_per_m) to image pixels
    (pinhole part of the camera)."""
    o, eu, ev = (np.asarray(v, float) for v in (origin, axis_u, axis_v))
    s = float(px_per_m)
    A = np.array([[1 / s, 0, 0.5 / s], [0, 1 / s, 0.5 / s], [0, 0, 1.0]])
    M = np.column_stack([pose.R @ eu, pose.R @ ev, pose.R @ o + pose.t])
    return camera.K @ M @ A


@dataclass
class LocateResult:
    pose: Pose | None
    inliers: int
    matches: int
    homography: np.ndarray | None = None   # plane (u, v) [m] -> image pixels
    keypoints: np.ndarray | None = None    # (n, 2) image positions of the inlier features
    outliers: np.ndarray | None = None     # (m, 2) matched features off the plane (environment)


class PlanarMap:
    """ORB features with known positions on a world plane :math:`X = o + a e_u + b e_v` (:math:`o` = origin);
    camera pose by
    descriptor matching + RANSAC homography + IPPE/LM pose (see the module docstring)."""

    def __init__(self, camera: Camera, uv: np.ndarray, descriptors: np.ndarray, origin, axis_u, axis_v,
                 n_features: int = 2000, ratio: float = 0.8, ransac_px: float = 3.0, min_inliers: int = 12):
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        if len(uv) < min_inliers:
            raise PhysarError(f"planar map: only {len(uv)} features on the plane (need >= {min_inliers}); "
                              f"the surface has too little texture")
        self.camera, self.uv, self.desc = camera, uv, np.ascontiguousarray(descriptors)
        self.origin, self.eu, self.ev = (np.asarray(v, float) for v in (origin, axis_u, axis_v))
        self.X = self.origin + uv[:, :1] * self.eu + uv[:, 1:] * self.ev
        self.orb = _orb(n_features)
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self.ratio, self.ransac_px, self.min_inliers = ratio, ransac_px, min_inliers

    # -- construction -----------------------------------------------------------------------------------
    @classmethod
    def from_frame(cls, camera: Camera, gray: np.ndarray, pose: Pose, origin, axis_u, axis_v,
                   mask: np.ndarray | None = None, n_features: int = 2000, **kw) -> PlanarMap:
        """Map of the plane's ORB features in a registered frame (known pose), restricted to `mask`
        (uint8, non-zero where the plane is visible and rigid)."""
        orb = _orb(n_features)
        kps, desc = orb.detectAndCompute(gray, mask)
        if desc is None or not kps:
            raise PhysarError("planar map: no ORB features in the reference frame (the plane has no texture)")
        p = np.array([k.pt for k in kps])
        eu, ev = np.asarray(axis_u, float), np.asarray(axis_v, float)
        X = camera.backproject_to_plane(p, pose, origin, np.cross(eu, ev))
        d = X - np.asarray(origin, float)
        uv = np.column_stack([d @ eu, d @ ev])
        return cls(camera, uv, desc, origin, axis_u, axis_v, n_features=n_features, **kw)

    @classmethod
    def from_image(cls, camera: Camera, image: np.ndarray, px_per_m: float, origin, axis_u, axis_v,
                   n_features: int = 3000, scales=(1.0,), **kw) -> PlanarMap:
        r"""Map from a fronto-parallel reference image of the plane: pixel (c, r) is the point
        :math:`o + \frac{c + 1/2}{s} e_u + \frac{r + 1/2}{s} e_v`, :math:`s` = px_per_m (e.g. the design
        drawing or a scan of the plate).
        ``scales``: the image is also described at these zooms (ORB's own pyramid covers a factor ~2.5 only;
        use the zooms at which the plate will be seen)."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        uv, descs = [], []
        for z in scales:
            g = gray if z == 1.0 else cv2.resize(gray, None, fx=z, fy=z, interpolation=cv2.INTER_AREA)
            kps, desc = _orb(n_features).detectAndCompute(g, None)
            if desc is None or not kps:
                continue
            p = np.array([k.pt for k in kps])
            uv.append((p + 0.5) / (float(px_per_m) * z))
            descs.append(desc)
        if not uv:
            raise PhysarError("planar map: no ORB features in the reference image (the plane has no texture)")
        return cls(camera, np.vstack(uv), np.vstack(descs), origin, axis_u, axis_v, n_features=n_features, **kw)

    # -- direct refinement -------------------------------------------------------------------------------
    def enable_refinement(self, reference: np.ndarray, px_per_m: float, origin_uv=(0.0, 0.0),
                          mask: np.ndarray | None = None, n_points: int = 400, min_points: int = 40,
                          max_rms_px: float = 1.0):
        r"""Refine every pose by Lucas-Kanade on the rectified plane: `reference` is a fronto-parallel view
        of the plane (pixel (c, r) is the point :math:`o + (u_0 + \frac{c + 1/2}{s}) e_u + (v_0 + \frac{r +
        1/2}{s}) e_v`); its
        features are tracked into the current frame rectified with the pose to refine (small residual flow),
        and the pose is re-fitted to all of them (LM). Also gives frame-to-frame tracking from the previous
        pose, ORB matching being needed only to (re)localise."""
        ref = reference if reference.ndim == 2 else cv2.cvtColor(reference, cv2.COLOR_BGR2GRAY)
        h, w = ref.shape
        o = self.origin + origin_uv[0] * self.eu + origin_uv[1] * self.ev
        self._ref_uv0 = np.asarray(origin_uv, float)
        self._refiner = PlaneTextureTracker(self.camera, o, self.eu, self.ev, (w / px_per_m, h / px_per_m),
                                            px_per_m, n_points=n_points, win=15, levels=2, fb_px=0.5)
        self._refiner.size = (w, h)
        self._refiner.set_reference([ref], mask)
        self._ref_min, self._ref_rms = min_points, max_rms_px

    def refine(self, gray: np.ndarray, pose: Pose) -> tuple[Pose | None, int]:
        """The refined pose and the number of features used (None if too few or a poor fit)."""
        tr = getattr(self, "_refiner", None)
        if tr is None:
            return pose, 0
        tr.reset()
        d, ok, _ = tr.update(gray, pose)
        if ok.sum() < self._ref_min:
            return None, int(ok.sum())
        p1 = (tr.p0.reshape(-1, 2) + d * tr.s)[ok]
        q = (p1 + 0.5) / tr.s  # where the reference features are now, in the plane of the prior pose
        img = self.camera.project(tr.origin + q[:, :1] * self.eu + q[:, 1:] * self.ev, pose)
        ab = (tr.p0.reshape(-1, 2)[ok] + 0.5) / tr.s + self._ref_uv0
        X = self.origin + ab[:, :1] * self.eu + ab[:, 1:] * self.ev
        K, dist = self.camera.to_opencv()
        rv, tv = cv2.solvePnPRefineLM(X, img, K, dist, pose.rvec.reshape(3, 1).copy(), pose.t.reshape(3, 1).copy())
        new = Pose.from_rvec(rv.ravel(), tv.ravel())
        e = np.linalg.norm(self.camera.project(X, new) - img, axis=1)
        keep = e < max(3 * np.median(e), 0.3)
        if keep.sum() >= self._ref_min and keep.sum() < len(e):
            rv, tv = cv2.solvePnPRefineLM(X[keep], img[keep], K, dist, rv, tv)
            new = Pose.from_rvec(rv.ravel(), tv.ravel())
        e = np.linalg.norm(self.camera.project(X[keep], new) - img[keep], axis=1)
        if np.sqrt(np.mean(e ** 2)) > self._ref_rms:
            return None, int(keep.sum())
        return new, int(keep.sum())

    def track(self, gray: np.ndarray, prior: Pose | None = None) -> LocateResult:
        """Pose of this frame: refinement from the prior (the previous frame's pose) when that works, else
        ORB relocalisation (:meth:`locate`) followed by refinement."""
        if prior is not None and getattr(self, "_refiner", None) is not None:
            pose, n = self.refine(gray, prior)
            if pose is not None:
                return LocateResult(pose, n, 0)
        loc = self.locate(gray)
        if loc.pose is not None and getattr(self, "_refiner", None) is not None:
            pose, n = self.refine(gray, loc.pose)
            if pose is not None:
                loc.pose, loc.inliers = pose, n
            elif loc.inliers < 2 * self.min_inliers:  # weak relocalisation that does not refine: reject
                loc.pose = None
        return loc

    # -- per frame --------------------------------------------------------------------------------------
    def locate(self, gray: np.ndarray, prior: Pose | None = None) -> LocateResult:
        """Pose by ORB matching + RANSAC homography + IPPE/LM (no prior needed: relocalisation)."""
        kps, desc = self.orb.detectAndCompute(gray, None)
        if desc is None or len(kps) < self.min_inliers:
            return LocateResult(None, 0, 0)
        knn = self.matcher.knnMatch(desc, self.desc, k=2)
        pairs = [(m.queryIdx, m.trainIdx) for m, *n in knn if not n or m.distance < self.ratio * n[0].distance]
        if len(pairs) < self.min_inliers:
            return LocateResult(None, 0, len(pairs))
        q, t = np.array(pairs).T
        img = np.array([kps[i].pt for i in q], np.float64)
        uv = self.uv[t]
        H, inl = cv2.findHomography(uv, img, cv2.USAC_MAGSAC, self.ransac_px, maxIters=500, confidence=0.999)
        if H is None:
            return LocateResult(None, 0, len(pairs))
        inl = inl.ravel().astype(bool)
        if inl.sum() < self.min_inliers:
            return LocateResult(None, int(inl.sum()), len(pairs))
        obj = np.column_stack([uv[inl], np.zeros(inl.sum())])
        K, dist = self.camera.to_opencv()
        ok, rvec, tvec = cv2.solvePnP(obj, img[inl], K, dist, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            return LocateResult(None, int(inl.sum()), len(pairs))
        rvec, tvec = cv2.solvePnPRefineLM(obj, img[inl], K, dist, rvec, tvec)
        pl = Pose.from_rvec(rvec.ravel(), tvec.ravel())  # plane frame (u, v, n) -> camera
        B = np.column_stack([self.eu, self.ev, np.cross(self.eu, self.ev)])  # plane frame -> world axes
        R = pl.R @ B.T
        pose = Pose(R, pl.t - R @ self.origin)
        if pose.apply(self.X[t[inl]].reshape(-1, 3))[:, 2].min() <= 0:
            return LocateResult(None, int(inl.sum()), len(pairs))
        return LocateResult(pose, int(inl.sum()), len(pairs), H, img[inl], img[~inl])


class PlaneTextureTracker:
    """In-plane displacements of texture features of a planar surface patch (see the module docstring).

    The patch: origin (top-left corner) + a e_u + b e_v, a in [0, size_u], b in [0, size_v] [m], sampled
    at `px_per_m`. ``set_reference(images)`` takes rectified reference views (averaged: less noise) and
    picks up to `n_points` ORB keypoints (one per grid bucket) inside `mask`; ``update`` returns their
    displacements (n, 2) [m] along (e_u, e_v) and a validity mask.
    """

    def __init__(self, camera: Camera, origin, axis_u, axis_v, size_uv, px_per_m: float, n_points: int = 300,
                 win: int = 21, levels: int = 3, fb_px: float = 0.3):
        self.camera = camera
        self.origin, self.eu, self.ev = (np.asarray(v, float) for v in (origin, axis_u, axis_v))
        self.s = float(px_per_m)
        self.size = (int(np.ceil(size_uv[0] * self.s)), int(np.ceil(size_uv[1] * self.s)))
        if min(self.size) < 8 or self.size[0] * self.size[1] > 2e7:
            raise ConfigError(f"texture tracker: rectified patch of {self.size} px is unusable")
        self.n_points, self.win, self.levels, self.fb_px = n_points, (win, win), levels, fb_px
        self.ref = None
        self.p0 = None
        self.flow = None

    def rectify(self, gray: np.ndarray, pose: Pose) -> np.ndarray:
        """The patch seen fronto-parallel at px_per_m (float32)."""
        if np.any(self.camera.dist):
            w, h = self.size
            c, r = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
            X = self.origin + (c.ravel() / self.s)[:, None] * self.eu + (r.ravel() / self.s)[:, None] * self.ev
            m = self.camera.project(X, pose).reshape(h, w, 2).astype(np.float32)
            return cv2.remap(gray, m[..., 0], m[..., 1], cv2.INTER_LINEAR).astype(np.float32)
        H = plane_homography(self.camera, pose, self.origin, self.eu, self.ev, self.s)
        return cv2.warpPerspective(gray, H, self.size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)

    def set_reference(self, rectified: list, mask: np.ndarray | None = None) -> np.ndarray:
        """Reference view = mean of `rectified` views; returns the chosen material points (n, 2) as (a, b) [m]."""
        ref = np.mean([np.asarray(r, np.float32) for r in rectified], axis=0)
        self.ref = np.clip(ref, 0, 255).astype(np.uint8)
        kps = _orb(20 * self.n_points, fast_threshold=5).detect(self.ref, mask)
        if not kps:
            raise PhysarError("texture tracker: no features on the object's surface")
        pts = np.array([k.pt for k in kps], np.float32)
        resp = np.array([k.response for k in kps])
        # one strongest keypoint per bucket: spread over the surface
        w, h = self.size
        nb = max(1, int(np.sqrt(self.n_points * w / h)))
        bucket = (np.clip(pts[:, 0] / w * nb, 0, nb - 1).astype(int) * 10000 +
                  np.clip(pts[:, 1] / h * max(1, self.n_points // nb), 0, 9999).astype(int))
        order = np.lexsort((-resp, bucket))
        first = order[np.r_[True, bucket[order][1:] != bucket[order][:-1]]]
        self.p0 = pts[first].reshape(-1, 1, 2)
        self.flow = np.zeros_like(self.p0)
        return (self.p0.reshape(-1, 2).astype(float) + 0.5) / self.s

    def reset(self):
        if self.flow is not None:
            self.flow[...] = 0

    def _track(self, cur, guess):
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(self.ref, cur, self.p0, self.p0 + guess, winSize=self.win,
                                             maxLevel=self.levels, criteria=crit,
                                             flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        pb, st2, _ = cv2.calcOpticalFlowPyrLK(cur, self.ref, p1, self.p0.copy(), winSize=self.win,
                                              maxLevel=self.levels, criteria=crit,
                                              flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        fb = np.linalg.norm((pb - self.p0).reshape(-1, 2), axis=1)
        ok = (st.ravel() == 1) & (st2.ravel() == 1) & (fb < self.fb_px)
        return p1, ok

    def update(self, gray: np.ndarray, pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(displacements (n, 2) [m] along (e_u, e_v), valid (n,), rectified view uint8)."""
        if self.ref is None:
            raise PhysarError("texture tracker: set_reference first")
        cur = np.clip(self.rectify(gray, pose), 0, 255).astype(np.uint8)
        p1, ok = self._track(cur, self.flow)
        if ok.mean() < 0.7:  # the surface jumped (load placed): retry from rest, keep the better per point
            p1b, okb = self._track(cur, np.zeros_like(self.flow))
            take = okb & ~ok
            p1[take], ok = p1b[take], ok | okb
        d = (p1 - self.p0).reshape(-1, 2)
        self.flow[ok] = (p1 - self.p0)[ok]
        return d / self.s, ok, cur


def lever_angle(rect_bgr: np.ndarray, pivot_px, r_min_px: float, r_max_px: float, sat_max: int = 40,
                val_min: int = 170, min_pixels: int = 30) -> tuple[float, int]:
    """Angle [rad] of a white lever about `pivot_px` in a rectified view, measured from the view's -v axis
    (image up) towards +u (image right); NaN if fewer than `min_pixels` white pixels in the annulus.

    White = HSV saturation <= sat_max and value >= val_min; the angle is that of the principal axis of the
    segmented pixels (second moments about the pivot), oriented along their mean direction.
    """
    hsv = cv2.cvtColor(rect_bgr, cv2.COLOR_BGR2HSV)
    white = (hsv[..., 1] <= sat_max) & (hsv[..., 2] >= val_min)
    ys, xs = np.nonzero(white)
    dx, dy = xs + 0.0 - pivot_px[0], ys + 0.0 - pivot_px[1]
    r = np.hypot(dx, dy)
    sel = (r >= r_min_px) & (r <= r_max_px)
    if sel.sum() < min_pixels:
        return float("nan"), int(sel.sum())
    dx, dy = dx[sel], dy[sel]
    M = np.array([[dx @ dx, dx @ dy], [dx @ dy, dy @ dy]])
    _w, V = np.linalg.eigh(M)
    d = V[:, 1]
    if d @ np.array([dx.mean(), dy.mean()]) < 0:
        d = -d
    return float(np.arctan2(d[0], -d[1])), int(sel.sum())
