r"""A synthetic video of ANY AR project: its object deformed by a finer finite-element model, textured, lit and
filmed by a handheld camera, with the project's markers, dots, plane image and levers, a cluttered wall behind,
sensor noise and occluders. Test data for the product pipeline, never part of it (it knows the truth).

Each frame (scenario time :math:`t`):

1. parameters :math:`p(t)` from the scenario's schedule, displacement :math:`u = u_\text{fine}(p(t))` of
   :class:`FineTruth` (a mesh ``refine`` times finer than the reduced model's: no inverse crime);
   :math:`u = 0` before ``[schedule] rest_until``; a virtual object (``[model] visible = false``) is not drawn
   and has no FineTruth;
2. one z-buffer (:func:`rasterize`) of: the fine mesh's boundary triangles at :math:`X + u`; the markers
   (rigid squares with a white quiet zone, as the project declares them; a depth bias keeps them above their
   face; only before ``[schedule] markers_until``); the ``[registration.plane]`` image on its rectangle (a
   grid whose UV puts image pixel :math:`j`'s centre at :math:`(j + 1/2) / \mathtt{px\_per\_m}` from the
   origin along :math:`u`, :math:`v`); each ``[[bar]]`` as a white box (the pivot
   :math:`p + \mathrm{face}\, a`, :math:`a` the axis through its point :math:`p`, along zero turned by its
   rotation parameter, the thickness behind its visible face); a ``[load_body]`` cylinder on the deformed
   surface at the load point; all projected with the camera's lens model;
3. per pixel the nearest front-facing triangle and its perspective-correct barycentric coordinates :math:`b`,
   so every surface pixel knows its REFERENCE point :math:`X = \sum_i b_i X_i`: the texture (tri-planar
   procedural noise, optional dark pores), the dots (coverage
   :math:`\operatorname{clip}(0.5 + (r - |X - d|) / m,\ 0,\ 1)`, :math:`m` = the triangle's metres per pixel:
   anti-aliased, sub-pixel exact) and the marker images are functions of :math:`X`, so they deform with the
   object;
4. Lambert shading :math:`I = \mathrm{albedo}\, (a + (1 - a) \max(0, n \cdot l))` with :math:`n` interpolated
   from the deformed vertex normals, global brightness with flicker, vignetting, motion blur along the
   target's image motion, a Gaussian PSF, read and shot noise.

The wall is a textured plane (the project's plane when it has no image: the pipeline learns its texture; else
perpendicular to the mean line of sight behind the target), drawn by intersecting every pixel's ray (lens
distortion included) with it. The camera orbits and shakes, and turns away and back in ``[[camera.pan]]``
events. Outputs (:func:`render_project`): ``video.mp4`` (H.264), ``truth.csv`` (per frame: time, every
parameter's true value, camera pose, occluders, at_rest, markers drawn, pan yaw), ``scenario.json`` (the scenario
with every default resolved) and ``camera.toml``.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from physar.geometry import path_point
from physar.synth.scenario import Resolved, Scenario
from physar.synth.truth import FineTruth

MARKER_LIFT = 2e-5  # m: a printed marker's thickness above its face
MARKER_BIAS = 5e-4  # m: depth bias of marker pixels in the z-test (a marker wins over the face it is stuck on)


# ----------------------------------------------------------------------------------------------- rasteriser
def rasterize(xy: np.ndarray, z: np.ndarray, tris: np.ndarray, width: int, height: int, front=None, bias=None):
    r"""Z-buffer rasterisation of triangles with a pinhole's perspective-correct interpolation.

    ``xy`` (n, 2) pixel coordinates of the vertices (pixel centres at integers), ``z`` (n,) their depths [m]
    (> 0 in front of the camera), ``tris`` (m, 3) vertex indices, ``front`` (m,) bool mask of triangles drawn
    (default: all), ``bias`` (m,) depth offsets [m] added in the z-test only (decals). A pixel :math:`p` is
    inside a triangle when its three edge functions are :math:`\ge 0`; its screen-space barycentrics
    :math:`\beta` give the perspective-correct :math:`b_i = (\beta_i / z_i) / \sum_j \beta_j / z_j` and the
    depth :math:`1 / \sum_j \beta_j / z_j`; the nearest triangle wins. Returns (pix (N,) flat pixel indices,
    tri (N,), b (N, 3)), one entry per covered pixel."""
    tris = np.asarray(tris, np.int64)
    keep = np.all(z[tris] > 1e-6, axis=1)
    if front is not None:
        keep &= front
    t_ids = np.flatnonzero(keep)
    if t_ids.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    P = xy[tris[t_ids]]  # (k, 3, 2)
    x0 = np.clip(np.floor(P[..., 0].min(1)), 0, width - 1).astype(np.int64)
    x1 = np.clip(np.ceil(P[..., 0].max(1)), 0, width - 1).astype(np.int64)
    y0 = np.clip(np.floor(P[..., 1].min(1)), 0, height - 1).astype(np.int64)
    y1 = np.clip(np.ceil(P[..., 1].max(1)), 0, height - 1).astype(np.int64)
    inside_img = (P[..., 0].max(1) >= 0) & (P[..., 0].min(1) <= width - 1) & (P[..., 1].max(1) >= 0) & \
        (P[..., 1].min(1) <= height - 1)
    bw, bh = (x1 - x0 + 1) * inside_img, (y1 - y0 + 1) * inside_img
    n = bw * bh
    total = int(n.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    owner = np.repeat(np.arange(t_ids.size), n)
    local = np.arange(total) - np.repeat(np.cumsum(n) - n, n)
    px = x0[owner] + local % bw[owner]
    py = y0[owner] + local // bw[owner]
    a, b, c = P[owner, 0], P[owner, 1], P[owner, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    ok = np.abs(area) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, area, 1.0), 0.0)

    def edge(p, q):  # twice the signed area of (p, q, pixel)
        return (q[:, 0] - p[:, 0]) * (py - p[:, 1]) - (q[:, 1] - p[:, 1]) * (px - p[:, 0])

    w0, w1, w2 = edge(b, c) * inv, edge(c, a) * inv, edge(a, b) * inv
    eps = -1e-9
    inside = ok & (w0 >= eps) & (w1 >= eps) & (w2 >= eps)
    owner, px, py = owner[inside], px[inside], py[inside]
    beta = np.column_stack([w0[inside], w1[inside], w2[inside]])
    tri = t_ids[owner]
    iz = 1.0 / z[tris[tri]]
    wz = beta * iz
    s = wz.sum(1)
    depth = 1.0 / s
    bary = wz / s[:, None]
    pix = py * width + px
    if bias is not None:
        depth = depth + bias[tri]
    order = np.lexsort((depth, pix))
    pix, tri, bary = pix[order], tri[order], bary[order]
    first = np.ones(pix.size, bool)
    first[1:] = pix[1:] != pix[:-1]
    return pix[first], tri[first], bary[first]


# ------------------------------------------------------------------------------------------------- textures
def noise_image(shape: tuple[int, int], feature_px: float, octaves: int, rng: np.random.Generator) -> np.ndarray:
    r"""Zero-mean, unit-std band-limited noise (h, w) float32: octaves :math:`o` of white noise upsampled with
    bicubic interpolation from cells of :math:`\mathtt{feature\_px} \cdot 2^o` pixels, amplitudes halving with
    the frequency."""
    h, w = shape
    out = np.zeros((h, w), np.float32)
    for o in range(octaves):
        cell = max(1.0, feature_px * 2 ** (octaves - 1 - o))
        small = rng.standard_normal((max(2, int(h / cell) + 2), max(2, int(w / cell) + 2))).astype(np.float32)
        out += cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) * 0.5 ** (octaves - 1 - o)
    out -= out.mean()
    return out / max(float(out.std()), 1e-9)


def aruco_texture(dictionary: str, marker_id: int, px_per_cell: int = 16) -> np.ndarray:
    r"""The marker's image (float32 grey in [0, 1]) with a white quiet zone of one cell on every side; the
    marker's own square spans :math:`[c, 1 - c]` of the texture, :math:`c = 1 / (\mathrm{cells} + 2)`."""
    from physar.vision.calibration import aruco_dictionary

    d = aruco_dictionary(dictionary)
    cells = d.markerSize + 2
    side = cells * px_per_cell
    img = cv2.aruco.generateImageMarker(d, int(marker_id), side, borderBits=1)
    out = np.full((side + 2 * px_per_cell,) * 2, 255, np.uint8)
    out[px_per_cell:-px_per_cell, px_per_cell:-px_per_cell] = img
    return out.astype(np.float32) / 255.0


def _remap(img: np.ndarray, u: np.ndarray, v: np.ndarray, border=cv2.BORDER_REFLECT) -> np.ndarray:
    """Bilinear samples of ``img`` at pixel coordinates (u, v) (1-D arrays)."""
    if u.size == 0:
        return np.zeros((0,) + img.shape[2:], np.float32)
    n, w = u.size, 4096  # OpenCV maps are at most 32767 wide: fold the samples into rows
    rows = -(-n // w)
    mx = np.zeros(rows * w, np.float32)
    my = np.zeros(rows * w, np.float32)
    mx[:n], my[:n] = u, v
    out = cv2.remap(img, mx.reshape(rows, w), my.reshape(rows, w), cv2.INTER_LINEAR, borderMode=border)
    return out.reshape((rows * w,) + img.shape[2:])[:n]


# ------------------------------------------------------------------------------------------------- renderer
class ProjectRenderer:
    """Renders frames of a project's synthetic clip: ``render(k) -> (BGR uint8 image, truth row dict)``.

    ``truth`` is None for a virtual object (``[model] visible = false``): its mesh is not drawn."""

    def __init__(self, project, scenario: Scenario | Resolved, truth: FineTruth | None = None, quick: bool = False):
        self.res = scenario if isinstance(scenario, Resolved) else Resolved(scenario, project, quick=quick)
        self.project = project
        sc = self.res.sc
        self.visible = self.res.visible
        self.truth = (truth or FineTruth(project, refine=sc.truth.refine, mesh_size=sc.truth.mesh_size,
                                         coarsest=quick)) if self.visible else None
        self.camera = self.res.camera
        self.rng = np.random.default_rng(sc.seed)
        if self.visible:
            self._surface(project, sc)
        else:
            self.X, self.n_vert = np.zeros((0, 3)), 0
            self.tris = np.zeros((0, 3), np.int64)
        self._markers()
        self._plate()
        self._load_path()
        self._wall()
        W, H = self.camera.size
        yy, xx = np.mgrid[0:H, 0:W]
        q = self.camera.normalized(np.column_stack([xx.ravel(), yy.ravel()]).astype(float))
        self.rays = np.column_stack([q, np.ones(len(q))]).astype(np.float32)  # camera-frame rays of the pixels

    # -------------------------------------------------------------------------------------- setup helpers
    def _surface(self, project, sc):
        """The fine truth mesh's boundary, its shading groups, the dots near each triangle, the textures."""
        mesh = self.truth.space.mesh
        surf = mesh.boundary()
        self.X = mesh.points  # reference vertex positions (P2 spaces number mesh points first)
        self.n_vert = len(self.X)
        self.tris = surf.faces_global
        # reference face normals (for tri-planar texture weights) and metres-per-unit reference quantities
        e1 = self.X[self.tris[:, 1]] - self.X[self.tris[:, 0]]
        e2 = self.X[self.tris[:, 2]] - self.X[self.tris[:, 0]]
        nref = np.cross(e1, e2)
        self.area_ref = 0.5 * np.linalg.norm(nref, axis=1)
        self.nref = nref / np.maximum(2 * self.area_ref, 1e-30)[:, None]
        self.corner_pairs = self._crease_pairs(math.radians(35.0))
        # dots: for each triangle the (up to 2) nearest dots within reach (static, reference frame)
        dots_cfg = project.config.dots
        self.dots = np.asarray(project.dots, float)
        self.dot_r = 0.5 * float(dots_cfg.diameter) if len(self.dots) else 0.0
        self.dot_rgb = np.asarray(dots_cfg.colour, float) / 255.0 if len(self.dots) else np.zeros(3)
        self.tri_dots = self._near_dots()
        # textures
        tex = sc.texture
        self.base_rgb = np.asarray(tex.base, float) / 255.0
        self.contrast = tex.contrast
        self.feature = self.res.feature
        lo, hi = mesh.bounds
        self.lo = lo - 1e-3
        ext = (hi - lo) + 2e-3
        texel = 0.5 * self.feature  # texture pixel [m]
        scale = min(1.0, 4096.0 / max(float(ext.max()) / texel, 1.0))
        self.texel = texel / scale
        self.planes = []  # tri-planar textures: projections onto yz, xz, xy (noise, then dark pores)
        for ax in range(3):
            a, b = [i for i in range(3) if i != ax]
            shape = (int(ext[b] / self.texel) + 4, int(ext[a] / self.texel) + 4)
            im = noise_image(shape, 2.0, tex.octaves, self.rng)
            if tex.pores > 0:
                im = np.stack([im, pore_image(shape, (tex.pore_size or 4 * self.feature) / self.texel, tex.pores,
                                              self.rng)], axis=-1)
            self.planes.append((a, b, im))

    def _crease_pairs(self, crease: float) -> tuple[np.ndarray, np.ndarray]:
        """Smoothing groups of the shading normals: pairs (corner :math:`c = 3 f + j`, face :math:`g`) such
        that :math:`g` touches the vertex of corner :math:`c` and its reference normal is within ``crease`` of
        face :math:`f`'s. A corner's normal is the sum of those faces' (area-weighted) normals: smooth on curved
        surfaces, sharp at edges."""
        m = len(self.tris)
        corner_v = self.tris.ravel()
        order = np.argsort(corner_v, kind="stable")
        sv = corner_v[order]
        starts = np.searchsorted(sv, np.arange(self.n_vert + 1))
        deg = starts[1:] - starts[:-1]
        n_c = deg[corner_v]
        c_idx = np.repeat(np.arange(3 * m), n_c)
        offs = np.arange(n_c.sum()) - np.repeat(np.cumsum(n_c) - n_c, n_c)
        g = order[np.repeat(starts[corner_v], n_c) + offs] // 3
        f = c_idx // 3
        keep = np.einsum("ij,ij->i", self.nref[f], self.nref[g]) >= math.cos(crease)
        return c_idx[keep], g[keep]

    def _near_dots(self) -> np.ndarray:
        m = len(self.tris)
        out = np.full((m, 2), -1, np.int64)
        if not len(self.dots):
            return out
        from scipy.spatial import cKDTree

        c = self.X[self.tris].mean(1)
        reach = np.linalg.norm(self.X[self.tris] - c[:, None], axis=2).max(1) + 1.5 * self.dot_r
        tree = cKDTree(self.dots)
        k = min(2, len(self.dots))
        d, i = tree.query(c, k=k)
        d, i = d.reshape(m, k), i.reshape(m, k)
        near = d <= reach[:, None]
        out[:, :k] = np.where(near, i, -1)
        return out

    def _markers(self):
        """Marker plates: a :math:`(g+1)^2` vertex grid per marker (follows the lens distortion), UV in the
        texture."""
        from physar.vision.calibration import aruco_dictionary

        board = self.project.board
        self.marker_tex, verts, uvs, tris, owner = [], [], [], [], []
        g = 4
        base = 0
        for k, (mid, C) in enumerate(zip(board.ids, board.corners) if board is not None else ()):
            tex = aruco_texture(board.dictionary, int(mid))
            self.marker_tex.append(tex)
            n = np.cross(C[1] - C[0], C[3] - C[0])
            n = -n / np.linalg.norm(n)  # outward normal (see physar.synth.scenario._marker_normals)
            cells = aruco_dictionary(board.dictionary).markerSize + 2
            q = 1.0 / cells  # quiet zone width as a fraction of the marker side
            s = np.linspace(-q, 1 + q, g + 1)
            S, T = np.meshgrid(s, s)  # S along TL->TR, T along TL->BL
            P = C[0] + S[..., None] * (C[1] - C[0]) + T[..., None] * (C[3] - C[0]) + MARKER_LIFT * n
            verts.append(P.reshape(-1, 3))
            side = tex.shape[0]
            # texel i covers [i - 1/2, i + 1/2] in remap coordinates: the texture spans [-1/2, side - 1/2]
            uvs.append(np.column_stack([(S.ravel() + q) / (1 + 2 * q) * side - 0.5,
                                        (T.ravel() + q) / (1 + 2 * q) * side - 0.5]))
            tris.append(_grid_tris(g, base))
            owner.append(np.full(2 * g * g, k))
            base += (g + 1) ** 2
        if verts:
            self.m_X = np.vstack(verts)
            self.m_uv = np.vstack(uvs)
            self.m_tris = np.vstack(tris)
            self.m_owner = np.concatenate(owner)
            self.m_n = _tri_normals(self.m_X, self.m_tris)
        else:
            self.m_X = np.zeros((0, 3))
            self.m_tris = np.zeros((0, 3), np.int64)

    def _plate(self):
        r"""The [registration.plane] image (when the project has one) on its rectangle, a :math:`(g+1)^2` grid
        with UV in image pixels (pixel :math:`j`'s centre at :math:`(j + 1/2) / \mathtt{px\_per\_m}` from the
        origin), and its dark rim."""
        pl = self.res.plane
        self.p_X = np.zeros((0, 3))
        self.p_tris = np.zeros((0, 3), np.int64)
        if pl is None or pl.image is None:
            return
        g = 16
        w, h = pl.size
        s = np.linspace(0.0, 1.0, g + 1)
        S, T = np.meshgrid(s, s)
        P = pl.origin + (S * w)[..., None] * pl.u + (T * h)[..., None] * pl.v
        self.p_X = P.reshape(-1, 3)
        self.p_uv = np.column_stack([S.ravel() * w * pl.px_per_m - 0.5, T.ravel() * h * pl.px_per_m - 0.5])
        self.p_tris = _grid_tris(g, 0)
        self.p_img = pl.image.astype(np.float32) / 255.0
        look = self.res.sc.plane
        self.rim = None
        if look.border > 0:
            b = look.border
            C = pl.corners() + np.array([-b * (pl.u + pl.v), b * (pl.u - pl.v), b * (pl.u + pl.v),
                                         b * (pl.v - pl.u)]) - 1e-4 * pl.normal
            self.rim = (C, np.asarray(look.border_colour, float)[::-1] / 255.0)

    def _load_path(self):
        """The load point of the load_position parameter (path, offset direction) for [load_body]."""
        self.load_def = None
        if self.res.sc.load_body is None or not self.visible:
            return
        ps = {p["kind"]: p for p in self.truth.params}
        pos = ps["load_position"]
        off = ps.get("load_offset")
        self.load_def = (pos["name"], np.asarray(pos["path"], float), np.asarray(pos["load"], float),
                         None if off is None else (off["name"], np.asarray(off["direction"], float)))
        surf = np.unique(self.tris)
        self.surf_nodes = surf

    def _wall(self):
        r"""A cluttered wall on the resolved wall plane (the project's plane without an image, else behind the
        target), with band-limited noise and random rectangles and discs (features for markerless
        registration); texture pixel :math:`(i, j)` centred at
        :math:`c + ((j + 1/2) s - h)\, \mathrm{right} + ((i + 1/2) s - h)\, \mathrm{down}`,
        :math:`s = 2 h / n` (:math:`c` = ``wall_centre``, :math:`h` the half side)."""
        res = self.res
        cam = self.camera
        D = res.distance + res.wall_distance
        half = 1.6 * D * max(cam.width / cam.fx, cam.height / cam.fy)  # half side [m], covers the orbit
        n = 2048
        self.wall_half, self.wall_n = half, n
        bg = self.res.sc.background
        rng = np.random.default_rng([self.res.sc.seed, 7])  # its own stream: the same wall whatever is drawn
        base = np.asarray(bg.base, float)[::-1] / 255.0  # BGR
        img = base * (1 + bg.contrast * noise_image((n, n), 3.0, 4, rng)[..., None])
        for _ in range(90):  # clutter: posters, boxes, round things
            col = np.clip(base * rng.uniform(0.5, 1.5, 3), 0, 1)
            x, y = rng.integers(0, n, 2)
            if rng.random() < 0.6:
                w, h = rng.integers(n // 80, n // 12, 2)
                cv2.rectangle(img, (int(x), int(y)), (int(x + w), int(y + h)), col.tolist(), -1, cv2.LINE_AA)
            else:
                cv2.circle(img, (int(x), int(y)), int(rng.integers(n // 150, n // 30)), col.tolist(), -1,
                           cv2.LINE_AA)
        self.wall_img = np.clip(img, 0, 1).astype(np.float32)

    def draw_wall(self, pose) -> np.ndarray:
        """The wall seen from ``pose`` (H, W, 3) float32 BGR, unlit: every pixel's ray (lens distortion
        included) meets the wall plane at X, sampled bilinearly; pixels whose ray misses it (behind the
        camera) are dark grey."""
        res = self.res
        W, H = self.camera.size
        e1, e2 = (np.asarray(a, np.float32) for a in res.wall_axes)
        n = np.asarray(res.wall_normal, np.float32)
        c = pose.center.astype(np.float32)
        d = self.rays @ pose.R.astype(np.float32)  # world directions (rows: R^T r)
        dn = d @ n
        depth = float((res.wall_centre - c) @ n)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = depth / dn
        hit = np.isfinite(lam) & (lam > 0)
        lam = np.where(hit, lam, 0.0).astype(np.float32)
        rel = (c - res.wall_centre).astype(np.float32)
        s = 2 * self.wall_half / self.wall_n
        mx = ((rel @ e1 + lam * (d @ e1)) + self.wall_half) / s - 0.5
        my = ((rel @ e2 + lam * (d @ e2)) + self.wall_half) / s - 0.5
        img = cv2.remap(self.wall_img, mx.reshape(H, W), my.reshape(H, W), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REFLECT)
        img[~hit.reshape(H, W)] = 0.25
        return img

    # ---------------------------------------------------------------------------------------------- frames
    def deformed(self, params: dict, at_rest: bool = False) -> np.ndarray:
        """Deformed vertex positions :math:`X + u` (n, 3) [m] of the fine truth at the parameter values
        (:math:`X` at rest)."""
        if at_rest or not self.visible:
            return self.X
        u = self.truth.solve(params).reshape(-1, 3)[: self.n_vert]
        return self.X + u

    def render(self, k: int) -> tuple[np.ndarray, dict]:
        res = self.res
        cam = self.camera
        W, H = cam.size
        t = k / res.fps
        params = res.params(t)
        rest = res.at_rest(t)
        markers = res.markers_on(t)
        pose = res.pose(t)
        x = self.deformed(params, rest)
        light = res.light
        sc = res.sc
        L = sc.lighting
        fr = np.random.default_rng([sc.seed, k])
        img = self.draw_wall(pose)
        img *= L.ambient + (1 - L.ambient) * max(0.0, float(res.wall_normal @ light)) * 0.8
        # geometry: object surface, markers, plate, bars, load body: one z-buffer
        parts = [(x, self.tris, 0.0, self._shade_surface_fn(x, light, L))] if self.visible else []
        if markers and len(self.m_tris):
            parts.append((self.m_X, self.m_tris, -MARKER_BIAS, lambda tri, b: self._shade_markers(tri, b, light, L)))
        if len(self.p_tris):
            parts.append((self.p_X, self.p_tris, 0.0, lambda tri, b: self._shade_plate(tri, b, light, L)))
            if self.rim is not None:
                C, col = self.rim
                T = np.array([[0, 3, 2], [0, 2, 1]])  # wound like the plate: normal -(u x v)
                parts.append((C, T, MARKER_BIAS, self._flat(C, T, col, light, L)))
        for bar in res.bars:
            X, T = bar_box(bar, params[bar.name], sc.bar.thickness * bar.width)
            parts.append((X, T, 0.0, self._flat(X, T, np.asarray(sc.bar.colour, float)[::-1] / 255.0, light, L)))
        if self.load_def is not None and not rest:
            X, T = self._load_body(params, x)
            parts.append((X, T, 0.0, self._flat(X, T, np.asarray(sc.load_body.colour, float)[::-1] / 255.0, light, L)))
        if parts:
            self._draw(img, parts, pose)
        # brightness, flicker, vignetting
        gain = L.brightness * (1 + L.flicker * math.sin(2 * math.pi * 1.7 * t + sc.seed))
        yy, xx = np.mgrid[0:H, 0:W]
        r2 = ((xx - cam.K[0, 2]) ** 2 + (yy - cam.K[1, 2]) ** 2) / (0.25 * (W * W + H * H))
        img *= (gain * (1 - L.vignetting * r2)).astype(np.float32)[..., None]
        occ = res.occlusions(k)
        for o in occ:
            self._occluder(img, o, pose)
        # sensor: motion blur, PSF, shot and read noise [DN]
        dn = img * 255.0
        sen = sc.sensor
        if sen.motion_blur > 0:
            tgt = res.target[None]
            blur = (cam.project(tgt, pose)[0] - cam.project(tgt, res.pose(t - 1 / res.fps))[0]) * sen.motion_blur
            dn = motion_blur(dn, blur)
        if sen.psf > 0:
            dn = cv2.GaussianBlur(dn, (0, 0), sen.psf)
        sigma = np.sqrt(sen.read_noise ** 2 + sen.shot_noise ** 2 * np.maximum(dn, 0))
        dn = dn + sigma * fr.standard_normal(dn.shape).astype(np.float32)
        out = np.clip(dn + 0.5, 0, 255).astype(np.uint8)
        row = {"frame": k, "time_s": t, **{f"{n}_true": v for n, v in params.items()},
               **dict(zip(("rx", "ry", "rz"), pose.rvec.tolist())), **dict(zip(("tx", "ty", "tz"), pose.t.tolist())),
               "occluders": len(occ), "at_rest": int(rest), "markers": int(markers and len(self.m_tris) > 0),
               "pan_deg": res.pan(t), "in_view": self._in_view(params, pose)}
        return out, row

    def _in_view(self, params: dict, pose) -> float:
        """Fraction of what the project observes (dots, the bars' corners, the features face's corners) that
        lies inside the image in front of the camera: a judged frame needs it seen."""
        dots = np.asarray(self.project.dots, float).reshape(-1, 3)
        pts = [dots] if len(dots) else []
        for bar in self.res.bars:
            pts.append(bar_box(bar, params[bar.name], self.res.sc.bar.thickness * bar.width)[0])
        f = self.project.config.features
        if f is not None:
            o, u, v = (np.asarray(a, float) for a in (f.origin, f.u, f.v))
            u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
            pts.append(np.array([o, o + f.size[0] * u, o + f.size[1] * v, o + f.size[0] * u + f.size[1] * v]))
        if not pts:
            return 1.0
        X = np.vstack(pts)
        z = pose.apply(X)[:, 2]
        q = self.camera.project(X, pose)
        W, H = self.camera.size
        ok = (z > 1e-6) & (q[:, 0] >= 0) & (q[:, 0] < W) & (q[:, 1] >= 0) & (q[:, 1] < H)
        return float(np.mean(ok))

    def _draw(self, img, parts, pose):
        """Rasterise the parts [(X (n, 3) world, tris (m, 3) outward-wound, depth bias [m], shader(tri, b) ->
        (N, 3) BGR)] in one z-buffer and write the shaded pixels into img."""
        cam = self.camera
        W, H = cam.size
        offs = np.cumsum([0] + [len(p[0]) for p in parts])
        toffs = np.cumsum([0] + [len(p[1]) for p in parts])
        allX = np.vstack([p[0] for p in parts])
        tris = np.vstack([p[1] + o for p, o in zip(parts, offs)])
        bias = np.concatenate([np.full(len(p[1]), p[2]) for p in parts])
        xc = allX @ pose.R.T + pose.t
        xy = cam.project(allX, pose)
        tn = np.cross(allX[tris[:, 1]] - allX[tris[:, 0]], allX[tris[:, 2]] - allX[tris[:, 0]])
        front = np.einsum("ij,ij->i", tn @ pose.R.T, -xc[tris].mean(1)) > 0
        pix, tri, b = rasterize(xy, xc[:, 2], tris, W, H, front, bias if np.any(bias) else None)
        flat = img.reshape(-1, 3)
        part = np.searchsorted(toffs, tri, side="right") - 1
        self._xy = xy[: offs[1]] if self.visible else None  # the object's projected vertices (dot coverage)
        for j, p in enumerate(parts):
            sel = part == j
            if sel.any():
                flat[pix[sel]] = p[3](tri[sel] - toffs[j], b[sel])

    def _flat(self, X, T, bgr, light, L):
        """Shader of a rigid part of one colour: Lambert with its triangles' normals."""
        n = _tri_normals(X, T)
        lam = L.ambient + (1 - L.ambient) * np.maximum(0.0, n @ light)
        cols = (bgr[None] * lam[:, None]).astype(np.float32)
        return lambda tri, b: cols[tri]

    def _load_body(self, params, x):
        """Cylinder (diameter, thickness of [load_body]) standing on the deformed surface at the load point:
        its base centre at the reference point moved by the mean displacement of the surface vertices under
        it, axis along -load."""
        name, path, load, off = self.load_def
        p = path_point(path, float(params[name]))
        if off is not None:
            p = p + float(params[off[0]]) * off[1] / np.linalg.norm(off[1])
        lb = self.res.sc.load_body
        r = 0.5 * lb.diameter
        a = -load / np.linalg.norm(load)
        Xs = self.X[self.surf_nodes]
        dist = np.linalg.norm((Xs - p) - np.outer((Xs - p) @ a, a), axis=1)
        under = (dist <= r) & (np.abs((Xs - p) @ a) < 0.5 * r)
        if not under.any():
            under = dist <= dist.min() + 1e-12
        base = p + (x[self.surf_nodes[under]] - Xs[under]).mean(0)
        return cylinder(base, a, r, lb.thickness)

    def _shade_surface_fn(self, x, light, L):
        return lambda tri, b: self._shade_surface(x, tri, b, self._xy, light, L)

    def _shade_surface(self, x, tri, b, xy, light, L) -> np.ndarray:
        T = self.tris[tri]
        Xr = np.einsum("ni,nij->nj", b, self.X[T])  # reference point of each pixel
        # deformed vertex normals (area weighted), interpolated
        fn = np.cross(x[self.tris[:, 1]] - x[self.tris[:, 0]], x[self.tris[:, 2]] - x[self.tris[:, 0]])
        c_idx, g = self.corner_pairs
        cn = np.zeros((3 * len(self.tris), 3))
        np.add.at(cn, c_idx, fn[g])
        cn /= np.maximum(np.linalg.norm(cn, axis=1, keepdims=True), 1e-30)
        n = np.einsum("ni,nij->nj", b, cn.reshape(-1, 3, 3)[tri])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        # tri-planar texture in the reference frame (noise, and dark pores when [texture] pores > 0)
        w = np.abs(self.nref[tri]) ** 4
        w /= w.sum(1, keepdims=True)
        tex = np.zeros(len(tri), np.float32)
        pore = np.zeros(len(tri), np.float32)
        for ax, (a, bb, im) in enumerate(self.planes):
            sel = w[:, ax] > 1e-3
            u = (Xr[sel, a] - self.lo[a]) / self.texel
            v = (Xr[sel, bb] - self.lo[bb]) / self.texel
            sample = _remap(im, u, v)
            if im.ndim == 3:
                tex[sel] += w[sel, ax] * sample[:, 0]
                pore[sel] += w[sel, ax] * sample[:, 1]
            else:
                tex[sel] += w[sel, ax] * sample
        albedo = np.clip(self.base_rgb[None, ::-1] * (1 + self.contrast * tex[:, None]), 0, 1)
        albedo *= 1 - 0.55 * pore[:, None]
        # dots: anti-aliased coverage from the distance in the reference frame, m = metres per pixel
        if len(self.dots):
            e1, e2 = xy[T[:, 1]] - xy[T[:, 0]], xy[T[:, 2]] - xy[T[:, 0]]
            a2 = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
            mpp = np.sqrt(self.area_ref[tri] / np.maximum(a2, 1e-12))
            cover = np.zeros(len(tri))
            for j in range(self.tri_dots.shape[1]):
                di = self.tri_dots[tri, j]
                has = di >= 0
                if has.any():
                    d = np.linalg.norm(Xr[has] - self.dots[di[has]], axis=1)
                    cover[has] = np.maximum(cover[has], np.clip(0.5 + (self.dot_r - d) / mpp[has], 0, 1))
            albedo = albedo * (1 - cover[:, None]) + self.dot_rgb[None, ::-1] * cover[:, None]
        lam = L.ambient + (1 - L.ambient) * np.maximum(0.0, n @ light)
        return (albedo * lam[:, None]).astype(np.float32)

    def _shade_markers(self, tri, b, light, L) -> np.ndarray:
        T = self.m_tris[tri]
        uv = np.einsum("ni,nij->nj", b, self.m_uv[T])
        out = np.zeros((len(tri), 3), np.float32)
        own = self.m_owner[tri]
        for k in np.unique(own):
            sel = own == k
            out[sel] = _remap(self.marker_tex[k], uv[sel, 0], uv[sel, 1], cv2.BORDER_REPLICATE)[:, None]
        paper = 0.05 + 0.85 * out  # printed black / white paper
        lam = L.ambient + (1 - L.ambient) * np.maximum(0.0, self.m_n[tri] @ light)
        return (paper * lam[:, None]).astype(np.float32)

    def _shade_plate(self, tri, b, light, L) -> np.ndarray:
        uv = np.einsum("ni,nij->nj", b, self.p_uv[self.p_tris[tri]])
        col = _remap(self.p_img, uv[:, 0], uv[:, 1], cv2.BORDER_REPLICATE)
        lam = L.ambient + (1 - L.ambient) * max(0.0, float(self.res.plane.normal @ light))
        return (col * lam).astype(np.float32)

    def _occluder(self, img, o, pose):
        cam = self.camera
        H = cam.height
        if o.point is not None:
            c = cam.project(np.asarray(o.point, float)[None], pose)[0]
        else:
            c = np.array([o.center[0] * cam.width, o.center[1] * H])
        r = o.radius * H
        col = (np.asarray(o.colour, float)[::-1] / 255.0).tolist()
        # a hand-like blob: a disc and an arm to the nearest image border, anti-aliased
        sh = 4
        cv2.circle(img, (round(c[0] * 2 ** sh), round(c[1] * 2 ** sh)), int(r * 2 ** sh), col, -1,
                   cv2.LINE_AA, sh)
        edge = np.array([c[0], H + r])
        cv2.line(img, (int(c[0]), int(c[1])), (int(edge[0]), int(edge[1])), col, int(1.2 * r), cv2.LINE_AA)


# ------------------------------------------------------------------------------------------- rigid parts
def _tri_normals(X, T) -> np.ndarray:
    n = np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def _grid_tris(g: int, base: int) -> np.ndarray:
    r"""Triangles of a :math:`(g+1) \times (g+1)` vertex grid (row-major, rows along the second axis
    :math:`T`, columns along :math:`S`), wound so that their normal is :math:`-(\mathrm{d}S \times \mathrm{d}T)`
    (the outward ``normal`` of a marker / plane whose :math:`S` and :math:`T` are its right and down
    directions)."""
    i = np.arange((g + 1) ** 2).reshape(g + 1, g + 1) + base
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    return np.concatenate([np.column_stack([a, d, c]), np.column_stack([a, c, b])])


def _outward(X, T) -> np.ndarray:
    """Triangles of a convex body wound so that their normals point away from its centroid."""
    n = np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]])
    flip = np.einsum("ij,ij->i", n, X[T].mean(1) - X.mean(0)) < 0
    T = T.copy()
    T[flip] = T[flip][:, ::-1]
    return T


_BOX_TRIS = np.array([[0, 1, 3], [0, 3, 2], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 3, 7], [1, 7, 5]])


def bar_box(bar, value: float, thickness: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (8, 3) and outward triangles (12, 3) of a [[bar]] at the parameter value: the box
    [0, length] along its direction, [-width/2, width/2] across, from its visible face (through the pivot)
    ``thickness`` back against its facing normal."""
    d = bar.direction(value)
    across = np.cross(bar.axis, d)
    X = np.array([bar.pivot + i * bar.length * d + (j - 0.5) * bar.width * across - k * thickness * bar.facing
                  for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    return X, _outward(X, _BOX_TRIS)


def cylinder(base, axis, radius: float, height: float, n: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward triangles of a closed cylinder: base centre (3,), unit axis (3,), radius, height."""
    e1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = radius * (np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2)
    X = np.vstack([base + ring, base + height * axis + ring, base, base + height * axis])
    i, j = np.arange(n), (np.arange(n) + 1) % n
    T = np.vstack([np.column_stack([i, j, n + j]), np.column_stack([i, n + j, n + i]),
                   np.column_stack([np.full(n, 2 * n), j, i]), np.column_stack([np.full(n, 2 * n + 1), n + i, n + j])])
    return X, _outward(X, T)


def pore_image(shape: tuple[int, int], size_px: float, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Coverage (h, w) float32 in [0, 1] of random dark pores (discs of diameter 0.5..1.2 ``size_px``,
    anti-aliased) covering about ``fraction`` of the area."""
    h, w = shape
    out = np.zeros((h, w), np.float32)
    r = rng.uniform(0.25, 0.6, max(1, int(fraction * h * w / (np.pi * (0.42 * size_px) ** 2))))
    r = r * size_px
    c = rng.uniform(0, 1, (len(r), 2)) * (w, h)
    for (cx, cy), rr in zip(c, r):
        cv2.circle(out, (int(cx * 16), int(cy * 16)), max(int(rr * 16), 8), 1.0, -1, cv2.LINE_AA, shift=4)
    return out


def motion_blur(img: np.ndarray, blur_px: np.ndarray) -> np.ndarray:
    """Blur along the image motion ``blur_px`` (2,) [px] during the exposure: a line kernel of that length."""
    n = float(np.linalg.norm(blur_px))
    if n <= 0.5:
        return img
    k = math.ceil(n) | 1
    ker = np.zeros((k + 2, k + 2), np.float32)
    c = (k + 1) / 2
    d = blur_px / n
    p0 = (round((c - d[0] * n / 2) * 16), round((c - d[1] * n / 2) * 16))
    p1 = (round((c + d[0] * n / 2) * 16), round((c + d[1] * n / 2) * 16))
    cv2.line(ker, p0, p1, 1.0, 1, cv2.LINE_AA, shift=4)
    return cv2.filter2D(img, -1, ker / ker.sum())


# ---------------------------------------------------------------------------------------------------- files
def truth_header(names) -> list[str]:
    return ["frame", "time_s", *[f"{n}_true" for n in names], "rx", "ry", "rz", "tx", "ty", "tz", "occluders",
            "at_rest", "markers", "pan_deg", "in_view"]


def render_project(project, scenario: Scenario, out_dir, progress: Callable[[int, int], None] | None = None,
                   quick: bool = False, crf: int | None = None) -> dict:
    """Render a project's synthetic clip into ``out_dir`` (created; only these files are written):
    ``video.mp4``, ``truth.csv``, ``camera.toml`` and ``scenario.json``. ``quick``: half size, at most 2 s, and
    the coarsest truth the scenario allows (:class:`FineTruth` ``coarsest``: a smoke check, not an accuracy figure).
    Returns a summary (paths, frames, size, truth solves)."""
    from physar.ar.video import write_clip
    from physar.output import atomic_write_text

    r = ProjectRenderer(project, scenario, quick=quick)
    res = r.res
    names = list(project.rom.names)
    header = truth_header(names)

    def frame(k):
        img, row = r.render(k)
        return img, [row[h] if not isinstance(row[h], float) else f"{row[h]:.9g}" for h in header]

    out = Path(out_dir)
    info = write_clip(out, "video.mp4", res.camera, res.fps, crf if crf is not None else res.sc.video.crf, header,
                      res.n_frames, frame, progress)
    atomic_write_text(out / "scenario.json", json.dumps(res.as_dict(), indent=1))
    info.update(scenario=str(out / "scenario.json"), truth_solves=0 if r.truth is None else r.truth.solves,
                truth_dofs=0 if r.truth is None else int(r.truth.space.n_dofs))
    return info


__all__ = ["ProjectRenderer", "aruco_texture", "bar_box", "cylinder", "motion_blur", "noise_image", "pore_image",
           "rasterize", "render_project", "truth_header"]
