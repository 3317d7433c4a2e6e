"""Linear and nonlinear static solvers.

* `factorize(K)`: sparse Cholesky by CHOLMOD (scikit-sparse) when available, factored once and re-solved
  many times; otherwise scipy's SuperLU with a warning. A matrix that is not positive definite (a
  tangent past a limit point) falls back to LU.
* `solve_static`: Newton–Raphson with backtracking line search on the residual and load stepping,
  R(u) = f_int(u) - lambda f_ext = 0 on the free dofs.
* `check_constraints`: fails early, with a clear message, when the fixed dofs leave rigid-body modes free.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from physar.errors import SolverError

try:  # pragma: no cover - depends on the platform
    from sksparse import cholmod as _cholmod
except (ImportError, OSError, ValueError):  # not installed, a broken shared library, or a numpy ABI mismatch
    _cholmod = None

_warned = False


def has_cholmod() -> bool:
    return _cholmod is not None


class Factor:
    """A factorisation of a sparse SPD (or, as fallback, general) matrix with `.solve(b)`."""

    def __init__(self, A: sp.spmatrix, method: str = "auto"):
        global _warned
        A = sp.csc_matrix(A)
        self.shape = A.shape
        self.method = None
        if method in ("auto", "cholmod") and _cholmod is not None:
            try:
                self._f = _cholmod.cholesky(A)
                self.method = "cholmod"
            except _cholmod.CholmodNotPositiveDefiniteError:
                if method == "cholmod":
                    raise SolverError("the matrix is not positive definite") from None
        elif method == "cholmod":
            raise SolverError("CHOLMOD is not available (install scikit-sparse and libsuitesparse-dev)")
        if self.method is None:
            if _cholmod is None and not _warned and method == "auto":
                warnings.warn(
                    "CHOLMOD (scikit-sparse) not available: using scipy SuperLU, much slower on large "
                    "meshes. Install with: apt-get install libsuitesparse-dev && pip install 'physar[cholmod]'",
                    RuntimeWarning,
                    stacklevel=2,
                )
                _warned = True
            try:
                self._f = spla.splu(A)
            except RuntimeError as exc:
                raise SolverError(f"the system matrix is singular ({exc})") from None
            self.method = "superlu"

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = self._f(b) if self.method == "cholmod" else self._f.solve(b)
        if not np.all(np.isfinite(x)):
            raise SolverError("the linear solve produced NaN or inf (singular system?)")
        return x


def factorize(A: sp.spmatrix, method: str = "auto") -> Factor:
    """Factor a sparse matrix once; call `.solve(b)` as often as needed."""
    return Factor(A, method)


def rigid_body_modes(nodes: np.ndarray) -> np.ndarray:
    """The six rigid-body modes (3 translations, 3 small rotations) as columns (n_dofs, 6)."""
    x = nodes - nodes.mean(axis=0)
    n = len(nodes)
    R = np.zeros((n, 3, 6))
    for i in range(3):
        R[:, i, i] = 1.0
    # rotations about x, y, z: omega x r
    R[:, 1, 3], R[:, 2, 3] = -x[:, 2], x[:, 1]
    R[:, 0, 4], R[:, 2, 4] = x[:, 2], -x[:, 0]
    R[:, 0, 5], R[:, 1, 5] = -x[:, 1], x[:, 0]
    return R.reshape(3 * n, 6)


_MODE_NAMES = ["translation x", "translation y", "translation z", "rotation x", "rotation y", "rotation z"]


def check_constraints(nodes: np.ndarray, fixed: np.ndarray) -> None:
    """Raise SolverError if the fixed dofs leave a rigid-body motion unconstrained."""
    R = rigid_body_modes(nodes)
    if len(fixed) == 0:
        raise SolverError(
            "the model is not constrained: all 6 rigid-body modes are free; add a [[fix]] box"
        )
    Rf = R[np.asarray(fixed)]
    scale = np.abs(R).max()
    _, s, Vt = np.linalg.svd(Rf, full_matrices=True)
    s = np.concatenate([s, np.zeros(6 - len(s))]) if len(s) < 6 else s
    free = np.flatnonzero(s <= 1e-10 * scale * max(1.0, np.sqrt(len(fixed))))
    if len(free):
        names = []
        for k in free:
            v = Vt[k]
            names.append(_MODE_NAMES[int(np.argmax(np.abs(v)))])
        raise SolverError(
            f"the model is not fully constrained: {len(free)} rigid-body mode(s) free "
            f"({', '.join(sorted(set(names)))}); fix more nodes"
        )


def _free_dofs(n: int, fixed: np.ndarray) -> np.ndarray:
    mask = np.ones(n, dtype=bool)
    mask[np.asarray(fixed, dtype=np.int64)] = False
    return np.flatnonzero(mask)


class LinearSolver:
    """K u = f with u = 0 on `fixed` for a linear model: factored once, re-solved for many loads."""

    def __init__(self, model, fixed: np.ndarray, method: str = "auto"):
        fixed = np.unique(np.asarray(fixed, dtype=np.int64))
        check_constraints(model.space.nodes, fixed)
        self.n = model.n_dofs
        self.fixed = fixed
        self.free = _free_dofs(self.n, fixed)
        K = model.tangent_stiffness()
        self.factor = factorize(K[self.free][:, self.free], method)

    def solve(self, f_ext: np.ndarray) -> np.ndarray:
        f_ext = np.asarray(f_ext, dtype=float)
        squeeze = f_ext.ndim == 1
        F = f_ext.reshape(self.n, -1)
        U = np.zeros_like(F)
        U[self.free] = self.factor.solve(F[self.free]).reshape(len(self.free), -1)
        return U[:, 0] if squeeze else U


def solve_linear(model, f_ext: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Displacement of a linear model under `f_ext` with zero displacement on `fixed` dofs [m]."""
    return LinearSolver(model, fixed).solve(f_ext)


@dataclass
class StaticResult:
    """Result of a static solve: displacement and Newton history per load step."""

    u: np.ndarray
    newton_iterations: list[int] = field(default_factory=list)
    residuals: list[list[float]] = field(default_factory=list)
    converged: bool = True


def solve_static(
    model,
    f_ext: np.ndarray,
    fixed: np.ndarray,
    steps: int = 1,
    u0: np.ndarray | None = None,
    tol: float = 1e-10,
    max_iter: int = 30,
    progress: Callable[[int, int], None] | None = None,
    prescribed: np.ndarray | None = None,
) -> StaticResult:
    """Static equilibrium f_int(u) = f_ext on the free dofs, u = u_D on `fixed` (Newton, line search, load steps).

    `prescribed` (shape (n_dofs,), only its entries at `fixed` are used; default 0) gives u_D, the
    Dirichlet values, e.g. a rigid rotation of a clamped lever. Load step k of `steps` applies
    lambda_k f_ext and lambda_k u_D with lambda_k = k / steps.
    Convergence: |R_free| <= tol * max(lambda |f_ext|, |f_int(u)|, tiny), where f_int over all dofs
    includes the reactions (the scale of a displacement-driven problem). For a linear model one
    factorisation and one solve. `progress(step, steps)` is called after each load step.
    Raises SolverError if a load step does not converge (try more `steps`).
    """
    f_ext = np.asarray(f_ext, dtype=float)
    fixed = np.unique(np.asarray(fixed, dtype=np.int64))
    n = model.n_dofs
    if f_ext.shape != (n,):
        raise SolverError(f"external force must have shape ({n},), got {f_ext.shape}")
    if steps < 1:
        raise SolverError(f"load steps must be >= 1, got {steps}")
    if prescribed is None:
        u_d = np.zeros(n)
    else:
        u_d = np.asarray(prescribed, dtype=float)
        if u_d.shape != (n,):
            raise SolverError(f"prescribed displacements must have shape ({n},), got {u_d.shape}")
        if not np.all(np.isfinite(u_d[fixed])):
            raise SolverError("prescribed displacements contain NaN or inf")
    check_constraints(model.space.nodes, fixed)
    free = _free_dofs(n, fixed)
    u = np.zeros(n) if u0 is None else np.array(u0, dtype=float)
    u[fixed] = 0.0
    if model.linear:
        u[fixed] = u_d[fixed]
        K = model.tangent_stiffness(u)
        r = model.internal_force(u) - f_ext
        u[free] -= factorize(K[free][:, free]).solve(r[free])
        res = np.linalg.norm((model.internal_force(u) - f_ext)[free])
        if progress:
            progress(1, 1)
        return StaticResult(u, [1], [[float(res)]])

    result = StaticResult(u)
    fnorm = np.linalg.norm(f_ext[free])
    for step in range(1, steps + 1):
        lam = step / steps
        history = []
        f = lam * f_ext
        u[fixed] = lam * u_d[fixed]
        f_int = model.internal_force(u)
        r = f_int - f
        rn = np.linalg.norm(r[free])
        history.append(float(rn))
        it = 0
        while rn > tol * max(lam * fnorm, np.linalg.norm(f_int), 1e-300):
            if it >= max_iter:
                raise SolverError(
                    f"Newton did not converge in {max_iter} iterations at load step {step}/{steps} "
                    f"(residual {rn:.3e}); increase [solver] steps"
                )
            K = model.tangent_stiffness(u)
            du = np.zeros(n)
            du[free] = -factorize(K[free][:, free]).solve(r[free])
            alpha = 1.0
            pi0 = model.energy(u) - f @ u
            for _ in range(16):
                # backtracking: accept the first step that lowers the residual or the total potential
                # energy Π = E(u) - f·u (the Newton step is a descent direction of Π where K > 0)
                trial = u + alpha * du
                f_int_t = model.internal_force(trial)
                r_t = f_int_t - f
                rn_t = np.linalg.norm(r_t[free])
                if np.isfinite(rn_t) and (rn_t < rn or model.energy(trial) - f @ trial < pi0):
                    break
                alpha *= 0.5
            else:
                raise SolverError(
                    f"line search failed at load step {step}/{steps} (residual {rn:.3e}); "
                    "increase [solver] steps"
                )
            u, r, rn, f_int = trial, r_t, rn_t, f_int_t
            history.append(float(rn))
            it += 1
        result.newton_iterations.append(it)
        result.residuals.append(history)
        if progress:
            progress(step, steps)
    result.u = u
    return result
