"""Post-processing: point probes, Cauchy and von Mises stress, nodal averaging."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from physar.errors import ConfigError
from physar.fem.elements import FESpace, shape_functions


def locate(space: FESpace, points: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Element index (p,) and barycentric coordinates (p, 4) of reference-configuration points."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    Jinv, _ = space.jacobians
    x0 = space.mesh.points[space.mesh.cells[:, 0]]
    cells = np.empty(len(points), dtype=np.int64)
    bary = np.empty((len(points), 4))
    for i, p in enumerate(points):  # loop over probes (few), vectorised over elements
        xi = np.einsum("mij,mj->mi", Jinv, p - x0)
        L = np.column_stack([1 - xi.sum(axis=1), xi])
        e = int(np.argmax(L.min(axis=1)))
        if L[e].min() < -tol:
            raise ConfigError(f"probe point {p.tolist()} lies outside the mesh")
        cells[i], bary[i] = e, L[e]
    return cells, bary


def probe(space: FESpace, u: np.ndarray, point: Sequence[float] | np.ndarray) -> np.ndarray:
    """Displacement interpolated at reference point(s): (3,) for one point, (p, 3) for several."""
    pts = np.asarray(point, dtype=float)
    cells, L = locate(space, pts)
    N = shape_functions(space.element, L)  # (p, nen)
    U = np.asarray(u).reshape(-1, 3)[space.cells[cells]]  # (p, nen, 3)
    out = np.einsum("pa,pai->pi", N, U)
    return out[0] if pts.ndim == 1 else out


def cauchy_stress(model, u: np.ndarray) -> np.ndarray:
    """Cauchy stress sigma = P Fᵀ / J (small-strain sigma for the linear material) averaged over each element's quadrature points: (m, 3, 3) [Pa]."""
    F = model.deformation_gradient(u)
    P = model.material.stress(F.reshape(-1, 3, 3)).reshape(F.shape)
    if model.material.linear:  # small strain: no distinction between stress measures
        sig = P
    else:
        J = np.linalg.det(F)
        sig = np.einsum("mqij,mqkj->mqik", P, F) / J[..., None, None]
    _, wdet = model._quad
    return np.einsum("mq,mqij->mij", wdet, sig) / wdet.sum(axis=1)[:, None, None]


def von_mises(model, u: np.ndarray) -> np.ndarray:
    """Per-element von Mises stress sqrt(3/2 s:s), s = deviatoric Cauchy stress [Pa]."""
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
