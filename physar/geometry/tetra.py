"""Tetrahedral meshes of a user's closed surface (gmsh), simple closed test shapes, tet quality.

:func:`tetrahedralize` fills a closed, outward- or inward-oriented triangle surface (an STL/OBJ/PLY/OFF
file read with :func:`physar.geometry.read_mesh`) with linear tetrahedra using gmsh (the Python wheel
``gmsh``, which bundles its C++ library; it needs no GUI libraries for this use). The surface is first
split into smooth patches at sharp edges (``classifySurfaces``, feature angle ``angle`` degrees), the
patches are remeshed at the target element size and the volume is meshed by gmsh's Delaunay algorithm,
then optimised (``Mesh.Optimize``, plus Netgen optimisation). Remeshing the surface is what makes the
mesh good on a CAD-exported STL, whose triangles are typically long slivers. A surface of several closed
bodies (:func:`surface_bodies`) gives one volume per solid, a body inside another being a cavity; bodies
that cross or touch are refused.

Before gmsh starts, the element count is estimated from the enclosed volume (:func:`estimate_tet_count`) and
a size that would give more than ``max_elements`` (default :data:`MAX_ELEMENTS`) or more memory than is
available is refused in one line. gmsh runs in a child process: its C++ meshing never returns to Python
until it ends, so in-process it could not be interrupted; Ctrl-C or SIGTERM now kills the child at once
(about 15-20 ms of start-up per call, 0.3 us per tetrahedron to send the mesh back: measured, against 0.4 s
for 1,400 tetrahedra and 300 us per tetrahedron of meshing).

Why gmsh and not TetGen (measured on 2 shared cores, default size = half the smallest bounding-box
extent, TetGen 0.8.4 with ``-pq1.2/10a<regular-tet volume of that size>``, min dihedral / min radius ratio):

================================  ================================  ================================
surface (input triangles)         gmsh 4.15: time, tets, dihedral    TetGen (tetgen 0.8.4): same
================================  ================================  ================================
plate with hole, fine (4340)      0.61 s, 9685, 18.1 deg, rr 0.31    0.13 s, 26363, 2.2 deg, rr 0.03
plate with hole, CAD-like (58)    0.51 s, 9850, 21.5 deg, rr 0.31    0.15 s, 25982, 1.9 deg, rr 0.04
L-bracket, fine (586)             68 ms, 732, 20.8 deg, rr 0.35      5 ms, 1036, 5.5 deg, rr 0.13
L-bracket, CAD-like (44)          57 ms, 743, 19.8 deg, rr 0.24      3 ms, 348, 7.0 deg, rr 0.16
================================  ================================  ================================

(dihedral: the smallest dihedral angle of the mesh; rr: the smallest radius ratio.)
TetGen is 4-20x faster but keeps slivers (dihedral angles of 2-7 degrees, which degrade the stiffness
matrix's conditioning and P2 accuracy); gmsh remeshes the surface and optimises the volume, and its
time (0.6 s for 10k tetrahedra) is negligible next to a solve. Mesh quality decides: gmsh.

:func:`plate_with_hole_surface` and :func:`l_bracket_surface` build closed, outward-oriented surfaces
with gmsh's OpenCASCADE kernel (exact CAD booleans), for tests and examples.

:func:`tet_quality` gives per-element minimum dihedral angle (degrees) and radius ratio
3 r_in / R_circ (1 for the regular tetrahedron, 0 for a degenerate one).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable

import numpy as np

from physar.errors import MeshError
from physar.geometry.mesh import TetMesh, TriMesh
from physar.geometry.regions import MeshTags

_GMSH_LOCK = threading.Lock()  # gmsh keeps one global model: serialise every use


class _Gmsh:
    """Context: an initialised, silent gmsh session (finalised on exit)."""

    def __enter__(self):
        try:
            import gmsh
        except ImportError as exc:  # pragma: no cover - gmsh is a dependency
            raise MeshError(f"tetrahedralisation needs the gmsh Python package (pip install gmsh): {exc}") from None
        _GMSH_LOCK.acquire()
        self._handlers = _signal_handlers()
        try:
            gmsh.initialize(readConfigFiles=False, interruptible=False)
        except Exception:
            _GMSH_LOCK.release()
            raise
        finally:
            _restore_handlers(self._handlers)
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        self.gmsh = gmsh
        return gmsh

    def __exit__(self, *exc):
        try:
            self.gmsh.finalize()
        finally:
            _restore_handlers(self._handlers)
            _GMSH_LOCK.release()
        return False


def _signal_handlers() -> dict:
    """Python's handlers of SIGINT and SIGTERM (gmsh's initialize/finalize reset them in C: measured, a
    SIGTERM after a gmsh session killed the process instead of unwinding through physar's cleanup)."""
    return {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}


def _restore_handlers(handlers: dict) -> None:
    """Install ``handlers`` again at the C level (main thread only; elsewhere signals are not ours to set)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for s, h in handlers.items():
        if h is not None:
            signal.signal(s, h)


def _add_discrete_surface(gmsh, surface: TriMesh) -> int:
    """Add ``surface``'s triangles to the current gmsh model as one discrete surface (gmsh node tags = vertex
    index + 1, unused vertices left out; element tags = face index + 1); returns its entity tag."""
    used = np.unique(surface.faces)
    s = gmsh.model.addDiscreteEntity(2)
    gmsh.model.mesh.addNodes(2, s, (used + 1).tolist(), surface.points[used].ravel().tolist())
    gmsh.model.mesh.addElementsByType(s, 2, np.arange(1, surface.n_faces + 1).tolist(),
                                      (surface.faces + 1).ravel().tolist())
    return s


def boundary_edge_count(mesh: TriMesh) -> int:
    """Number of edges used by exactly one face (0 for a closed surface)."""
    e = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(e[:, 0] * np.int64(mesh.n_points) + e[:, 1], return_counts=True)
    return int(np.sum(counts == 1))


FLAT_RTOL = 1e-6  # plane-fit tolerance of is_flat, relative to the bounding-box diagonal (float32 STL: ~1e-7)


def is_flat(mesh: TriMesh, rtol: float = FLAT_RTOL) -> bool:
    """True when all the vertices used by ``mesh``'s faces lie in one plane (a 2-D mesh, a single sheet).

    The plane is the least-squares fit of the centred vertices: its normal is the right singular vector of
    the smallest singular value; the surface is flat when every vertex is within ``rtol`` times the
    bounding-box diagonal of that plane (collinear or coincident vertices count as flat)."""
    p = mesh.points[np.unique(mesh.faces)]
    if len(p) == 0:
        return False
    diag = float(np.linalg.norm(np.ptp(p, axis=0)))
    c = p - p.mean(axis=0)
    normal = np.linalg.svd(c, full_matrices=False)[2][-1]
    return bool(np.abs(c @ normal).max() <= rtol * diag)


def check_closed(mesh: TriMesh, source: str | None = None) -> None:
    """MeshError unless every edge has two faces: "<source>: surface is not closed (N boundary edges)", or, for
    an open surface whose vertices all lie in one plane (:func:`is_flat`, e.g. a 2-D mesh), "<source>: the
    surface is flat ..." saying that a volume needs a closed 3-D surface. A closed surface is never called flat."""
    from physar.geometry.quality import check_surface

    check_surface(mesh)  # empty, repeated vertices, non-manifold edges
    n = boundary_edge_count(mesh)
    if n and is_flat(mesh):
        raise MeshError(f"{source or mesh.name}: the surface is flat (all its points lie in one plane, e.g. a 2-D "
                        f"mesh; {n} boundary edges); a volume mesh needs a closed 3-D surface that encloses "
                        "the solid")
    if n:
        raise MeshError(f"{source or mesh.name}: surface is not closed ({n} boundary edges); "
                        "a volume mesh needs a watertight surface")


def default_size(surface: TriMesh) -> float:
    """Default element size (m): half the smallest extent of the bounding box (two P2 elements through
    the thickness of a plate-like part, enough for bending; pass `size` to refine)."""
    ext = np.ptp(surface.points, axis=0)
    ext = ext[ext > 0]
    if ext.size == 0:
        raise MeshError(f"{surface.name}: the surface has no extent")
    return float(ext.min() / 2.0)


# ------------------------------------------------------------------------------ element-count estimate
#: tetrahedra gmsh makes per regular tetrahedron of edge `size` that fits in the enclosed volume
#: (volume / (size^3 / (6 sqrt 2))), measured with gmsh 4.15 (Delaunay + optimisers, as tetrahedralize runs
#: it): unit box 0.50 / 0.47 / 0.46 at size 0.05 / 0.025 / 0.0167 (33,923 / 254,733 / 834,999 tets), sphere
#: r = 0.5 0.67 / 0.59 at 0.05 / 0.025, L-bracket 0.70 / 0.54 at 0.005 / 0.0025, plate with hole 0.91 / 0.63 /
#: 0.53 at 0.005 / 0.0025 / 0.00125. Fine sizes, where a limit matters, tend to 0.5; coarse ones (a few
#: elements across) have up to 2.4x more (unit box at 0.2: 1,425), far below any limit.
TETS_PER_REGULAR_VOLUME = 0.55
#: memory of the gmsh child process per tetrahedron (bytes) and fixed (bytes), from peak resident sizes:
#: gmsh alone 191 / 523 MB at 254,733 / 834,999 tets of the unit box (0.57 kB/tet slope, 41 MB base), sphere
#: 145 MB at 166,545; the child of tetrahedralize 258 MB at 254,648 (0.51 kB/tet above its parent's 131 MB).
#: 1 kB/tet and 60 MB are taken: a margin of 2 for the optimisers' peaks on other shapes
GMSH_BYTES_PER_TET = 1000.0
GMSH_BYTES_FIXED = 60e6
#: default cap of :func:`tetrahedralize`'s estimated element count (``max_elements``): gmsh meshes about
#: 3,000 tetrahedra a second on one core (347 us/tet measured at 835k tets, 255-330 us/tet from 34k to 255k,
#: Netgen optimiser included), so 2 million is 10-12 minutes, and a P2 model of it ~9 million unknowns
MAX_ELEMENTS = 2_000_000


def estimate_tet_count(volume: float, area: float, size: float) -> float:
    r"""Tetrahedra gmsh makes at element size ``size`` in a solid of enclosed ``volume`` bounded by ``area``:
    the larger of :data:`TETS_PER_REGULAR_VOLUME` :math:`\cdot V / (h^3 / (6\sqrt 2))` (regular tetrahedra of
    edge h filling the volume) and the surface's equilateral triangles :math:`A / (\sqrt 3 h^2 / 4)` (a thin
    part has at least about one tetrahedron per boundary triangle)."""
    h = float(size)
    return max(TETS_PER_REGULAR_VOLUME * abs(volume) * 6.0 * np.sqrt(2.0) / h**3, area / (np.sqrt(3.0) / 4 * h**2))


# ------------------------------------------------------------------------------ bodies of a surface
def _face_components(faces: np.ndarray) -> tuple[int, np.ndarray]:
    """Number of edge-connected components of a closed manifold triangle surface, and each face's label
    (0, 1, ... in the order of their first face)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nf = len(faces)
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    key = e[:, 0] * np.int64(faces.max() + 1) + e[:, 1]
    order = np.argsort(key, kind="stable")
    a, b = order[0::2] // 3, order[1::2] // 3  # every edge has exactly two faces (check_closed)
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(nf, nf))
    n, lab = connected_components(g, directed=False)
    _, first = np.unique(lab, return_index=True)
    rank = np.empty(n, np.int64)
    rank[np.argsort(np.argsort(first))] = np.arange(n)  # relabel by first face
    return int(n), rank[lab]


def _signed_volume(x: np.ndarray) -> float:
    r"""Signed volume enclosed by the triangles ``x`` (f, 3, 3): :math:`\sum x_0 \cdot (x_1 \times x_2) / 6`,
    about their centroid (less cancellation); positive for an outward orientation."""
    x = x - x.reshape(-1, 3).mean(axis=0)
    return float(np.einsum("fi,fi->", x[:, 0], np.cross(x[:, 1], x[:, 2])) / 6.0)


def _winding_number(q: np.ndarray, tri: np.ndarray) -> np.ndarray:
    r"""Winding numbers of the points ``q`` (k, 3) with respect to the closed triangles ``tri`` (m, 3, 3): the
    sum of the triangles' signed solid angles (Van Oosterom and Strackee,
    :math:`\tan(\Omega/2) = a \cdot (b \times c) / (abc + (a \cdot b) c + (a \cdot c) b + (b \cdot c) a)`)
    over :math:`4\pi`; +-1 inside, 0 outside."""
    out = np.empty(len(q))
    step = max(1, 2**17 // max(len(tri), 1))
    for i in range(0, len(q), step):
        d = tri[None] - q[i:i + step, None, None]  # (k, m, 3, 3)
        a, b, c = d[:, :, 0], d[:, :, 1], d[:, :, 2]
        la, lb, lc = (np.linalg.norm(v, axis=2) for v in (a, b, c))
        num = np.einsum("kmi,kmi->km", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("kmi,kmi->km", a, b) * lc + np.einsum("kmi,kmi->km", a, c) * lb
               + np.einsum("kmi,kmi->km", b, c) * la)
        out[i:i + step] = 2.0 * np.arctan2(num, den).sum(axis=1) / (4.0 * np.pi)
    return out


def _meet(p0: np.ndarray, p1: np.ndarray, t0: np.ndarray, t1: np.ndarray, t2: np.ndarray, tol: float) -> bool:
    """True when, for some row, the segment (p0, p1) crosses or touches the triangle (t0, t1, t2), up to the
    length ``tol``: its ends strictly on both sides of the triangle's plane (farther than ``tol``) with the
    crossing point in the triangle, or an end within ``tol`` of the plane with its projection in the
    triangle ("in": at most ``tol`` outside each of its edges). A segment lying in the triangle's plane is only
    tested by its ends; for two closed bodies, faces in contact with no vertex in the other's face (bars
    stacked crosswise) and edges touching edges are still seen, where an edge of one crosses a side face of the
    other at that face's border (the ``tol`` margin)."""
    n = np.cross(t1 - t0, t2 - t0)
    nn = np.linalg.norm(n, axis=1)
    lim = tol * nn

    def in_triangle(x, k):  # rows k: x in the triangle's plane, at most tol outside each of its edges
        ok = np.ones(len(k), bool)
        for u, v in ((t1, t2), (t2, t0), (t0, t1)):
            u, v = u[k], v[k]
            ok &= np.einsum("ki,ki->k", np.cross(u - x, v - x), n[k]) >= -tol * np.linalg.norm(v - u, axis=1) * nn[k]
        return ok

    d0 = np.einsum("ki,ki->k", p0 - t0, n)
    d1 = np.einsum("ki,ki->k", p1 - t0, n)
    k = np.flatnonzero(((d0 > lim) & (d1 < -lim)) | ((d0 < -lim) & (d1 > lim)))
    if len(k) and in_triangle(p0[k] + (d0[k] / (d0[k] - d1[k]))[:, None] * (p1[k] - p0[k]), k).any():
        return True
    for p, d in ((p0, d0), (p1, d1)):
        k = np.flatnonzero(np.abs(d) <= lim)
        if len(k) and in_triangle(p[k] - (d[k] / nn[k] ** 2)[:, None] * n[k], k).any():  # its projection
            return True
    return False


def _grid_cells(lo: np.ndarray, hi: np.ndarray, origin: np.ndarray, cell: float, dims: np.ndarray):
    """(cell key, primitive index) of every grid cell that each box [lo, hi] (k, 3) covers."""
    i0 = np.floor((lo - origin) / cell).astype(np.int64)
    d = np.floor((hi - origin) / cell).astype(np.int64) - i0 + 1
    cnt = d.prod(axis=1)
    rep = np.repeat(np.arange(len(lo)), cnt)
    r = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    dx, dy = d[rep, 0], d[rep, 1]
    x, y, z = i0[rep, 0] + r % dx, i0[rep, 1] + (r // dx) % dy, i0[rep, 2] + r // (dx * dy)
    return x + dims[0] * (y + dims[1] * z), rep


def _runs(v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Values, first indices and lengths of the runs of equal values of the sorted ``v``."""
    start = np.flatnonzero(np.r_[True, v[1:] != v[:-1]])
    return v[start], start, np.diff(np.r_[start, len(v)])


#: most (cell, primitive) entries of the grid of :func:`_any_meeting` (the cell is doubled until they fit)
GRID_ENTRIES = 20_000_000


def _any_meeting(seg: np.ndarray, tri: np.ndarray, tol: float) -> bool:
    """:func:`_meet` over the pairs of a segment of ``seg`` (n, 2, 3) and a triangle of ``tri`` (m, 3, 3)
    whose bounding boxes (grown by ``tol``) share a cell of a uniform grid (cell: twice the median extent of
    the primitives, doubled while the grid would hold more than :data:`GRID_ENTRIES` entries), and overlap;
    tested in chunks of a million pairs. Measured on two concentric spheres 1 mm apart (327k and 82k triangles,
    each edge near the other surface): 3.5 s each way, :func:`surface_bodies` 10 s, against 36 s of gmsh for
    the outer sphere alone at size 0.1 (a k-d recursion took 15-35 s)."""
    slo, shi = seg.min(axis=1) - tol, seg.max(axis=1) + tol
    tlo, thi = tri.min(axis=1), tri.max(axis=1)
    lo, hi = np.maximum(slo.min(axis=0), tlo.min(axis=0)), np.minimum(shi.max(axis=0), thi.max(axis=0))
    if (lo > hi).any():
        return False
    ks = np.flatnonzero(np.all((shi >= lo) & (slo <= hi), axis=1))  # both cut down to their common box
    ms = np.flatnonzero(np.all((thi >= lo) & (tlo <= hi), axis=1))
    if len(ks) == 0 or len(ms) == 0:
        return False
    slo, shi, tlo, thi = np.maximum(slo[ks], lo), np.minimum(shi[ks], hi), np.maximum(tlo[ms], lo), np.minimum(thi[ms], hi)
    ext = np.concatenate([shi - slo, thi - tlo]).max(axis=1)
    cell = max(2.0 * float(np.median(ext)), float((hi - lo).max()) / 2**20, tol, 1e-300)
    while True:
        dims = np.floor((hi - lo) / cell).astype(np.int64) + 1
        d_s = np.floor((shi - lo) / cell) - np.floor((slo - lo) / cell) + 1
        d_t = np.floor((thi - lo) / cell) - np.floor((tlo - lo) / cell) + 1
        if d_s.prod(axis=1).sum() + d_t.prod(axis=1).sum() <= GRID_ENTRIES:
            break
        cell *= 2.0
    key_s, id_s = _grid_cells(slo, shi, lo, cell, dims)
    key_t, id_t = _grid_cells(tlo, thi, lo, cell, dims)
    o_s, o_t = np.argsort(key_s, kind="stable"), np.argsort(key_t, kind="stable")
    key_s, id_s, key_t, id_t = key_s[o_s], id_s[o_s], key_t[o_t], id_t[o_t]
    u_s, start_s, cnt_s = _runs(key_s)
    u_t, start_t, cnt_t = _runs(key_t)
    _, ia, ib = np.intersect1d(u_s, u_t, assume_unique=True, return_indices=True)
    sa, ca, sb, cb = start_s[ia], cnt_s[ia], start_t[ib], cnt_t[ib]
    npair = ca * cb
    ends = np.cumsum(npair)
    c0 = 0
    while c0 < len(npair):  # chunks of cells holding about a million pairs
        c1 = max(c0 + 1, int(np.searchsorted(ends, (ends[c0 - 1] if c0 else 0) + 2**20)))
        rep = np.repeat(np.arange(c0, c1), npair[c0:c1])
        r = np.arange(len(rep)) - np.repeat(np.cumsum(npair[c0:c1]) - npair[c0:c1], npair[c0:c1])
        i = id_s[sa[rep] + r // cb[rep]]
        j = id_t[sb[rep] + r % cb[rep]]
        pair = np.sort(i * np.int64(len(ms)) + j)  # a pair met in several cells: tested once
        pair = pair[np.r_[True, pair[1:] != pair[:-1]]]  # (np.unique's hash path took 1 s per call here)
        i, j = pair // len(ms), pair % len(ms)
        keep = np.all((shi[i] >= tlo[j]) & (slo[i] <= thi[j]), axis=1)
        i, j = ks[i[keep]], ms[j[keep]]
        if len(i) and _meet(seg[i, 0], seg[i, 1], tri[j, 0], tri[j, 1], tri[j, 2], tol):
            return True
        c0 = c1
    return False


def _box_text(x: np.ndarray) -> str:
    lo, hi = x.reshape(-1, 3).min(axis=0), x.reshape(-1, 3).max(axis=0)
    return "[" + ", ".join(f"{v:.4g}" for v in lo) + "]-[" + ", ".join(f"{v:.4g}" for v in hi) + "]"


def surface_bodies(surface: TriMesh, source: str | None = None) -> dict:
    """The separate closed bodies of the closed surface ``surface`` and how they nest.

    Bodies are the edge-connected components of the triangles. Two bodies whose surfaces cross or touch (an
    edge of one through a triangle of the other, or a vertex of one on a triangle of the other, within
    :data:`FLAT_RTOL` of the bounding-box diagonal, tested both ways) are refused in one MeshError line: gmsh
    cannot mesh overlapping solids, and touching ones would be meshed as unconnected parts. Otherwise a body
    lies inside another when its vertices have winding number 1 with respect to the other's triangles; its
    ``depth`` is the number of bodies around it. A body at even depth is a solid's outer boundary, one at odd
    depth a cavity of the body just around it (a body in a cavity is a solid again).

    Returns ``labels`` (a body per face), ``volumes`` (one ``(outer, [cavities])`` per solid region),
    ``depth``, ``signed_volumes`` and ``areas`` per body, and ``volume``, the enclosed volume (the sum of the
    bodies' volumes at even depth minus those at odd depth)."""
    name = source or surface.name
    n, lab = _face_components(surface.faces)
    x = surface.points[surface.faces]
    order = np.argsort(lab, kind="stable")
    split = np.cumsum(np.bincount(lab, minlength=n))[:-1]
    tris = [x[i] for i in np.split(order, split)]
    vols = np.array([_signed_volume(t) for t in tris])
    areas = np.array([0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
                      for t in tris])
    depth = np.zeros(n, np.int64)
    inside = np.zeros((n, n), bool)  # inside[i, j]: body i lies in body j
    if n > 1:
        diag = float(np.linalg.norm(np.ptp(x.reshape(-1, 3), axis=0)))
        tol = FLAT_RTOL * diag  # float32 STL coordinates: bodies that touch may overlap by ~1e-7 of the size
        lo = np.array([t.reshape(-1, 3).min(axis=0) for t in tris])
        hi = np.array([t.reshape(-1, 3).max(axis=0) for t in tris])
        from physar.geometry.quality import unique_edges

        fb = np.split(surface.faces[order], split)
        segs = [surface.points[unique_edges(f, surface.n_points)] for f in fb]  # (e, 2, 3) per body
        meet = np.all((lo[:, None] <= hi[None] + tol) & (lo[None] <= hi[:, None] + tol), axis=2)
        for i, j in zip(*np.nonzero(np.triu(meet, 1)), strict=True):  # pairs of overlapping bounding boxes
            if _any_meeting(segs[i], tris[j], tol) or _any_meeting(segs[j], tris[i], tol):
                raise MeshError(
                    f"{name}: gmsh could not mesh the volume (self-intersecting surface: of its {n} separate "
                    f"closed bodies, body {i + 1} in {_box_text(tris[i])} and body {j + 1} in "
                    f"{_box_text(tris[j])} cross or touch each other); join them into one closed surface "
                    "(their union) or move them apart")
            for a, b in ((i, j), (j, i)):
                if (lo[a] >= lo[b] - tol).all() and (hi[a] <= hi[b] + tol).all():
                    q = tris[a].reshape(-1, 3)
                    q = q[np.linspace(0, len(q) - 1, min(len(q), 9)).astype(int)]
                    w = _winding_number(q, tris[b]) * np.sign(vols[b])
                    inside[a, b] = np.median(w) > 0.5
        depth = inside.sum(axis=1)
    regions = []
    for i in np.flatnonzero(depth % 2 == 0):
        holes = [int(j) for j in np.flatnonzero((depth == depth[i] + 1) & inside[:, i])]
        regions.append((int(i), holes))
    volume = float(np.sum(np.where(depth % 2 == 0, 1.0, -1.0) * np.abs(vols)))
    return {"labels": lab, "volumes": regions, "depth": depth, "signed_volumes": vols, "areas": areas,
            "volume": volume}


# ------------------------------------------------------------------------------ meshing in a child process
#: how the gmsh child process is started: "fork" on Linux (no start-up cost: 0-20 ms measured, against
#: 500-700 ms for "spawn", which imports physar again), "spawn" elsewhere (fork is unsafe on macOS)
START_METHOD = "fork" if sys.platform.startswith("linux") else "spawn"


def _die_with_parent(parent: int) -> None:
    """In the child: be killed when the parent dies, even by SIGKILL (Linux ``prctl(PR_SET_PDEATHSIG)``), so a
    killed physar leaves no gmsh behind; exit at once when the parent is already gone."""
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1
        except (OSError, AttributeError):  # pragma: no cover - no prctl
            pass
    if os.getppid() != parent:
        os._exit(1)


def _child_main(conn, parent: int, fn: Callable, args: tuple) -> None:
    """Entry point of the gmsh child: signals as the parent decides (Ctrl-C reaches the whole process group,
    the parent kills the child), ``fn(*args)`` sent back as ("ok", result), ("error", MeshError text) or
    ("bug", traceback). gmsh.initialize leaves an ignored SIGINT ignored and sets SIGTERM to its default
    action (measured, gmsh 4.15), which is what the child needs."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _die_with_parent(parent)
    try:
        out = ("ok", fn(*args))
    except MeshError as exc:
        out = ("error", str(exc))
    except BaseException:  # noqa: BLE001 - a bug: its traceback goes to the parent
        import traceback

        out = ("bug", traceback.format_exc())
    conn.send(out)
    conn.close()


def _in_process(fn: Callable, args: tuple):
    """``fn(*args)`` in this process, serialised with every other gmsh use, gmsh finalised and Python's signal
    handlers restored afterwards (gmsh's initialize resets them in C)."""
    import gmsh

    with _GMSH_LOCK:
        handlers = _signal_handlers()
        try:
            return fn(*args)
        finally:
            try:
                if gmsh.isInitialized():
                    gmsh.finalize()
            finally:
                _restore_handlers(handlers)


def _in_child(fn: Callable, args: tuple, name: str):
    """``fn(*args)`` run in a child process (:data:`START_METHOD`), its result returned; a MeshError raised
    there is raised here. Ctrl-C, or SIGTERM under :func:`physar.output.sigterm_as_interrupt`, raises
    KeyboardInterrupt here while waiting, and the child is killed (SIGKILL) before it propagates: gmsh's C++
    loop never returns to Python, so in-process meshing could not be interrupted. A child that dies (out of
    memory, a gmsh crash) is one MeshError line with its exit status."""
    import multiprocessing as mp
    import warnings

    if mp.current_process().daemon:  # a Pool or Dask worker may not start a child: mesh here (as before;
        return _in_process(fn, args)  # Ctrl-C then waits for gmsh)
    ctx = mp.get_context(START_METHOD)
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child_main, args=(send, os.getpid(), fn, args), daemon=True, name="physar-gmsh")
    with _GMSH_LOCK, warnings.catch_warnings():  # no thread of ours is inside gmsh while the child forks
        warnings.filterwarnings("ignore", message=".*multi-threaded.*fork", category=DeprecationWarning)
        proc.start()
    send.close()
    try:
        try:
            status, payload = recv.recv()
        except EOFError:
            proc.join()
            code = proc.exitcode
            why = (f"killed by signal {signal.Signals(-code).name}" if code is not None and code < 0
                   and -code in signal.valid_signals() else f"exit status {code}")
            hint = " (out of memory? try a larger mesh size)" if code == -signal.SIGKILL else ""
            raise MeshError(f"{name}: gmsh stopped without a mesh ({why}){hint}") from None
        proc.join()
    finally:
        recv.close()
        if proc.is_alive():  # interrupted (KeyboardInterrupt) or failed while waiting: stop gmsh now
            proc.kill()
            proc.join()
    if status == "error":
        raise MeshError(payload)
    if status == "bug":
        raise RuntimeError(f"gmsh child process failed:\n{payload}")
    return payload


def _tag_edges(faces: np.ndarray, face_tags: np.ndarray) -> np.ndarray:
    """Edges (e, 2) of a closed triangle surface whose two faces carry different tags: the boundaries of its
    tagged regions (vertex ids, smaller first)."""
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    order = np.lexsort((e[:, 1], e[:, 0]))
    a, b = order[0::2], order[1::2]  # the two faces of each edge (check_closed: exactly two)
    t = np.repeat(face_tags, 3)
    return e[a[t[a] != t[b]]]


def _patch_tags(gmsh, faces: np.ndarray, face_tags: np.ndarray) -> dict[int, int]:
    """{surface entity: tag} of the patches classifySurfaces made of the input triangles (element tag = face
    index + 1, :func:`_add_discrete_surface`; classifySurfaces moves triangles between patches, keeping them):
    the tag most of its triangles carry (all of them, as the tag boundaries are patch boundaries)."""
    out = {}
    for _, t in gmsh.model.getEntities(2):
        elements, nodes = gmsh.model.mesh.getElementsByType(2, t)
        f = np.asarray(elements, np.int64) - 1
        ok = (f >= 0) & (f < len(faces))
        ok[ok] = (np.sort(faces[f[ok]] + 1, axis=1)
                  == np.sort(np.asarray(nodes, np.int64).reshape(-1, 3)[ok], axis=1)).all(axis=1)
        if ok.any():
            values, counts = np.unique(face_tags[f[ok]], return_counts=True)
            out[t] = int(values[np.argmax(counts)])
    return out


def _gmsh_volume_mesh(points: np.ndarray, faces: np.ndarray, labels: np.ndarray, regions: list, size: float,
                      angle: float, optimize: bool, name: str, face_tags: np.ndarray | None = None) -> tuple:
    """In the gmsh child: the tetrahedra (points, cells; only the nodes they use) of the solid regions
    ``regions`` (``(outer body, [cavity bodies])``, bodies as ``labels`` of the faces) of the closed surface
    (points, faces), and the boundary triangles (k, 3) of the tetrahedra with their tags (k,) when
    ``face_tags`` (one per face) are given, else None, None.

    The edges between faces of different tags are added as a discrete curve before ``classifySurfaces``, which
    keeps every existing curve's edges as patch boundaries; so no patch, and no remeshed triangle, straddles two
    tags, and each remeshed boundary triangle takes the tag of its patch's input triangles."""
    import gmsh

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.Verbosity", 0)
    body_of_node = np.full(len(points) + 1, -1, np.int64)
    body_of_node[faces.ravel() + 1] = np.repeat(labels, 3)
    seams = _tag_edges(faces, face_tags) if face_tags is not None else np.zeros((0, 2), np.int64)
    patch_tag: dict[int, int] = {}

    def attempt(reparametrize: bool) -> None:
        gmsh.clear()
        gmsh.model.add("physar")
        _add_discrete_surface(gmsh, TriMesh(points, faces, name=name))
        if len(seams):  # tag boundaries: kept as patch boundaries by classifySurfaces
            c = gmsh.model.addDiscreteEntity(1)
            gmsh.model.mesh.addElementsByType(c, 1, [], (seams + 1).ravel().tolist())
        gmsh.model.mesh.classifySurfaces(np.radians(angle), True, reparametrize, np.pi)
        gmsh.model.mesh.createGeometry()
        if face_tags is not None:
            patch_tag.clear()
            patch_tag.update(_patch_tags(gmsh, faces, face_tags))
        patches: dict[int, list[int]] = {}  # body -> its patches (by the original nodes of their triangles)
        for _, t in gmsh.model.getEntities(2):
            _, nodes = gmsh.model.mesh.getElementsByType(2, t)
            nodes = np.asarray(nodes, np.int64)
            b = body_of_node[nodes[nodes < len(body_of_node)]]
            b = b[b >= 0]
            if len(b):
                patches.setdefault(int(np.bincount(b).argmax()), []).append(t)
        for outer, holes in regions:
            loops = [gmsh.model.geo.addSurfaceLoop(patches.get(body, [])) for body in (outer, *holes)]
            gmsh.model.geo.addVolume(loops)
        gmsh.model.geo.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", float(size))
        gmsh.option.setNumber("Mesh.MeshSizeMin", float(size) / 4)
        gmsh.option.setNumber("Mesh.Optimize", 1 if optimize else 0)
        gmsh.option.setNumber("Mesh.OptimizeNetgen", 1 if optimize else 0)
        gmsh.model.mesh.generate(3)

    try:
        try:
            attempt(False)
        except Exception as exc:
            if "parametri" not in str(exc).lower():
                raise
            # a patch that is not a topological disc (a sphere or any smooth closed surface: "Invalid exterior
            # boundary mesh for parametrization"): split the patches so that each can be parametrised. Not by
            # default: the split changes the mesh of every surface (the example bracket.stl at 2.5 mm: 25,981
            # tetrahedra become 27,799), and with it the results of existing models
            attempt(True)
    except Exception as exc:  # noqa: BLE001 - gmsh raises a bare Exception with its last error message
        msg = " ".join(str(exc).split())
        hint = " (self-intersecting surface?)" if "intersect" in msg.lower() or "invalid" in msg.lower() else ""
        raise MeshError(f"{name}: gmsh could not mesh the volume{hint}: {msg}"[:300]) from None
    tags, xyz, _ = gmsh.model.mesh.getNodes()
    _, tet_nodes = gmsh.model.mesh.getElementsByType(4)
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    tags = np.asarray(tags, np.int64)
    if len(tet_nodes) == 0:
        return np.zeros((0, 3)), np.zeros((0, 4), np.int64), None, None
    lookup = np.full(int(tags.max()) + 1, -1, np.int64)
    lookup[tags] = np.arange(len(tags))
    cells = lookup[np.asarray(tet_nodes, np.int64).reshape(-1, 4)]
    used, cells = np.unique(cells, return_inverse=True)
    if face_tags is None:
        return xyz[used], cells.reshape(-1, 4), None, None
    tri, tri_tags = [], []
    for t, tag in patch_tag.items():
        _, nodes = gmsh.model.mesh.getElementsByType(2, t)
        tri.append(lookup[np.asarray(nodes, np.int64).reshape(-1, 3)])
        tri_tags.append(np.full(len(tri[-1]), tag, np.int64))
    tri = np.searchsorted(used, np.concatenate(tri)) if tri else np.zeros((0, 3), np.int64)
    return xyz[used], cells.reshape(-1, 4), tri, np.concatenate(tri_tags) if tri_tags else np.zeros(0, np.int64)


def _bytes_text(n: float) -> str:
    return f"{n / 2**30:.3g} GiB" if n >= 2**30 else f"{n / 2**20:.3g} MiB"


def _count_text(n: float) -> str:
    return f"{n / 1e6:.3g} million" if n >= 1e6 else f"{n:,.0f}"


def tetrahedralize(surface: TriMesh, size: float | None = None, angle: float = 40.0,
                   optimize: bool = True, source: str | None = None,
                   max_elements: float | None = None) -> TetMesh:
    """Linear tetrahedral mesh of the solid bounded by the closed triangle surface `surface` (gmsh).

    ``size`` (m) is the target element edge length, default :func:`default_size`; surface patches are
    split at edges sharper than ``angle`` degrees and remeshed at that size, the volume is meshed by
    Delaunay and optimised (gmsh + Netgen optimisers when ``optimize``). ``source`` names the input in
    errors (default: the surface's name).

    A surface made of several closed bodies (:func:`surface_bodies`) gives one volume per solid: separate
    bodies are meshed side by side, a body inside another is a cavity (and a body inside a cavity a solid
    again); bodies whose surfaces cross are refused.

    Before gmsh starts, the element count is estimated (:func:`estimate_tet_count`) and refused in one line
    naming the size that gives about a million elements when it exceeds ``max_elements`` (default
    :data:`MAX_ELEMENTS`) or when gmsh's memory for it (:data:`GMSH_BYTES_PER_TET`) exceeds the memory
    available. gmsh runs in a child process (:func:`_in_child`): Ctrl-C (or SIGTERM under
    :func:`physar.output.sigterm_as_interrupt`) stops it at once with a KeyboardInterrupt here.

    Region tags: when ``surface.face_tags`` is given (e.g. a .msh or VTU surface with physical groups, an OBJ
    with groups, read by :func:`physar.geometry.read_mesh`), the mesh gets ``tags`` (:class:`MeshTags`): every
    boundary triangle of the tetrahedra carries the tag of the input triangles it was remeshed from, and the
    names of ``surface.tag_names`` (dim 2). Exact, not a nearest-face guess: the edges between differently
    tagged faces are made patch boundaries before gmsh remeshes the patches, so no boundary triangle straddles
    two regions (a tag boundary across a flat face gets a row of mesh edges along it; an untagged surface
    meshes exactly as before). Faces tagged negative (untagged) stay untagged.

    Raises MeshError for an open surface, a non-manifold one, a self-intersecting one (as gmsh reports it),
    crossing bodies, a non-positive size or too many elements.
    """
    from physar.output import available_memory

    name = source or surface.name
    check_closed(surface, name)
    if size is None:
        size = default_size(surface)
    if not (np.isfinite(size) and size > 0):
        raise MeshError(f"{name}: mesh size must be a positive length in m, got {size}")
    limit = MAX_ELEMENTS if max_elements is None else max_elements
    if not limit > 0:
        raise MeshError(f"{name}: max_elements must be positive, got {max_elements}")
    bodies = surface_bodies(surface, name)
    volume = bodies["volume"]
    est = estimate_tet_count(volume, float(bodies["areas"].sum()), size)
    million = size * (est / 1e6) ** (1 / 3)
    if est > limit:
        raise MeshError(f"{name}: mesh size {size:g} m would give about {_count_text(est)} tetrahedra "
                        f"(enclosed volume {volume:.4g} m^3), more than the limit of {_count_text(limit)} "
                        f"(max_elements); size {million:.3g} m gives about 1 million")
    need, avail = GMSH_BYTES_FIXED + GMSH_BYTES_PER_TET * est, available_memory()
    if need > avail:
        raise MeshError(f"{name}: mesh size {size:g} m would give about {_count_text(est)} tetrahedra, which "
                        f"need about {_bytes_text(need)} of memory in gmsh, more than the {_bytes_text(avail)} "
                        f"available; size {million:.3g} m gives about 1 million")
    try:
        import gmsh  # noqa: F401 - imported here, before the child forks, so that the child imports nothing
    except ImportError as exc:  # pragma: no cover - gmsh is a dependency
        raise MeshError(f"tetrahedralisation needs the gmsh Python package (pip install gmsh): {exc}") from None

    xyz, cells, tri, tri_tags = _in_child(
        _gmsh_volume_mesh, (surface.points, surface.faces, bodies["labels"], bodies["volumes"], float(size),
                            float(angle), bool(optimize), name, surface.face_tags), name)
    if len(cells) == 0:
        raise MeshError(f"{name}: gmsh produced no tetrahedra (is the surface self-intersecting or inside out?)")
    tags = None
    if surface.face_tags is not None:
        keep = tri_tags >= 0  # faces of untagged input triangles stay untagged
        tags = MeshTags(face_nodes=tri[keep], face_tags=tri_tags[keep],
                        names={n: (i, 2) for n, (i, _) in surface.tag_names.items()})
    return TetMesh.reoriented(xyz, cells, name=name, tags=tags)


def _occ_surface(build: Callable, size: float, name: str) -> TriMesh:
    """Closed outward-oriented surface of the OpenCASCADE solid that ``build(occ)`` creates."""
    with _Gmsh() as gmsh:
        gmsh.model.add(name)
        build(gmsh.model.occ)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", float(size))
        gmsh.option.setNumber("Mesh.MeshSizeMin", float(size) / 4)
        gmsh.model.mesh.generate(2)
        tags, xyz, _ = gmsh.model.mesh.getNodes()
        faces, patch = [], []
        for dim, tag in gmsh.model.getBoundary(gmsh.model.getEntities(3), oriented=True):
            _, nt = gmsh.model.mesh.getElementsByType(2, abs(tag))
            faces.append(np.asarray(nt, np.int64).reshape(-1, 3))
            patch.append(np.full(len(faces[-1]), len(patch)))
    tags = np.asarray(tags, np.int64)
    lookup = np.full(int(tags.max()) + 1, -1, np.int64)
    lookup[tags] = np.arange(len(tags))
    faces = lookup[np.concatenate(faces)]
    used, faces = np.unique(faces, return_inverse=True)
    pts = np.asarray(xyz, float).reshape(-1, 3)[used]
    faces = _orient_patches(pts, faces.reshape(-1, 3), np.concatenate(patch), name)
    return TriMesh(pts, faces, name=name)


def _orient_patches(pts: np.ndarray, faces: np.ndarray, patch: np.ndarray, name: str) -> np.ndarray:
    r"""Wind every patch (a CAD face, meshed consistently by gmsh, but with the orientation of its underlying
    surface, which the OCC boolean results do not keep consistent) like its neighbours, then each closed
    connected part outward (positive signed volume :math:`\sum_f x_0 \cdot (x_1 \times x_2) / 6`).

    Two patches sharing an edge agree when the edge runs in opposite directions in their triangles; the
    flips follow by a breadth-first walk over the patch graph. An edge with other than two triangles, or
    patches that no flips can make agree (a non-orientable surface), is refused in one line."""
    npatch = int(patch.max()) + 1 if len(patch) else 0
    half = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)  # directed half-edges, 3 per face
    hp = np.repeat(patch, 3)
    _, inv, cnt = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True, return_counts=True)
    if (cnt != 2).any():
        raise MeshError(f"{name}: the CAD surface is not closed and manifold ({int((cnt != 2).sum())} edges "
                        f"with other than two triangles)")
    order = np.argsort(inv.ravel(), kind="stable")
    a, b = order[0::2], order[1::2]  # the two half-edges of each edge
    same = half[a, 0] == half[b, 0]  # same direction: the two sides need opposite flips
    pa, pb = hp[a], hp[b]
    if (same & (pa == pb)).any():
        raise MeshError(f"{name}: a CAD patch of the surface is not consistently triangulated")
    cross = pa != pb
    links = np.unique(np.c_[pa[cross], pb[cross], same[cross]], axis=0)
    nbrs: list[list[tuple[int, bool]]] = [[] for _ in range(npatch)]
    for p, q, sm in links:
        nbrs[p].append((q, bool(sm)))
        nbrs[q].append((p, bool(sm)))
    flip = np.full(npatch, -1)
    comp = np.full(npatch, -1)
    for start in range(npatch):
        if flip[start] >= 0:
            continue
        flip[start], comp[start], stack = 0, start, [start]
        while stack:
            p = stack.pop()
            for q, sm in nbrs[p]:
                want = flip[p] ^ int(sm)
                if flip[q] < 0:
                    flip[q], comp[q] = want, start
                    stack.append(q)
                elif flip[q] != want:
                    raise MeshError(f"{name}: the CAD surface cannot be oriented consistently")
    out = np.where(flip[patch][:, None] == 1, faces[:, ::-1], faces)
    x = pts[out]
    vol6 = np.einsum("fi,fi->f", x[:, 0], np.cross(x[:, 1], x[:, 2]))
    comp_vol = np.bincount(comp[patch], weights=vol6, minlength=npatch)
    return np.where((comp_vol[comp[patch]] < 0)[:, None], out[:, ::-1], out)


def plate_with_hole_surface(length: float = 0.2, width: float = 0.1, thickness: float = 0.01,
                            radius: float = 0.02, size: float | None = None) -> TriMesh:
    """Closed surface of the plate [0, length] x [0, width] x [0, thickness] (m) with a through hole of
    `radius` along z at its centre; triangles of edge length about `size` (default thickness / 2)."""
    if not (0 < radius < min(length, width) / 2) or min(length, width, thickness) <= 0:
        raise MeshError(f"plate_with_hole_surface: need positive sizes and 0 < radius < min(length, width)/2, got "
                        f"{length}, {width}, {thickness}, radius {radius}")

    def build(occ):
        b = occ.addBox(0, 0, 0, length, width, thickness)
        c = occ.addCylinder(length / 2, width / 2, -thickness, 0, 0, 3 * thickness, radius)
        occ.cut([(3, b)], [(3, c)])

    return _occ_surface(build, size or thickness / 2, "plate_with_hole")


def l_bracket_surface(length: float = 0.1, height: float = 0.1, depth: float = 0.04, thickness: float = 0.02,
                      size: float | None = None) -> TriMesh:
    """Closed surface of an L-shaped bracket: the union of the flange [0, length] x [0, depth] x
    [0, thickness] and the web [0, thickness] x [0, depth] x [0, height] (m); triangles of edge length
    about `size` (default thickness / 2)."""
    if min(length, height, depth, thickness) <= 0 or thickness >= min(length, height):
        raise MeshError(f"l_bracket_surface: need positive sizes with thickness < length, height; got "
                        f"{length}, {height}, {depth}, {thickness}")

    def build(occ):
        a = occ.addBox(0, 0, 0, length, depth, thickness)
        b = occ.addBox(0, 0, 0, thickness, depth, height)
        occ.fuse([(3, a)], [(3, b)])

    return _occ_surface(build, size or thickness / 2, "l_bracket")


def tet_quality(mesh: TetMesh) -> dict[str, np.ndarray]:
    r"""Per-element quality: ``min_dihedral`` (degrees) and ``radius_ratio`` =
    :math:`3 r_\text{in} / R_\text{circ}`.

    Dihedral angle at edge :math:`(i, j)`: :math:`\pi` minus the angle between the outward normals of the two
    faces that share it. :math:`r_\text{in} = 3 V / (\text{sum of face areas})`; :math:`R_\text{circ}` from
    the circumcentre solve of the 3x3 system :math:`2 (x_k - x_0) \cdot c = |x_k|^2 - |x_0|^2`.
    """
    x = mesh.points[mesh.cells]  # (m, 4, 3)
    from physar.geometry.mesh import TET_FACES

    fx = x[:, TET_FACES]  # (m, 4, 3, 3), face k opposite vertex k, outward
    n = np.cross(fx[:, :, 1] - fx[:, :, 0], fx[:, :, 2] - fx[:, :, 0])
    area = 0.5 * np.linalg.norm(n, axis=2)
    n = n / np.linalg.norm(n, axis=2, keepdims=True)
    dihedral = []
    for a in range(4):
        for b in range(a + 1, 4):  # faces a and b share the edge opposite to vertices a, b
            cos = np.clip(-np.einsum("mi,mi->m", n[:, a], n[:, b]), -1.0, 1.0)
            dihedral.append(np.degrees(np.arccos(cos)))
    vol = np.abs(mesh.volumes)
    r_in = 3.0 * vol / area.sum(axis=1)
    A = 2.0 * (x[:, 1:] - x[:, :1])
    rhs = (x[:, 1:] ** 2).sum(axis=2) - (x[:, :1] ** 2).sum(axis=2)
    c = np.linalg.solve(A, rhs[..., None])[..., 0]
    R = np.linalg.norm(c - x[:, 0], axis=1)
    return {"min_dihedral": np.min(dihedral, axis=0), "radius_ratio": 3.0 * r_in / R}


__all__ = [
    "boundary_edge_count",
    "check_closed",
    "default_size",
    "is_flat",
    "l_bracket_surface",
    "plate_with_hole_surface",
    "tet_quality",
    "tetrahedralize",
]
