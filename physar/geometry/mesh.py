"""Mesh containers, generators and selection helpers.

`TetMesh` and `TriMesh` are frozen dataclasses of numpy arrays, validated on construction: a bad mesh
raises :class:`physar.errors.MeshError` naming the first offending element.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from physar.errors import MeshError
from physar.geometry.regions import MeshTags
from physar.output import check_memory

# Local faces of a positively oriented tetrahedron (vol = det[x1-x0, x2-x0, x3-x0] / 6 > 0), ordered
# so that the right-hand normal points outward; face k is opposite local vertex k.
#: (4, 3) local vertex ids of the faces of a tetrahedron, outward normals; face k is opposite vertex k.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


def tet_signed_volumes(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    r"""Signed volume of each tetrahedron, :math:`\det[x_1 - x_0, x_2 - x_0, x_3 - x_0] / 6` (m^3)."""
    x = points[cells[:, :4]]
    d = x[:, 1:4] - x[:, 0:1]
    return np.linalg.det(d) / 6.0


def _bounds_text(points: np.ndarray, unit: str = "m") -> str:
    """``[xmin, xmax] x [ymin, ymax] x [zmin, zmax] m`` of `points` (n, 3) for a summary (4 significant digits;
    ``empty`` for no points): one min/max pass, no copy."""
    if len(points) == 0:
        return "empty"
    lo, hi = points.min(axis=0), points.max(axis=0)
    return " x ".join(f"[{a:.4g}, {b:.4g}]" for a, b in zip(lo.tolist(), hi.tolist())) + (f" {unit}" if unit else "")


def _plural(n: int, word: str, many: str | None = None) -> str:
    """``1 node``, ``2 nodes`` (``many``: the plural when it is not `word` + s)."""
    return f"{n} {word}" if n == 1 else f"{n} {many or word + 's'}"


def _check_points(points: np.ndarray, name: str) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise MeshError(f"{name}: points must have shape (n, 3), got {points.shape}")
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise MeshError(f"{name}: point {int(np.flatnonzero(bad)[0])} has a NaN or infinite coordinate")
    return points


def _frozen(a: np.ndarray) -> np.ndarray:
    """`a` made read-only for storing in a mesh: a private copy unless `a` is already read-only (and so is the
    array it views), never the caller's writable array (freezing that would break the caller's code)."""
    base = a.base if isinstance(a.base, np.ndarray) else None
    if a.flags.writeable or (base is not None and base.flags.writeable):
        a = a.copy()
    a.setflags(write=False)
    return a


def _check_cells(cells: np.ndarray, npts: int, width: int, name: str) -> np.ndarray:
    cells = np.asarray(cells)
    if cells.ndim != 2 or cells.shape[1] != width:
        raise MeshError(f"{name}: cells must have shape (m, {width}), got {cells.shape}")
    if not np.issubdtype(cells.dtype, np.integer):
        raise MeshError(f"{name}: cells must be integer indices, got dtype {cells.dtype}")
    cells = cells.astype(np.int64)
    if cells.size:
        bad = (cells < 0) | (cells >= npts)
        if bad.any():
            e = int(np.flatnonzero(bad.any(axis=1))[0])
            raise MeshError(f"{name}: element {e} refers to a node outside 0..{npts - 1}: {cells[e].tolist()}")
    return cells


@dataclass(frozen=True, repr=False)
class TetMesh:
    """A linear tetrahedral mesh: `points` (n, 3) in metres, `cells` (m, 4) node indices.

    Every tetrahedron must be positively oriented with a volume above `rel_tol` times the mean volume;
    otherwise a MeshError names the element. Use :meth:`reoriented` to fix orientation of a mesh read
    from a tool that uses the other convention. `tags` (optional, :class:`MeshTags`): physical groups
    of a mesh file (tetrahedra and boundary triangles), for ``region = ...`` selections.
    """

    points: np.ndarray
    cells: np.ndarray
    name: str = field(default="mesh", compare=False)
    rel_tol: float = field(default=1e-12, compare=False, repr=False)
    tags: MeshTags | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        pts = _check_points(self.points, self.name)
        cells = _check_cells(self.cells, len(pts), 4, self.name)
        if len(cells) == 0:
            raise MeshError(f"{self.name}: the mesh has no tetrahedra")
        vol = tet_signed_volumes(pts, cells)
        scale = np.abs(vol).mean()
        inverted = vol < -self.rel_tol * scale
        if inverted.any():
            e = int(np.flatnonzero(inverted)[0])
            raise MeshError(
                f"{self.name}: element {e} is inverted (signed volume {vol[e]:.3e}); "
                f"{int(inverted.sum())} inverted in all (TetMesh.reoriented fixes orientation)"
            )
        degenerate = np.abs(vol) <= self.rel_tol * scale
        if degenerate.any():
            e = int(np.flatnonzero(degenerate)[0])
            raise MeshError(f"{self.name}: element {e} is degenerate (volume {vol[e]:.3e})")
        object.__setattr__(self, "points", _frozen(pts))
        object.__setattr__(self, "cells", _frozen(cells))

    @classmethod
    def reoriented(cls, points: np.ndarray, cells: np.ndarray, name: str = "mesh",
                   tags: MeshTags | None = None) -> TetMesh:
        """Build a mesh after swapping two nodes of every negatively oriented tetrahedron."""
        points = _check_points(points, name)
        cells = _check_cells(cells, len(points), 4, name).copy()
        neg = tet_signed_volumes(points, cells) < 0
        cells[neg, 2], cells[neg, 3] = cells[neg, 3].copy(), cells[neg, 2].copy()
        return cls(points, cells, name=name, tags=tags)

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    @property
    def volumes(self) -> np.ndarray:
        return tet_signed_volumes(self.points, self.cells)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.points.min(axis=0), self.points.max(axis=0)

    def checksum(self) -> str:
        """A SHA-256 of points and cells, to tie derived data (reduced models) to this mesh."""
        import hashlib

        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.points).tobytes())
        h.update(np.ascontiguousarray(self.cells).tobytes())
        return h.hexdigest()

    def boundary(self) -> BoundarySurface:
        return boundary_surface(self)

    def __repr__(self) -> str:
        """One line: name, node and tetrahedron counts, bounding box [m], and the tag names if any (no arrays)."""
        text = (f"TetMesh({self.name!r}, {_plural(self.n_points, 'node')}, "
                f"{_plural(self.n_cells, 'tetrahedron', 'tetrahedra')}, bounds {_bounds_text(self.points)}")
        if self.tags is not None and self.tags.names:
            names = sorted(self.tags.names)
            more = f", ... ({len(names)} in all)" if len(names) > 6 else ""
            text += f", regions {', '.join(names[:6])}{more}"
        return text + ")"


def _repeats_vertex(faces: np.ndarray) -> np.ndarray:
    """(m,) bool: faces (m, 3) that hold one vertex index twice or more."""
    return (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])


def _check_face_tags(tags, n_faces: int, name: str) -> np.ndarray | None:
    """`tags` as a read-only int64 array (n_faces,), or None; anything else is one MeshError line."""
    if tags is None:
        return None
    t = np.asarray(tags)
    if t.shape != (n_faces,) or not (np.issubdtype(t.dtype, np.integer) or t.size == 0):
        raise MeshError(f"{name}: face_tags must be {n_faces} integers (one per face), got shape {t.shape} "
                        f"dtype {t.dtype}")
    return _frozen(t.astype(np.int64))


def _check_tag_names(names, name: str) -> dict:
    """`names` as {str: (int tag, int dim)} (the gmsh $PhysicalNames convention); else one MeshError line."""
    out = {}
    for k, v in dict(names or {}).items():
        pair = np.asarray(v).ravel()
        if not isinstance(k, str) or pair.size != 2 or pair.dtype.kind not in "iu":
            raise MeshError(f"{name}: tag_names[{k!r}] must be (tag, dim), two integers, got {v!r}")
        out[k] = (int(pair[0]), int(pair[1]))
    return out


@dataclass(frozen=True, repr=False)
class TriMesh:
    """A triangle surface mesh: `points` (n, 3), `faces` (m, 3); validated for NaN and index range.

    `face_tags` (optional, (m,) integers): the region tag of each face (a physical group of a mesh file, an OBJ
    group); a negative tag marks an untagged face. `tag_names` {name: (tag, dim)}: the names of those tags
    (dim 2 for faces, the gmsh ``$PhysicalNames`` convention). :func:`physar.geometry.tetrahedralize` carries
    both to the boundary triangles of the tetrahedral mesh it builds (``TetMesh.tags``).
    """

    points: np.ndarray
    faces: np.ndarray
    name: str = field(default="surface", compare=False)
    face_tags: np.ndarray | None = field(default=None, compare=False, repr=False)
    tag_names: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        pts = _check_points(self.points, self.name)
        faces = _check_cells(self.faces, len(pts), 3, self.name)
        object.__setattr__(self, "points", _frozen(pts))
        object.__setattr__(self, "faces", _frozen(faces))
        object.__setattr__(self, "face_tags", _check_face_tags(self.face_tags, len(faces), self.name))
        object.__setattr__(self, "tag_names", _check_tag_names(self.tag_names, self.name))

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def face_normals(self, normalize: bool = True) -> np.ndarray:
        r"""Right-hand face normals :math:`(x_1 - x_0) \times (x_2 - x_0)`; unit length if `normalize`, else
        :math:`2\, \mathrm{area}`."""
        x = self.points[self.faces]
        n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        if normalize:
            nn = np.linalg.norm(n, axis=1, keepdims=True)
            n = n / np.where(nn > 0, nn, 1.0)
        return n

    def face_areas(self) -> np.ndarray:
        return 0.5 * np.linalg.norm(self.face_normals(normalize=False), axis=1)

    def degenerate_faces(self, rel_tol: float = 1e-12) -> np.ndarray:
        """(m,) bool: faces that repeat a vertex index, or whose area is at most `rel_tol` times the mean face
        area (collinear corners; the rule :class:`TetMesh` applies to tetrahedron volumes)."""
        rep = _repeats_vertex(self.faces)
        area = self.face_areas()
        return rep | (area <= rel_tol * area.mean()) if len(rep) else rep

    def with_points(self, points: np.ndarray) -> TriMesh:
        """The same faces (and face tags) on new `points` (n, 3)."""
        return TriMesh(points, self.faces, name=self.name, face_tags=self.face_tags, tag_names=self.tag_names)

    def __repr__(self) -> str:
        """One line: name, node and triangle counts, bounding box (no unit: a surface file's own), and the tag
        names if any (no arrays)."""
        text = (f"TriMesh({self.name!r}, {_plural(self.n_points, 'node')}, {_plural(self.n_faces, 'triangle')}, "
                f"bounds {_bounds_text(self.points, unit='')}")
        if self.tag_names:
            names = sorted(self.tag_names)
            more = f", ... ({len(names)} in all)" if len(names) > 6 else ""
            text += f", regions {', '.join(names[:6])}{more}"
        return text + ")"


def check_faces(mesh: TriMesh, source: str | None = None) -> None:
    """Refuse a surface with degenerate faces (:meth:`TriMesh.degenerate_faces`: a vertex index repeated in a
    face, or zero area) in one MeshError line naming `source` (default: the mesh's name), how many faces of each
    kind and the first of each; the surface commands refuse them too (``denoise`` and the tetrahedralisation of
    ``fem`` stop at a face that repeats a vertex, gmsh at overlapping facets)."""
    bad = mesh.degenerate_faces()
    if not bad.any():
        return
    f = mesh.faces
    rep = _repeats_vertex(f)
    parts = []
    for mask, what in ((rep, "repeating a vertex index"), (bad & ~rep, "of zero area")):
        if mask.any():
            e = int(np.flatnonzero(mask)[0])
            parts.append(f"{int(mask.sum())} {what} (e.g. face {e}, vertices {f[e].tolist()}, numbered from 0)")
    n = int(bad.sum())
    raise MeshError(f"{source or mesh.name}: {_plural(n, 'degenerate face')} of {mesh.n_faces}: {'; '.join(parts)}; "
                    f"remove {'it' if n == 1 else 'them'} first (e.g. MeshLab's Remove Zero Area Faces)")


@dataclass(frozen=True, repr=False)
class BoundarySurface:
    """Boundary of a tet mesh.

    `mesh` is a TriMesh on its own compact node numbering, outward oriented; `node_map[i]` is the volume
    node of surface node i; `face_cell[f]` and `face_local[f]` give the tetrahedron and its local face
    (see TET_FACES) of surface face f.
    """

    mesh: TriMesh
    node_map: np.ndarray
    face_cell: np.ndarray
    face_local: np.ndarray

    @property
    def faces_global(self) -> np.ndarray:
        """Surface faces in volume node numbering."""
        return self.node_map[self.mesh.faces]

    def face_centroids(self) -> np.ndarray:
        return self.mesh.points[self.mesh.faces].mean(axis=1)

    def __repr__(self) -> str:
        """One line: the surface's name, node and triangle counts, bounding box [m] (no arrays)."""
        m = self.mesh
        return (f"BoundarySurface({m.name!r}, {_plural(m.n_points, 'node')}, {_plural(m.n_faces, 'triangle')}, "
                f"bounds {_bounds_text(m.points)})")


def row_keys(rows: np.ndarray, n: int) -> np.ndarray:
    r"""One integer per row of small non-negative integers < n (for fast 1-D np.unique).

    Falls back to a structured void view when :math:`n^{\text{width}}` does not fit in 63 bits.
    """
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    w = rows.shape[1]
    if float(n) ** w < 2.0**63:
        key = np.zeros(len(rows), dtype=np.int64)
        for j in range(w):
            key = key * n + rows[:, j]
        return key
    return rows.view(np.dtype((np.void, rows.dtype.itemsize * w))).ravel()


def _boundary_tags(mesh: TetMesh, faces: np.ndarray) -> tuple[np.ndarray | None, dict]:
    """(face_tags, tag_names) of the boundary `faces` (k, 3) (volume node ids) from ``mesh.tags``: each face the
    tag of the tagged triangle with the same three vertices (any order; a triangle tagged more than once keeps
    its first tag), -1 where none is; the names of surface groups (dim 2) whose tag some face carries.
    (None, {}) when no boundary face is tagged (tagged triangles inside the volume are not boundary faces)."""
    tags = mesh.tags
    if tags is None or len(tags.face_nodes) == 0 or len(faces) == 0:
        return None, {}
    n = mesh.n_points
    tagged, first = np.unique(row_keys(np.sort(tags.face_nodes, axis=1), n), return_index=True)
    key = row_keys(np.sort(faces, axis=1), n)
    at = np.searchsorted(tagged, key).clip(0, len(tagged) - 1)
    out = np.where(tagged[at] == key, np.asarray(tags.face_tags, np.int64)[first[at]], -1)
    if not (out >= 0).any():
        return None, {}
    present = set(np.unique(out[out >= 0]).tolist())
    return out, {k: (i, d) for k, (i, d) in tags.names.items() if d == 2 and i in present}


def boundary_surface(mesh: TetMesh) -> BoundarySurface:
    """Faces that belong to exactly one tetrahedron, outward oriented (vectorised, O(m log m)).

    A tagged mesh (``mesh.tags`` with tagged triangles, e.g. physical groups of a .msh file or the regions
    :func:`physar.geometry.tetrahedralize` carries) gives a surface with ``face_tags`` (one per surface face, in
    its face order; -1 for an untagged face) and ``tag_names`` (the surface groups, dim 2, present on it)."""
    cells = mesh.cells
    all_faces = cells[:, TET_FACES].reshape(-1, 3)  # (4m, 3), outward for each tet
    _, inverse, counts = np.unique(row_keys(np.sort(all_faces, axis=1), mesh.n_points),
                                   return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    is_bnd = counts[inverse] == 1
    if (counts > 2).any():
        raise MeshError(f"{mesh.name}: a face is shared by more than two tetrahedra (non-manifold mesh)")
    idx = np.flatnonzero(is_bnd)
    faces = all_faces[idx]
    node_map, local = np.unique(faces, return_inverse=True)
    face_tags, tag_names = _boundary_tags(mesh, faces)
    tri = TriMesh(mesh.points[node_map], local.reshape(-1, 3), name=f"{mesh.name}-boundary", face_tags=face_tags,
                  tag_names=tag_names)
    return BoundarySurface(tri, node_map, idx // 4, idx % 4)


def in_box(points: np.ndarray, box: Sequence[Sequence[float]], tol: float | None = None) -> np.ndarray:
    """Boolean mask of points inside the closed box [[xmin, ymin, zmin], [xmax, ymax, zmax]].

    `tol` (default: 1e-9 times the box/point-cloud diagonal) makes the test robust to round-off for
    boxes of zero thickness (a face of the domain).
    """
    b = np.asarray(box, dtype=np.float64)
    if b.shape != (2, 3):
        raise MeshError(f"box must be [[xmin, ymin, zmin], [xmax, ymax, zmax]], got shape {b.shape}")
    lo, hi = np.minimum(b[0], b[1]), np.maximum(b[0], b[1])
    if tol is None:
        span = np.ptp(points, axis=0).max() if len(points) else 1.0
        tol = 1e-9 * max(span, np.linalg.norm(hi - lo), 1e-300)
    return np.all((points >= lo - tol) & (points <= hi + tol), axis=1)


def select_nodes(
    mesh: TetMesh | TriMesh,
    box: Sequence[Sequence[float]] | None = None,
    where: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Indices of nodes in `box` and/or satisfying `where(points) -> bool mask` (both if both given)."""
    mask = np.ones(mesh.n_points, dtype=bool)
    if box is not None:
        mask &= in_box(mesh.points, box)
    if where is not None:
        mask &= np.asarray(where(mesh.points), dtype=bool)
    return np.flatnonzero(mask)


def select_boundary_faces(
    surface: BoundarySurface,
    box: Sequence[Sequence[float]] | None = None,
    where: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Indices of boundary faces whose centroid lies in `box` and/or satisfies `where`."""
    c = surface.face_centroids()
    mask = np.ones(len(c), dtype=bool)
    if box is not None:
        mask &= in_box(c, box, tol=1e-9 * max(np.ptp(surface.mesh.points, axis=0).max(), 1e-300))
    if where is not None:
        mask &= np.asarray(where(c), dtype=bool)
    return np.flatnonzero(mask)


# Kuhn (Freudenthal) subdivision of the unit cube into 6 tets sharing the diagonal 0 -> 7; corners are
# numbered by bits (x + 2 y + 4 z). Neighbouring cubes then share conforming face diagonals.
def _kuhn_tets() -> np.ndarray:
    import itertools

    tets = []
    for perm in itertools.permutations(range(3)):
        corner = 0
        path = [corner]
        for axis in perm:
            corner |= 1 << axis
            path.append(corner)
        tets.append(path)
    tets = np.array(tets, dtype=np.int64)
    xyz = np.array([[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=float)
    neg = tet_signed_volumes(xyz, tets) < 0
    tets[neg, 2], tets[neg, 3] = tets[neg, 3].copy(), tets[neg, 2].copy()
    return tets


_KUHN = _kuhn_tets()


# Peak bytes per hexahedron while box_mesh builds: index grids (3 x 8), corner ids (8 x 8), tetrahedra
# (6 x 4 x 8, twice while reshaping) and the points with their coordinate grids (~4 x 24 per node).
BOX_BYTES_PER_CELL = 3 * 8 + 8 * 8 + 2 * 6 * 4 * 8 + 4 * 24


def box_mesh(
    size: Sequence[float], cells: Sequence[int], origin: Sequence[float] = (0.0, 0.0, 0.0)
) -> TetMesh:
    """Structured tetrahedral mesh of the box origin + [0, L] x [0, W] x [0, H].

    `cells = (nx, ny, nz)` hexahedra, each split into 6 Kuhn tetrahedra (6 nx ny nz tets in all). A mesh
    whose construction would need more memory than is available (``BOX_BYTES_PER_CELL`` per cell) is
    refused with a ConfigError before anything is allocated.
    """
    size = np.asarray(size, dtype=float)
    given = np.asarray(cells)
    if size.shape != (3,) or np.any(size <= 0) or not np.all(np.isfinite(size)):
        raise MeshError(f"box size must be three positive lengths, got {[float(v) for v in np.atleast_1d(size)]}")
    whole = (np.issubdtype(given.dtype, np.integer) or np.issubdtype(given.dtype, np.floating)) and np.all(np.isfinite(given)) \
        and np.all(given == np.round(given))
    if given.shape != (3,) or not whole or np.any(given < 1):
        raise MeshError(f"box cells must be three positive integers, got {np.atleast_1d(given).tolist()}")
    n = given.astype(int)
    nx, ny, nz = (int(v) for v in n)
    n_cells = nx * ny * nz  # Python ints: no overflow for absurd requests
    check_memory(BOX_BYTES_PER_CELL * n_cells, f"a box mesh of {nx} x {ny} x {nz} cells ({6 * n_cells:.3g} tetrahedra)")
    axes = [np.linspace(0.0, size[i], n[i] + 1) + origin[i] for i in range(3)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])

    def nid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    I, J, K = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    I, J, K = I.ravel(), J.ravel(), K.ravel()
    corners = np.column_stack(
        [nid(I + ((c >> 0) & 1), J + ((c >> 1) & 1), K + ((c >> 2) & 1)) for c in range(8)]
    )
    tets = corners[:, _KUHN].reshape(-1, 4)
    return TetMesh(points, tets, name=f"box{tuple(float(s) for s in size)}")
