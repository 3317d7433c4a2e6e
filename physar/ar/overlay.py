"""Augmented overlay (seed 000 §5.1, Fig. 7): the reduced model's deformed mesh drawn on the object,
coloured by |u| or von Mises stress with a colour bar, an arrow at the estimated load and the estimate
± its standard deviation as text.

The fields are linear in the mode coefficients c(mu): u = Σ c_i F_i and σ = Σ c_i σ(F_i), so the
per-mode front-face displacements and nodal stresses are precomputed and each frame costs a few small
matrix products; von Mises is sqrt(3/2 s:s) with s the deviatoric part of σ.
"""
from __future__ import annotations

import cv2
import numpy as np

from physar.vision.camera import Camera, Pose

_FONT = cv2.FONT_HERSHEY_SIMPLEX


def turbo_lut(n: int = 64) -> np.ndarray:
    """(n, 3) BGR uint8 colours of OpenCV's TURBO colormap."""
    ramp = np.linspace(0, 255, n).astype(np.uint8).reshape(-1, 1)
    return cv2.applyColorMap(ramp, cv2.COLORMAP_TURBO).reshape(n, 3)


class BeamOverlay:
    """Draws the reduced model of a box-shaped object (front face y = 0) for one frame.

    ``field``: "u" (|u| in mm) or "von_mises" (MPa). ``exaggeration`` scales the drawn deformation.
    """

    def __init__(self, space, model, obj, field: str = "von_mises", exaggeration: float = 1.0, levels: int = 48,
                 refine: int = 4):
        from physar.fem import ElasticModel, LinearElastic
        from physar.fem.post import cauchy_stress, nodal_average

        self.obj, self.field, self.exag, self.levels = obj, field, exaggeration, levels
        self.model = model
        pts = space.mesh.points
        front = np.flatnonzero(np.abs(pts[:, 1]) < 1e-12)
        xs, zs = np.unique(pts[front, 0].round(12)), np.unique(pts[front, 2].round(12))
        order = np.lexsort((pts[front, 0], pts[front, 2]))
        grid = front[order].reshape(zs.size, xs.size)  # vertex ids (nz, nx)
        self.xs, self.zs = xs, zs
        F = model.F.reshape(model.n_modes, -1, 3)
        Fg = F[:, grid]  # (n_modes, nz, nx, 3)
        # refine along x for smooth colours (linear interpolation of the vertex values)
        self.xf = np.linspace(xs[0], xs[-1], (xs.size - 1) * refine + 1)
        interp = np.zeros((self.xf.size, xs.size))
        idx = np.clip(np.searchsorted(xs, self.xf) - 1, 0, xs.size - 2)
        a = (self.xf - xs[idx]) / (xs[idx + 1] - xs[idx])
        interp[np.arange(self.xf.size), idx] = 1 - a
        interp[np.arange(self.xf.size), idx + 1] = a
        self.Fg = np.einsum("fx,mzxc->mzfc", interp, Fg)  # (n_modes, nz, nxf, 3)
        if field == "von_mises":
            em = ElasticModel(space, LinearElastic(obj.E, obj.nu))
            S = []
            for Fi in model.F:
                sig = cauchy_stress(em, Fi)
                S.append(nodal_average(space, sig.reshape(len(sig), 9))[grid])  # (nz, nx, 9)
            self.S = np.einsum("fx,mzxc->mzfc", interp, np.array(S))  # (n_modes, nz, nxf, 9)
        elif field != "u":
            raise ValueError(f"overlay field must be 'u' or 'von_mises', got {field!r}")
        # colour scale: the largest value over the parameter range (98th percentile of each field, so the
        # contact stress right under the regularised point load does not wash out the bending stresses)
        lo_hi = model.ranges
        samples = np.stack(np.meshgrid(*[np.linspace(a, b, 41) for a, b in lo_hi], indexing="ij"), -1).reshape(
            -1, len(lo_hi))
        self.vmax = max(float(np.percentile(self.values(model.coefficients(mu)[0]), 98)) for mu in samples) or 1.0
        self.lut = turbo_lut(levels)
        self.unit = "MPa" if field == "von_mises" else "mm"
        self.label = "von Mises stress" if field == "von_mises" else "|u|"
        self._bar = None

    def values(self, c: np.ndarray) -> np.ndarray:
        """Field on the refined front-face grid (nz, nxf) in display units (mm or MPa)."""
        if self.field == "u":
            u = np.tensordot(c, self.Fg, 1)
            return np.linalg.norm(u, axis=-1) * 1e3
        s = np.tensordot(c, self.S, 1).reshape(*self.S.shape[1:3], 3, 3)
        dev = s - np.trace(s, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) / 3
        return np.sqrt(1.5 * np.einsum("...ij,...ij->...", dev, dev)) * 1e-6

    def _colour_bar(self, h: int) -> np.ndarray:
        bh = int(0.45 * h)
        if self._bar is None or self._bar.shape[0] != bh:
            ramp = np.linspace(255, 0, bh).astype(np.uint8).reshape(-1, 1)
            bar = cv2.applyColorMap(np.repeat(ramp, 18, 1), cv2.COLORMAP_TURBO)
            self._bar = bar
        return self._bar

    def _strips(self, lev: np.ndarray) -> list:
        """Runs of equal colour level along each row of cells: [(level, row, first cell, end cell)]. A run
        is drawn as one polygon (the union of its quads), so the painter fills a few dozen polygons instead
        of one per cell and no anti-aliased seams appear between cells of the same colour."""
        out = []
        for r, row in enumerate(lev):
            cut = np.flatnonzero(np.diff(row)) + 1
            starts, ends = np.r_[0, cut], np.r_[cut, row.size]
            out += [(int(row[a]), r, int(a), int(b)) for a, b in zip(starts, ends)]
        return out

    def draw(self, img: np.ndarray, camera: Camera, pose: Pose, c: np.ndarray, mu: np.ndarray, std: np.ndarray,
             status: str, info: dict, values: np.ndarray | None = None) -> np.ndarray:
        """Draw onto `img` (BGR uint8, modified in place) and return it. ``values``: :meth:`values` of c when
        the caller has computed them already."""
        h, w = img.shape[:2]
        o = self.obj
        if pose is not None and status != "lost":
            u = np.tensordot(c, self.Fg, 1) * self.exag  # (nz, nxf, 3)
            if getattr(self, "_P0", None) is None:  # undeformed front-face grid (nz, nxf, 3)
                X = np.stack(np.meshgrid(self.xf, self.zs), -1)  # (nz, nxf, 2) (x, z)
                self._P0 = np.stack([X[..., 0], np.zeros_like(X[..., 0]), X[..., 1]], -1)
            P3 = self._P0 + u
            p = camera.project(P3.reshape(-1, 3), pose).reshape(*P3.shape[:2], 2)
            vals = self.values(c) if values is None else values
            q = 0.25 * (vals[:-1, :-1] + vals[1:, :-1] + vals[:-1, 1:] + vals[1:, 1:])
            lev = np.clip((q / self.vmax * (self.levels - 1)).round().astype(int), 0, self.levels - 1)
            lo = np.floor(p.reshape(-1, 2).min(0)).astype(int) - 3
            hi = np.ceil(p.reshape(-1, 2).max(0)).astype(int) + 3
            x0, y0 = max(lo[0], 0), max(lo[1], 0)
            x1, y1 = min(hi[0], w), min(hi[1], h)
            if x1 > x0 and y1 > y0:
                roi = img[y0:y1, x0:x1]
                layer = roi.copy()
                pi = np.round((p - (x0, y0)) * 16).astype(np.int32)  # 4 fractional bits
                polys = {}
                for L, r, a, b in self._strips(lev):  # top edge left to right, bottom edge back
                    polys.setdefault(L, []).append(np.concatenate([pi[r, a:b + 1], pi[r + 1, b:a - 1 if a else None:-1]]))
                for L, pl in polys.items():
                    cv2.fillPoly(layer, pl, tuple(int(v) for v in self.lut[L]), cv2.LINE_AA, shift=4)
                # element edges of the reduced model's mesh (vertex grid)
                step = (self.xf.size - 1) // (self.xs.size - 1)
                edges = list(pi) + list(pi[:, ::step].transpose(1, 0, 2).copy())
                cv2.polylines(layer, edges, False, (40, 40, 40), 1, cv2.LINE_AA, shift=4)
                cv2.addWeighted(layer, 0.7, roi, 0.3, 0, dst=roi)
            # arrow at the estimated load position
            s = float(mu[0])
            uz = float(np.interp(s, self.xf, u[-1, :, 2]))
            tip = camera.project([[s, 0.0, o.height + uz]], pose)[0]
            tail = camera.project([[s, 0.0, o.height + uz + 0.07]], pose)[0]
            cv2.arrowedLine(img, tuple(np.round(tail * 16).astype(int)), tuple(np.round(tip * 16).astype(int)),
                            (30, 30, 230), max(2, round(3 * h / 720)), cv2.LINE_AA, 4, 0.25)
            if np.isfinite(std[0]) and std[0] > 0:
                a = camera.project([[max(s - 2 * std[0], 0), 0, o.height + uz], [min(s + 2 * std[0], o.length), 0,
                                                                                    o.height + uz]], pose)
                cv2.line(img, tuple(np.round(a[0]).astype(int) - (0, 6)), tuple(np.round(a[1]).astype(int) - (0, 6)),
                         (30, 30, 230), 2, cv2.LINE_AA)
        self._hud(img, mu, std, status, info)
        return img

    def _hud(self, img, mu, std, status, info):
        h, w = img.shape[:2]
        sc = h / 720
        # text panel
        lines = []
        if status == "lost":
            lines.append(("no pose: markers not found", (80, 80, 255)))
        else:
            held = status != "tracking"
            lines.append((f"load position s = {mu[0] * 1e3:6.1f} +/- {2 * std[0] * 1e3:.1f} mm (2 sd)",
                          (255, 255, 255) if not held else (150, 200, 255)))
            if len(mu) > 1:
                lines.append((f"load P = {mu[1]:.1f} +/- {2 * std[1]:.1f} N", (255, 255, 255)))
            lines.append(((f"max {self.label} {info.get('field_max', float('nan')):.1f} {self.unit}, "
                           f"tip deflection {info.get('tip_mm', float('nan')):.2f} mm"), (230, 230, 230)))
        lines.append(((f"{status}: {info.get('markers', 0)} markers, {info.get('dots', 0)}/{info.get('dots_total', 0)} "
                       f"dots  |  frame {info.get('frame', 0)}  {info.get('latency_ms', 0):.1f} ms"), (200, 200, 200)))
        fs = 0.62 * sc
        lh = int(28 * sc)
        pw = int(640 * sc)
        ph = lh * len(lines) + int(14 * sc)
        x0, y0 = int(14 * sc), int(14 * sc)
        roi = img[y0:y0 + ph, x0:x0 + pw]
        cv2.addWeighted(roi, 0.35, np.zeros_like(roi), 0.65, 0, dst=roi)
        for k, (txt, col) in enumerate(lines):
            cv2.putText(img, txt, (x0 + int(10 * sc), y0 + int((k + 1) * lh)), _FONT, fs, col, 1, cv2.LINE_AA)
        # colour bar
        bar = self._colour_bar(h)
        bh, bw = bar.shape[:2]
        bx, by = w - bw - int(100 * sc), int(0.27 * h)
        panel = img[by - int(46 * sc):by + bh + int(16 * sc), bx - int(10 * sc):w - int(8 * sc)]
        cv2.addWeighted(panel, 0.35, np.zeros_like(panel), 0.65, 0, dst=panel)
        img[by:by + bh, bx:bx + bw] = bar
        for j, txt in enumerate((self.label, f"[{self.unit}]")):
            cv2.putText(img, txt, (bx - int(6 * sc), by - int((26 - 16 * j) * sc)), _FONT, 0.45 * sc,
                        (255, 255, 255), 1, cv2.LINE_AA)
        for k in range(5):
            v = self.vmax * k / 4
            yy = by + bh - 1 - int(k / 4 * (bh - 1))
            cv2.line(img, (bx + bw, yy), (bx + bw + 5, yy), (255, 255, 255), 1)
            cv2.putText(img, f"{v:.1f}" if self.vmax < 100 else f"{v:.0f}", (bx + bw + int(8 * sc), yy + 5),
                        _FONT, 0.45 * sc, (255, 255, 255), 1, cv2.LINE_AA)
