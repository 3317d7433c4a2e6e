"""Post-processing: point probes, Cauchy and von Mises stress, nodal averaging and nodal stress recovery.

Two stress fields at the mesh vertices:

* :func:`nodal_average` of the element-averaged stress (:func:`cauchy_stress`): smooth but low where the
  stress varies across an element (bending: the mean over an element reaching from the neutral axis to the
  top fibre is half the fibre stress);
* :func:`nodal_stress`: the stress of each element evaluated at its own vertices from the shape-function
  gradients there (exact for the linear strain field of P2), then averaged at shared vertices: the value a
  user should read at a surface. Its von Mises stress, :func:`nodal_von_mises`, is the field `physar fem
  solve` writes at the vertices and whose peak it reports (the AR overlay and `rom info --check` use
  :func:`nodal_stress` too).

:func:`probe` / :func:`locate` accept a point on the exact surface of a curved part, outside the mesh's
chords, by snapping it to the nearest boundary point (see :func:`locate` for the bound).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from physar.errors import ConfigError
from physar.fem.elements import FESpace, shape_functions, shape_gradients_ref
from physar.fem.loads import closest_on_triangles as _closest_on_triangles


def _displacement(u, n_dofs: int) -> np.ndarray:
    """`u` as a float displacement (n_dofs,) [m], else ConfigError naming the shapes."""
    u = np.asarray(u, dtype=float)
    if u.shape != (n_dofs,):
        raise ConfigError(f"displacement u must have shape ({n_dofs},) (3 per node of the space), got {u.shape}")
    return u


SNAP_FRACTION = 0.5  # a probe outside a curved surface is accepted at most this fraction of the element size out
FEATURE_ANGLE = 60.0  # degrees: boundary faces turning more than this meet at a sharp edge, not a curved surface


def locate(space: FESpace, points: np.ndarray, tol: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    r"""Element index (p,) and barycentric coordinates (p, 4) of reference-configuration points.

    A point inside an element, or outside every element by at most `tol` [m] (default
    :func:`physar.fem.loads.default_tol`: a point on a boundary face of a float32 STL mesh, read 1 ulp inside),
    is located in the element nearest to it (barycentric coordinates clipped at 0).

    A point farther out is snapped to the nearest point of the mesh's boundary surface (exact point-triangle
    distance), in the element of that boundary face, when its distance ``d`` is within what the faceted surface
    may cut inside a curved one there (a probe on the CAD surface of a curved part lies outside the chords):
    ``d <= min(SNAP_FRACTION * h, 2 s)``, with ``h`` the mean edge length of that element and ``s`` the
    sagitta the face's vertex normals imply, the largest over its edges of :math:`(n_i - n_j) \cdot (x_i - x_j)
    / 8` (the normal curvature along the edge, :math:`(n_i - n_j) \cdot (x_i - x_j) / |x_i - x_j|^2`, times
    :math:`|x_i - x_j|^2 / 8`: :math:`h^2 / 8R` for a chord of length :math:`h` on a circle of radius :math:`R`;
    0 along a straight generator and on a concave surface, whose chords lie outside the body). The vertex
    normals average the neighbouring faces within :data:`FEATURE_ANGLE` of the face, so a flat face, also one
    next to a sharp edge, has ``s = 0`` and accepts only ``tol``. Anything farther is refused in one
    ConfigError line with its distance and the accepted one.
    """
    from physar.fem.loads import default_tol

    given = np.asarray(points, dtype=float)
    points = np.atleast_2d(given)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ConfigError(f"probe points must have shape (3,) or (p, 3) [m], got shape {given.shape}")
    tol = default_tol(space.mesh.points) if tol is None else float(tol)
    Jinv, _ = space.jacobians
    x0 = space.mesh.points[space.mesh.cells[:, 0]]
    # |grad L_i|: rows of Jinv for L_1..L_3, minus their sum for L_0; L_i / |grad L_i| is the signed
    # distance [m] to the plane of the face opposite vertex i (negative outside)
    G = np.concatenate([-Jinv.sum(axis=1)[:, None, :], Jinv], axis=1)
    gnorm = np.linalg.norm(G, axis=2)
    cells = np.empty(len(points), dtype=np.int64)
    bary = np.empty((len(points), 4))
    for i, p in enumerate(points):  # loop over probes (few), vectorised over elements
        if not np.all(np.isfinite(p)):  # NaN fails every comparison: it would land in element 0
            raise ConfigError(f"probe point {p.tolist()} is not finite")
        xi = np.einsum("mij,mj->mi", Jinv, p - x0)
        L = np.column_stack([1 - xi.sum(axis=1), xi])
        dist = (L / gnorm).min(axis=1)
        e = int(np.argmax(dist))
        if dist[e] < -tol:
            e, Le = _snap_outside(space, p, tol)
        else:
            Le = L[e]
        Le = np.clip(Le, 0.0, None)
        cells[i], bary[i] = e, Le / Le.sum()
    return cells, bary


def _snap_outside(space: FESpace, p: np.ndarray, tol: float) -> tuple[int, np.ndarray]:
    """(element, barycentric coordinates (4,)) of the nearest boundary point to `p`, a point outside every
    element by more than `tol`, when within the curved-surface slack of :func:`locate`; else ConfigError."""
    surf, tree, tri, reach, normal, area, vf_ptr, vf_idx = _boundary_search(space)
    dc, _ = tree.query(p)
    cand = np.asarray(tree.query_ball_point(p, dc + reach * (1 + 1e-9) + 1e-12), dtype=np.int64)
    q, d = _closest_on_triangles(np.broadcast_to(p, (len(cand), 3)), tri[cand])
    k = int(np.argmin(d))
    f, q, d = int(cand[k]), q[k], float(d[k])
    # the sagitta of face f from its vertex normals (neighbouring faces within FEATURE_ANGLE of its normal)
    nf = normal[f]
    cos_feat = np.cos(np.radians(FEATURE_ANGLE))
    vn = np.empty((3, 3))
    for j, v in enumerate(surf.mesh.faces[f]):
        around = vf_idx[vf_ptr[v]:vf_ptr[v + 1]]
        around = around[normal[around] @ nf >= cos_feat]
        n = (area[around, None] * normal[around]).sum(axis=0)
        vn[j] = n / np.linalg.norm(n)  # `around` holds f itself: never zero
    x = tri[f]
    sag = max(0.0, *((vn[a] - vn[b]) @ (x[a] - x[b]) / 8.0 for a, b in ((0, 1), (1, 2), (2, 0))))
    e = int(surf.face_cell[f])
    X = space.mesh.points[space.mesh.cells[e]]
    h = float(np.mean([np.linalg.norm(X[a] - X[b]) for a in range(4) for b in range(a + 1, 4)]))
    allowed = max(tol, min(SNAP_FRACTION * h, 2.0 * sag))
    if d > allowed:
        why = ("the mesh's surface is flat there" if allowed == tol else
               f"about twice the sagitta of the facets of the curved surface there, elements of {h:.3g} m")
        raise ConfigError(f"probe point {p.tolist()} lies outside the mesh by {d:.3g} m (the nearest boundary "
                          f"point is {np.round(q, 9).tolist()}; accepted there: {allowed:.3g} m, {why})")
    Jinv, _ = space.jacobians
    xi = Jinv[e] @ (q - X[0])
    return e, np.concatenate([[1.0 - xi.sum()], xi])


def _boundary_search(space: FESpace):
    """Cached per space: the boundary surface, a KD-tree of its face centroids, its triangles (f, 3, 3), the
    largest centroid-to-vertex distance, unit face normals, face areas, vertex -> faces (CSR ptr, idx)."""
    from scipy.spatial import cKDTree

    cache = space.__dict__.setdefault("_physar_cache", {})
    if "boundary_search" not in cache:
        surf = cache["boundary"] if "boundary" in cache else space.mesh.boundary()
        cache["boundary"] = surf
        tri = surf.mesh.points[surf.mesh.faces]
        c = tri.mean(axis=1)
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area = 0.5 * np.linalg.norm(nrm, axis=1)
        nrm = nrm / np.maximum(2.0 * area, 1e-300)[:, None]
        flat = surf.mesh.faces.ravel()
        order = np.argsort(flat, kind="stable")
        ptr = np.concatenate([[0], np.cumsum(np.bincount(flat, minlength=surf.mesh.n_points))])
        reach = float(np.linalg.norm(tri - c[:, None], axis=2).max())
        cache["boundary_search"] = (surf, cKDTree(c), tri, reach, nrm, area, ptr, order // 3)
    return cache["boundary_search"]


def probe(space: FESpace, u: np.ndarray, point: Sequence[float] | np.ndarray) -> np.ndarray:
    """Displacement interpolated at reference point(s): (3,) for one point, (p, 3) for several. A point
    outside the mesh is placed by :func:`locate`: on a curved surface within about twice the facets' sagitta it
    is snapped to the nearest boundary point, else refused in one ConfigError line."""
    pts = np.asarray(point, dtype=float)
    u = _displacement(u, space.n_dofs)
    cells, L = locate(space, pts)
    N = shape_functions(space.element, L)  # (p, nen)
    U = u.reshape(-1, 3)[space.cells[cells]]  # (p, nen, 3)
    out = np.einsum("pa,pai->pi", N, U)
    return out[0] if pts.ndim == 1 else out


def cauchy_stress(model, u: np.ndarray) -> np.ndarray:
    r"""Cauchy stress :math:`\sigma = P F^\top / J` (small-strain :math:`\sigma` for the linear material)
    averaged over each element's quadrature points: (m, 3, 3) [Pa]."""
    sig = _cauchy(model.material, model.deformation_gradient(_displacement(u, model.n_dofs)))
    _, wdet = model._quad
    return np.einsum("mq,mqij->mij", wdet, sig) / wdet.sum(axis=1)[:, None, None]


def _cauchy(material, F: np.ndarray) -> np.ndarray:
    r"""Cauchy stress :math:`\sigma = P F^\top / J` (:math:`P` for a linear material) at deformation gradients
    F (..., 3, 3) [Pa]."""
    P = material.stress(F.reshape(-1, 3, 3)).reshape(F.shape)
    if material.linear:
        return P
    return np.einsum("...ij,...kj->...ik", P, F) / np.linalg.det(F)[..., None, None]


def nodal_stress(model, u: np.ndarray, vertices: np.ndarray | None = None,
                 cell_scale: np.ndarray | None = None) -> np.ndarray:
    r"""Cauchy stress at mesh vertices recovered from each element's own vertex values: (n, 3, 3) [Pa].

    For every element :math:`e` holding vertex :math:`a`, the deformation gradient is evaluated at that vertex
    from the shape-function gradients there (not at the quadrature points),

    .. math::

        F_e(X_a) = I + \sum_b u_b \otimes \nabla N_b(X_a), \qquad \sigma_e(X_a) = \sigma(F_e(X_a))

    (:math:`P F^\top / J`; the small-strain :math:`\sigma` if linear), and the element values are averaged with
    the element volumes :math:`V_e` as weights,

    .. math::

        \sigma(X_a) = \frac{\sum_{e \ni a} V_e\, \sigma_e(X_a)}{\sum_{e \ni a} V_e}.

    On P2 the strain is linear in each element, so :math:`\sigma_e(X_a)` is its exact vertex value and a linear stress
    field (pure bending) is recovered exactly; on P1 it is the element's constant stress. ``vertices``:
    indices into ``model.space.mesh.points`` (default all); only the elements touching them are evaluated.
    ``u``: (n_dofs,) [m]. ``cell_scale`` (n_cells,): :math:`\sigma_e` multiplied by it before averaging (a
    Young's modulus :math:`E_e` = cell_scale[e] :math:`E` varying by cell: :math:`\sigma` is proportional to
    :math:`E` at fixed :math:`\nu` for every physar material).
    """
    space = model.space
    mesh = space.mesh
    cells = mesh.cells
    if vertices is None:
        vertices = np.arange(mesh.n_points)
        elems = np.arange(len(cells))
    else:
        vertices = np.asarray(vertices, dtype=np.int64).ravel()
        wanted = np.zeros(mesh.n_points, dtype=bool)
        wanted[vertices] = True
        elems = np.flatnonzero(wanted[cells].any(axis=1))
    Jinv, detJ = space.jacobians
    dref = shape_gradients_ref(space.element, np.eye(4))  # (4 vertices, nen, 3)
    ue = _displacement(u, space.n_dofs).reshape(-1, 3)[space.cells[elems]]  # (m, nen, 3)
    H = np.einsum("mbi,vbk,mkj->mvij", ue, dref, Jinv[elems], optimize=True)  # ∇u at the 4 vertices
    sig = _cauchy(model.material, np.eye(3) + H)  # (m, 4, 3, 3)
    if cell_scale is not None:
        sig = sig * np.asarray(cell_scale, dtype=float)[elems, None, None, None]
    vol = np.abs(detJ[elems]) / 6.0
    idx = cells[elems].ravel()
    w = np.bincount(idx, weights=np.repeat(vol, 4), minlength=mesh.n_points)[vertices]
    flat = (sig * vol[:, None, None, None]).reshape(-1, 9)
    out = np.stack([np.bincount(idx, weights=flat[:, k], minlength=mesh.n_points)[vertices] for k in range(9)],
                   axis=1)
    return (out / w[:, None]).reshape(-1, 3, 3)


def von_mises_of(stress: np.ndarray) -> np.ndarray:
    r"""Von Mises stress :math:`\sqrt{\tfrac32\, s : s}` of stresses (..., 3, 3), :math:`s` the deviatoric part
    [Pa]."""
    sig = np.asarray(stress, dtype=float)
    s = sig - np.trace(sig, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) / 3
    return np.sqrt(1.5 * np.einsum("...ij,...ij->...", s, s))


def von_mises(model, u: np.ndarray) -> np.ndarray:
    r"""Per-element von Mises stress :math:`\sqrt{\tfrac32\, s : s}` of the element-averaged Cauchy stress
    (:func:`cauchy_stress`), :math:`s` its deviatoric part [Pa]. Reads low where the stress varies across an
    element (bending); :func:`nodal_von_mises` is the value at the vertices."""
    return von_mises_of(cauchy_stress(model, u))


def nodal_von_mises(model, u: np.ndarray, vertices: np.ndarray | None = None,
                    cell_scale: np.ndarray | None = None) -> np.ndarray:
    """Von Mises stress [Pa] at the mesh vertices (default all, else ``vertices``) of the stress recovered by
    :func:`nodal_stress` (each element's stress at its own vertices, volume-averaged at shared vertices): the
    field `physar fem solve` writes and whose peak it reports."""
    return von_mises_of(nodal_stress(model, u, vertices, cell_scale))


def nodal_average(space: FESpace, per_element: np.ndarray) -> np.ndarray:
    """Volume-weighted average of per-element values at the mesh vertices: (n_points, ...)."""
    vals = np.asarray(per_element, dtype=float)
    vol = np.abs(space.jacobians[1]) / 6.0
    cells = space.mesh.cells
    w = np.bincount(cells.ravel(), weights=np.repeat(vol, 4), minlength=space.mesh.n_points)
    flat = vals.reshape(len(vals), -1)
    out = np.stack(
        [
            np.bincount(cells.ravel(), weights=np.repeat(vol * flat[:, k], 4), minlength=space.mesh.n_points)
            for k in range(flat.shape[1])
        ],
        axis=1,
    ) / w[:, None]
    return out.reshape((space.mesh.n_points,) + vals.shape[1:])
