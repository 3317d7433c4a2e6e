r"""Intrusive PGD for :math:`K u = \sum_k f_k\, g_k(\mu)`, one parameter on a 1-D grid (seed 000 §3).

Greedy rank-one enrichment :math:`u_n = u_{n-1} + F_n G_n(\mu)`, with :math:`F_n, G_n` found by the
alternating-direction fixed point:

.. math::

    \text{F-step:} \quad (G^\top W G)\, K F = \sum_k f_k\, (g_k^\top W G) - \sum_i K F_i\, (G_i^\top W G),

    \text{G-step:} \quad G(\mu_q) = \frac{F^\top \big(\sum_k f_k\, g_k(\mu_q) - \sum_i K F_i\, G_i(\mu_q)\big)}
    {F^\top K F}

with :math:`W` the trapezoidal quadrature weights of the parameter grid (the greedy loop and the fixed point of
seed 000 §3). After each new term the update step re-solves the parameter functions of all terms on the
spatial modes found so far (a Galerkin projection of the parametric problem on :math:`\operatorname{span}\{F_i\}`), so the fixed
point of a term only has to find a direction F and is stopped early; the enrichment stops on an
estimate of the relative residual of the whole parametric problem on the grid (seed §3: "a stopping
criterion is mandatory"), besides the amplitude of the last term. See :func:`pgd_linear` (there, with K
independent of :math:`\mu`, the fixed point's G-step already is that projection).

:func:`pgd_affine` is the same for 1 to 3 parameters on tensor grids and an operator affine in them,
:math:`K(\mu) = \sum_m A_m \prod_j \alpha_m^j(\mu_j)` (the Young's modulus of a region), with the update step
as alternating least squares on the parameter functions (exact for one parameter); :func:`pgd_linear_tensor`
is its case :math:`K(\mu) = K`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from physar.rom._threads import single_blas_thread
from physar.rom.separated import SeparatedModel

#: Fixed-point tolerance of a new term when the update step follows (the update re-solves its parameter
#: functions, so only its spatial direction F matters and a loose fixed point suffices; chosen on the
#: cantilever, the patch and a 1-D Laplacian: 0.01-0.3 gave the same error per mode, 0.2 the fewest solves
#: without losing the odd modes of the symmetric Laplacian; RESULTS.md "PGD with the update step").
FP_TOL_UPDATE = 0.2
#: Relative noise added to the previous term's G to start the fixed point of the next (see pgd_linear).
START_NOISE = 0.3
#: Sweeps of the update step with two or three parameters (alternating least squares; exact in one sweep
#: for one parameter).
UPDATE_SWEEPS = 2
#: Random probes of the residual estimate (see :func:`pgd_linear`).
PROBES = 6


def _trapz_weights(x):
    w = np.zeros_like(x)
    d = np.diff(x)
    w[:-1] += d / 2
    w[1:] += d / 2
    return w


def _solve_columns(solve, B):
    """solve(B) for B (n, k): one call with the block where ``solve`` takes one, else column by column."""
    try:
        X = np.asarray(solve(B), float)
        if X.shape == B.shape:
            return X
    except (ValueError, TypeError):
        pass
    return np.stack([np.asarray(solve(B[:, i]), float) for i in range(B.shape[1])], 1)


def _change_norm(gram, Gnew, Gold, W):
    r""":math:`\|u_n - u_{n-1}\|`, L2 over the grid (trapezoidal weights W[j]),
    :math:`u_n = \sum_i F_i \prod_j G^{\mathrm{new}}_{j,i}` and :math:`u_{n-1}` the same with Gold (one term
    fewer); gram = :math:`(F_i^\top F_k)`. Without the update step this is the
    norm of the new term, with it the change the new term made to the whole model."""
    if len(Gnew) == 1:
        D = Gnew[0].copy()
        D[:-1] -= Gold[0]
        return float(np.sqrt(max(np.sum(((D * W[0]) @ D.T) * gram), 0.0)))
    m = gram.shape[0]
    idx = np.r_[np.arange(m), np.arange(m - 1)]
    prod = gram[np.ix_(idx, idx)]
    for j, (gn, go) in enumerate(zip(Gnew, Gold)):
        G = np.vstack([gn, -go if j == 0 else go])
        prod = prod * ((G * W[j]) @ G.T)
    return float(np.sqrt(max(prod.sum(), 0.0)))


def _gram_solve(M, b):
    """Solve the small symmetric Galerkin system M x = b (Cholesky; least squares if M is singular)."""
    try:
        return scipy.linalg.solve(M, b, assume_a="pos")
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return np.linalg.lstsq(M, b, rcond=None)[0]


def pgd_linear(K, f, g, grid, max_modes=20, tol=1e-4, max_fp=50, fp_tol=None, solve=None,
               name="mu", unit="", progress=None, check=None, check_tol=None, update=True, residual_tol=None,
               probes=PROBES, seed=0, start=None):
    r"""Build a SeparatedModel for :math:`K u = \sum_k f_k\, g_k(\mu)` (f: (r, n), g: (r, n_grid) on grid);
    with ``g`` None, f (n_grid, n) is the load at each grid point (:math:`g = I`: no separation of the load
    needed).

    Greedy enrichment with the alternating fixed point of the module docstring (seed 000 §3). With
    ``update`` (default), each new term is followed by the update step: the spatial modes
    :math:`F_1, \dots, F_n` fixed, the parameter functions of *all* terms are re-solved jointly, the Galerkin
    projection of the parametric problem on :math:`\operatorname{span}\{F_i\}` at every grid point :math:`q`,

    .. math::

        \sum_k (F_i \cdot K F_k)\, G_k(q) = F_i \cdot f(\mu_q), \qquad i = 1, \dots, n

    (one :math:`n \times n` system, every :math:`q` at once), so the model is the best one in
    :math:`\operatorname{span}\{F_i\}` in the energy norm at each grid point, whatever the directions
    :math:`F_i`: the fixed point of a new term only has to find a good direction and stops at the loose
    ``fp_tol`` = FP_TOL_UPDATE (1e-6 without the update, the old algorithm). Here :math:`K` does not depend
    on :math:`\mu`, and then the last G-step of the fixed point already is this projection (a new
    :math:`F` solved from a residual orthogonal to :math:`\operatorname{span}\{F_1, \dots, F_{n-1}\}` is
    :math:`K`-orthogonal to it), so the update changes the model by rounding only
    (tests/rom/test_pgd_update.py) and is kept as the guarantee; what makes the build cheaper than before is
    the early stop it allows. Where :math:`K` depends on :math:`\mu` (:func:`pgd_affine`) the update changes
    the model (15 terms of the (s, E) cantilever: error 1.5e-3 with it, 1.4e-2 without).

    Each new term's fixed point starts from the previous term's :math:`G` (scaled to :math:`\max |G| = 1`)
    plus START_NOISE times standard normal noise (``start`` = "previous", the default with the update; "ones":
    :math:`G = 1`, the old start and the default without it; "random": standard normal): the next term is most
    like the previous one, and the noise keeps every symmetry class in the start (from the previous :math:`G`
    alone the fixed point of a symmetric problem stays in that term's class and finds the dominant direction
    late: on the 1-D Laplacian of tests/rom/test_pgd_generic.py the residual after 4 terms was 1.25e-1 instead
    of 2.4e-2). The fixed point then takes 2-3 iterations per term instead of ~28 on the cantilever, for the
    same error per mode.

    Stopping: at ``max_modes``; when the relative residual of the parametric problem on the grid is <=
    ``residual_tol`` (default: ``tol``); when the relative mode amplitude
    :math:`\lVert u_n - u_{n-1} \rVert / \lVert u_1 \rVert` (L2 over the grid: without the update
    :math:`\lVert F_n \rVert \lVert G_n \rVert_w / (\lVert F_1 \rVert \lVert G_1 \rVert_w)` as before, with it
    the change the new term made to the whole model; the new term's own :math:`G` before the update means
    little once its fixed point is stopped early) is < ``tol``; with ``check``, when check(model) <=
    ``check_tol``. The residual :math:`r(\mu) = f(\mu) - K u_n(\mu)` is measured by the displacement error it
    causes, :math:`\lVert K^{-1} r(\mu) \rVert = \lVert u(\mu) - u_n(\mu) \rVert` (the Euclidean norm of
    :math:`r` itself weighs the stiff, high-frequency part and overstates the error by orders of magnitude),
    relative to :math:`\lVert K^{-1} f(\mu) \rVert = \lVert u(\mu) \rVert`, over the grid with the trapezoidal
    weights :math:`w`, and estimated with ``probes`` fixed random combinations :math:`z_k = \sqrt{w}\, \xi_k`
    (:math:`\xi_k` standard normal) of the grid points:

    .. math::

        \rho_n^2 = \frac{\sum_k \lVert K^{-1} R_n z_k \rVert^2}{\sum_k \lVert K^{-1} F z_k \rVert^2}, \qquad
        R_n z = F z - K U_n z,

    (:math:`F, U_n, R_n`: the load, the model and the residual as (n, n_grid) tables), whose expectation is
    :math:`\sum_q w_q \lVert u(\mu_q) - u_n(\mu_q) \rVert^2 / \sum_q w_q \lVert u(\mu_q) \rVert^2`: the
    measure of POD's discarded energy, so ``tol`` means the same for both. :math:`K^{-1} F z_k` are ``probes``
    solves made once; each later estimate, :math:`K^{-1} R_n z_k = K^{-1} F z_k - U_n z_k`, costs no solve
    (info["residuals"], one per term). It is an error on the grid: between grid points the cubic interpolation
    of :math:`G` adds its own (off-grid check points, ``check``, see both).

    Returns (model, info) with info["amplitudes"], info["residuals"], info["fixed_point_iterations"],
    info["solves"] (solves with K: fixed point and probes). ``progress(n, max_modes)`` after each mode.
    ``check(model) -> error`` (e.g. against full solves at random parameters) is called after each mode,
    its values are info["check_errors"]. Runs with one BLAS thread (see :mod:`physar.rom._threads`).
    """
    with single_blas_thread():
        return _pgd_linear(K, f, g, [grid], max_modes, tol, max_fp, fp_tol, solve, [name], [unit], progress,
                           check, check_tol, update, residual_tol, probes, seed, start)


#: The SVD terms of a grouped model dropped may add this fraction of the residual estimate to the error.
SEPARATION_SHARE = 0.1


def _grouped_model(F, A, grids, names, units, gram=None, drop=0.0):
    r"""SeparatedModel of :math:`u(\mu) = \sum_i F_i A_i(\mu)`, :math:`A_i` (n_grid,) tables on the tensor grid
    (C order) of 1 or 2 parameters. With two, each table is written as
    :math:`\sum_r \sigma_r U_r(\mu_1) V_r(\mu_2)` by the SVD of :math:`W_1^{1/2} A_i W_2^{1/2}` (:math:`W_j` the
    trapezoidal weights: :math:`\sigma_r` is the term's L2 norm over the grid), :math:`F_i` repeated once per
    term (as :func:`physar.rom.pod.pod_from_snapshots`), and the smallest terms of all modes are dropped while
    their norms sum (in squares) to at most ``drop`` times the model's norm :math:`\|u\|_W` (``gram`` =
    :math:`(F_i^\top F_k)`; the cross terms between modes neglected)."""
    if len(grids) == 1:
        return SeparatedModel(F, grids, [A], names, units)
    if len(grids) != 2:
        raise ValueError(f"grouped parameters: 1 or 2 parameters, got {len(grids)}")
    r1, r2 = (np.sqrt(_trapz_weights(x)) for x in grids)
    terms = []  # (sigma, i, u, v)
    for i, Ai in enumerate(A):
        U, s, Vt = np.linalg.svd(r1[:, None] * Ai.reshape(grids[0].size, grids[1].size) * r2, full_matrices=False)
        terms += [(s[k], i, U[:, k] * s[k] / r1, Vt[k] / r2) for k in range(len(s)) if s[k] > 1e-12 * s[0]]
    if drop > 0 and gram is not None and len(terms) > 1:
        W = np.multiply.outer(r1**2, r2**2).ravel()
        norm2 = max(float(np.sum(gram * ((A * W) @ A.T))), 0.0)
        terms.sort(key=lambda t: t[0])
        cut = np.searchsorted(np.cumsum([t[0] ** 2 for t in terms]), (drop**2) * norm2, side="right")
        terms = terms[min(int(cut), len(terms) - 1):]
        terms.sort(key=lambda t: (t[1], -t[0]))
    return SeparatedModel(np.array([F[t[1]] for t in terms]), grids, [np.array([t[2] for t in terms]),
                                                                      np.array([t[3] for t in terms])], names, units)


def _pgd_linear(K, f, g, grids, max_modes, tol, max_fp, fp_tol, solve, names, units, progress, check=None,
                check_tol=None, update=True, residual_tol=None, probes=PROBES, seed=0, start=None):
    grids = [np.asarray(x, float) for x in grids]
    size = int(np.prod([x.size for x in grids]))
    if sp.issparse(f):
        f = f.tocsr()
    else:
        f = np.atleast_2d(np.asarray(f, float))
    if g is not None:
        g = np.atleast_2d(np.asarray(g, float))
        if g.shape[0] == g.shape[1] and np.array_equal(g, np.eye(g.shape[0])):
            g = None  # f is the load at the grid points: f(v) = f^T v, (F.f(mu_q))_q = f F
    w = _trapz_weights(grids[0])
    for x in grids[1:]:
        w = np.multiply.outer(w, _trapz_weights(x)).ravel()
    if solve is None:
        lu = spla.splu(K.tocsc())
        solve = lu.solve
    if fp_tol is None:
        fp_tol = FP_TOL_UPDATE if update else 1e-6
    if start is None:
        start = "previous" if update else "ones"
    residual_tol = tol if residual_tol is None else residual_tol
    n = K.shape[0]
    fT = f.T.tocsr() if sp.issparse(f) else np.ascontiguousarray(f.T)  # (n, r)

    def load(v):  # sum_q v_q f(mu_q), v (n_grid,) or (n_grid, k)
        return fT @ (v if g is None else g @ v)

    def project(F):  # (F.f(mu_q))_q
        return f @ F if g is None else (F @ fT) @ g

    # residual probes: U z_k = K^-1 f z_k, solved once
    Z = np.sqrt(w)[:, None] * np.random.default_rng(seed).standard_normal((size, int(probes)))
    FZ = load(Z)
    UZ = _solve_columns(solve, FZ) if probes else FZ
    norm2 = max(float(np.sum(UZ * UZ)), 1e-300)
    n_solves = int(probes)
    Fs, KFs, Ff = np.zeros((0, n)), np.zeros((0, n)), np.zeros((0, size))
    Gs, gram = np.zeros((0, size)), np.zeros((0, 0))
    rng = np.random.default_rng(seed + 1)
    amps, checks, residuals, fp_its = [], [], [], []
    for _ in range(max_modes):
        G = np.ones(size)
        if start == "previous" and len(Gs):
            G = Gs[-1] / (np.abs(Gs[-1]).max() or 1.0) + START_NOISE * rng.standard_normal(size)
        elif start == "random":
            G = rng.standard_normal(size)
        F = None
        for it in range(max_fp):
            rhs = load(w * G)
            if len(Fs):
                rhs -= KFs.T @ (Gs @ (w * G))
            F = solve(rhs / (G @ (w * G)))
            n_solves += 1
            KF = K @ F
            Gnew = project(F)
            if len(Fs):
                Gnew -= (KFs @ F) @ Gs
            Gnew /= F @ KF
            delta = np.linalg.norm(Gnew - G) / max(np.linalg.norm(Gnew), 1e-300)
            G = Gnew
            if delta < fp_tol:
                break
        fp_its.append(it + 1)
        # normalise: F unit norm, amplitude in G
        nF = np.linalg.norm(F)
        F, G = F / nF, G * nF
        Gold = Gs
        Fs, KFs, Gs = np.vstack([Fs, F]), np.vstack([KFs, K @ F]), np.vstack([Gs, G])
        Ff = np.vstack([Ff, project(F)])
        row = Fs @ F
        gram = np.block([[gram, row[:-1, None]], [row[None, :]]]) if len(Gold) else row[None, :]
        if update:  # Galerkin projection on span{F_i} at every grid point
            M = Fs @ KFs.T
            Gs = _gram_solve((M + M.T) / 2, Ff)
        amps.append(_change_norm(gram, [Gs], [Gold], [w]))
        if probes:
            EZ = UZ - Fs.T @ (Gs @ Z)
            residuals.append(float(np.sqrt(np.sum(EZ * EZ) / norm2)))
        if progress:
            progress(len(Fs), max_modes)
        if check is not None:
            drop = SEPARATION_SHARE * residuals[-1] if residuals else 0.0
            checks.append(float(check(_grouped_model(Fs, Gs, grids, names, units, gram, drop))))
            if check_tol is not None and checks[-1] <= check_tol:
                break
        if amps[-1] < tol * amps[0] or (residuals and residuals[-1] <= residual_tol):
            break
    model = _grouped_model(Fs, Gs, grids, names, units, gram, SEPARATION_SHARE * residuals[-1] if residuals else 0.0)
    info = {"amplitudes": np.array(amps), "residuals": residuals, "fixed_point_iterations": fp_its,
            "solves": n_solves, "spatial_modes": len(Fs)}
    if check is not None:
        info["check_errors"] = checks
    return model, info


def pgd_linear_tensor(K, B, grids, max_modes=40, tol=1e-4, max_fp=50, fp_tol=None, solve=None,
                      names=None, units=None, progress=None, check=None, check_tol=None, grouped=False, **options):
    r"""Intrusive PGD for :math:`K u = f(x; \mu_1, \dots, \mu_p)` with :math:`p \ge 1` parameters on tensor
    grids (seed 000 §3).

    The load is given by its samples on the tensor grid: ``B`` (n, N) (dense or sparse), column q the
    load at grid node q (C order over ``grids``). ``solve(b)`` solves with K (default: a factorisation of
    K). Two forms of the separated representation:

    * ``grouped`` False (default): :math:`u = \sum_i F_i(x) \prod_j G_i^j(\mu_j)`, one function per parameter
      and term (seed eq. 3): :func:`pgd_affine` with one operator term :math:`K` and one load term :math:`B`
      over every parameter (see there for the fixed point and the update step). With :math:`p > 1` the greedy
      sum of rank-one terms converges more slowly than the optimal (POD) basis, and the update step does not
      change that: on the patch of benchmarks/bench_rom.py 40 terms reach 3-6e-4 where 10 POD modes reach 4e-4
      (RESULTS.md "PGD with the update step").
    * ``grouped`` True (:math:`p \le 2`): space separated from the parameters taken together,
      :math:`u = \sum_i F_i(x)\, A_i(\mu)` with :math:`A_i` on the tensor grid: :func:`pgd_linear` on the N
      grid points with the product of the trapezoidal weights, its update step the Galerkin projection on
      :math:`\operatorname{span}\{F_i\}` at every grid point (one :math:`n \times n` system for all), its
      residual estimate over the whole grid. The tables :math:`A_i` are then written as separated terms by
      their SVD, the smallest terms of all modes dropped while they add at most SEPARATION_SHARE of the
      residual estimate (:func:`_grouped_model`; info["spatial_modes"] counts the :math:`F_i`, the model's
      n_modes the terms). On the patch: 10 spatial modes (26 terms) reach 4.7e-4, 10 POD
      modes (110 terms) 4.1e-4, with 35 solves instead of the 451 snapshots.

    ``max_modes`` counts terms (spatial modes with ``grouped``). Returns (model, info) with
    info["amplitudes"], info["residuals"], info["fixed_point_iterations"], info["solves"];
    ``check``/``check_tol`` as in :func:`pgd_linear`; ``options``: update, residual_tol, probes, seed, start.
    """
    p = len(grids)
    if grouped:
        with single_blas_thread():
            return _pgd_linear(K, sp.csr_matrix(B).T if sp.issparse(B) else np.asarray(B, float).T, None, grids,
                               max_modes, tol, max_fp, fp_tol, solve, names or [f"mu{j + 1}" for j in range(p)],
                               units or [""] * p, progress, check, check_tol, **options)
    factor = None if solve is None else (lambda A: solve)
    return pgd_affine([SeparatedTerm(K)], [SeparatedTerm(B, tuple(range(p)))], grids, max_modes=max_modes,
                      tol=tol, max_fp=max_fp, fp_tol=fp_tol, factor=factor, names=names, units=units,
                      progress=progress, check=check, check_tol=check_tol, **options)


@dataclass(frozen=True, repr=False)
class SeparatedTerm:
    r"""One term of a separated operator or load: ``value`` times 1-D functions of the parameters.

    An operator term is a sparse (n, n) matrix :math:`A` with ``factors`` {j: :math:`\alpha(\mu_j)` on grid j}:
    the operator is :math:`\sum_m A_m \prod_j \alpha_m^j(\mu_j)` (e.g.
    :math:`K_{\mathrm{rest}} + (E / E_{\mathrm{ref}}) K_{\mathrm{region}}`). A load term is
    ``value`` (n, N) (dense or sparse), its columns the load at the nodes of the tensor grid of the
    parameters ``axes`` (C order; N = 1 for axes = ()), times ``factors`` {j: :math:`h(\mu_j)`} for j not in
    ``axes``. A parameter named nowhere enters as the constant 1.
    """

    value: object
    axes: tuple = ()
    factors: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        """One line: the value's kind and shape, the tensor-grid axes and the parameters with factors."""
        kind = "sparse" if sp.issparse(self.value) else "dense"
        shape = "x".join(map(str, np.shape(self.value) if kind == "dense" else self.value.shape))
        return f"SeparatedTerm({kind} {shape}, axes {tuple(self.axes)}, factors on {sorted(self.factors)})"


def pgd_affine(ops, loads, grids, max_modes=40, tol=1e-4, max_fp=50, fp_tol=None, factor=None, names=None,
               units=None, progress=None, check=None, check_tol=None, update=None, residual_tol=None,
               probes=PROBES, seed=0, start=None):
    r"""Intrusive PGD for :math:`K(\mu) u = f(\mu)`, :math:`K(\mu) = \sum_m A_m \prod_j \alpha_m^j(\mu_j)` and
    :math:`f(\mu) = \sum_t` (load term t), 1 to 3 parameters on tensor grids (seed 000 §3: an operator affine
    in the parameter).

    ``ops``, ``loads``: lists of :class:`SeparatedTerm`. With the trapezoidal weights :math:`w_j` of each grid,
    :math:`a_j = w_j G^j` and :math:`\langle x, y \rangle_j = \sum_q w_j(q)\, x(q)\, y(q)`, the greedy
    enrichment :math:`u_n = u_{n-1} + F \prod_j G^j` alternates

    .. math::

        \text{F-step:} \quad \sum_m A_m \prod_j \langle \alpha_m^j G^j, G^j \rangle_j\, F
        = \Big\langle f, \prod_j G^j \Big\rangle - \sum_i \sum_m A_m F_i \prod_j
        \langle \alpha_m^j G_i^j, G^j \rangle_j,

    and the :math:`G^j`-step (each :math:`j` in turn, the others fixed; at each grid point :math:`q` of
    parameter :math:`j`)

    .. math::

        G^j(q) \sum_m (F^\top A_m F)\, \alpha_m^j(q) \prod_{k \ne j} \langle \alpha_m^k G^k, G^k \rangle_k
        = \Big\langle f, F \prod_{k \ne j} G^k \Big\rangle(q)
        - \sum_i \sum_m (F^\top A_m F_i)\, \alpha_m^j(q)\, G_i^j(q) \prod_{k \ne j}
        \langle \alpha_m^k G_i^k, G^k \rangle_k

    until the change of the rank-one term :math:`F \prod_j G^j` is below ``fp_tol`` (default FP_TOL_UPDATE with
    the update step, 1e-6 without). With ``update`` = k > 0 (default: 1 sweep for one parameter,
    UPDATE_SWEEPS for more; 0: none), k sweeps of the update step follow each new term: the spatial modes
    :math:`F_1, \dots, F_n` fixed, the functions of every term for parameter :math:`j` are recomputed together
    (Galerkin, one :math:`n \times n` system per grid point :math:`q`):

    .. math::

        \sum_k \Big[ \sum_m (F_i^\top A_m F_k)\, \alpha_m^j(q) \prod_{l \ne j}
        \langle \alpha_m^l G_k^l, G_i^l \rangle_l \Big] G_k^j(q)
        = \Big\langle f, F_i \prod_{l \ne j} G_i^l \Big\rangle(q), \qquad i = 1, \dots, n,

    for :math:`j = 1, \dots, p` in turn (alternating least squares on the parameter functions; for one parameter
    the Galerkin projection on :math:`\operatorname{span} F`, exactly). The greedy sum alone converges slowly with two parameters:
    for E of a region x a moving load (tests/rom/test_param_kinds.py, P1, 81 x 21 grid) the error at
    random points is 2.3e-3 after 40 terms, 1.7e-4 after 30 with ``update`` = 2. With a constant operator
    and two load parameters (the patch of benchmarks/bench_rom.py) the sweeps change nothing measurable:
    there the rank-one terms, not their parameter functions, limit the sum (RESULTS.md).

    With the defaults (update, loose fixed point) on a P1 12 x 2 x 2 cantilever with E of its outer half x
    a moving load (41 x 21 grid, tests/rom/test_pgd_update.py), 15 terms: error 1.5e-3 from 66 solves;
    without the update (fixed point to 1e-6): 1.4e-2 from 413.

    Each term is normalised (:math:`|F| = 1`, :math:`\langle G^j, G^j \rangle_j = 1` for :math:`j \ge 2`, the
    amplitude in :math:`G^1`). The greedy loop stops at ``max_modes``, when the relative amplitude
    :math:`\|u_n - u_{n-1}\| / \|u_1\|` (as in :func:`pgd_linear`; without the update
    :math:`|G_n^1|_w / |G_1^1|_w` of the new term) < ``tol``, or when the
    relative residual estimate (:class:`_Probes`, ``probes`` fixed probes: the L2 displacement error the
    residual causes, relative, on the grid; info["residuals"]) <= ``residual_tol`` (default ``tol``). The
    fixed point of the first term starts from seeded random :math:`G^j` (a constant start keeps a symmetric
    problem in its even subspace); later ones too with two or three parameters or without the update, from
    the previous term's G plus noise with one parameter and the update (``start`` "random" | "previous",
    as in :func:`pgd_linear`). The :math:`A_m` must be symmetric. ``factor(A) -> solve`` factorises an F-step
    matrix (default :func:`physar.fem.factorize`; see :class:`_FStepSolver`). Returns (model, info) with
    info["amplitudes"], info["residuals"], info["fixed_point_iterations"], info["factorizations"],
    info["cg_iterations"], info["solves"] (F-step and probe solves); ``check``/``check_tol`` as in
    :func:`pgd_linear`. Runs with one BLAS thread.
    """
    with single_blas_thread():
        return _pgd_affine(ops, loads, grids, max_modes, tol, max_fp, fp_tol, factor, names, units, progress,
                           check, check_tol, update, residual_tol, probes, seed, start)


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
        r""":math:`\langle f, \prod_j G^j \rangle` for :math:`a_j = w_j G^j`: (n,)."""
        out = 0.0
        for B, axes, h in self.terms:
            scale = np.prod([a[k] @ hk for k, hk in h.items()])
            out = out + scale * (B @ (_outer([a[k] for k in axes]).ravel() if axes else np.ones(1)))
        return np.asarray(out).ravel()

    def projections(self, F):
        r""":math:`B_t^\top F` on each term's tensor grid."""
        return [np.asarray(B.T @ F).reshape([self.shape[k] for k in axes]) for B, axes, _ in self.terms]

    def contract(self, P, a, j):
        r""":math:`\langle f, F \prod_{k \ne j} G^k \rangle` at the grid points of parameter j
        (P = projections(F)): (n_j,)."""
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
    r"""Solves :math:`\sum_m c_m A_m x = b` for the F-step of :func:`pgd_affine`.

    One operator term: :math:`A_1` is factorised once. Several: the coefficient ratios :math:`r_m = c_m / c_1`
    are rounded to bins 20 % wide (in :math:`\log r`); the matrix of the bin,
    :math:`A_1 + \sum_m r_{\mathrm{bin}} A_m`, is factorised once
    (the last ``keep`` kept) and preconditions conjugate gradients on the exact matrix (its eigenvalues
    lie within a factor 1.2 of the preconditioner's: ~10 iterations to 1e-12).
    """

    BIN = np.log(1.2)

    def __init__(self, A, factor, keep=6):
        self.A, self.factor, self.keep = A, factor, keep
        self.cache: dict = {}
        self.n_factor = self.n_cg = self.n_solve = 0

    def _factor(self, key, matrix):
        if key not in self.cache:
            if len(self.cache) >= self.keep:
                self.cache.pop(next(iter(self.cache)))
            self.cache[key] = self.factor(matrix())
            self.n_factor += 1
        return self.cache[key]

    def __call__(self, c, b):
        A = self.A
        self.n_solve += 1
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
    r""":math:`|F| = 1` and :math:`\langle G^j, G^j \rangle_j = 1` for :math:`j \ge 2` per term, the amplitude in
    :math:`G^1` (in place on the lists)."""
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


class _Probes:
    r"""The residual estimate of :func:`pgd_affine`: ``k`` fixed probes of the tensor grid, the exact
    solutions there (k solves, once) and the relative L2 error of the model at them.

    Probe :math:`k` weights each parameter :math:`j` that no operator factor depends on by
    :math:`\sqrt{w_j}\, \xi_j` (:math:`\xi_j` standard normal, a product of independent Gaussian vectors:
    :math:`E[z z^\top] = \operatorname{diag}(w)`) and fixes every parameter the operator depends on at a random
    grid point (:math:`K` differs between those, so their probes are not combined).
    :math:`u_k = K_k^{-1} f(z_k)`, :math:`K_k` the operator there; the estimate is

    .. math::

        \rho_n = \sqrt{\frac{\sum_k \|u_k - u_n(z_k)\|^2}{\sum_k \|u_k\|^2}}, \qquad
        u_k - u_n(z_k) = K_k^{-1} \big(f(z_k) - K_k u_n(z_k)\big),

    the residual of the parametric problem at the probes, measured by the displacement error it causes
    (its :math:`K^{-1}` image, relative: the same measure as POD's discarded energy).
    :math:`u_n(z_k) = \sum_i F_i \prod_j \langle G_i^j, z_k^j \rangle` needs no solve.
    """

    def __init__(self, alpha, f, W, shape, solve, k, seed):
        p = len(shape)
        varies = [any(np.ptp(al[j]) > 0 for al in alpha) for j in range(p)]
        rng = np.random.default_rng(seed)
        self.z, self.u = [], []
        for _ in range(int(k)):
            z = []
            for j in range(p):
                if varies[j]:
                    e = np.zeros(shape[j])
                    e[rng.integers(shape[j])] = 1.0
                    z.append(e)
                else:
                    z.append(np.sqrt(W[j]) * rng.standard_normal(shape[j]))
            c = np.array([np.prod([al[j] @ z[j] if varies[j] else al[j][0] for j in range(p)]) for al in alpha])
            self.z.append(z)
            self.u.append(solve(c, f.rhs(z)))
        self.norm2 = max(sum(float(u @ u) for u in self.u), 1e-300)

    def __call__(self, Fs, Gs):
        """rho_n of the model (Fs (n, N), Gs[j] (n, n_j))."""
        err2 = 0.0
        for z, u in zip(self.z, self.u):
            coef = np.prod([Gj @ zj for Gj, zj in zip(Gs, z)], axis=0)
            e = u - Fs.T @ coef
            err2 += float(e @ e)
        return float(np.sqrt(err2 / self.norm2))


def _pgd_affine(ops, loads, grids, max_modes, tol, max_fp, fp_tol, factor, names, units, progress, check=None,
                check_tol=None, update=None, residual_tol=None, probes=PROBES, seed=0, start=None):
    grids = [np.asarray(x, float) for x in grids]
    p = len(grids)
    shape = tuple(x.size for x in grids)
    names = list(names) if names is not None else [f"mu{j + 1}" for j in range(p)]
    units = list(units) if units is not None else [""] * p
    if update is None:
        update = 1 if p == 1 else UPDATE_SWEEPS
    if fp_tol is None:
        fp_tol = FP_TOL_UPDATE if update else 1e-6
    if start is None:
        start = "previous" if p == 1 and update else "random"
    residual_tol = tol if residual_tol is None else residual_tol
    W = [_trapz_weights(x) for x in grids]
    A = [t.value for t in ops]
    alpha = [[np.asarray(t.factors.get(j, np.ones(shape[j])), float) for j in range(p)] for t in ops]
    f = _Loads(loads, shape)
    if factor is None:
        from physar.fem import factorize

        def factor(M):
            return factorize(M).solve
    solve = _FStepSolver(A, factor)
    probe = _Probes(alpha, f, W, shape, solve, probes, seed) if probes else None

    Fs, AFs, Gs, Ps, amps, fp_its, checks, residuals = [], [[] for _ in A], [[] for _ in range(p)], [], [], [], [], []
    gram = np.zeros((0, 0))
    rng = np.random.default_rng(seed)
    for _ in range(max_modes):
        # a start with no symmetry: a constant start keeps the fixed point in the subspace of functions
        # even in t for a load path on a symmetry plane, and the odd (torsion) part is never found (the
        # previous term's functions, even as well, found it only after 8 terms on the patch instead of 4)
        G = [rng.uniform(0.5, 1.5, n) for n in shape]
        if start == "previous" and Fs:
            G = [Gs[j][-1] / (np.abs(Gs[j][-1]).max() or 1.0) + START_NOISE * rng.standard_normal(shape[j])
                 for j in range(p)]
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
        Gold = [np.array(g, float).reshape(len(Fs), shape[j]) for j, g in enumerate(Gs)]
        row = np.array(Fs + [F]) @ F
        gram = np.block([[gram, row[:-1, None]], [row[None, :]]]) if Fs else row[None, :]
        Fs.append(F)
        for m, Am in enumerate(A):
            AFs[m].append(Am @ F)
        for j in range(p):
            Gs[j].append(G[j])
        if update:
            Ps.append(f.projections(F))
            _update(Fs, AFs, Gs, Ps, alpha, f, W, update)
        amps.append(_change_norm(gram, [np.array(g) for g in Gs], Gold, W))
        if probe is not None:
            residuals.append(probe(np.array(Fs), [np.array(g) for g in Gs]))
        if progress:
            progress(len(Fs), max_modes)
        if check is not None:
            checks.append(float(check(SeparatedModel(np.array(Fs), grids, [np.array(g) for g in Gs], names, units))))
            if check_tol is not None and checks[-1] <= check_tol:
                break
        if amps[-1] < tol * amps[0] or (residuals and residuals[-1] <= residual_tol):
            break
    model = SeparatedModel(np.array(Fs), grids, [np.array(g) for g in Gs], names, units)
    info = {"amplitudes": np.array(amps), "residuals": residuals, "fixed_point_iterations": fp_its,
            "factorizations": solve.n_factor, "cg_iterations": solve.n_cg, "solves": solve.n_solve}
    if check is not None:
        info["check_errors"] = checks
    return model, info
