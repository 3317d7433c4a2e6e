r"""Which points of an object its own surface hides from the camera (self-occlusion of the dots, seed 000 §5.1:
a dot is measured only where the camera sees all of it).

A point :math:`P` (camera frame) is hidden when a triangle :math:`(V_0, V_1, V_2)` of the surface crosses the ray
from the camera centre to it nearer than :math:`P`: with :math:`d = P / P_z` and the triangle's plane
:math:`n \cdot X = n \cdot V_0`, the ray meets the plane at depth :math:`z = (n \cdot V_0) / (n \cdot d)`, and
the triangle hides :math:`P` when the ray's image point :math:`(d_x, d_y)` lies inside the triangle's image
(barycentric coordinates of the normalised image coordinates :math:`V_{xy} / V_z`, all :math:`\ge 0`) and
:math:`z < P_z - \varepsilon`. Lens distortion does not change what hides what, so the test is made in
normalised (pinhole) coordinates. Triangles are first culled to those in front of the camera whose image box
overlaps the points' image box, then each point is tested against the triangles whose box holds it.
"""
from __future__ import annotations

import numpy as np


def hidden_points(points, vertices, faces, eps: float, closed: bool = False) -> np.ndarray:
    r"""(k,) bool: the camera-frame ``points`` (k, 3) [m] that a triangle of the surface (``vertices`` (v, 3) in
    the camera frame [m], ``faces`` (f, 3)) hides, i.e. crosses their ray more than ``eps`` [m] (in depth) in
    front of them (see the module doc). Points behind the camera (:math:`P_z \le 0`) count as hidden.
    ``closed``: the faces bound a solid and are wound outward (counter-clockwise seen from outside), so only
    the faces turned towards the camera are tested (a ray into a solid enters it through one of those)."""
    P = np.asarray(points, float).reshape(-1, 3)
    V = np.asarray(vertices, float).reshape(-1, 3)
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    out = ~(P[:, 2] > 0)
    if len(P) == 0 or len(F) == 0 or out.all():
        return out
    ok = np.flatnonzero(~out)
    d = P[ok, :2] / P[ok, 2:3]                                    # (k', 2) normalised image points
    front_v = V[:, 2] > 1e-9
    v2 = V[:, :2] / np.where(front_v, V[:, 2], 1.0)[:, None]      # vertices' normalised image points
    keep = front_v[F].all(1)                                      # a triangle crossing the camera plane is skipped
    t2 = v2[F]                                                    # (f, 3, 2)
    if closed:   # turned towards the camera: n . V0 = z0 z1 z2 (2-D signed area of the image triangle) < 0
        e1, e2 = t2[:, 1] - t2[:, 0], t2[:, 2] - t2[:, 0]
        keep &= e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    lo, hi = t2.min(1), t2.max(1)
    keep &= np.all((hi >= d.min(0)) & (lo <= d.max(0)), axis=1)   # boxes overlapping the points' box
    sel = np.flatnonzero(keep)
    if len(sel) == 0:
        return out
    T, t2, lo, hi = V[F[sel]], t2[sel], lo[sel], hi[sel]          # (f', 3, 3) ...
    # boxes clipped to the points' box (a triangle near the camera plane spans a huge image box that would
    # set the grid's extent); a point inside a clipped box is inside the box
    ip, it = _box_pairs(d, np.maximum(lo, d.min(0)), np.minimum(hi, d.max(0)))
    a, b, c = t2[it, 0], t2[it, 1], t2[it, 2]
    v0, v1, q = b - a, c - a, d[ip] - a
    den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    safe = np.where(np.abs(den) > 1e-15, den, 1.0)
    l1 = (q[:, 0] * v1[:, 1] - q[:, 1] * v1[:, 0]) / safe
    l2 = (v0[:, 0] * q[:, 1] - v0[:, 1] * q[:, 0]) / safe
    inside = (np.abs(den) > 1e-15) & (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1)
    n = np.cross(T[it, 1] - T[it, 0], T[it, 2] - T[it, 0])       # (pairs, 3) triangle normals
    ray = np.column_stack([d[ip], np.ones(len(ip))])
    nd = np.einsum("ij,ij->i", n, ray)
    z = np.einsum("ij,ij->i", n, T[it, 0]) / np.where(np.abs(nd) > 1e-15, nd, np.nan)
    hit = inside & np.isfinite(z) & (z > 0) & (z < P[ok[ip], 2] - eps)
    out[ok[np.unique(ip[hit])]] = True
    return out


def _box_pairs(d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point, box) index pairs of the points d (k, 2) inside the boxes [lo, hi] (f, 2), through a uniform grid
    of cells about the median box's size (each box listed in the cells it overlaps): O(k + f + pairs)."""
    size = np.maximum(np.median(hi - lo, 0), 1e-12)
    o = np.minimum(d.min(0), lo.min(0))
    span = np.maximum(d.max(0), hi.max(0)) - o
    nx, ny = (np.minimum(np.ceil(span / size), 2048).astype(np.int64) + 1).tolist()
    cell = span / np.array([nx - 1, ny - 1]).clip(1)
    c0 = np.floor((lo - o) / cell).astype(np.int64)
    c1 = np.floor((hi - o) / cell).astype(np.int64)
    w = c1 - c0 + 1                                              # (f, 2) cells per box along x, y
    cnt = w[:, 0] * w[:, 1]
    big = cnt > 64                                               # a box over many cells: tested against every point
    cnt[big] = 0
    box = np.repeat(np.arange(len(lo)), cnt)
    k = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)  # index within the box's cells
    gx = c0[box, 0] + k % w[box, 0]
    gy = c0[box, 1] + k // w[box, 0]
    key = gy * nx + gx
    order = np.argsort(key, kind="stable")
    key, box = key[order], box[order]
    pc = np.floor((d - o) / cell).astype(np.int64)
    pkey = pc[:, 1] * nx + pc[:, 0]
    start, stop = np.searchsorted(key, pkey, "left"), np.searchsorted(key, pkey, "right")
    m = stop - start
    ip = np.repeat(np.arange(len(d)), m)
    it = box[np.repeat(start, m) + np.arange(m.sum()) - np.repeat(np.cumsum(m) - m, m)]
    jb = np.flatnonzero(big)
    ip = np.concatenate([ip, np.repeat(np.arange(len(d)), len(jb))])
    it = np.concatenate([it, np.tile(jb, len(d))])
    inb = np.all((d[ip] >= lo[it]) & (d[ip] <= hi[it]), axis=1)
    return ip[inb], it[inb]
