"""Sparse solves for the implicit steppers: Cholesky (CHOLMOD) with the symbolic analysis reused
across steps when the sparsity pattern is unchanged, LU fallback, and a factor cache for constant
matrices (linear models)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from physar.errors import SolverError
from physar.fem.solvers import factorize, has_cholmod

try:  # pragma: no cover - platform dependent
    from sksparse import cholmod as _cholmod
except Exception:  # noqa: BLE001
    _cholmod = None


class SparseSolver:
    """Solve A x = b for a sequence of SPD(-ish) sparse matrices sharing one sparsity pattern.

    `solve(A, b, key)`: when `key` is not None and a factor was cached under it, that factor is reused (for constant matrices). Otherwise A is refactored, reusing CHOLMOD's symbolic
    analysis if the pattern (indptr, indices) is the same as before. Non-positive-definite matrices
    fall back to LU (physar.fem.factorize). Counts factorisations in `n_factorizations`.
    """

    def __init__(self):
        self._cache = {}  # key -> factor, for constant matrices
        self._factor = None
        self._symbolic = None
        self._pattern = None
        self.n_factorizations = 0

    def _diag(self, A):
        return A.nnz <= A.shape[0] and np.array_equal(A.indices, np.arange(A.shape[0])) and np.array_equal(
            A.indptr, np.arange(A.shape[0] + 1))

    def factor(self, A: sp.spmatrix, key=None):
        if key is not None and key in self._cache:
            return self._cache[key]
        f = self._factorize(A)
        if key is not None:
            if len(self._cache) >= 8:
                self._cache.clear()
            # a cached CHOLMOD factor must not be refactored in place later
            self._cache[key] = f
            if f[0] == "cholmod":
                self._symbolic, self._pattern = None, None
        return f

    def _factorize(self, A):
        A = sp.csc_matrix(A)
        A.sort_indices()
        self.n_factorizations += 1
        if self._diag(A):
            d = A.data.copy()
            if np.any(d == 0) or not np.all(np.isfinite(d)):
                raise SolverError("singular diagonal system matrix (a free dof has zero mass?)")
            self._factor = ("diag", d)
            return self._factor
        if _cholmod is not None and has_cholmod():
            same = (self._pattern is not None and self._pattern[0].shape == A.indptr.shape
                    and self._pattern[1].shape == A.indices.shape
                    and np.array_equal(self._pattern[0], A.indptr) and np.array_equal(self._pattern[1], A.indices))
            try:
                if same and self._symbolic is not None:
                    self._symbolic.cholesky_inplace(A)
                else:
                    self._symbolic = _cholmod.cholesky(A)
                    self._pattern = (A.indptr.copy(), A.indices.copy())
                self._factor = ("cholmod", self._symbolic)
                return self._factor
            except _cholmod.CholmodNotPositiveDefiniteError:
                self._symbolic, self._pattern = None, None
        self._factor = ("lu", factorize(A, method="lu"))
        return self._factor

    def solve(self, A: sp.spmatrix, b: np.ndarray, key=None) -> np.ndarray:
        kind, f = self.factor(A, key)
        if kind == "diag":
            x = b / f if b.ndim == 1 else b / f[:, None]
        elif kind == "cholmod":
            x = f(b)
        else:
            x = f.solve(b)
        if not np.all(np.isfinite(x)):
            raise SolverError("the linear solve produced NaN or inf (singular system or a blow-up; "
                              "try a smaller time step)")
        return x
