r"""Sparse solves for the implicit steppers (seed 001 §2: every implicit step is a sparse SPD solve).

* :class:`FreePattern`: the restriction A[free][:, free] of matrices that share one CSR pattern, done
  as index arithmetic on their data (no sparse indexing per step, and the same pattern every step).
* :class:`SparseSolver`: Cholesky (CHOLMOD) with the symbolic analysis reused across steps when the
  pattern is unchanged, LU fallback, a factor cache for constant matrices (linear models), and an
  optional preconditioned-CG mode ('pcg') that keeps one Cholesky factor :math:`A_{\mathrm{ref}}` and solves
  later matrices :math:`A` by CG preconditioned with

  .. math::

      P^{-1} = Q A_{\mathrm{ref}}^{-1} Q^\top, \qquad
      Q = \operatorname{blockdiag}(R_i R_{\mathrm{ref},i}^\top)

  the per-node rotation since the factorisation (co-rotated elasticity:
  :math:`A \approx Q A_{\mathrm{ref}} Q^\top`, the "rotated preconditioner"); it refactors when CG needs more than `refactor_iters` iterations. CG may start from
  a guess x0 (the caller's previous solution), and runs its preconditioner solves on `threads` BLAS /
  OpenMP threads (default 1: a 10⁴-dof triangular solve gains nothing from a second thread and loses
  several times on a loaded machine; see benchmarks/bench_integrators.py).
"""

from __future__ import annotations

import contextlib

import numpy as np
import scipy.sparse as sp

from physar.errors import ConfigError, SolverError
from physar.fem.solvers import cholmod_ordering, factorize, has_cholmod

try:  # pragma: no cover - platform dependent
    from sksparse import cholmod as _cholmod
except Exception:  # noqa: BLE001
    _cholmod = None

try:  # pragma: no cover - optional
    from threadpoolctl import ThreadpoolController as _ThreadpoolController
except Exception:  # noqa: BLE001
    _ThreadpoolController = None

_CONTROLLER = []


def thread_limit(threads: int | None):
    """Context manager limiting BLAS/OpenMP threads to `threads` (no-op for None or without threadpoolctl)."""
    if threads is None or _ThreadpoolController is None:
        return contextlib.nullcontext()
    if not _CONTROLLER:
        _CONTROLLER.append(_ThreadpoolController())
    return _CONTROLLER[0].limit(limits=int(threads))


class FreePattern:
    """Free-dof restriction of matrices with the CSR pattern of `A` (n x n): data -> data[sel].

    `indptr`, `indices` (sorted) the pattern on the free dofs, `diag` the position of each diagonal
    entry in it (a structurally missing diagonal is an error: FE matrices always have one).
    """

    def __init__(self, A: sp.csr_matrix, free: np.ndarray):
        A = sp.csr_matrix(A)
        if not A.has_sorted_indices:
            A = A.sorted_indices()
        self.full_indptr, self.full_indices = A.indptr.copy(), A.indices.copy()
        ids = sp.csr_matrix((np.arange(1, A.nnz + 1, dtype=np.float64), A.indices, A.indptr), shape=A.shape)
        if len(free) != A.shape[0]:
            ids = ids[free][:, free]
        ids = sp.csr_matrix(ids)
        ids.sort_indices()
        self.sel = ids.data.astype(np.int64) - 1
        self.indptr, self.indices = ids.indptr, ids.indices
        self.n = len(free)
        rows = np.repeat(np.arange(self.n), np.diff(self.indptr))
        d = np.flatnonzero(self.indices == rows)
        if len(d) != self.n:
            raise SolverError("the stiffness pattern lacks diagonal entries on some free dofs")
        self.diag = d
        self._keys = rows.astype(np.int64) * self.n + self.indices

    def matches(self, A: sp.csr_matrix) -> bool:
        return A.indptr is self.full_indptr or (
            A.indptr.shape == self.full_indptr.shape and A.indices.shape == self.full_indices.shape
            and np.array_equal(A.indptr, self.full_indptr) and np.array_equal(A.indices, self.full_indices))

    def matches_pattern(self, indptr: np.ndarray, indices: np.ndarray) -> bool:
        """Whether the full pattern (indptr, indices) is the one this was built from (checked once per
        pair of arrays, then by identity)."""
        if getattr(self, "_seen", None) == (id(indptr), id(indices)):
            return True
        ok = (indptr.shape == self.full_indptr.shape and indices.shape == self.full_indices.shape
              and np.array_equal(indptr, self.full_indptr) and np.array_equal(indices, self.full_indices))
        if ok:
            self._seen = (id(indptr), id(indices))
        return ok

    def restrict_data(self, A: sp.csr_matrix) -> np.ndarray:
        """A[free][:, free].data on this pattern (A must have the pattern this was built from)."""
        return A.data[self.sel]

    def align(self, B: sp.spmatrix) -> np.ndarray:
        """Data of a free-dof matrix B (its pattern a subset of this one) laid out on this pattern."""
        B = sp.coo_matrix(B)
        keys = B.row.astype(np.int64) * self.n + B.col
        pos = np.searchsorted(self._keys, keys)
        ok = (pos < len(self._keys)) & (self._keys[np.minimum(pos, len(self._keys) - 1)] == keys)
        if not np.all(ok | (B.data == 0)):
            raise SolverError("a matrix has entries outside the stiffness pattern")
        out = np.zeros(len(self.indices))
        np.add.at(out, pos[ok], B.data[ok])
        return out

    def csr(self, data: np.ndarray) -> sp.csr_matrix:
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))


_PATTERNS: dict = {}


def _rotation_pattern(n: int, free: np.ndarray):
    """CSR pattern of blockdiag(R_i) on the free dofs: nodes with 3 free dofs carry their block, the
    free dofs of partially pinned nodes the identity. Returns (block nodes, order, indices, indptr) with
    data = concat(R[nodes].ravel(), ones)[order]. Cached per (n, free)."""
    key = (n, len(free), hash(free.tobytes()))
    hit = _PATTERNS.get(key)
    if hit is not None and np.array_equal(hit[0], free):
        return hit[1]
    pos = np.full(n, -1, dtype=np.int64)
    pos[free] = np.arange(len(free))
    p = pos.reshape(-1, 3)
    nodes = np.flatnonzero((p >= 0).all(axis=1))
    part = p[(p >= 0).any(axis=1) & ~(p >= 0).all(axis=1)].ravel()
    part = part[part >= 0]
    rows = np.concatenate([np.repeat(p[nodes], 3, axis=1).ravel(), part])
    cols = np.concatenate([np.tile(p[nodes], (1, 3)).ravel(), part])
    m = len(free)
    ids = sp.csr_matrix((np.arange(1, len(rows) + 1, dtype=np.float64), (rows, cols)), shape=(m, m))
    ids.sort_indices()
    out = (nodes, ids.data.astype(np.int64) - 1, ids.indices, ids.indptr)
    if len(_PATTERNS) > 16:
        _PATTERNS.clear()
    _PATTERNS[key] = (free.copy(), out)
    return out


class BlockRotation:
    """Q = blockdiag(R_1, ..., R_N) (one 3 x 3 rotation per node) restricted to the free dofs; nodes
    with a pinned component keep the identity (so Q stays orthogonal on the free dofs)."""

    def __init__(self, R: np.ndarray, free: np.ndarray, n: int):
        R = np.array(R, dtype=float, copy=True)
        mask = np.zeros(n, dtype=bool)
        mask[free] = True
        partial = ~mask.reshape(-1, 3).all(axis=1)
        R[partial] = np.eye(3)
        self.R, self.free, self.n = R, free, n

    def _apply(self, R, x):
        full = np.zeros(self.n)
        full[self.free] = x
        return np.matmul(R, full.reshape(-1, 3, 1)).ravel()[self.free]

    def matrix(self) -> sp.csr_matrix:
        """Q on the free dofs as a CSR matrix (its pattern cached per free set; a product with it is
        several times cheaper than the batched 3 x 3 products of mul/mul_t)."""
        Q = getattr(self, "_Q", None)
        if Q is None:
            nodes, order, indices, indptr = _rotation_pattern(self.n, self.free)
            data = np.concatenate([self.R[nodes].ravel(), np.ones(len(order) - 9 * len(nodes))])[order]
            m = len(self.free)
            Q = self._Q = sp.csr_matrix((data, indices, indptr), shape=(m, m))
            self._QT = Q.T  # a CSC view, built once
        return Q

    def mul(self, x):
        return self.matrix() @ x

    def mul_t(self, x):
        self.matrix()
        return self._QT @ x

    def relative_to(self, ref: BlockRotation) -> BlockRotation:
        r""":math:`Q Q_{\mathrm{ref}}^\top` (per node :math:`R_i R_{\mathrm{ref},i}^\top`)."""
        out = BlockRotation.__new__(BlockRotation)
        out.R, out.free, out.n = np.matmul(self.R, np.swapaxes(ref.R, 1, 2)), self.free, self.n
        return out


def pcg(A, b: np.ndarray, prec, rtol: float, maxiter: int, x0=None) -> tuple[np.ndarray, int, bool]:
    r"""Preconditioned conjugate gradients (Hestenes-Stiefel) for SPD A: (x, iterations, converged).

    Stops when :math:`|b - A x| \le \mathrm{rtol}\, |b|` (scipy.sparse.linalg.cg's criterion with atol = 0);
    `prec(r)` applies :math:`P^{-1}`. Starts from x0 when given and its residual is below :math:`|b|` (else from
    0: a worse guess only costs iterations). Returns converged = False on a non-positive curvature
    :math:`p^\top A p \le 0` or after maxiter iterations. The loop is written out (one A-product, one
    :math:`P^{-1}` apply, two dot products per
    iteration) because scipy's cg adds ~0.1 ms of wrapper work per iteration at 10⁴ unknowns.
    """
    bn = float(np.linalg.norm(b))
    tol = rtol * bn
    x = np.zeros_like(b)
    r = b.copy()
    if x0 is not None:
        r0 = b - A @ x0
        if np.linalg.norm(r0) < bn:
            x, r = np.array(x0, dtype=float, copy=True), r0
    if np.linalg.norm(r) <= tol:
        return x, 0, True
    z = prec(r)
    p = z.copy()
    rz = float(r @ z)
    for it in range(1, maxiter + 1):
        Ap = A @ p
        pAp = float(p @ Ap)
        if not pAp > 0:
            return x, it, False
        alpha = rz / pAp
        x += alpha * p
        r -= alpha * Ap
        if np.linalg.norm(r) <= tol:
            return x, it, True
        z = prec(r)
        rz_new = float(r @ z)
        p *= rz_new / rz
        p += z
        rz = rz_new
    return x, maxiter, False


class SparseSolver:
    """Solve :math:`A x = b` for a sequence of SPD(-ish) sparse matrices sharing one sparsity pattern.

    `solve(A, b, key, frame)`: when `key` is not None and a factor was cached under it, that factor is
    reused (constant matrices; always a direct solve). Otherwise, method 'direct' refactors A (reusing
    CHOLMOD's symbolic analysis when the pattern (indptr, indices) is unchanged); method 'pcg' solves by
    CG to relative residual `rtol` with the rotated preconditioner built from the last factor and
    `frame()` (a callable returning a :class:`BlockRotation` or None), refactoring when CG took more
    than `refactor_iters` iterations or failed; `x0` (optional) is CG's starting guess, used when its
    residual :math:`|b - A x_0|` is below :math:`|b|`. `threads`: BLAS/OpenMP threads during CG (None: unchanged).
    Non-positive-definite matrices fall back to LU. Counts `n_factorizations` and `n_cg_iterations`.
    """

    def __init__(self, method: str = "direct", rtol: float = 1e-8, refactor_iters: int = 30,
                 threads: int | None = 1):
        if method not in ("direct", "pcg"):
            raise ConfigError(f"linear solver must be 'direct' or 'pcg', got {method!r}")
        if not (0 < rtol < 1):
            raise ConfigError(f"linear solver rtol must be in (0, 1), got {rtol}")
        self.method = method
        self.rtol = float(rtol)
        self.refactor_iters = int(refactor_iters)
        if threads is not None and int(threads) < 1:
            raise ConfigError(f"linear solver threads must be >= 1 or None, got {threads}")
        self.threads = None if threads is None else int(threads)
        self._cache = {}  # key -> factor, for constant matrices
        self._factor = None
        self._symbolic = None
        self._pattern = None
        self._ref_frame = None
        self._stale = True
        self.n_factorizations = 0
        self.n_cg_iterations = 0
        self.n_cg_solves = 0

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
            self._stale = True  # the PCG reference factor is no longer self._factor
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
                    self._symbolic = _cholmod.cholesky(A, ordering_method=cholmod_ordering(A.shape[0]))
                    self._pattern = (A.indptr.copy(), A.indices.copy())
                self._factor = ("cholmod", self._symbolic)
                return self._factor
            except _cholmod.CholmodNotPositiveDefiniteError:
                self._symbolic, self._pattern = None, None
        self._factor = ("lu", factorize(A, method="lu"))
        return self._factor

    @staticmethod
    def _apply(factor, b):
        kind, f = factor
        if kind == "diag":
            return b / f if b.ndim == 1 else b / f[:, None]
        if kind == "cholmod":
            return f(b)
        return f.solve(b)

    def _check(self, x):
        if not np.all(np.isfinite(x)):
            raise SolverError("the linear solve produced NaN or inf (singular system or a blow-up; "
                              "try a smaller time step)")
        return x

    def _direct(self, A, b, frame):
        factor = self._factorize(A)
        self._ref_frame = frame() if (frame is not None and self.method == "pcg") else None
        self._stale = factor[0] != "cholmod"  # PCG only on an SPD (Cholesky) reference
        return self._check(self._apply(factor, b))

    def solve(self, A: sp.spmatrix, b: np.ndarray, key=None, frame=None, x0=None) -> np.ndarray:
        if key is not None or self.method == "direct":
            if key is None:
                return self._direct(A, b, None)
            return self._check(self._apply(self.factor(A, key), b))
        if self._stale or self._factor is None:
            return self._direct(A, b, frame)
        factor = self._factor
        Q = None
        if self._ref_frame is not None and frame is not None:
            cur = frame()
            Q = None if cur is None else cur.relative_to(self._ref_frame)
        if Q is None:
            def prec(x):
                return self._apply(factor, x)
        else:
            def prec(x):
                return Q.mul(self._apply(factor, Q.mul_t(x)))
        maxiter = max(3 * self.refactor_iters, 50)
        if x0 is not None:
            x0 = np.asarray(x0, dtype=float)
            if x0.shape != b.shape or not np.all(np.isfinite(x0)):
                x0 = None
        with thread_limit(self.threads):
            x, its, ok = pcg(A, b, prec, self.rtol, maxiter, x0)
        self.n_cg_iterations += its
        self.n_cg_solves += 1
        if not ok or not np.all(np.isfinite(x)):
            return self._direct(A, b, frame)  # not SPD or preconditioner too stale: factor this A
        if its > self.refactor_iters:
            self._stale = True
        return x
