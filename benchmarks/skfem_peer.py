"""The same clamped cantilever solved with scikit-fem: the peer for tests and benchmarks.

Kept outside the package: scikit-fem is only the reference here, physar does not call it for this.
"""

from __future__ import annotations

import time

import numpy as np


def skfem_cantilever(mesh, element, E, nu, L, b, h, load, solver="default", timings=None):
    """Clamp x = 0, uniform traction (total -`load` in z) on x = L; returns the displacement at the
    tip centre (a mesh vertex) and fills `timings` with assembly/solve seconds."""
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
    else:
        u = solve(*condense(K, f, D=D))
    t2 = time.perf_counter()
    timings.update(assemble=t1 - t0, solve=t2 - t1)
    tip = np.argmin(np.linalg.norm(mesh.points - [L, b / 2, h / 2], axis=1))
    return u[ib.nodal_dofs[:, tip]]
