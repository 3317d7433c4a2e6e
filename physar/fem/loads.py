r"""External loads as consistent nodal force vectors (n_dofs,) [N], and Dirichlet dof selection.

Nodes and boundary faces are selected by exactly one of: a `box`, a mesh `region` (physical group name
or id of the mesh file, :class:`physar.geometry.regions.MeshTags`), `points` (nodes within `tol`) or a
`plane` ((point, normal): nodes within `tol` of it) — see :func:`select_nodes_mask`, :func:`select_faces`.
The default `tol` is :func:`default_tol` (robust to float32 coordinates, e.g. of an STL file).

Surface loads integrate :math:`f_a = \int_\Gamma N_a\, t \,\mathrm{d}A` over boundary faces; the tet shape
functions are evaluated on the face (the barycentric coordinate of the opposite vertex is 0), so P1 and P2 are
treated alike.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from physar.errors import ConfigError, MeshError
from physar.fem.elements import P2_EDGES, FESpace, shape_functions, tri_quadrature
from physar.geometry.mesh import TET_FACES, BoundarySurface, in_box, row_keys
from physar.geometry.path import path_length, path_point  # noqa: F401 - re-exported: the load path helpers
from physar.geometry.regions import near_points, on_plane

_COMPONENTS = {"x": 0, "y": 1, "z": 2}


def _surface(space: FESpace) -> BoundarySurface:
    cache = space.__dict__.setdefault("_physar_cache", {})
    if "boundary" not in cache:
        cache["boundary"] = space.mesh.boundary()
    return cache["boundary"]


def _face_quadrature(space: FESpace, faces: np.ndarray, degree: int):
    """For boundary faces: quadrature points (f, q, 3), weights x area (f, q), nodal N (f, q, nen)."""
    surf = _surface(space)
    Lt, wt = tri_quadrature(degree)  # (q, 3)
    local = surf.face_local[faces]
    cells = surf.face_cell[faces]
    verts = TET_FACES[local]  # (f, 3) local tet vertices of each face
    Ltet = np.zeros((len(faces), len(wt), 4))
    for j in range(3):
        Ltet[np.arange(len(faces))[:, None], :, verts[:, j : j + 1]] = Lt[None, :, j]
    N = shape_functions(space.element, Ltet)  # (f, q, nen)
    x = space.mesh.points[space.mesh.cells[cells]]  # (f, 4, 3)
    pts = np.einsum("fqa,fai->fqi", Ltet, x)
    area = surf.mesh.face_areas()[faces]
    w = 2.0 * area[:, None] * wt[None, :]  # reference triangle area is 1/2
    return cells, pts, w, N


def _scatter(space: FESpace, cells: np.ndarray, nodal: np.ndarray) -> np.ndarray:
    """Sum element nodal forces (f, nen, 3) into a global vector."""
    dofs = space.cell_dofs[cells]
    return np.bincount(dofs.ravel(), weights=nodal.reshape(len(cells), -1).ravel(), minlength=space.n_dofs)


_EPS32 = float(np.finfo(np.float32).eps)  # 2**-23


def default_tol(points: np.ndarray) -> float:
    r"""The default selection tolerance [m] for the nodes ``points`` (n, 3):
    :math:`4\, \varepsilon_{32} \max|x| + 10^{-6}\, \mathrm{extent}`.

    * :math:`4\, \varepsilon_{32} \max|x|` (:math:`\varepsilon_{32} = 2^{-23}`): an STL file (and other
      float32 mesh files) rounds each coordinate to float32, an error of at most half a float32 ulp,
      :math:`\le \varepsilon_{32}/2 \cdot |x|`; so a face written at :math:`x = 0.16` is read at 0.1599999964
      and a plane or point given in float64 at 0.16 must still pick it. Four ulps leave room for the rounding
      of both the mesh and the written selector and for the float64 arithmetic of the distance; it scales with
      the coordinates' magnitude, so it also holds for a part placed far from the origin.
    * :math:`10^{-6}\, \mathrm{extent}`: round-off of a mesher that moved nodes by a relative 1e-6 or less
      (gmsh writes 16 digits, but projections onto a surface are not exact).

    Both are far below any element size (a mesh finer than 1e-5 of its extent has :math:`10^{15}` cells), so
    the default never reaches the next layer of nodes; a larger `tol` is the user's choice.
    """
    X = np.asarray(points, float)
    if X.size == 0:
        return 0.0
    scale = float(np.abs(X).max())
    extent = float(np.ptp(X.reshape(-1, X.shape[-1]), axis=0).max())
    return 4.0 * _EPS32 * scale + 1e-6 * extent


def _tol(space: FESpace, tol) -> float:
    return default_tol(space.mesh.points) if tol is None else tol


def plane_miss_hint(space: FESpace, point, normal, tol=None) -> str:
    """The end of a 'no node matches plane' message: the nearest node's distance to the plane, and the
    `tol` that would select it."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    d = np.abs((space.nodes - np.asarray(point, float)) @ n)
    i = int(np.argmin(d))
    return (f"the nearest node {np.round(space.nodes[i], 9).tolist()} is {d[i]:.3g} m from the plane "
            f"(tol used {_tol(space, tol):.3g} m); give the plane a larger tol (e.g. tol = {d[i] * 1.01:.3g}) "
            "if that node is meant, or check the point (metres, in the mesh's frame)")


def points_miss_hint(space: FESpace, points, tol=None) -> str:
    """The end of a 'no node matches points' message: the nearest node's distance to the points."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(space.nodes).query(np.asarray(points, float).reshape(-1, 3), k=1)
    return (f"the nearest node is {d.max():.3g} m from a point (tol used {_tol(space, tol):.3g} m); "
            "give a larger tol if that node is meant")


def _one_selector(box, region, points, plane) -> str:
    given = [k for k, v in (("box", box), ("region", region), ("points", points), ("plane", plane)) if v is not None]
    if len(given) != 1:
        raise ConfigError(f"give exactly one of box, region, points, plane (got {', '.join(given) or 'none'})")
    return given[0]


def _describe(kind, box, region, points, plane, tol) -> str:
    if kind == "box":
        return f"box {np.asarray(box, float).tolist()}"
    if kind == "region":
        return f"region {region!r}"
    if kind == "points":
        return f"points {np.asarray(points, float).tolist()} (tol {tol})"
    return f"plane point {np.asarray(plane[0], float).tolist()} normal {np.asarray(plane[1], float).tolist()} (tol {tol})"


def _region(space: FESpace, region, what: str):
    tags = space.mesh.tags
    if tags is None:
        raise ConfigError(f"{what} region {region!r} not in mesh (available: none, the mesh has no tags; "
                          "use a mesh file with physical groups, or box/points/plane)")
    try:
        return tags.resolve(region, what=f"{what} region")
    except MeshError as exc:
        raise ConfigError(str(exc)) from None


def _edge_nodes(space: FESpace, edges: np.ndarray) -> np.ndarray:
    """P2 nodes at the midpoints of the given vertex edges (e, 2) (empty for P1)."""
    if space.element == "P1" or len(edges) == 0:
        return np.zeros(0, np.int64)
    n = space.mesh.n_points
    want = row_keys(np.sort(edges, axis=1), n)
    cells = space.mesh.cells
    ce = np.sort(cells[:, P2_EDGES].reshape(-1, 2), axis=1)
    hit = np.isin(row_keys(ce, n), want)
    return space.cells[:, 4:].reshape(-1)[hit]


def select_nodes_mask(space: FESpace, box=None, region=None, points=None, plane=None, tol=None,
                      what: str = "selection") -> np.ndarray:
    """Mask over ``space.nodes`` of the nodes picked by exactly one selector.

    box [[lo], [hi]] (closed); region (name or id): the vertices of the tagged triangles/tetrahedra and,
    for P2, the midpoints of their edges; points [[x, y, z], ...]: nodes within `tol` of one of them;
    plane (point, normal): nodes within `tol` of the plane. `tol` (also the slack of a box) defaults to
    :func:`default_tol`. An empty selection is not an error here (see :func:`fixed_dofs` callers).
    """
    kind = _one_selector(box, region, points, plane)
    X = space.nodes
    if kind == "box":
        return in_box(X, box, tol=_tol(space, None))
    if kind == "points":
        return near_points(X, points, _tol(space, tol))
    if kind == "plane":
        return on_plane(X, plane[0], plane[1], _tol(space, tol))
    rows, cells = _region(space, region, what)
    mask = np.zeros(space.n_nodes, bool)
    mask[rows.ravel()] = True
    mask[space.mesh.cells[cells].ravel()] = True
    edges = [rows[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), space.mesh.cells[cells][:, P2_EDGES].reshape(-1, 2)]
    mask[_edge_nodes(space, np.concatenate(edges))] = True
    return mask


def select_cells_mask(space: FESpace, box=None, region=None, what: str = "selection") -> np.ndarray:
    """Mask over the cells (tetrahedra) picked by a `box` (the cell centroid lies in it, closed) or a mesh
    `region` (its tagged tetrahedra); neither: every cell. A region of triangles only selects no cell.
    An empty selection is not an error here."""
    mesh = space.mesh
    if box is not None and region is not None:
        raise ConfigError("give at most one of box, region (a cell selection)")
    if box is not None:
        return in_box(mesh.points[mesh.cells].mean(axis=1), box, tol=_tol(space, None))
    if region is not None:
        _, cells = _region(space, region, what)
        return cells if cells.size == mesh.n_cells else np.zeros(mesh.n_cells, bool)
    return np.ones(mesh.n_cells, bool)


def select_faces(space: FESpace, box=None, region=None, points=None, plane=None, tol=None,
                 what: str = "selection") -> np.ndarray:
    """Indices of boundary faces (of ``space.mesh.boundary()``) picked by exactly one selector.

    box: the face centroid lies in it; region: the face is a tagged triangle of that region, or a
    boundary face of a tagged tetrahedron; points / plane: all three vertices are selected (as in
    :func:`select_nodes_mask`).
    """
    kind = _one_selector(box, region, points, plane)
    surf = _surface(space)
    if kind == "box":
        return np.flatnonzero(in_box(surf.face_centroids(), box, tol=_tol(space, None)))
    fg = surf.faces_global
    if kind in ("points", "plane"):
        X = space.mesh.points
        t = _tol(space, tol)
        m = near_points(X, points, t) if kind == "points" else on_plane(X, plane[0], plane[1], t)
        return np.flatnonzero(m[fg].all(axis=1))
    rows, cells = _region(space, region, what)
    n = space.mesh.n_points
    hit = np.isin(row_keys(np.sort(fg, axis=1), n), row_keys(np.sort(rows, axis=1), n)) if len(rows) else \
        np.zeros(len(fg), bool)
    if cells.any():
        hit |= cells[surf.face_cell]
    return np.flatnonzero(hit)


def _vector3(value, name: str, unit: str) -> np.ndarray:
    """`value` as a finite float vector (3,), else ConfigError naming `name` and the value."""
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be a vector of 3 numbers [{unit}], got {value!r}") from e
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{name} must be a finite vector of 3 numbers [{unit}], got {value!r}")
    return v


def traction_load(space: FESpace, box: Sequence[Sequence[float]] | None = None,
                  total: Sequence[float] | None = None, *, region=None, points=None, plane=None,
                  tol=None) -> np.ndarray:
    r"""Uniform traction :math:`t = \mathtt{total} / \mathrm{area}` on the boundary faces picked by
    :func:`select_faces` (e.g. whose centroids lie in `box`)."""
    if total is None:
        raise ConfigError("traction load needs total = [Fx, Fy, Fz]")
    total = _vector3(total, "traction load total", "N")
    surf = _surface(space)
    kind = _one_selector(box, region, points, plane)
    faces = select_faces(space, box=box, region=region, points=points, plane=plane, tol=tol, what="traction load:")
    if len(faces) == 0:
        if kind == "box":
            raise ConfigError(f"traction load: no boundary face has its centroid in box {np.asarray(box).tolist()}")
        hint = ""
        if kind == "plane":
            hint = "; " + plane_miss_hint(space, plane[0], plane[1], tol)
        raise ConfigError(f"traction load: no boundary face matches {_describe(kind, box, region, points, plane, tol)}"
                          + hint)
    area = surf.mesh.face_areas()[faces].sum()
    cells, _, w, N = _face_quadrature(space, faces, 2)
    nodal = np.einsum("fq,fqa,i->fai", w, N, total / area)
    return _scatter(space, cells, nodal)


def closest_on_triangles(P: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points (m, 3) on triangles T (m, 3, 3) to points P (m, 3), pairwise, and their distances (m,):
    the projection onto the plane when it falls inside the triangle, else the nearest point of its edges."""
    A, B, C = T[:, 0], T[:, 1], T[:, 2]
    e0, e1, v = B - A, C - A, P - A
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (v * e0).sum(1), (v * e1).sum(1)
    den = d00 * d11 - d01 * d01
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = (d11 * d20 - d01 * d21) / den
        b2 = (d00 * d21 - d01 * d20) / den
    inside = (den > 0) & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1)
    Q = A + np.nan_to_num(b1)[:, None] * e0 + np.nan_to_num(b2)[:, None] * e1
    d = np.where(inside, np.linalg.norm(P - Q, axis=1), np.inf)
    for a, b in ((A, B), (B, C), (C, A)):
        ab = b - a
        t = np.clip(((P - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-300), 0.0, 1.0)
        qe = a + t[:, None] * ab
        de = np.linalg.norm(P - qe, axis=1)
        better = de < d
        Q[better], d[better] = qe[better], de[better]
    return Q, d


def _point_triangle_distance(P: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Exact distance of points P (m, 3) to triangles T (m, 3, 3), pairwise (:func:`closest_on_triangles`)."""
    return closest_on_triangles(P, T)[1]


def surface_distance(space: FESpace, points) -> np.ndarray:
    """Exact distance [m] of each point (n, 3) to the mesh's boundary surface (its triangles), from inside or
    outside the body. Candidate triangles: those whose centroid lies within the nearest centroid's distance
    plus the largest centroid-to-vertex distance of any triangle (no closer triangle can lie outside)."""
    from scipy.spatial import cKDTree

    cache = space.__dict__.setdefault("_physar_cache", {})
    if "surface_tree" not in cache:
        surf = _surface(space).mesh
        tri = surf.points[surf.faces]
        c = tri.mean(1)
        cache["surface_tree"] = (cKDTree(c), tri, float(np.linalg.norm(tri - c[:, None], axis=2).max()))
    tree, tri, reach = cache["surface_tree"]
    P = np.asarray(points, float).reshape(-1, 3)
    if len(P) == 0:
        return np.zeros(0)
    dc, _ = tree.query(P)
    cand = tree.query_ball_point(P, dc + reach * (1 + 1e-9) + 1e-12)
    lens = np.array([len(c) for c in cand])
    pi = np.repeat(np.arange(len(P)), lens)
    fi = np.concatenate([np.asarray(c, np.int64) for c in cand])
    out = np.full(len(P), np.inf)
    np.minimum.at(out, pi, _point_triangle_distance(P[pi], tri[fi]))
    return out


def bump(d: np.ndarray, radius: float) -> np.ndarray:
    r"""Smooth compact kernel :math:`(1 - (d/r)^2)^2` for :math:`d < r`, else 0 (:math:`C^1` in :math:`d`;
    regularised Dirac)."""
    s = np.clip(1.0 - (d / radius) ** 2, 0.0, None)
    return s * s


def point_load(
    space: FESpace, point: Sequence[float], total: Sequence[float], radius: float, degree: int = 6
) -> np.ndarray:
    r"""A force `total` [N] spread over the boundary within `radius` [m] of `point` (regularised Dirac).

    The traction is :math:`t(x) = \mathtt{total}\, k(\lvert x - p \rvert) / \int_\Gamma k \,\mathrm{d}A`
    with the bump kernel :math:`k` of :func:`bump`, so the
    nodal forces sum exactly to `total` and vary smoothly as the point moves (seed 000 §5.1).
    """
    if not (radius > 0 and np.isfinite(radius)):
        raise ConfigError(f"point load radius must be positive, got {radius}")
    p = _vector3(point, "point load point", "m")
    total = _vector3(total, "point load total", "N")
    surf = _surface(space)
    c = surf.face_centroids()
    pts_face = surf.mesh.points[surf.mesh.faces]
    reach = np.linalg.norm(pts_face - c[:, None], axis=2).max(axis=1)
    faces = np.flatnonzero(np.linalg.norm(c - p, axis=1) <= radius + reach)
    if len(faces) == 0:
        d = float(surface_distance(space, p)[0])
        raise ConfigError(f"point load at {p.tolist()}: no boundary within radius {radius}: the point is "
                          f"{d:.3g} m from the object's surface; check the point (metres, in the mesh's frame)")
    cells, x, w, N = _face_quadrature(space, faces, degree)
    k = w * bump(np.linalg.norm(x - p, axis=2), radius)
    if k.sum() <= 0:
        d = float(surface_distance(space, p)[0])
        if d >= radius:
            raise ConfigError(f"point load at {p.tolist()}: no boundary within radius {radius}: the point is "
                              f"{d:.3g} m from the object's surface; check the point (metres, in the mesh's frame)")
        raise ConfigError(
            f"point load at {p.tolist()}: radius {radius} is too small for the mesh there "
            "(no surface quadrature point within it); increase the radius or refine the mesh"
        )
    nodal = np.einsum("fq,fqa,i->fai", k / k.sum(), N, total)
    return _scatter(space, cells, nodal)


def gravity_load(space: FESpace, density: float, g: Sequence[float]) -> np.ndarray:
    r"""Body force :math:`\rho g` [N/m^3] integrated consistently:
    :math:`f_a = \int \rho g N_a \,\mathrm{d}V`."""
    from physar.fem.assembly import ElasticModel  # local: avoids a cycle at import time
    from physar.fem.materials import LinearElastic

    g = _vector3(g, "gravity g", "m/s²")
    if np.ndim(density) != 0 or np.asarray(density).dtype.kind not in "iuf" \
            or not (density >= 0 and np.isfinite(density)):
        raise ConfigError(f"density must be a number >= 0 [kg/m³], got {density!r}")
    vol = ElasticModel(space, LinearElastic(1.0, 0.0)).volume_integrals()
    return (density * vol[:, None] * g[None, :]).ravel()


def fixed_dofs(
    space: FESpace,
    box: Sequence[Sequence[float]] | None = None,
    where: Callable[[np.ndarray], np.ndarray] | None = None,
    components: str | Sequence[str] = "xyz",
    *,
    region=None,
    points=None,
    plane=None,
    tol=None,
) -> np.ndarray:
    """Dofs of the nodes in `box` (and/or satisfying `where(nodes)`), or picked by `region`, `points` or
    `plane` (:func:`select_nodes_mask`), for the given components."""
    comps = []
    for c in components:
        if c not in _COMPONENTS:
            raise ConfigError(f"unknown component {c!r}; use x, y or z")
        comps.append(_COMPONENTS[c])
    mask = np.ones(space.n_nodes, dtype=bool)
    if region is not None or points is not None or plane is not None:
        mask &= select_nodes_mask(space, box=box, region=region, points=points, plane=plane, tol=tol)
    elif box is not None:
        mask &= in_box(space.nodes, box, tol=_tol(space, None))
    if where is not None:
        mask &= np.asarray(where(space.nodes), dtype=bool)
    nodes = np.flatnonzero(mask)
    return np.sort((3 * nodes[:, None] + np.array(comps)[None, :]).ravel())
