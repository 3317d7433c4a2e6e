r"""Observation operator :math:`C`: mesh displacements -> displacements of observed surface points (seed 000
§2.1, §4).

Each observed point is located on the boundary surface of the mesh (closest surface triangle, barycentric
coordinates :math:`\lambda` on it). On that face the tetrahedron's shape functions are evaluated with the
barycentric coordinate of the opposite vertex set to 0, so :math:`u(x) = \sum_a N_a(\lambda)\, u_a` is exact
for P1 and P2 (the trace of the element on its face). :math:`C` has one row per observed point and component:
row :math:`k \cdot n_c + j` is
component ``components[j]`` of point k.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from physar.errors import PhysarError
from physar.fem.elements import shape_functions


def closest_on_triangles(points, tri) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For points (p, 3) and triangles (f, 3, 3): index of the closest triangle, barycentrics (p, 3), distance.

    Exact point-triangle distance (projection clamped to the triangle by testing the 3 edges). ``tri`` may
    also be (p, k, 3, 3), k candidate triangles per point (the index returned is then into its k).
    """
    P = np.asarray(points, float)[:, None, :]  # (p, 1, 3)
    tri = np.asarray(tri, float)
    A, B, C = (tri[..., i, :] if tri.ndim == 4 else tri[None, :, i] for i in range(3))
    e0, e1 = B - A, C - A
    v = P - A
    d00, d01, d11 = (e0 * e0).sum(-1), (e0 * e1).sum(-1), (e1 * e1).sum(-1)
    d20, d21 = (v * e0).sum(-1), (v * e1).sum(-1)
    den = d00 * d11 - d01 * d01
    b1 = (d11 * d20 - d01 * d21) / den
    b2 = (d00 * d21 - d01 * d20) / den
    lam = np.stack([1 - b1 - b2, b1, b2], -1)  # (p, f, 3)
    inside = np.all(lam >= 0, -1)
    best_lam = lam.copy()
    best_d = np.where(inside, np.linalg.norm(v - b1[..., None] * e0 - b2[..., None] * e1, axis=-1), np.inf)
    verts = [A, B, C]
    for i, j in ((0, 1), (1, 2), (2, 0)):  # closest point on each edge
        a, b = verts[i], verts[j]
        ab = b - a
        t = np.clip(((P - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
        d = np.linalg.norm(P - a - t[..., None] * ab, axis=-1)
        better = ~inside & (d < best_d)
        best_d = np.where(better, d, best_d)
        l = np.zeros_like(lam)
        l[..., i], l[..., j] = 1 - t, t
        best_lam = np.where(better[..., None], l, best_lam)
    f = np.argmin(best_d, axis=1)
    r = np.arange(len(f))
    return f, best_lam[r, f], best_d[r, f]


def surface_observation_matrix(space, points, components: Sequence[int] = (0, 1, 2), tol: float = 1e-6,
                               faces: np.ndarray | None = None) -> sp.csr_matrix:
    """Sparse :math:`C` (p·nc, n_dofs): :math:`C u` = components of :math:`u` at reference surface `points`
    (p, 3) [m].

    ``faces``: restrict the search to these boundary faces (indices into ``space.mesh.boundary()``).
    Points farther than ``tol`` (m) from the surface raise a PhysarError.
    """
    pts = np.atleast_2d(np.asarray(points, float))
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise PhysarError(f"observed points must have shape (p, 3) with p > 0, got {pts.shape}")
    comps = np.asarray(components, int)
    if comps.size == 0 or comps.min() < 0 or comps.max() > 2:
        raise PhysarError(f"components must be a subset of 0, 1, 2, got {list(components)}")
    surf = space.mesh.boundary()
    fidx = np.arange(len(surf.face_cell)) if faces is None else np.asarray(faces, int)
    tri = surf.mesh.points[surf.mesh.faces[fidx]]
    f, lam, dist = closest_on_triangles(pts, tri)
    if np.any(dist > tol):
        k = int(np.argmax(dist))
        raise PhysarError(f"observed point {pts[k].tolist()} is {dist[k]:.3g} m from the mesh surface (tol {tol})")
    f = fidx[f]
    cells = surf.face_cell[f]
    # barycentrics of the face vertices -> barycentrics of the tet (opposite vertex 0)
    face_nodes_global = surf.node_map[surf.mesh.faces[f]]  # (p, 3) volume vertex ids, in face order
    L = np.zeros((len(pts), 4))
    tet_vertices = space.mesh.cells[cells]  # (p, 4)
    for j in range(3):
        pos = np.argmax(tet_vertices == face_nodes_global[:, j:j + 1], axis=1)
        L[np.arange(len(pts)), pos] = lam[:, j]
    N = shape_functions(space.element, L)  # (p, nen)
    nodes = space.cells[cells]
    p, nen = N.shape
    nc = comps.size
    rows = (nc * np.arange(p)[:, None, None] + np.arange(nc)[None, None, :]) * np.ones((1, nen, 1), int)
    cols = 3 * nodes[:, :, None] + comps[None, None, :]
    vals = np.broadcast_to(N[:, :, None], (p, nen, nc))
    return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(nc * p, space.n_dofs))
