"""Intrusive PGD for K u = sum_k f_k g_k(mu), one parameter on a 1-D grid (seed 000 §3).

Greedy rank-one enrichment u_n = u_{n-1} + F_n G_n(mu), with F_n, G_n found by the
alternating-direction fixed point:
  F-step: (G.W G) K F = sum_k f_k (g_k.W G) - sum_i K F_i (G_i.W G)
  G-step: G(mu_q) = F.(sum_k f_k g_k(mu_q) - sum_i K F_i G_i(mu_q)) / (F.K F)
with W the trapezoidal quadrature weights of the parameter grid.

:func:`pgd_affine` is the same for 1 to 3 parameters on tensor grids and an operator affine in them,
K(mu) = sum_m A_m prod_j alpha_m^j(mu_j) (the Young's modulus of a region), with an update step of the
parameter functions; :func:`pgd_linear_tensor` is its case K(mu) = K.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from physar.rom._threads import single_blas_thread
from physar.rom.separated import SeparatedModel


def _trapz_weights(x):
    w = np.zeros_like(x)
    d = np.diff(x)
    w[:-1] += d / 2
    w[1:] += d / 2
    return w


def pgd_linear(K, f, g, grid, max_modes=20, tol=1e-4, max_fp=50, fp_tol=1e-6, solve=None,
               name="mu", unit="", progress=None, check=None, check_tol=None):
    """Build a SeparatedModel for K u = sum_k f[k] g[k](mu) (f: (r, n), g: (r, n_grid) on grid).

    Stops when the relative mode amplitude ||F_n|| ||G_n|| / (||F_1|| ||G_1||) < tol.
    Returns (model, info) with info["amplitudes"]. ``progress(n, max_modes)`` after each mode.
    ``check(model) -> error`` (e.g. against full solves at random parameters) is called after each
    mode, its values are info["check_errors"], and with ``check_tol`` the enrichment also stops
    once the error is <= check_tol (the second stopping criterion of seed §3).
    Runs with one BLAS thread (see :mod:`physar.rom._threads`).
    """
    with single_blas_thread():
        return _pgd_linear(K, f, g, grid, max_modes, tol, max_fp, fp_tol, solve, name, unit, progress,
                           check, check_tol)


def _pgd_linear(K, f, g, grid, max_modes, tol, max_fp, fp_tol, solve, name, unit, progress, check=None,
                check_tol=None):
    f = np.atleast_2d(np.asarray(f, float))
    g = np.atleast_2d(np.asarray(g, float))
    grid = np.asarray(grid, float)
    w = _trapz_weights(grid)
    if solve is None:
        lu = spla.splu(K.tocsc())
        solve = lu.solve
    Fs, Gs, KFs, amps, checks = [], [], [], [], []
    for _ in range(max_modes):
        G = np.ones_like(grid)
        F = None
        for _ in range(max_fp):
            gw = g @ (w * G)
            rhs = f.T @ gw
            if Fs:
                rhs -= np.array(KFs).T @ (np.array(Gs) @ (w * G))
            F = solve(rhs / (G @ (w * G)))
            KF = K @ F
            Gnew = (F @ f.T) @ g
            if Fs:
                Gnew -= (np.array(KFs) @ F) @ np.array(Gs)
            Gnew /= F @ KF
            delta = np.linalg.norm(Gnew * np.linalg.norm(F) - G * np.linalg.norm(F)) / max(
                np.linalg.norm(Gnew) * np.linalg.norm(F), 1e-300)
            G = Gnew
            if delta < fp_tol:
                break
        # normalise: F unit norm, amplitude in G
        nF = np.linalg.norm(F)
        F, G = F / nF, G * nF
        Fs.append(F)
        Gs.append(G)
        KFs.append(K @ F)
        amps.append(np.linalg.norm(G * np.sqrt(w)))
        if progress:
            progress(len(Fs), max_modes)
        if check is not None:
            checks.append(float(check(SeparatedModel(np.array(Fs), [grid], [np.array(Gs)], [name], [unit]))))
            if check_tol is not None and checks[-1] <= check_tol:
                break
        if amps[-1] < tol * amps[0]:
            break
    model = SeparatedModel(np.array(Fs), [grid], [np.array(Gs)], [name], [unit])
    info = {"amplitudes": np.array(amps)}
    if check is not None:
        info["check_errors"] = checks
    return model, info


def pgd_linear_tensor(K, B, grids, max_modes=40, tol=1e-4, max_fp=50, fp_tol=1e-6, solve=None,
                      names=None, units=None, progress=None, check=None, check_tol=None):
    """Intrusive PGD for K u = f(x; mu_1, .., mu_p) with p >= 1 parameters on tensor grids (seed 000 §3).

    The load is given by its samples on the tensor grid: ``B`` (n, N) (dense or sparse), column q the
    load at grid node q (C order over ``grids``). This is :func:`pgd_affine` with one operator term K
    and one load term B over every parameter (see there for the fixed point). With p > 1 the greedy sum
    converges more slowly than the optimal (POD) basis: for the cantilever with a load on a 1 x 0.2 m
    patch, 20 modes reach 1.4e-3 where 20 POD modes reach 1.6e-4. ``solve(b)`` solves with K (default:
    a factorisation of K). Returns (model, info) with info["amplitudes"] and
    info["fixed_point_iterations"]; ``check``/``check_tol`` as in :func:`pgd_linear`.
    """
    p = len(grids)
    factor = None if solve is None else (lambda A: solve)
    return pgd_affine([SeparatedTerm(K)], [SeparatedTerm(B, tuple(range(p)))], grids, max_modes=max_modes,
                      tol=tol, max_fp=max_fp, fp_tol=fp_tol, factor=factor, names=names, units=units,
                      progress=progress, check=check, check_tol=check_tol)


@dataclass(frozen=True)
class SeparatedTerm:
    """One term of a separated operator or load: ``value`` times 1-D functions of the parameters.

    An operator term is a sparse (n, n) matrix A with ``factors`` {j: alpha(mu_j) on grid j}: the
    operator is sum_m A_m prod_j alpha_m^j(mu_j) (e.g. K_rest + (E / E_ref) K_region). A load term is
    ``value`` (n, N) (dense or sparse), its columns the load at the nodes of the tensor grid of the
    parameters ``axes`` (C order; N = 1 for axes = ()), times ``factors`` {j: h(mu_j)} for j not in
    ``axes``. A parameter named nowhere enters as the constant 1.
    """

    value: object
    axes: tuple = ()
    factors: dict = field(default_factory=dict)


def pgd_affine(ops, loads, grids, max_modes=40, tol=1e-4, max_fp=50, fp_tol=1e-6, factor=None, names=None,
               units=None, progress=None, check=None, check_tol=None, update=0):
    """Intrusive PGD for K(mu) u = f(mu), K(mu) = sum_m A_m prod_j alpha_m^j(mu_j) and f(mu) = sum_t
    (load term t), 1 to 3 parameters on tensor grids (seed 000 §3: an operator affine in the parameter).

    ``ops``, ``loads``: lists of :class:`SeparatedTerm`. With the trapezoidal weights w_j of each grid,
    a_j = w_j G^j and <x, y>_j = sum_q w_j(q) x(q) y(q), the greedy enrichment u_n = u_{n-1} + F prod_j G^j
    alternates

      F-step:  sum_m A_m prod_j <alpha_m^j G^j, G^j>_j F = <f, prod_j G^j> - sum_i sum_m A_m F_i prod_j
               <alpha_m^j G_i^j, G^j>_j
      G^j-step (each j in turn, the others fixed; at each grid point q of parameter j):
               G^j(q) sum_m (F.A_m F) alpha_m^j(q) prod_{k != j} <alpha_m^k G^k, G^k>_k =
               <f, F prod_{k != j} G^k>(q) - sum_i sum_m (F.A_m F_i) alpha_m^j(q) G_i^j(q) prod_{k != j}
               <alpha_m^k G_i^k, G^k>_k

    until the change of the rank-one term F prod_j G^j is below ``fp_tol``. With ``update`` = k > 0, k
    sweeps of the update step follow each new term: the spatial modes F_1..F_n fixed, the functions of
    every term for parameter j are recomputed together (Galerkin, one n x n system per grid point q):

      sum_k [sum_m (F_i.A_m F_k) alpha_m^j(q) prod_{l != j} <alpha_m^l G_k^l, G_i^l>_l] G_k^j(q)
          = <f, F_i prod_{l != j} G_i^l>(q),   i = 1..n,

    for j = 1..p in turn (alternating least squares on the parameter functions; for one parameter the
    Galerkin projection on span F, exactly). The greedy sum alone converges slowly with two parameters:
    for E of a region x a moving load (tests/rom/test_param_kinds.py, P1, 81 x 21 grid) the error at
    random points is 2.3e-3 after 40 terms, 1.7e-4 after 30 with ``update`` = 2.

    Each term is normalised (|F| = 1, <G^j, G^j>_j = 1 for j >= 2, the amplitude in G^1); the greedy loop
    stops when the relative amplitude |G_n^1|_w / |G_1^1|_w of the new term (before the update) < ``tol``
    or at ``max_modes``. The fixed point starts from seeded random G^j (a constant start keeps a symmetric
    problem in its even subspace). The A_m must be symmetric. ``factor(A) -> solve`` factorises an
    F-step matrix (default :func:`physar.fem.factorize`; see :class:`_FStepSolver`). Returns (model,
    info) with info["amplitudes"], info["fixed_point_iterations"], info["factorizations"],
    info["cg_iterations"]; ``check``/``check_tol`` as in :func:`pgd_linear`. Runs with one BLAS thread.
    """
    with single_blas_thread():
        return _pgd_affine(ops, loads, grids, max_modes, tol, max_fp, fp_tol, factor, names, units, progress,
                           check, check_tol, update)


def _outer(vectors):
    out = vectors[0]
    for v in vectors[1:]:
        out = np.multiply.outer(out, v)
    return out


def _contract_except(T, vectors, j):
    """Contract tensor T (n_1..n_p) with vectors[k] over every axis k != j; result (n_j,)."""
    for k in reversed(range(T.ndim)):
        if k != j:
            T = np.tensordot(T, vectors[k], axes=([k], [0]))
    return T


class _Loads:
    """The load terms of :func:`pgd_affine`, contracted with parameter functions."""

    def __init__(self, loads, shape):
        self.terms = []
        for t in loads:
            axes = tuple(t.axes)
            B = t.value if sp.issparse(t.value) else np.asarray(t.value, float).reshape(len(t.value), -1)
            n_cols = int(np.prod([shape[k] for k in axes])) if axes else 1
            if B.shape[1] != n_cols:
                raise ValueError(f"a load term over parameters {axes} has {B.shape[1]} columns, "
                                 f"its tensor grid {n_cols} nodes")
            h = {k: np.asarray(t.factors.get(k, np.ones(shape[k])), float) for k in range(len(shape))
                 if k not in axes}
            self.terms.append((sp.csr_matrix(B) if sp.issparse(B) else B, axes, h))
        self.shape = shape

    def rhs(self, a):
        """<f, prod_j G^j> for a_j = w_j G^j: (n,)."""
        out = 0.0
        for B, axes, h in self.terms:
            scale = np.prod([a[k] @ hk for k, hk in h.items()])
            out = out + scale * (B @ (_outer([a[k] for k in axes]).ravel() if axes else np.ones(1)))
        return np.asarray(out).ravel()

    def projections(self, F):
        """B_t^T F on each term's tensor grid."""
        return [np.asarray(B.T @ F).reshape([self.shape[k] for k in axes]) for B, axes, _ in self.terms]

    def contract(self, P, a, j):
        """<f, F prod_{k != j} G^k> at the grid points of parameter j (P = projections(F)): (n_j,)."""
        out = np.zeros(self.shape[j])
        for Pt, (_, axes, h) in zip(P, self.terms):
            scale = np.prod([a[k] @ hk for k, hk in h.items() if k != j])
            if j in axes:
                out += scale * (_contract_except(Pt, [a[k] for k in axes], axes.index(j)) if axes != (j,) else Pt)
            else:
                full = float(_outer([a[k] for k in axes]).ravel() @ Pt.ravel()) if axes else float(Pt)
                out += scale * full * h[j]
        return out


class _FStepSolver:
    """Solves sum_m c_m A_m x = b for the F-step of :func:`pgd_affine`.

    One operator term: A_1 is factorised once. Several: the coefficient ratios r_m = c_m / c_1 are
    rounded to bins 20 % wide (in log r); the matrix of the bin, A_1 + sum_m r_bin A_m, is factorised once
    (the last ``keep`` kept) and preconditions conjugate gradients on the exact matrix (its eigenvalues
    lie within a factor 1.2 of the preconditioner's: ~10 iterations to 1e-12).
    """

    BIN = np.log(1.2)

    def __init__(self, A, factor, keep=6):
        self.A, self.factor, self.keep = A, factor, keep
        self.cache: dict = {}
        self.n_factor = self.n_cg = 0

    def _factor(self, key, matrix):
        if key not in self.cache:
            if len(self.cache) >= self.keep:
                self.cache.pop(next(iter(self.cache)))
            self.cache[key] = self.factor(matrix())
            self.n_factor += 1
        return self.cache[key]

    def __call__(self, c, b):
        A = self.A
        b = b / c[0]
        if len(A) == 1:
            return self._factor(None, lambda: A[0])(b)
        r = np.asarray(c[1:], float) / c[0]
        if np.any(r <= 0):  # no bins: the exact matrix
            M = A[0] + sum(ri * Ai for ri, Ai in zip(r, A[1:]))
            return self.factor(M)(b)
        key = tuple(np.round(np.log(r) / self.BIN).astype(int))
        prec = self._factor(key, lambda: A[0] + sum(np.exp(k * self.BIN) * Ai for k, Ai in zip(key, A[1:])))
        return self._pcg(lambda x: A[0] @ x + sum(ri * (Ai @ x) for ri, Ai in zip(r, A[1:])), b, prec)

    def _pcg(self, matvec, b, prec, rtol=1e-12, max_iter=200):
        x = prec(b)
        res = b - matvec(x)
        z = prec(res)
        d = z.copy()
        rz = res @ z
        nb = np.linalg.norm(b) or 1.0
        for _ in range(max_iter):
            if np.linalg.norm(res) <= rtol * nb:
                break
            Ad = matvec(d)
            step = rz / (d @ Ad)
            x += step * d
            res -= step * Ad
            z = prec(res)
            rz, rz_old = res @ z, rz
            d = z + (rz / rz_old) * d
            self.n_cg += 1
        return x


def _normalise(F, G, W):
    """|F| = 1 and <G^j, G^j>_j = 1 for j >= 2 per term, the amplitude in G^1 (in place on the lists)."""
    for i in range(len(F)):
        nF = np.linalg.norm(F[i]) or 1.0
        F[i] = F[i] / nF
        G[0][i] = G[0][i] * nF
        for j in range(1, len(G)):
            nj = np.sqrt(G[j][i] @ (W[j] * G[j][i])) or 1.0
            G[j][i] = G[j][i] / nj
            G[0][i] = G[0][i] * nj


def _update(Fs, AFs, Gs, Ps, alpha, f, W, sweeps):
    """The update step of :func:`pgd_affine`: the parameter functions of all terms, F fixed."""
    n, p = len(Fs), len(Gs)
    FAF = [np.array(Fs) @ np.array(AF).T for AF in AFs]  # (n, n): F_i.A_m F_k
    for _ in range(sweeps):
        for j in range(p):
            Gl = [np.array(g) for g in Gs]
            M = 0.0
            for m, al in enumerate(alpha):
                gram = np.ones((n, n))
                for k in range(p):
                    if k != j:
                        gram = gram * ((Gl[k] * (W[k] * al[k])) @ Gl[k].T)
                M = M + al[j][:, None, None] * (FAF[m] * gram)[None]
            b = np.stack([f.contract(Ps[i], [W[k] * Gl[k][i] for k in range(p)], j) for i in range(n)], axis=1)
            try:
                g = np.linalg.solve(M, b[..., None])[..., 0]
            except np.linalg.LinAlgError:  # nearly dependent terms: least squares, grid point by grid point
                g = np.stack([np.linalg.lstsq(Mq, bq, rcond=None)[0] for Mq, bq in zip(M, b)])
            Gs[j] = list(g.T)
        _normalise(Fs, Gs, W)


def _pgd_affine(ops, loads, grids, max_modes, tol, max_fp, fp_tol, factor, names, units, progress, check=None,
                check_tol=None, update=0):
    grids = [np.asarray(x, float) for x in grids]
    p = len(grids)
    shape = tuple(x.size for x in grids)
    names = list(names) if names is not None else [f"mu{j + 1}" for j in range(p)]
    units = list(units) if units is not None else [""] * p
    W = [_trapz_weights(x) for x in grids]
    A = [t.value for t in ops]
    alpha = [[np.asarray(t.factors.get(j, np.ones(shape[j])), float) for j in range(p)] for t in ops]
    f = _Loads(loads, shape)
    if factor is None:
        from physar.fem import factorize

        def factor(M):
            return factorize(M).solve
    solve = _FStepSolver(A, factor)

    Fs, AFs, Gs, Ps, amps, fp_its, checks = [], [[] for _ in A], [[] for _ in range(p)], [], [], [], []
    rng = np.random.default_rng(0)
    for _ in range(max_modes):
        # a start with no symmetry: a constant start keeps the fixed point in the subspace of functions
        # even in t for a load path on a symmetry plane, and the odd (torsion) part is never found
        G = [rng.uniform(0.5, 1.5, n) for n in shape]
        F = None
        prev = None
        for it in range(max_fp):
            a = [w * g for w, g in zip(W, G)]
            c = np.array([np.prod([(al[j] * G[j]) @ a[j] for j in range(p)]) for al in alpha])
            rhs = f.rhs(a)
            if Fs:
                for m, al in enumerate(alpha):
                    coef = np.prod([np.array(Gs[j]) @ (al[j] * a[j]) for j in range(p)], axis=0)  # (n_modes,)
                    rhs = rhs - np.array(AFs[m]).T @ coef
            F = solve(c, rhs)
            AF = [Am @ F for Am in A]
            FAF = np.array([F @ x for x in AF])
            FAFi = [np.array(AFs[m]) @ F for m in range(len(A))] if Fs else None
            P = f.projections(F)
            for j in range(p):
                a = [w * g for w, g in zip(W, G)]
                den = np.zeros(shape[j])
                num = f.contract(P, a, j)
                for m, al in enumerate(alpha):
                    others = np.prod([(al[k] * G[k]) @ a[k] for k in range(p) if k != j])
                    den += FAF[m] * al[j] * others
                    if Fs:
                        w_i = np.prod([np.array(Gs[k]) @ (al[k] * a[k]) for k in range(p) if k != j], axis=0) \
                            if p > 1 else np.ones(len(Fs))
                        num -= al[j] * (np.array(Gs[j]).T @ (FAFi[m] * w_i))
                G[j] = num / den
            # change of the rank-one term, measured on |F| prod_j G^j (F is not normalised yet)
            nF = np.linalg.norm(F)
            term = [g.copy() for g in G]
            term[0] = term[0] * nF
            if prev is not None:
                num_ = np.linalg.norm(_outer(term) - _outer(prev))
                if num_ <= fp_tol * max(np.linalg.norm(_outer(term)), 1e-300):
                    break
            prev = term
        fp_its.append(it + 1)
        nF = np.linalg.norm(F)
        F = F / nF
        G[0] = G[0] * nF
        for j in range(1, p):
            nj = np.sqrt(G[j] @ (W[j] * G[j])) or 1.0
            G[j] = G[j] / nj
            G[0] = G[0] * nj
        Fs.append(F)
        for m, Am in enumerate(A):
            AFs[m].append(Am @ F)
        for j in range(p):
            Gs[j].append(G[j])
        amps.append(float(np.sqrt(Gs[0][-1] @ (W[0] * Gs[0][-1]))))
        if update:
            Ps.append(f.projections(F))
            _update(Fs, AFs, Gs, Ps, alpha, f, W, update)
        if progress:
            progress(len(Fs), max_modes)
        if check is not None:
            checks.append(float(check(SeparatedModel(np.array(Fs), grids, [np.array(g) for g in Gs], names, units))))
            if check_tol is not None and checks[-1] <= check_tol:
                break
        if amps[-1] < tol * amps[0]:
            break
    model = SeparatedModel(np.array(Fs), grids, [np.array(g) for g in Gs], names, units)
    info = {"amplitudes": np.array(amps), "fixed_point_iterations": fp_its, "factorizations": solve.n_factor,
            "cg_iterations": solve.n_cg}
    if check is not None:
        info["check_errors"] = checks
    return model, info
