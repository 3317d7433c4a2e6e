"""External loads as consistent nodal force vectors (n_dofs,) [N], and Dirichlet dof selection.

Surface loads integrate f_a = ∫_Γ N_a t dA over boundary faces; the tet shape functions are evaluated
on the face (the barycentric coordinate of the opposite vertex is 0), so P1 and P2 are treated alike.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from physar.errors import ConfigError
from physar.fem.elements import FESpace, shape_functions, tri_quadrature
from physar.geometry.mesh import TET_FACES, BoundarySurface, in_box, select_boundary_faces

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


def traction_load(space: FESpace, box: Sequence[Sequence[float]], total: Sequence[float]) -> np.ndarray:
    """Uniform traction t = total / area on the boundary faces whose centroids lie in `box`."""
    surf = _surface(space)
    faces = select_boundary_faces(surf, box=box)
    if len(faces) == 0:
        raise ConfigError(f"traction load: no boundary face has its centroid in box {np.asarray(box).tolist()}")
    total = np.asarray(total, dtype=float)
    area = surf.mesh.face_areas()[faces].sum()
    cells, _, w, N = _face_quadrature(space, faces, 2)
    nodal = np.einsum("fq,fqa,i->fai", w, N, total / area)
    return _scatter(space, cells, nodal)


def bump(d: np.ndarray, radius: float) -> np.ndarray:
    """Smooth compact kernel (1 - (d/r)^2)^2 for d < r, else 0 (C1 in d; regularised Dirac)."""
    s = np.clip(1.0 - (d / radius) ** 2, 0.0, None)
    return s * s


def point_load(
    space: FESpace, point: Sequence[float], total: Sequence[float], radius: float, degree: int = 6
) -> np.ndarray:
    """A force `total` [N] spread over the boundary within `radius` [m] of `point` (regularised Dirac).

    The traction is t(x) = total * k(|x - p|) / ∫_Γ k dA with the bump kernel k of :func:`bump`, so the
    nodal forces sum exactly to `total` and vary smoothly as the point moves (seed 000 §5.1).
    """
    if not (radius > 0 and np.isfinite(radius)):
        raise ConfigError(f"point load radius must be positive, got {radius}")
    p = np.asarray(point, dtype=float)
    surf = _surface(space)
    c = surf.face_centroids()
    pts_face = surf.mesh.points[surf.mesh.faces]
    reach = np.linalg.norm(pts_face - c[:, None], axis=2).max(axis=1)
    faces = np.flatnonzero(np.linalg.norm(c - p, axis=1) <= radius + reach)
    if len(faces) == 0:
        raise ConfigError(f"point load at {p.tolist()}: no boundary within radius {radius}")
    cells, x, w, N = _face_quadrature(space, faces, degree)
    k = w * bump(np.linalg.norm(x - p, axis=2), radius)
    if k.sum() <= 0:
        raise ConfigError(
            f"point load at {p.tolist()}: radius {radius} is too small for the mesh there "
            "(no surface quadrature point within it); increase the radius or refine the mesh"
        )
    total = np.asarray(total, dtype=float)
    nodal = np.einsum("fq,fqa,i->fai", k / k.sum(), N, total)
    return _scatter(space, cells, nodal)


def gravity_load(space: FESpace, density: float, g: Sequence[float]) -> np.ndarray:
    """Body force rho g [N/m^3] integrated consistently: f_a = ∫ rho g N_a dV."""
    from physar.fem.assembly import ElasticModel  # local: avoids a cycle at import time
    from physar.fem.materials import LinearElastic

    vol = ElasticModel(space, LinearElastic(1.0, 0.0)).volume_integrals()
    return (density * vol[:, None] * np.asarray(g, dtype=float)[None, :]).ravel()


def fixed_dofs(
    space: FESpace,
    box: Sequence[Sequence[float]] | None = None,
    where: Callable[[np.ndarray], np.ndarray] | None = None,
    components: str | Sequence[str] = "xyz",
) -> np.ndarray:
    """Dofs of the nodes in `box` (and/or satisfying `where(nodes)`), for the given components."""
    comps = []
    for c in components:
        if c not in _COMPONENTS:
            raise ConfigError(f"unknown component {c!r}; use x, y or z")
        comps.append(_COMPONENTS[c])
    mask = np.ones(space.n_nodes, dtype=bool)
    if box is not None:
        mask &= in_box(space.nodes, box)
    if where is not None:
        mask &= np.asarray(where(space.nodes), dtype=bool)
    nodes = np.flatnonzero(mask)
    return np.sort((3 * nodes[:, None] + np.array(comps)[None, :]).ravel())
