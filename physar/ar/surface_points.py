r"""Natural features of the object's surface tracked as image points, beside the printed dots (seed 000 §5.2,
"some existing pattern in the solid"; the project's ``[features]`` with ``mode = "points"``).

The features are chosen once, in a reference frame where the dots already give the parameters
:math:`\mu_\mathrm{ref}` and the camera pose: corners of the image (Shi-Tomasi) inside the projection of the
project's planar face, deformed by the reduced model at :math:`\mu_\mathrm{ref}`, away from the dots. Each
corner's ray from the camera centre meets a triangle of the deformed face at barycentrics :math:`b`; the
feature's material point is the same barycentric combination of the triangle's reference vertices,
:math:`x_k = \sum_j b_j X_j`, so a feature is a material point of the surface like a dot. Its displacement is
:math:`u_k(\mu) = \sum_m c_m(\mu)\, C_k F_m` with :math:`C` the surface observation operator
(:func:`physar.vision.observation.surface_observation_matrix`).

Each later frame, the reference view is warped by the homography that best maps the features' reference pixels
to their predicted ones, :math:`P(x_k + u_k(\mu_\mathrm{prev}))` with the frame's pose, and pyramidal
Lucas-Kanade tracks each feature from there, with a forward-backward check. The material points are averaged
over their first 30 frames (:meth:`SurfacePoints.refine`).
The tracked pixels :math:`f^*_k` enter the frame's joint (pose, :math:`\mu`) solve of
:mod:`physar.ar.project_pipeline` as rows :math:`(P(x_k + u_k(\mu)) - f^*_k) / \sigma_f`, beside the dots'
rows; :math:`\sigma_f` is set from the features' own residuals relative to the dots' (see
:class:`GroupSigma`). A feature's error with the material point fixed in the reference frame is drift free:
the reference view is never replaced while enough features are tracked.
"""
from __future__ import annotations

import cv2
import numpy as np

from physar.errors import PhysarError
from physar.vision.camera import Pose
from physar.vision.observation import surface_observation_matrix


def ray_triangle(origin: np.ndarray, dirs: np.ndarray, tri: np.ndarray):
    r"""First hits of rays on triangles (Möller-Trumbore, vectorised over rays × triangles).

    ``origin`` (3,), ``dirs`` (r, 3), ``tri`` (k, 3, 3) -> (index (r,) of the nearest triangle hit with
    :math:`t > 0`, -1 if none; barycentrics (r, 3) :math:`(1 - \beta - \gamma, \beta, \gamma)` of the hit;
    ray parameter t (r,)): the hit point is :math:`o + t\, d = \sum_j b_j T_j`."""
    A, B, C = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = B - A, C - A                                    # (k, 3)
    p = np.cross(dirs[:, None, :], e2[None])                 # (r, k, 3)
    det = np.einsum("rkj,kj->rk", p, e1)
    ok = np.abs(det) > 1e-30
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin[None] - A                                     # (k, 3)
    beta = np.einsum("rkj,kj->rk", p, s) * inv
    q = np.cross(s[None], e1[None])[0]                       # (k, 3)
    gamma = np.einsum("rj,kj->rk", dirs, q) * inv
    t = np.einsum("kj,kj->k", e2, q)[None] * inv
    hit = ok & (beta >= 0) & (gamma >= 0) & (beta + gamma <= 1) & (t > 0)
    t = np.where(hit, t, np.inf)
    idx = np.argmin(t, axis=1)
    r = np.arange(len(dirs))
    tb = t[r, idx]
    idx = np.where(np.isfinite(tb), idx, -1)
    bary = np.stack([1 - beta[r, idx] - gamma[r, idx], beta[r, idx], gamma[r, idx]], 1)
    return idx, bary, tb


class GroupSigma:
    r"""The noise of a group of image observations relative to a reference group, from their own residuals.

    Each frame adds both groups' RMS residuals [px]; :meth:`sigma` returns
    :math:`\sigma_g = \sigma_\mathrm{ref}\, \mathrm{median}(r_g) / \mathrm{median}(r_\mathrm{ref})` over the last
    ``window`` frames (``start`` before ``min_frames`` frames): a group whose rows fit worse (tracking noise,
    model error where it looks) weighs less, and the reference group's configured sigma keeps its meaning."""

    def __init__(self, start: float, window: int = 30, min_frames: int = 3, floor: float = 0.25):
        self.start, self.window, self.min_frames, self.floor = float(start), window, min_frames, floor
        self.ratios: list[float] = []

    def add(self, rms_group: float, rms_ref: float) -> None:
        if np.isfinite(rms_group) and np.isfinite(rms_ref) and rms_ref > 0:
            self.ratios.append(rms_group / rms_ref)
            del self.ratios[:-self.window]

    def sigma(self, sigma_ref: float) -> float:
        if len(self.ratios) < self.min_frames:
            return self.start
        return sigma_ref * max(float(np.median(self.ratios)), self.floor)

    def reset(self) -> None:
        self.ratios = []


class SurfacePoints:
    """Texture features of the project's ``[features]`` face, tracked as image points (see the module doc)."""

    def __init__(self, project):
        f = project.config.features
        self.cfg, self.camera, self.rom = f, project.camera, project.rom
        self.space = space = self.rom.space()
        self.n_target = f.points or 80
        self.win = int(f.window_px)
        o, eu, ev = (np.asarray(v, float) for v in (f.origin, f.u, f.v))
        eu, ev = eu / np.linalg.norm(eu), ev / np.linalg.norm(ev)
        n = np.cross(eu, ev)
        L = np.asarray(f.size, float)
        surf = space.mesh.boundary()
        X, faces = surf.mesh.points, surf.mesh.faces
        T = X[faces]
        d = T.mean(1) - o
        a, b, h = d @ eu, d @ ev, d @ n
        fn = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        tol = 1e-4 + 1e-3 * float(L.max())
        sel = ((np.abs(h) < tol) & (np.abs(fn @ n) > 0.99) & (a > -tol) & (a < L[0] + tol)
               & (b > -tol) & (b < L[1] + tol))
        if not sel.any():
            raise PhysarError(f"[features]: no boundary face of the model lies on the face origin "
                              f"{list(f.origin)}, u {list(f.u)}, v {list(f.v)}, size {list(f.size)} m "
                              f"(tol {tol:.2g} m)")
        self.T0 = T[sel]                                                        # (k, 3, 3) reference
        self.face_idx = np.flatnonzero(sel)                                     # into the boundary's faces
        F = self.rom.F.reshape(self.rom.n_modes, -1, 3)
        self.TU = np.ascontiguousarray(F[:, surf.node_map[faces[sel]]])          # (modes, k, 3, 3)
        self.eu, self.ev = eu, ev
        self.points = None          # (n, 3) material points
        self.Fp = None              # (modes, n, 3)
        self.ref = None             # reference gray image
        self.f0 = None              # (n, 2) reference pixels
        self.valid_fraction = 1.0

    @property
    def ready(self) -> bool:
        return self.points is not None

    def positions(self, c: np.ndarray) -> np.ndarray:
        """Deformed positions (n, 3) [m] of the features for mode coefficients c."""
        return self.points + np.tensordot(c, self.Fp, 1)

    def set_reference(self, gray: np.ndarray, pose: Pose, c: np.ndarray, avoid_px=None, avoid_r=None) -> int:
        """Choose the features in this frame (the object deformed by mode coefficients c, seen with ``pose``);
        ``avoid_px`` (m, 2) / ``avoid_r`` (m,): image discs to leave out (the dots). Returns how many."""
        cam = self.camera
        Td = self.T0 + np.tensordot(c, self.TU, 1)                               # (k, 3, 3) deformed
        Xc = Td @ pose.R.T + pose.t
        nrm = np.cross(Xc[:, 1] - Xc[:, 0], Xc[:, 2] - Xc[:, 0])
        vis = (np.einsum("kj,kj->k", nrm, Xc.mean(1)) < 0) & np.all(Xc[..., 2] > 0, axis=1)
        if not vis.any():
            return 0
        Td = Td[vis]
        q = cam.project(Td.reshape(-1, 3), pose).reshape(-1, 3, 2)
        h, w = gray.shape[:2]
        mask = np.zeros((h, w), np.uint8)
        for tri in np.round(q * 16).astype(np.int32):
            cv2.fillConvexPoly(mask, tri, 255, cv2.LINE_8, 4)
        k = self.win // 2 + 2
        mask = cv2.erode(mask, np.ones((2 * k + 1, 2 * k + 1), np.uint8))
        if avoid_px is not None:
            for (x, y), r in zip(np.asarray(avoid_px, float), np.asarray(avoid_r, float)):
                if np.isfinite(x) and np.isfinite(y):
                    cv2.circle(mask, (round(x), round(y)), int(np.ceil(2.5 * r + k)), 0, -1)
        area = float(np.count_nonzero(mask))
        if area < 4 * self.n_target:
            return 0
        md = max(0.6 * np.sqrt(area / self.n_target), 3.0)
        pts = cv2.goodFeaturesToTrack(gray, self.n_target, 0.01, md, mask=mask, blockSize=5)
        if pts is None or len(pts) < 3:
            return 0
        px = pts.reshape(-1, 2).astype(float)
        ray = cv2.undistortPoints(px.reshape(-1, 1, 2), cam.K, np.asarray(cam.dist, float)).reshape(-1, 2)
        dirs = np.column_stack([ray, np.ones(len(ray))]) @ pose.R                # camera -> object frame
        origin = -pose.R.T @ pose.t
        idx, bary, _ = ray_triangle(origin, dirs, Td)
        hit = idx >= 0
        if hit.sum() < 3:
            return 0
        T0v = self.T0[vis][idx[hit]]
        x = np.einsum("nj,njd->nd", bary[hit], T0v)
        C = surface_observation_matrix(self.space, x, components=(0, 1, 2), tol=1e-6, faces=self.face_idx)
        self.Fp = np.asarray(C @ self.rom.F.T).T.reshape(self.rom.n_modes, -1, 3)
        self.points = x
        self.count = np.ones(len(x))
        self.f0 = np.ascontiguousarray(px[hit], np.float32)
        self.ref = gray.copy()
        self.valid_fraction = 1.0
        return len(x)

    def track(self, gray: np.ndarray, pose: Pose, c: np.ndarray, fb_px: float = 0.5):
        """Tracked pixels (n, 2) and their validity (n,): Lucas-Kanade from the reference view, started at
        the pixels predicted by the model (coefficients c) and the frame's pose; a feature whose
        backward track misses its reference pixel by more than ``fb_px`` is dropped."""
        n = len(self.points)
        px = np.full((n, 2), np.nan)
        pred = self.camera.project(self.positions(c), pose)
        h, w = gray.shape[:2]
        inside = np.all(np.isfinite(pred), 1) & (pred[:, 0] > 0) & (pred[:, 1] > 0) & (pred[:, 0] < w - 1) & (
            pred[:, 1] < h - 1)
        if inside.sum() < 4:                    # (a homography needs four)
            self.valid_fraction = 0.0
            return px, np.zeros(n, bool)
        # the reference view warped to this frame by the homography that best maps the features' reference
        # pixels to their predicted ones (the face seen from the new pose, moved by the model): Lucas-Kanade
        # then compares patches seen alike (a translational LK window on a patch turned or foreshortened by
        # the new view drifts by a fraction of a pixel)
        H, _ = cv2.findHomography(self.f0[inside].astype(np.float64), pred[inside].astype(np.float64), 0)
        if H is None or not np.all(np.isfinite(H)):
            H = np.eye(3)
        m = self.win + 8
        x0, y0 = (np.maximum(np.floor(pred[inside].min(0)) - m, 0)).astype(int)
        x1, y1 = np.minimum(np.ceil(pred[inside].max(0)) + m, [w, h]).astype(int)
        T = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]])
        a = cv2.warpPerspective(self.ref, T @ H, (int(x1 - x0), int(y1 - y0)), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE)
        b = gray[y0:y1, x0:x1]
        off = np.array([x0, y0], np.float32)
        p0 = cv2.perspectiveTransform(self.f0[inside].reshape(-1, 1, 2).astype(np.float64), T @ H).astype(np.float32)
        p1 = (pred[inside].astype(np.float32) - off).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01)
        win = (self.win, self.win)
        p1, st1, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, p1.copy(), winSize=win, maxLevel=2, criteria=crit,
                                              flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        pb, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, p0.copy(), winSize=win, maxLevel=2, criteria=crit,
                                              flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm((pb - p0).reshape(-1, 2), axis=1) < fb_px)
        idx = np.flatnonzero(inside)
        px[idx] = p1.reshape(-1, 2) + off
        valid = np.zeros(n, bool)
        valid[idx[ok]] = True
        self.valid_fraction = float(valid.mean())
        return px, valid

    def refine(self, pose: Pose, c: np.ndarray, px: np.ndarray, valid: np.ndarray, frames: int = 30) -> None:
        r"""Average each feature's material point over its first ``frames`` frames: the point that puts the
        feature on its tracked pixel with this frame's estimate (pose, coefficients c), moved within the face
        (along :math:`e_u, e_v`, first order: :math:`\Delta = -J^{-1} r`, J the 2x2 derivative of the pixel
        along the face, r the pixel residual), enters a running mean. One frame's estimate error would
        otherwise stay in every later frame as a bias (the features measure motion relative to the frame
        where they were placed)."""
        k = np.flatnonzero(valid & (self.count < frames))
        if k.size == 0:
            return
        X = self.positions(c)[k]
        h = 1e-4
        q = self.camera.project(np.vstack([X, X + h * self.eu, X + h * self.ev]), pose).reshape(3, -1, 2)
        J = np.stack([(q[1] - q[0]) / h, (q[2] - q[0]) / h], -1)                  # (k, 2, 2) px per m
        r = q[0] - px[k]
        ok = np.abs(np.linalg.det(J)) > 1e-12 * np.max(np.abs(J)) ** 2
        d = np.zeros((k.size, 2))
        d[ok] = -np.linalg.solve(J[ok], r[ok][..., None])[..., 0]
        w = 1.0 / (self.count[k] + 1)
        self.points[k] += (w * d[:, 0])[:, None] * self.eu + (w * d[:, 1])[:, None] * self.ev
        self.count[k] += 1

    def reset(self) -> None:
        """Forget the reference (a new stream: another view)."""
        self.points = self.Fp = self.ref = self.f0 = None


__all__ = ["GroupSigma", "SurfacePoints", "ray_triangle"]
