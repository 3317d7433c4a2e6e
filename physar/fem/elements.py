r"""Lagrange tetrahedra (P1, P2), quadrature and the vector function space.

Reference tetrahedron with barycentric coordinates :math:`L_0 = 1 - \xi - \eta - \zeta`, :math:`L_1 = \xi`,
:math:`L_2 = \eta`, :math:`L_3 = \zeta`. P1: :math:`N_a = L_a`. P2 (10 nodes, VTK `tetra10` order: vertices,
then edges 01, 12, 02, 03, 13, 23): :math:`N_a = L_a (2 L_a - 1)` at vertices, :math:`N_{ab} = 4 L_a L_b` at
edge midpoints. Elements are affine
(straight edges), so the Jacobian is constant per element. Quadrature rules come from scikit-fem.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from skfem.quadrature import get_quadrature
from skfem.refdom import RefTet, RefTri

from physar.errors import ConfigError
from physar.geometry.mesh import TetMesh, _bounds_text, row_keys

P2_EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]], dtype=np.int64)
N_NODES = {"P1": 4, "P2": 10}
# quadrature degree for stiffness/force (exact for linear elasticity) and for mass
STIFFNESS_DEGREE = {"P1": 1, "P2": 2}
MASS_DEGREE = {"P1": 2, "P2": 4}


def shape_functions(element: str, L: np.ndarray) -> np.ndarray:
    """Shape function values at points given by barycentric coordinates `L` (..., 4) -> (..., nen)."""
    if element == "P1":
        return np.array(L, dtype=float, copy=True)
    Lv = np.asarray(L, dtype=float)
    vert = Lv * (2.0 * Lv - 1.0)
    edge = 4.0 * Lv[..., P2_EDGES[:, 0]] * Lv[..., P2_EDGES[:, 1]]
    return np.concatenate([vert, edge], axis=-1)


# d L / d (xi, eta, zeta): rows L0..L3
_DL = np.array([[-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def shape_gradients_ref(element: str, L: np.ndarray) -> np.ndarray:
    """Gradients w.r.t. reference coordinates at barycentric points `L` (q, 4) -> (q, nen, 3)."""
    L = np.atleast_2d(L)
    if element == "P1":
        return np.broadcast_to(_DL, (len(L), 4, 3)).copy()
    dvert = (4.0 * L - 1.0)[:, :, None] * _DL[None, :, :]
    a, b = P2_EDGES[:, 0], P2_EDGES[:, 1]
    dedge = 4.0 * (L[:, a, None] * _DL[None, b, :] + L[:, b, None] * _DL[None, a, :])
    return np.concatenate([dvert, dedge], axis=1)


def tet_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric points (q, 4) and weights (q,) on the reference tet (weights sum to 1/6)."""
    X, W = get_quadrature(RefTet, degree)
    L = np.column_stack([1.0 - X.sum(axis=0), X.T])
    return L, W


def tri_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric points (q, 3) and weights (q,) on the reference triangle (weights sum to 1/2)."""
    X, W = get_quadrature(RefTri, degree)
    return np.column_stack([1.0 - X.sum(axis=0), X.T]), W


def p2_nodes(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray]:
    """P2 node coordinates (mesh points, then unique edge midpoints) and (m, 10) connectivity."""
    cells = mesh.cells
    edges = np.sort(cells[:, P2_EDGES].reshape(-1, 2), axis=1)
    _, first, inv = np.unique(row_keys(edges, mesh.n_points), return_index=True, return_inverse=True)
    uniq = edges[first]
    mid = 0.5 * (mesh.points[uniq[:, 0]] + mesh.points[uniq[:, 1]])
    nodes = np.vstack([mesh.points, mid])
    conn = np.hstack([cells, mesh.n_points + inv.reshape(-1, 6)])
    return nodes, conn


@dataclass(frozen=True, eq=False, repr=False)
class FESpace:
    """Vector-valued Lagrange space on a tet mesh; dof of node :math:`a`, component :math:`i` is
    :math:`3a + i`.

    Attributes: `nodes` (n_nodes, 3) [m] (P2: mesh points first, then edge midpoints), `cells`
    (m, nen) node indices, `element` in {"P1", "P2"}.
    """

    mesh: TetMesh
    element: str = "P2"
    nodes: np.ndarray = field(init=False, repr=False)
    cells: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.element not in N_NODES:
            raise ConfigError(f"unknown element {self.element!r}; use 'P1' or 'P2'")
        if self.element == "P1":
            nodes, cells = self.mesh.points, self.mesh.cells
        else:
            nodes, cells = p2_nodes(self.mesh)
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "cells", cells)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_dofs(self) -> int:
        return 3 * len(self.nodes)

    @property
    def nen(self) -> int:
        return N_NODES[self.element]

    def __repr__(self) -> str:
        """One line: element, mesh name, tetrahedra, nodes, dofs and bounding box [m] (no arrays)."""
        return (f"FESpace({self.element} on {self.mesh.name!r}, {len(self.cells)} tetrahedra, {self.n_nodes} nodes, "
                f"{self.n_dofs} dofs, bounds {_bounds_text(self.mesh.points)})")

    @cached_property
    def cell_dofs(self) -> np.ndarray:
        """(m, 3 nen) global dofs of each element, ordered (node a, component i) -> 3 a + i."""
        return (3 * self.cells[:, :, None] + np.arange(3)).reshape(len(self.cells), -1)

    @cached_property
    def jacobians(self) -> tuple[np.ndarray, np.ndarray]:
        r"""Per element :math:`J^{-1}` (m, 3, 3) and :math:`\det J` (m,) of the affine map from the reference tet."""
        x = self.mesh.points[self.mesh.cells]
        J = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)  # columns
        return np.linalg.inv(J), np.linalg.det(J)

    def gradients(self, L: np.ndarray) -> np.ndarray:
        r"""Physical shape-function gradients :math:`\partial N_a / \partial X_J` at barycentric points L:
        (m, q, nen, 3)."""
        Jinv, _ = self.jacobians
        dref = shape_gradients_ref(self.element, L)  # (q, nen, 3)
        return np.einsum("qak,mkj->mqaj", dref, Jinv, optimize=True)

    def vertex_values(self, u: np.ndarray) -> np.ndarray:
        """A nodal vector field (n_dofs,) restricted to the mesh vertices: (n_points, 3)."""
        return np.asarray(u).reshape(-1, 3)[: self.mesh.n_points]
