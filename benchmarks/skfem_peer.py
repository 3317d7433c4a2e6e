"""The same clamped cantilever solved with scikit-fem: the peer for tests and benchmarks.

Kept outside the package: scikit-fem is only the reference here, physar does not call it for this.
"""

from __future__ import annotations

import time

import numpy as np


def _rigid_modes(ib, I):
    """The 6 rigid-body modes (translations, rotations ω × (x - x̄)) on the dofs I of a vector basis."""
    x = ib.doflocs.T - ib.doflocs.mean(axis=1)  # (n, 3) location of each dof
    comp = np.empty(ib.N, dtype=int)
    for c, idx in enumerate(ib.split_indices()):
        comp[idx] = c
    B = np.zeros((ib.N, 6))
    B[np.arange(ib.N), comp] = 1.0
    for k, (i, j) in enumerate([(1, 2), (2, 0), (0, 1)]):  # rotation about axis k: (-x_j, +x_i) in (i, j)
        B[comp == i, 3 + k] = -x[comp == i, j]
        B[comp == j, 3 + k] = x[comp == j, i]
    return B[I]


def skfem_cantilever(mesh, element, E, nu, L, b, h, load, solver="default", timings=None, rtol=1e-10,
                     info=None):
    """Clamp x = 0, uniform traction (total -`load` in z) on x = L; returns the displacement at the
    tip centre (a mesh vertex) and fills `timings` with assembly/solve seconds.

    solver: "default" (scikit-fem's `solve`, scipy spsolve), "cholmod" (scikit-sparse), or "amg" (scipy CG
    preconditioned by pyamg smoothed aggregation with its default settings and the rigid-body modes as
    near-nullspace, to relative residual `rtol`; `info["iterations"]` gets the CG iterations)."""
    from skfem import (
        Basis,
        ElementTetP1,
        ElementTetP2,
        ElementVector,
        FacetBasis,
        LinearForm,
        MeshTet,
        asm,
        condense,
        solve,
    )
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    timings = {} if timings is None else timings
    t0 = time.perf_counter()
    m = MeshTet(mesh.points.T.copy(), mesh.cells.T.copy())
    e = ElementVector(ElementTetP2() if element == "P2" else ElementTetP1())
    ib = Basis(m, e)
    K = asm(linear_elasticity(*lame_parameters(E, nu)), ib)
    fb = FacetBasis(m, e, facets=m.facets_satisfying(lambda x: x[0] > L - 1e-9))
    tz = -load / (b * h)

    @LinearForm
    def traction(v, w):
        return tz * v.value[2]

    f = asm(traction, fb)
    D = ib.get_dofs(lambda x: x[0] < 1e-9).all()
    t1 = time.perf_counter()
    if solver == "cholmod":
        from sksparse.cholmod import cholesky

        A, bb, _x, I = condense(K, f, D=D)
        u = np.zeros(K.shape[0])
        u[I] = cholesky(A.tocsc())(bb)
    elif solver == "amg":
        import pyamg
        import scipy.sparse.linalg as spla

        A, bb, _x, I = condense(K, f, D=D)
        ml = pyamg.smoothed_aggregation_solver(A.tocsr(), B=_rigid_modes(ib, I))
        its = [0]

        def count(_x):
            its[0] += 1

        x, _ = spla.cg(A, bb, rtol=rtol, atol=0.0, maxiter=5000, M=ml.aspreconditioner(), callback=count)
        u = np.zeros(K.shape[0])
        u[I] = x
        if info is not None:
            info["iterations"] = its[0]
    else:
        u = solve(*condense(K, f, D=D))
    t2 = time.perf_counter()
    timings.update(assemble=t1 - t0, solve=t2 - t1)
    tip = np.argmin(np.linalg.norm(mesh.points - [L, b / 2, h / 2], axis=1))
    return u[ib.nodal_dofs[:, tip]]
