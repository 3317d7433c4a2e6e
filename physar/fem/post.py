"""Post-processing: point probes, Cauchy and von Mises stress, nodal averaging and nodal stress recovery.

Two stress fields at the mesh vertices:

* :func:`nodal_average` of the element-averaged stress (:func:`cauchy_stress`): smooth but low where the
  stress varies across an element (bending: the mean over an element reaching from the neutral axis to the
  top fibre is half the fibre stress);
* :func:`nodal_stress`: the stress of each element evaluated at its own vertices from the shape-function
  gradients there (exact for the linear strain field of P2), then averaged at shared vertices: the value a
  user should read at a surface.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from physar.errors import ConfigError
from physar.fem.elements import FESpace, shape_functions, shape_gradients_ref


def _displacement(u, n_dofs: int) -> np.ndarray:
    """`u` as a float displacement (n_dofs,) [m], else ConfigError naming the shapes."""
    u = np.asarray(u, dtype=float)
    if u.shape != (n_dofs,):
        raise ConfigError(f"displacement u must have shape ({n_dofs},) (3 per node of the space), got {u.shape}")
    return u


def locate(space: FESpace, points: np.ndarray, tol: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Element index (p,) and barycentric coordinates (p, 4) of reference-configuration points.

    A point outside every element by at most `tol` [m] (default :func:`physar.fem.loads.default_tol`:
    a point on a boundary face of a float32 STL mesh, read 1 ulp inside) is accepted and projected onto
    the nearest element (its barycentric coordinates clipped at 0).
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
            raise ConfigError(f"probe point {p.tolist()} lies outside the mesh (by {-dist[e]:.3g} m at least; "
                              f"points within {tol:.3g} m of it are accepted)")
        Le = np.clip(L[e], 0.0, None)
        cells[i], bary[i] = e, Le / Le.sum()
    return cells, bary


def probe(space: FESpace, u: np.ndarray, point: Sequence[float] | np.ndarray) -> np.ndarray:
    """Displacement interpolated at reference point(s): (3,) for one point, (p, 3) for several."""
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


def von_mises(model, u: np.ndarray) -> np.ndarray:
    r"""Per-element von Mises stress :math:`\sqrt{\tfrac32\, s : s}`, :math:`s` = deviatoric Cauchy stress
    [Pa]."""
    sig = cauchy_stress(model, u)
    s = sig - np.trace(sig, axis1=1, axis2=2)[:, None, None] * np.eye(3) / 3
    return np.sqrt(1.5 * np.einsum("mij,mij->m", s, s))


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
