"""Camera pose of every frame for an AR project (seed 000 §2.1, §5.2, §5.3.2): from ArUco markers fixed in
the object's frame, or from a textured plane fixed in it.

* ``markers``: :class:`physar.vision.markers.MarkerTracker` (detection, corner tracking, filtering).
* ``plane`` with a reference image (a support plate, a printed poster: its design file or a scan): ORB
  features of the image at the zooms the plane will be seen at, RANSAC homography and IPPE/LM pose
  (:class:`physar.vision.markerless.PlanarMap`), refined by Lucas-Kanade on the rectified plane; when the
  plane is lost (the camera looked away), relocalisation at half resolution (the motion blur of a camera
  swinging back is halved in pixels) (§5.3.3).
* ``plane`` without an image (the wall behind the object): the markers give the pose of the first frame
  they are found in; the plane's ORB map is built from that frame, without the markers and the object
  (masked by their projections), and the markers are not looked for again (§5.2, Fig. 8).

A ``[[marker]]`` whose corners disagree with the pose the other markers give (wrong centre, normal, up, size
or id) is left out of the pose, with one warning line naming the project file and the marker
(:meth:`physar.vision.markers.MarkerTracker._consistent`).

:meth:`Registration.update` returns a :class:`physar.vision.markers.PoseEstimate` (status measured /
predicted / lost, the marker corners when markers gave the pose, for the joint refinement).
"""
from __future__ import annotations

import cv2
import numpy as np

from physar.errors import PhysarError
from physar.vision.camera import Pose
from physar.vision.markers import MarkerTracker, PoseEstimate


class Registration:
    """Pose source of a project (see the module doc). ``bounds``: (2, 3) box of the object in its frame,
    masked out of a learned plane."""

    def __init__(self, project, bounds: np.ndarray | None = None):
        cfg = project.config
        self.camera = cam = project.camera
        self.method = cfg.registration.method
        self.plane = cfg.registration.plane
        self.markers = None
        if project.board is not None:
            # a [[marker]] table that disagrees with the others is left out of the pose, said once naming the file
            self.markers = MarkerTracker(cam, project.board, noise_px=cfg.tracking.corner_sigma_px,
                                         source=getattr(project, "source", None))
        self.board = project.board
        self.bounds = bounds
        self.map = self.coarse = None
        self._pose = None
        self.info: dict = {}
        if self.method == "plane" and project.plane_image is not None:
            self._map_from_image(project.plane_image)

    # -- plane from its reference image ------------------------------------------------------------------
    def _map_from_image(self, img: np.ndarray):
        from physar.vision.markerless import PlanarMap

        cam, pl = self.camera, self.plane
        o, eu, ev = (np.asarray(v, float) for v in (pl.origin, pl.u, pl.v))
        eu, ev = eu / np.linalg.norm(eu), ev / np.linalg.norm(ev)
        s = float(pl.px_per_m)
        w = img.shape[1]
        # the zoom the plane is seen at: from the distance given, else the plane filling 3/4 of the image width
        seen = cam.fx / pl.distance if pl.distance is not None else 0.75 * cam.size[0] / (w / s)
        z0 = seen / s
        zooms = tuple(sorted({round(min(1.0, z0 * f), 3) for f in (1.4, 0.8, 0.45)}, reverse=True))
        self.map = PlanarMap.from_image(cam, img, s, o, eu, ev, n_features=2500, scales=zooms)
        r = float(np.clip(0.418 * z0, 0.1, 1.0))
        small = cv2.resize(img, None, fx=r, fy=r, interpolation=cv2.INTER_AREA)
        self.map.enable_refinement(small, r * s, n_points=300)
        self.map.orb = cv2.ORB_create(nfeatures=2000, scaleFactor=1.2, nlevels=8, edgeThreshold=19, patchSize=19,
                                      fastThreshold=10)
        self.map.min_inliers = 10
        half = cam.scaled(0.5)
        z1 = z0 / 2
        self.coarse = PlanarMap.from_image(half, img, s, o, eu, ev, n_features=2500,
                                           scales=tuple(sorted({round(min(1.0, z1 * f), 3) for f in (1.4, 0.8, 0.45)},
                                                               reverse=True)))
        self.coarse.min_inliers = 10

    # -- plane learned from a frame registered by the markers ---------------------------------------------
    def _learn(self, gray: np.ndarray, pose: Pose):
        from physar.vision.markerless import PlanarMap, PlaneTextureTracker

        cam, pl = self.camera, self.plane
        o, eu, ev = (np.asarray(v, float) for v in (pl.origin, pl.u, pl.v))
        eu, ev = eu / np.linalg.norm(eu), ev / np.linalg.norm(ev)
        n = np.cross(eu, ev)
        h, w = gray.shape
        mask = np.full((h, w), 255, np.uint8)
        for c in self.board.corners:                # the markers (removed after this frame) ...
            q = c.mean(0) + 1.6 * (c - c.mean(0))
            cv2.fillPoly(mask, [np.round(cam.project(q, pose)).astype(np.int32)], 0)
        if self.bounds is not None:                 # ... and the object, which moves
            lo, hi = self.bounds
            m = 0.1 * float(np.max(hi - lo))
            box = np.array([lo - m, hi + m])
            corners = np.array([[box[i, 0], box[j, 1], box[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
            Xc = pose.apply(corners)
            if np.all(Xc[:, 2] > 1e-6):
                hull = cv2.convexHull(np.round(cam.project(corners, pose)).astype(np.int32))
                cv2.fillPoly(mask, [hull], 0)
        try:
            self.map = PlanarMap.from_frame(cam, gray, pose, o, eu, ev, mask=mask)
        except PhysarError as e:
            raise PhysarError(f"[registration.plane]: {e}") from None
        # direct refinement on the rectified plane (the part seen in this frame), at ~0.6 of the image scale
        wc = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float)
        Xw = cam.backproject_to_plane(wc, pose, o, n)
        a, b = (Xw - o) @ eu, (Xw - o) @ ev
        u0, u1, v0, v1 = a.min(), a.max(), b.min(), b.max()
        depth = float(np.median(pose.apply(Xw)[:, 2]))
        sw = 0.6 * cam.fx / depth
        rect = PlaneTextureTracker(cam, o + u0 * eu + v0 * ev, eu, ev, (u1 - u0, v1 - v0), sw, n_points=1)
        ref = np.clip(rect.rectify(gray, pose), 0, 255).astype(np.uint8)
        rmask = rect.rectify(mask, pose) >= 254
        rmask = cv2.erode(rmask.astype(np.uint8) * 255, np.ones((15, 15), np.uint8))
        self.map.enable_refinement(ref, sw, (u0, v0), rmask, n_points=250)
        self.info["plane_features"] = len(self.map.uv)

    # -- per frame ---------------------------------------------------------------------------------------
    def update(self, gray: np.ndarray) -> PoseEstimate:
        if self.method == "markers":
            return self.markers.update(gray)
        if self.map is None:                        # learn the plane from the first marker-registered frame
            pe = self.markers.update(gray)
            if pe.status == "measured":
                self._learn(gray, pe.pose)
                self._pose = pe.pose
            return pe if pe.status == "measured" else PoseEstimate(None, "lost", pe.n_markers)
        loc = self.map.track(gray, self._pose)
        if loc.pose is None and self.coarse is not None:   # relocalise at half resolution
            small = cv2.resize(gray, self.coarse.camera.size, interpolation=cv2.INTER_AREA)
            loc2 = self.coarse.locate(small)
            if loc2.pose is not None and loc2.inliers >= 2 * self.coarse.min_inliers:
                ref, n = self.map.refine(gray, loc2.pose)
                loc = loc2 if ref is None else type(loc2)(ref, n, loc2.matches)
        self._pose = loc.pose
        if loc.pose is None:
            return PoseEstimate(None, "lost", 0)
        return PoseEstimate(loc.pose, "measured", int(loc.inliers))

    def reset(self):
        self._pose = None
        if self.markers is not None:
            self.markers.reset()


__all__ = ["Registration"]
