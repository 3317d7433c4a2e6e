r"""Deformation observed on the object's own texture, without fiducials (seed 000 §5.2, "some existing pattern
in the solid").

The project's ``[features]`` face is a planar face of the object: :math:`X = o + a e_u + b e_v`,
:math:`a \in [0, L_u]`, :math:`b \in [0, L_v]`. With each frame's pose the face (and a band around it) is
rectified at about the image's own scale. The first ``reference_frames`` frames show the object at rest
(:math:`u = 0`): their rectified views are averaged into the reference view, whose ORB keypoints (one per grid
bucket, inside the face) become the tracked material points :math:`x_k`; optionally (``ends``) the face's two
ends along :math:`e_u` are located in the averaged colour view (where each column's mean colour crosses halfway
between the surroundings' and the face's) and correct the material coordinates for a pose error of the
registration frame (measured on the foam scene: 1.26 instead of 1.53 mm mean on the old specialised
renderer's clip; 1.82 instead of 1.15 mm on the test-data renderer's clip, where the detected ends lay 1.5 px
too close together: off by default). Each later frame: pyramidal Lucas-Kanade from the reference view with a
forward-backward check gives the in-plane displacements :math:`y_k = (u \cdot e_u,\ u \cdot e_v)(x_k)`, and

.. math::

    \mu^* = \arg\min_\mu \min_{a, n} \| P (y - a\, C u(\mu) - N n) \|^2 \qquad \text{(seed 000 Eq. (2))}

with :math:`C` the surface observation operator at the :math:`x_k` projected on :math:`(e_u, e_v)`,
:math:`u(\mu) = \sum_m c_m(\mu) F_m` the reduced model, :math:`a` a free amplitude (``free_scale``: a stiffness
error of the model does not bias :math:`\mu`; else :math:`a = 1`) and :math:`N` the apparent in-plane motion of
the whole face (``nuisance``: rigid, similarity or affine; a pose error between the registration plane and the
face), projected out (variable projection). The cost is a quadratic form in the mode coefficients
:math:`c(\mu)`, evaluated on a fine grid of the parameter box (global: no local minima) and refined by a
parabola through the best grid point and its neighbours along each parameter;
:math:`\operatorname{sd}(\mu^*)^2 = 2 \sigma^2 / \mathrm{cost}''` with
:math:`\sigma^2 = \mathrm{cost}(\mu^*) / (m - p)` (Gauss-Newton covariance of seed 000 §4).
Features farther than 4 robust :math:`\sigma` from the fitted field (locked onto a wrong pore) are dropped, the
fit is repeated, and they are re-seeded from the model's prediction.
"""
from __future__ import annotations

import cv2
import numpy as np

from physar.errors import PhysarError
from physar.vision.camera import Pose


class FeatureObserver:
    """Texture features of one face of a project's object (see the module doc)."""

    def __init__(self, project):
        from physar.vision.markerless import PlaneTextureTracker  # noqa: F401  (checked import)

        f = project.config.features
        self.cfg, self.camera, self.rom = f, project.camera, project.rom
        self.space = self.rom.space()
        o, eu, ev = (np.asarray(v, float) for v in (f.origin, f.u, f.v))
        self.o, self.eu, self.ev = o, eu / np.linalg.norm(eu), ev / np.linalg.norm(ev)
        self.L = np.asarray(f.size, float)
        self.margin = f.margin if f.margin is not None else 0.25 * float(self.L.min())
        self.tracker = None
        self._refs, self._refs_col = [], []
        self.points = None
        self.registration: dict = {}
        rom = self.rom
        p = rom.n_params
        n_grid = {1: 601, 2: 61}.get(p, 21)
        self.grids = [np.linspace(a, b, n_grid) for a, b in rom.ranges]
        mus = np.stack(np.meshgrid(*self.grids, indexing="ij"), -1).reshape(-1, p)
        self.mu_grid = mus
        self.c_grid = np.array([rom.coefficients(m)[0] for m in mus])      # (G, modes)
        self.scale = float("nan")

    # -- reference ---------------------------------------------------------------------------------------
    def _make_tracker(self, pose: Pose):
        from physar.vision.markerless import PlaneTextureTracker

        m = self.margin
        centre = self.o + 0.5 * self.L[0] * self.eu + 0.5 * self.L[1] * self.ev
        dist = float(pose.apply(centre[None])[0, 2])
        s = self.camera.fx / max(dist, 1e-6)
        self.tracker = PlaneTextureTracker(self.camera, self.o - m * self.eu - m * self.ev, self.eu, self.ev,
                                           (self.L[0] + 2 * m, self.L[1] + 2 * m), s, n_points=self.cfg.points or 600,
                                           win=self.cfg.window_px)

    def add_reference(self, frame: np.ndarray, gray: np.ndarray, pose: Pose) -> bool:
        """Collect a reference frame (object at rest); True once the reference is set."""
        if self.tracker is None:
            self._make_tracker(pose)
        self._refs.append(self.tracker.rectify(gray, pose))
        self._refs_col.append(self.tracker.rectify(frame, pose))
        if len(self._refs) >= self.cfg.reference_frames:
            self._set_reference()
            return True
        return False

    @staticmethod
    def _crossing(t, c_expected, half, rising: bool):
        """Sub-pixel column where the face score t (0 outside, 1 on the face) crosses 1/2 nearest c_expected
        within +- half (None if it does not)."""
        lo, hi = max(int(c_expected - half), 0), min(int(c_expected + half), len(t) - 2)
        if not rising:
            t = 1.0 - t
        k = np.flatnonzero((t[lo:hi] < 0.5) & (t[lo + 1:hi + 1] >= 0.5)) + lo
        if k.size == 0:
            return None
        k = int(k[np.argmin(np.abs(k + 0.5 - c_expected))])
        return k + (0.5 - t[k]) / (t[k + 1] - t[k])

    def _ends(self, ref_col) -> tuple[float, float]:
        """Affine map (gain, offset) from rectified a-coordinates to material ones, from the face's two ends
        along e_u in the averaged colour view (identity where they are not found). Each column's mean colour
        (rows within the face) is scored between the surroundings' colour (0) and the face's (1): the texture
        averages out, and an end is where the score crosses 1/2."""
        s, m, L = self.tracker.s, self.margin, self.L
        img = np.asarray(ref_col, np.float32)
        band = img[int((m + 0.2 * L[1]) * s):int((m + 0.8 * L[1]) * s)]
        prof = cv2.GaussianBlur(band.mean(0)[None], (0, 0), 1.0)[0]          # (w, 3) mean colour per column
        w = len(prof)
        xl0, xr0 = m * s - 0.5, (m + L[0]) * s - 0.5
        face = np.median(prof[int(xl0 + 0.1 * L[0] * s):int(xr0 - 0.1 * L[0] * s)], axis=0)
        half = max(0.015 * s, 3.0)
        ends = []
        for x0, side in ((xl0, slice(0, max(int(xl0 - half), 1))), (xr0, slice(min(int(xr0 + half), w - 1), w))):
            out = np.median(prof[side], axis=0)
            d = face - out
            if not float(d @ d) > 20.0 ** 2:                     # too little colour contrast to see the end
                ends.append(None)
                continue
            t = (prof - out) @ d / float(d @ d)
            ends.append(self._crossing(t, x0, half, rising=x0 == xl0))
        xl, xr = ends
        gain, off = 1.0, -m
        if xl is not None and xr is not None and abs((xr - xl) / s / L[0] - 1) < 0.02:
            a0, a1 = (xl + 0.5) / s, (xr + 0.5) / s
            gain, off = L[0] / (a1 - a0), -a0 * L[0] / (a1 - a0)
        self.registration = {"ends_px": [None if xl is None else float(xl), None if xr is None else float(xr)],
                             "a_map": [float(gain), float(off)]}
        return gain, off

    def _set_reference(self):
        from physar.vision.observation import surface_observation_matrix

        tr = self.tracker
        w, h = tr.size
        mask = np.zeros((h, w), np.uint8)
        m = self.margin
        inset = (tr.win[0] // 2 + 2) / tr.s + 0.003
        r0, r1 = int((m + inset) * tr.s), int((m + self.L[1] - inset) * tr.s)
        c0, c1 = int((m + inset) * tr.s), int((m + self.L[0] - inset) * tr.s)
        if r1 <= r0 or c1 <= c0:
            raise PhysarError("[features]: the face is too small in the image to track its texture")
        mask[r0:r1, c0:c1] = 255
        ab = tr.set_reference(self._refs, mask)
        gain, off = self._ends(np.mean(self._refs_col, axis=0)) if self.cfg.ends else (1.0, -m)
        self._refs, self._refs_col = [], []
        a = np.clip(gain * ab[:, 0] + off, 0, self.L[0])
        b = np.clip(ab[:, 1] - m, 0, self.L[1])
        self.points = self.o + a[:, None] * self.eu + b[:, None] * self.ev
        self.ab = np.column_stack([a, b])
        C = surface_observation_matrix(self.space, self.points, components=(0, 1, 2)).tocsr()
        F3 = np.asarray(C @ self.rom.F.T).reshape(len(a), 3, -1)              # (n, 3, modes)
        self.CF = np.stack([np.einsum("k,nkm->nm", self.eu, F3), np.einsum("k,nkm->nm", self.ev, F3)],
                           1).reshape(2 * len(a), -1)                           # (2 n, modes)

    @property
    def ready(self) -> bool:
        return self.points is not None

    # -- estimation --------------------------------------------------------------------------------------
    def _nuisance_basis(self, valid) -> np.ndarray:
        """(2 n, k): apparent in-plane motions of all points (centred on the valid ones)."""
        p = self.ab
        ac, bc = p[:, 0] - p[valid, 0].mean(), p[:, 1] - p[valid, 1].mean()
        kind = self.cfg.nuisance
        N = np.zeros((2 * len(p), {"rigid": 3, "similarity": 4, "affine": 6}[kind]))
        N[0::2, 0], N[1::2, 1] = 1.0, 1.0
        if kind == "affine":
            N[0::2, 2], N[0::2, 3], N[1::2, 4], N[1::2, 5] = ac, bc, ac, bc
        else:
            N[0::2, 2], N[1::2, 2] = -bc, ac
            if kind == "similarity":
                N[0::2, 3], N[1::2, 3] = ac, bc
        return N

    def _estimate(self, y, valid):
        rows = np.flatnonzero(np.repeat(valid, 2))
        A, yv = self.CF[rows], y[rows]
        k_nuis = 0
        if self.cfg.nuisance != "none":
            Q, _ = np.linalg.qr(self._nuisance_basis(valid)[rows])
            yv = yv - Q @ (Q.T @ yv)
            A = A - Q @ (Q.T @ A)
            k_nuis = Q.shape[1]
        Aty, AtA, yy = A.T @ yv, A.T @ A, float(yv @ yv)
        num = self.c_grid @ Aty
        den = np.einsum("si,ij,sj->s", self.c_grid, AtA, self.c_grid)
        if self.cfg.free_scale:
            cost = yy - np.where(num > 0, num ** 2 / np.maximum(den, 1e-300), 0.0)
        else:
            cost = yy - 2 * num + den
        shape = tuple(len(g) for g in self.grids)
        C = cost.reshape(shape)
        idx = list(np.unravel_index(int(np.argmin(cost)), shape))
        p = len(shape)
        mu, std = np.empty(p), np.empty(p)
        cmin = float(C[tuple(idx)])
        dof = max(len(yv) - p - int(self.cfg.free_scale) - k_nuis, 1)
        for j in range(p):           # parabola through the best grid point and its neighbours along each axis
            k = int(np.clip(idx[j], 1, shape[j] - 2))
            h = self.grids[j][1] - self.grids[j][0]
            ii = list(idx)
            vals = []
            for dk in (-1, 0, 1):
                ii[j] = k + dk
                vals.append(float(C[tuple(ii)]))
            c0, c1, c2 = vals
            curv = (c0 - 2 * c1 + c2) / h ** 2
            d = float(np.clip(0.5 * (c0 - c2) / (c0 - 2 * c1 + c2), -1, 1)) if curv > 0 else 0.0
            mu[j] = float(np.clip(self.grids[j][k] + d * h, self.grids[j][0], self.grids[j][-1]))
            cj = max(c1 - 0.25 * (c0 - c2) * d, 0.0)
            cmin = min(cmin, cj)
            std[j] = np.sqrt(2 * max(cj, 1e-30) / dof / curv) if curv > 0 else np.nan
        g = int(np.ravel_multi_index(tuple(idx), shape))
        scale = num[g] / den[g] if den[g] > 0 else np.nan
        return mu, std, float(np.sqrt(cmin)), float(scale)

    def _predict(self, mu, y, valid) -> np.ndarray:
        c = self.rom.coefficients(mu)[0]
        a = self.scale if self.cfg.free_scale and np.isfinite(self.scale) else 1.0
        pred = a * (self.CF @ c)
        if self.cfg.nuisance != "none":
            N = self._nuisance_basis(valid)
            rows = np.flatnonzero(np.repeat(valid, 2))
            th = np.linalg.lstsq(N[rows], (y - pred)[rows], rcond=None)[0]
            pred = pred + N @ th
        return pred

    def update(self, gray: np.ndarray, pose: Pose, min_fraction: float = 0.3):
        """-> (status, mu, std, residual rms [m], features used): status tracking | rest | hold."""
        p = self.rom.n_params
        nan = np.full(p, np.nan)
        d, ok, _ = self.tracker.update(gray, pose)
        n = int(ok.sum())
        y = d.ravel()                                        # (a, b) displacement per point
        if n < max(3, min_fraction * len(ok)):
            return "hold", nan, nan, float("nan"), n
        if np.sqrt(np.mean(d[ok] ** 2) * 2) < self.cfg.rest_mm * 1e-3:
            return "rest", nan, nan, float("nan"), n
        mu, std, res, self.scale = self._estimate(y, ok)
        pred = self._predict(mu, y, ok)
        r = np.linalg.norm((y - pred).reshape(-1, 2), axis=1)
        sig = 1.4826 * np.median(r[ok])
        bad = ok & (r > max(4 * sig, 0.5e-3))
        if bad.any() and (ok & ~bad).sum() >= max(3, min_fraction * len(ok)):
            ok = ok & ~bad
            mu, std, res, self.scale = self._estimate(y, ok)
            pred = self._predict(mu, y, ok)
        reseed = ~ok                                          # lost or wrong features restart from the model
        self.tracker.flow[reseed, 0, :] = pred.reshape(-1, 2)[reseed] * self.tracker.s
        n = int(ok.sum())
        return "tracking", mu, std, res / np.sqrt(max(n, 1)), n

    def reset(self):
        if self.tracker is not None and self.tracker.ref is not None:
            self.tracker.reset()


__all__ = ["FeatureObserver"]
