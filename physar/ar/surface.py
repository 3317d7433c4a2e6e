r"""The overlay of any object (seed 000 §5.1, Fig. 7): the reduced model's deformed surface drawn on the
video, coloured by a field (von Mises stress, |u| or a displacement component) with a colour bar, an
arrow at the estimated load and the estimates ± std.

The fields are linear in the mode coefficients :math:`c(\mu)`: :math:`u = \sum c_i F_i` and
:math:`\sigma = \sum c_i \sigma(F_i)`, so the per-mode displacements and stresses at the surface vertices are
precomputed (stress evaluated at each element's own vertices and averaged there,
:func:`physar.fem.post.nodal_stress`: element means read low where the stress varies across an element, as in
bending; README "What you can trust") and a frame costs a few small matrix products (von Mises
:math:`= \sqrt{\tfrac32\, s : s}`, :math:`s` the deviatoric part of :math:`\sigma`). The surface is drawn by
the painter's algorithm: faces turned away from the camera are culled, the others filled far to near.

Drawing costs about 1.8 µs per visible face (one polygon fill each), so a model meshed finely for accuracy
(11k surface triangles: 11 ms at 1280×720) would cost the frame rate. Above ``max_faces`` the surface drawn is
therefore a coarser, even triangulation of the model's surface (:func:`display_surface`,
:func:`physar.geometry.remesh.remesh_surface`) whose vertices carry the model's fields interpolated linearly
from the closest point of the model's surface (:math:`v_d = W v`, W the barycentric weights): the shape and
the colours are the model's, at the drawn triangles' resolution; the reported maximum is the model surface's.
"""
from __future__ import annotations

import cv2
import numpy as np

from physar.fem import ElasticModel, LinearElastic
from physar.fem.post import nodal_stress
from physar.vision.camera import Camera, Pose

_FONT = cv2.FONT_HERSHEY_SIMPLEX
UNITS = {"von_mises": ("von Mises", "MPa", 1e-6), "u": ("|u|", "mm", 1e3), "ux": ("u_x", "mm", 1e3),
         "uy": ("u_y", "mm", 1e3), "uz": ("u_z", "mm", 1e3)}


def turbo_lut(n: int = 64) -> np.ndarray:
    """(n, 3) BGR uint8 colours of OpenCV's TURBO colormap."""
    ramp = np.linspace(0, 255, n).astype(np.uint8).reshape(-1, 1)
    return cv2.applyColorMap(ramp, cv2.COLORMAP_TURBO).reshape(n, 3)


def surface_stress_modes(space, F, E: float, nu: float, nodes) -> np.ndarray:
    r"""Cauchy stress (n_modes, len(nodes), 3, 3) [Pa] of each displacement mode (rows of F, (n_modes,
    n_dofs)) at the mesh vertices ``nodes``, linear elasticity with (E [Pa], nu).

    Recovered by :func:`physar.fem.post.nodal_stress`:
    :math:`\sigma = \lambda \operatorname{tr}(\varepsilon)\, I + 2 \mu\, \varepsilon` with :math:`\varepsilon`
    evaluated at each element's own vertices from the shape-function gradients there, averaged over the
    elements sharing a vertex (weights: element volumes). Only the elements touching ``nodes`` are
    evaluated."""
    em = ElasticModel(space, LinearElastic(E, nu))
    return np.array([nodal_stress(em, Fi, nodes) for Fi in F])


def sampled_stress(rom, model, nodes, cell_scale=None, points: int | None = None):
    r"""(grids, values): the nodal von Mises stress [Pa] at the surface vertices ``nodes`` on a grid of the
    parameter box, from the reduced model's displacement :math:`u(\mu)` and the FE ``model``'s own material
    (Cauchy stress :math:`P F^\top / J`, so a nonlinear material, a rigid rotation or a Young's modulus region,
    via ``cell_scale(mu)``, are all right; :func:`physar.fem.post.nodal_stress`). The overlay interpolates it
    multilinearly in :math:`\mu`; stress is not linear in the mode coefficients for these models."""
    grids = [np.asarray(g, float) for g in getattr(rom, "grids", [])]
    if points is not None or len(grids) != rom.n_params or np.prod([len(g) for g in grids]) > 4000:
        n = points or {1: 33, 2: 9}.get(rom.n_params, 5)     # the model's own parameter grids when small enough
        grids = [np.linspace(a, b, n) for a, b in rom.ranges]   # (a modulus grid is geometric there)
    mus = np.stack(np.meshgrid(*grids, indexing="ij"), -1).reshape(-1, rom.n_params)
    vals = np.array([von_mises(nodal_stress(model, rom.evaluate(m), nodes,
                                            cell_scale=None if cell_scale is None else cell_scale(m))) for m in mus])
    return grids, vals.reshape(*[len(g) for g in grids], -1)


def von_mises(s: np.ndarray) -> np.ndarray:
    r""":math:`\sqrt{\tfrac32\, s : s}` of stresses (..., 3, 3), :math:`s` the deviatoric part."""
    dev = s - np.trace(s, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) / 3
    return np.sqrt(1.5 * np.einsum("...ij,...ij->...", dev, dev))


def display_surface(X: np.ndarray, faces: np.ndarray, max_faces: int, angle: float = 40.0):
    """(points (d, 3), faces (g, 3), W (d, v) sparse) of an even triangulation with about ``max_faces``
    triangles of the surface (X (v, 3), faces), or None when it has no more than ``max_faces`` already.

    :math:`W` holds the barycentric weights of each new vertex's closest point on the surface (exact
    point-triangle distance among the 12 triangles with the nearest centroids): a field :math:`v` at the
    surface's vertices is :math:`W v` at the new ones. New triangles are wound like the surface triangle
    closest to their centroid, so outward normals stay outward. Sharp edges (dihedral above ``angle`` degrees)
    are kept."""
    import scipy.sparse as sp
    from scipy.spatial import cKDTree

    from physar.geometry import TriMesh
    from physar.geometry.remesh import remesh_surface, size_for_faces
    from physar.vision.observation import closest_on_triangles

    faces = np.asarray(faces, np.int64)
    if max_faces <= 0 or len(faces) <= max_faces:
        return None
    surf = TriMesh(np.asarray(X, float), faces, name="model surface")
    h = size_for_faces(surf, max_faces)
    new = remesh_surface(surf, h, angle)
    for _ in range(3):                  # patch borders and thin sides take more triangles than the area says
        if new.n_faces <= 1.1 * max_faces:
            break
        h *= np.sqrt(new.n_faces / max_faces)
        new = remesh_surface(surf, h, angle)
    if new.n_faces >= 0.9 * len(faces):                 # no real saving (thin parts need their triangles)
        return None
    tri = surf.points[faces]
    tree = cKDTree(tri.mean(1))
    k = min(12, len(faces))

    def closest(q):
        _, cand = tree.query(q, k=k)
        cand = cand.reshape(len(q), k)
        f, lam, _ = closest_on_triangles(q, tri[cand])
        return cand[np.arange(len(q)), f], lam

    fid, lam = closest(new.points)
    W = sp.csr_matrix((lam.ravel(), (np.repeat(np.arange(new.n_points), 3), faces[fid].ravel())),
                      shape=(new.n_points, len(X)))
    g = new.faces.copy()
    near, _ = closest(new.points[g].mean(1))
    flip = np.einsum("ij,ij->i", new.face_normals(), surf.face_normals()[near]) < 0
    g[flip] = g[flip][:, ::-1]
    return new.points, g, W



def _peak(v: np.ndarray) -> float:
    """The value of largest magnitude, with its sign (the maximum of a non-negative field such as von Mises
    or |u|; for a displacement component the deflection, e.g. -2.97 mm, not the largest positive value)."""
    return float(v[int(np.argmax(np.abs(v)))]) if v.size else float("nan")

class SurfaceOverlay:
    """Draws a reduced model's deformed boundary surface for one frame.

    ``field``: von_mises | u | ux | uy | uz; ``vrange``: colour range in SI units (default 0 to the 98th
    percentile of the field's maximum over a grid of the parameter box); ``exaggeration`` scales the drawn
    displacement; ``alpha`` the surface's opacity; ``load_path``: (k, 3) polyline of the load position
    parameter (index ``load_param``), for the arrow; ``show``: indices of the parameters written;
    ``max_faces``: above this many surface triangles, a coarser even triangulation is drawn
    (:func:`display_surface`; 0: always the model's own surface)."""

    def __init__(self, rom, field: str = "von_mises", vrange=None, exaggeration: float = 1.0, alpha: float = 0.65,
                 material: tuple[float, float] | None = None, load_path=None, load_param: int | None = None,
                 load_dir=None, show=None, levels: int = 48, stress_table=None, max_faces: int = 3000):
        space = rom.space()
        surf = space.mesh.boundary()
        self.faces = surf.mesh.faces                       # (f, 3) into the drawn surface's vertices
        self.X0 = surf.mesh.points                          # (v, 3) reference positions of the drawn surface
        nodes = surf.node_map                               # volume vertex ids (P2: vertices come first)
        F = rom.F.reshape(rom.n_modes, -1, 3)
        self.U = np.ascontiguousarray(F[:, nodes])           # (modes, v, 3)
        self.X_model = self.X0                              # the model's surface vertices (where values() are)
        self.W = None                                      # model surface vertex field -> drawn vertices
        disp = display_surface(self.X0, self.faces, max_faces)
        if disp is not None:
            self.X0, self.faces, self.W = disp
            self._U_model = self.U
            self.U = np.ascontiguousarray(np.stack([self.W @ u for u in self.U]))
        self.field, self.exag, self.alpha = field, exaggeration, alpha
        self.rom = rom
        self.table = None
        if field == "von_mises" and stress_table is not None:   # sampled over the parameters (any material)
            from scipy.interpolate import RegularGridInterpolator

            grids, vals = stress_table
            self.table = RegularGridInterpolator(tuple(np.asarray(g, float) for g in grids), np.asarray(vals, float),
                                                 bounds_error=False, fill_value=None)
        elif field == "von_mises":
            if material is None:
                raise ValueError("von Mises overlay needs the material (E, nu)")
            self.S = surface_stress_modes(space, rom.F, *material, nodes)
        elif field not in UNITS:
            raise ValueError(f"overlay field must be one of {', '.join(UNITS)}, got {field!r}")
        self.label, self.unit, self.scale = UNITS[field]
        if vrange is None:  # 98th percentile over a grid of the parameter box (a point load's contact stress
            grids = [np.linspace(a, b, 9 if rom.n_params < 3 else 5) for a, b in rom.ranges]  # would wash out the rest)
            mus = np.stack(np.meshgrid(*grids, indexing="ij"), -1).reshape(-1, rom.n_params)
            top = max(float(np.percentile(np.abs(self.values(rom.coefficients(m)[0], m)), 98)) for m in mus) or 1.0
            vrange = (0.0, top) if field in ("von_mises", "u") else (-top, top)
        self.vrange = (float(vrange[0]), float(vrange[1]))
        self.lut = turbo_lut(levels)
        self._colours = [tuple(int(x) for x in col) for col in self.lut]
        self.levels = levels
        self.load_path = None if load_path is None else np.asarray(load_path, float)
        self.load_param = load_param
        self.load_dir = None if load_dir is None else np.asarray(load_dir, float) / np.linalg.norm(load_dir)
        self.show = list(range(rom.n_params)) if show is None else list(show)
        self._bar = None

    def values(self, c: np.ndarray, mu=None) -> np.ndarray:
        """The field (SI units) at the model's surface vertices for mode coefficients c (at parameters mu)."""
        if self.table is not None:
            lo = [g[0] for g in self.table.grid]
            hi = [g[-1] for g in self.table.grid]
            return self.table(np.clip(np.asarray(mu, float), lo, hi)[None])[0]
        if self.field == "von_mises":
            return von_mises(np.tensordot(c, self.S, 1))
        u = np.tensordot(c, self.U if self.W is None else self._U_model, 1)
        if self.field == "u":
            return np.linalg.norm(u, axis=1)
        return u[:, "xyz".index(self.field[1])]

    def _colour_bar(self, h: int) -> np.ndarray:
        bh = int(0.45 * h)
        if self._bar is None or self._bar.shape[0] != bh:
            ramp = np.linspace(255, 0, bh).astype(np.uint8).reshape(-1, 1)
            self._bar = cv2.applyColorMap(np.repeat(ramp, 18, 1), cv2.COLORMAP_TURBO)
        return self._bar

    def draw(self, img: np.ndarray, camera: Camera, pose: Pose, c: np.ndarray, mu, std, status: str,
             info: dict, names=(), units=()) -> np.ndarray:
        """Draw onto ``img`` (BGR, in place) and return it. No estimate (``mu`` NaN: before the first one, or after
        the object was lost from sight): the panel says so and no surface is drawn."""
        if pose is not None and status != "lost" and np.all(np.isfinite(mu)):
            info = dict(info, field_max=float(self._surface(img, camera, pose, c, mu)))
            self._arrow(img, camera, pose, c, mu)
        self._hud(img, mu, std, status, info, names, units)
        return img

    def geometry(self, camera: Camera, pose: Pose, c: np.ndarray, mu=None):
        """What a frame's surface is drawn from: (p (v, 2) pixels of the deformed surface vertices, faces
        ids (k,) into ``faces`` of those turned towards the camera sorted far to near, their colour levels (k,)
        into the LUT, the field's peak [SI]: its value of largest magnitude, signed); the arrays are None when nothing is in front of the camera."""
        vm = self.values(c, mu)
        v = vm if self.W is None else self.W @ vm
        X = self.X0 + self.exag * np.tensordot(c, self.U, 1)
        Xc = X @ pose.R.T + pose.t
        if np.any(Xc[:, 2] <= 1e-6):
            return None, None, None, _peak(vm)
        p = camera.project(X, pose)
        tri = self.faces
        n = np.cross(Xc[tri[:, 1]] - Xc[tri[:, 0]], Xc[tri[:, 2]] - Xc[tri[:, 0]])
        front = np.einsum("ij,ij->i", n, Xc[tri[:, 0]]) < 0      # outward normal towards the camera
        ids = np.flatnonzero(front)
        if not len(ids):
            return None, None, None, _peak(vm)
        ids = ids[np.argsort(-Xc[tri[ids], 2].mean(1))]
        lo, hi = self.vrange
        lev = np.clip(((v[tri[ids]].mean(1) - lo) / (hi - lo) * (self.levels - 1)).round(), 0,
                      self.levels - 1).astype(int)
        return p, ids, lev, _peak(vm)

    def _surface(self, img, camera, pose, c, mu=None) -> float:
        """Fill the deformed surface; returns the field's maximum (SI units)."""
        p, ids, lev, vmax = self.geometry(camera, pose, c, mu)
        if ids is None:
            return vmax
        tri = self.faces[ids]
        h, w = img.shape[:2]
        pts = np.round(p[tri] * 16).astype(np.int32)             # 4 bits of sub-pixel precision
        lo_xy = np.clip(p[tri].reshape(-1, 2).min(0).astype(int) - 2, 0, [w, h])
        hi_xy = np.clip(np.ceil(p[tri].reshape(-1, 2).max(0)).astype(int) + 2, 0, [w, h])
        if np.any(hi_xy - lo_xy <= 0):
            return vmax
        x0, y0 = lo_xy
        x1, y1 = hi_xy
        roi = img[y0:y1, x0:x1]
        layer = roi.copy()
        off = np.array([x0, y0]) * 16
        colours = self._colours
        for q, k in zip(pts - off, lev.tolist()):
            cv2.fillConvexPoly(layer, q, colours[k], cv2.LINE_8, 4)
        cv2.addWeighted(layer, self.alpha, roi, 1 - self.alpha, 0, dst=roi)
        return vmax

    def arrow(self, camera: Camera, pose: Pose, mu):
        """(tail, tip) pixels of the arrow at the estimated load position, or None."""
        if self.load_path is None or self.load_param is None:
            return None
        from physar.geometry import path_length, path_point

        s = float(np.clip(mu[self.load_param], 0.0, path_length(self.load_path)))
        base = path_point(self.load_path, s)
        d = self.load_dir if self.load_dir is not None else np.array([0, 0, -1.0])
        span = float(np.linalg.norm(self.X0.max(0) - self.X0.min(0)))
        q = camera.project(np.array([base - d * 0.12 * span, base]), pose)
        return q if np.all(np.isfinite(q)) else None

    def _arrow(self, img, camera, pose, c, mu):
        q = self.arrow(camera, pose, mu)
        if q is not None:
            a, b = (tuple(round(v) for v in x.tolist()) for x in q)
            cv2.arrowedLine(img, a, b, (255, 255, 255), 4, cv2.LINE_AA, tipLength=0.25)
            cv2.arrowedLine(img, a, b, (0, 0, 200), 2, cv2.LINE_AA, tipLength=0.25)

    def _hud(self, img, mu, std, status, info, names, units):
        """Text panel (estimates ± 2 std in display units, tracking state) and the colour bar."""
        h, w = img.shape[:2]
        sc = h / 720
        lines = []
        if status == "lost":
            lines.append((f"no pose: {info.get('pose_from', 'markers')} not found", (80, 80, 255)))
        else:
            col = (255, 255, 255) if status == "tracking" else (150, 200, 255)
            for j in self.show:
                if not np.isfinite(mu[j]):
                    lines.append((f"{names[j]}: no estimate yet", col))
                    continue
                unit = units[j] if j < len(units) else ""
                f, u = (1e3, "mm") if unit == "m" else (np.degrees(1.0), "deg") if unit == "rad" else (1.0, unit)
                sd = f"+/- {2 * std[j] * f:.3g} {u} (2 sd)" if np.isfinite(std[j]) else u
                lines.append((f"{names[j]} = {mu[j] * f:.4g} {sd}", col))
            if "field_max" in info:
                v = info["field_max"] * self.scale
                lines.append((f"max {self.label} {v:.3g} {self.unit}" if v >= 0 else
                              f"max |{self.label}| {-v:.3g} {self.unit} (negative)", (230, 230, 230)))
        obs = info.get("observed", f"{info.get('dots', 0)}/{info.get('dots_total', 0)} dots")
        lines.append((f"{status}: {info.get('markers', 0)} {info.get('pose_from', 'markers')}, {obs}",
                      (200, 200, 200)))
        fs, lh = 0.62 * sc, int(28 * sc)
        x0, y0 = int(14 * sc), int(14 * sc)
        roi = img[y0:y0 + lh * len(lines) + int(14 * sc), x0:x0 + int(560 * sc)]
        cv2.addWeighted(roi, 0.35, np.zeros_like(roi), 0.65, 0, dst=roi)
        for k, (txt, c) in enumerate(lines):
            cv2.putText(img, txt, (x0 + int(10 * sc), y0 + (k + 1) * lh), _FONT, fs, c, 1, cv2.LINE_AA)
        bar = self._colour_bar(h)
        bh, bw = bar.shape[:2]
        bx, by = w - bw - int(100 * sc), int(0.27 * h)
        panel = img[by - int(46 * sc):by + bh + int(16 * sc), bx - int(10 * sc):w - int(8 * sc)]
        cv2.addWeighted(panel, 0.35, np.zeros_like(panel), 0.65, 0, dst=panel)
        img[by:by + bh, bx:bx + bw] = bar
        cv2.putText(img, f"{self.label} [{self.unit}]", (bx - int(6 * sc), by - int(16 * sc)), _FONT, 0.45 * sc,
                    (255, 255, 255), 1, cv2.LINE_AA)
        lo, hi = self.vrange
        for k in range(5):
            yy = by + bh - 1 - int(k / 4 * (bh - 1))
            cv2.line(img, (bx + bw, yy), (bx + bw + 5, yy), (255, 255, 255), 1)
            cv2.putText(img, f"{(lo + (hi - lo) * k / 4) * self.scale:.3g}", (bx + bw + int(8 * sc), yy + 5), _FONT,
                        0.45 * sc, (255, 255, 255), 1, cv2.LINE_AA)


__all__ = ["SurfaceOverlay", "display_surface", "surface_stress_modes", "von_mises"]
