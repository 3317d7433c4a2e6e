r"""Assembly of internal force, tangent stiffness, energy and mass (vectorised over elements).

With shape-function gradients :math:`G_{aJ} = \partial N_a / \partial X_J` and
:math:`F = I + \sum_a u_a \otimes G_a` at each quadrature point :math:`q` (weight :math:`w_q`):

.. math::

    f_{ai} &= \sum_q w_q \det J\, P_{iJ}(F)\, G_{aJ}
    \quad \text{internal force, } f_{\mathrm{int}} = \partial \Pi / \partial u, \\
    K_{aibk} &= \sum_q w_q \det J\, G_{aJ}\, \mathbb{A}_{iJkL}(F)\, G_{bL}
    \quad \text{tangent, } K = \partial f_{\mathrm{int}} / \partial u, \\
    M_{ab} &= \sum_q w_q \det J\, \rho\, N_a N_b
    \quad \text{consistent mass (times } I_3\text{); lumped by HRZ diagonal scaling.}

Element arrays go to a CSR matrix through a precomputed scatter map (pattern built once per space).
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse as sp

from physar.errors import ConfigError
from physar.fem.elements import (
    MASS_DEGREE,
    STIFFNESS_DEGREE,
    FESpace,
    shape_functions,
    tet_quadrature,
)
from physar.fem.materials import Material

_CHUNK = 20000  # elements per block: bounds temporary memory for large P2 meshes


class CSRPattern:
    """Sparsity pattern of element matrices and the map from element entries to CSR data slots."""

    def __init__(self, cell_dofs: np.ndarray, n: int):
        _m, nd = cell_dofs.shape
        if n < 2**31 - 1:  # scipy is several times faster with 32-bit indices
            cell_dofs = cell_dofs.astype(np.int32)
        rows = np.repeat(cell_dofs, nd, axis=1).ravel()
        cols = np.tile(cell_dofs, (1, nd)).ravel()
        # CSR via a COO matrix whose data are entry ids; duplicates are summed, so use ones for the
        # pattern and recover each entry's slot by a sorted search on row-major keys.
        pat = sp.csr_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n, n))
        pat.sum_duplicates()
        pat.sort_indices()
        self.indptr = pat.indptr
        self.indices = pat.indices
        keys_csr = np.repeat(np.arange(n, dtype=np.int64), np.diff(pat.indptr)) * n + pat.indices
        self.slot = np.searchsorted(keys_csr, rows.astype(np.int64) * n + cols).astype(np.int64)
        self.n = n
        self.nnz = len(pat.indices)

    def assemble(self, element_matrices: np.ndarray) -> sp.csr_matrix:
        data = np.bincount(self.slot, weights=element_matrices.ravel(), minlength=self.nnz)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))


def assemble_coo(cell_dofs: np.ndarray, element_matrices: np.ndarray, n: int) -> sp.csr_matrix:
    """One-shot assembly through scipy's COO -> CSR (faster than building a reusable pattern)."""
    nd = cell_dofs.shape[1]
    if n < 2**31 - 1:  # scipy is several times faster with 32-bit indices
        cell_dofs = cell_dofs.astype(np.int32)
    rows = np.repeat(cell_dofs, nd, axis=1).ravel()
    cols = np.tile(cell_dofs, (1, nd)).ravel()
    return sp.coo_matrix((element_matrices.ravel(), (rows, cols)), shape=(n, n)).tocsr()


class ElasticModel:
    """Hyperelastic body discretised on an FESpace (seed 000 §5; Lagrange P1/P2 tetrahedra).

    `u` is always the nodal displacement vector (n_dofs,) in metres; forces are in newtons.
    """

    def __init__(self, space: FESpace, material: Material, density: float = 0.0):
        if not isinstance(space, FESpace):
            hint = " (wrap a mesh as FESpace(mesh, 'P1') or 'P2')" if hasattr(space, "cells") else ""
            raise ConfigError(f"space must be a physar.fem FESpace, got {type(space).__name__}{hint}")
        if not isinstance(material, Material):
            raise ConfigError(f"material must be a physar.fem Material, got {type(material).__name__}")
        if density < 0 or not np.isfinite(density):
            raise ConfigError(f"density must be >= 0, got {density}")
        self.space = space
        self.material = material
        self.density = float(density)
        self._K_linear = None
        self._n_assembled = 0

    # -- geometry at quadrature points ------------------------------------------------------------
    @cached_property
    def _quad(self):
        L, w = tet_quadrature(STIFFNESS_DEGREE[self.space.element])
        G = self.space.gradients(L)  # (m, q, nen, 3)
        _, detJ = self.space.jacobians
        wdet = detJ[:, None] * w[None, :]  # (m, q)
        return G, wdet

    @cached_property
    def pattern(self) -> CSRPattern:
        return CSRPattern(self.space.cell_dofs, self.space.n_dofs)

    @property
    def linear(self) -> bool:
        return bool(self.material.linear)

    @property
    def n_dofs(self) -> int:
        return self.space.n_dofs

    def __repr__(self) -> str:
        """One line: the space (element, mesh, counts), the material and the density (no arrays)."""
        sp_ = self.space
        return (f"{type(self).__name__}({sp_.element} on {sp_.mesh.name!r}, {len(sp_.cells)} tetrahedra, "
                f"{sp_.n_dofs} dofs, {self.material!r}, density {self.density:g} kg/m^3)")

    def deformation_gradient(self, u: np.ndarray, sl: slice = slice(None)) -> np.ndarray:
        r""":math:`F = I + \sum_a u_a \otimes \partial N_a / \partial X` at each quadrature point:
        (m, q, 3, 3)."""
        G, _ = self._quad
        ue = np.asarray(u).reshape(-1, 3)[self.space.cells[sl]]  # (m, nen, 3)
        return np.eye(3) + np.einsum("mai,mqaj->mqij", ue, G[sl], optimize=True)

    def _check_u(self, u):
        u = np.asarray(u, dtype=float)
        if u.shape != (self.n_dofs,):
            raise ConfigError(f"displacement must have shape ({self.n_dofs},), got {u.shape}")
        return u

    def _blocks(self):
        m = len(self.space.cells)
        for s in range(0, m, _CHUNK):
            yield slice(s, min(s + _CHUNK, m))

    # -- energy, force, tangent ---------------------------------------------------------------------
    def energy(self, u: np.ndarray) -> float:
        r"""Stored energy :math:`\Pi_\text{int}(u) = \sum_q w \det J\, W(F)` [J]; +inf if an element is
        inverted (:math:`J \le 0`)."""
        u = self._check_u(u)
        _, wdet = self._quad
        total = 0.0
        for sl in self._blocks():
            W = self.material.energy_density(self.deformation_gradient(u, sl))
            total += float(np.sum(wdet[sl] * W))
        return total

    def internal_force(self, u: np.ndarray) -> np.ndarray:
        u = self._check_u(u)
        G, wdet = self._quad
        out = np.zeros(self.n_dofs)
        for sl in self._blocks():
            P = self.material.stress(self.deformation_gradient(u, sl))
            fe = np.einsum("mq,mqij,mqaj->mai", wdet[sl], P, G[sl], optimize=True)
            out += np.bincount(
                self.space.cell_dofs[sl].ravel(), weights=fe.ravel(), minlength=self.n_dofs
            )
        return out

    def element_stiffness(self, u: np.ndarray, sl: slice) -> np.ndarray:
        """Element tangent matrices (m_block, 3 nen, 3 nen), dof order (a, i)."""
        G, wdet = self._quad
        F = self.deformation_gradient(u, sl)
        _, A = self.material.stress_tangent(F)  # (m, q, i, J, k, L)
        Gs = G[sl]
        m, q, nen, _ = Gs.shape
        # H[m,q,a,(i,k,L)] = Σ_J G[a,J] A[i,J,k,L]
        At = np.ascontiguousarray(np.moveaxis(A, 3, 2)).reshape(m, q, 3, 27)  # (J, i k L)
        H = (Gs @ At).reshape(m, q, nen * 9, 3)  # rows (a, i, k), cols L
        Ke = H @ np.swapaxes(Gs, -1, -2)  # (m, q, (a,i,k), b)
        Ke = np.einsum("mq,mqxb->mxb", wdet[sl], Ke, optimize=True).reshape(m, nen, 3, 3, nen)
        return Ke.transpose(0, 1, 2, 4, 3).reshape(m, 3 * nen, 3 * nen)

    def tangent_stiffness(self, u: np.ndarray | None = None) -> sp.csr_matrix:
        r""":math:`K(u) = \mathrm{d} f_\text{int} / \mathrm{d} u` (CSR, n_dofs x n_dofs); cached for linear
        materials."""
        if u is None:
            u = np.zeros(self.n_dofs)
        u = self._check_u(u)
        if self.linear and self._K_linear is not None:
            return self._K_linear
        blocks = [self.element_stiffness(u, sl) for sl in self._blocks()]
        Ke = np.concatenate(blocks) if len(blocks) > 1 else blocks[0]
        self._n_assembled += 1
        if self._n_assembled == 1:  # the reusable pattern pays off from the second assembly on
            K = assemble_coo(self.space.cell_dofs, Ke, self.n_dofs)
        else:
            K = self.pattern.assemble(Ke)
        if self.linear:
            self._K_linear = K
        return K

    # -- mass --------------------------------------------------------------------------------------
    def mass_matrix(self, lumped: bool = False) -> sp.csr_matrix:
        r"""Consistent mass :math:`M_{ab} = \int \rho N_a N_b \,\mathrm{d}V` (:math:`\times I_3`), or its
        HRZ-lumped diagonal [kg]."""
        if self.density <= 0:
            raise ConfigError("the model has no density; set density > 0 to build a mass matrix")
        L, w = tet_quadrature(MASS_DEGREE[self.space.element])
        N = shape_functions(self.space.element, L)  # (q, nen)
        _, detJ = self.space.jacobians
        Me = self.density * np.einsum("m,q,qa,qb->mab", detJ, w, N, N, optimize=True)
        if lumped:
            diag = np.einsum("maa->ma", Me)
            mass = Me.sum(axis=(1, 2))
            lump = diag * (mass / diag.sum(axis=1))[:, None]
            nodal = np.bincount(self.space.cells.ravel(), weights=lump.ravel(), minlength=self.space.n_nodes)
            return sp.diags(np.repeat(nodal, 3)).tocsr()
        nen = self.space.nen
        Mfull = np.einsum("mab,ij->maibj", Me, np.eye(3)).reshape(-1, 3 * nen, 3 * nen)
        return assemble_coo(self.space.cell_dofs, Mfull, self.n_dofs)

    def volume_integrals(self) -> np.ndarray:
        r""":math:`\int N_a \,\mathrm{d}V` per node (n_nodes,) [m^3]: consistent weights for body forces."""
        L, w = tet_quadrature(MASS_DEGREE[self.space.element])
        N = shape_functions(self.space.element, L)
        _, detJ = self.space.jacobians
        ve = np.einsum("m,q,qa->ma", detJ, w, N)
        return np.bincount(self.space.cells.ravel(), weights=ve.ravel(), minlength=self.space.n_nodes)
