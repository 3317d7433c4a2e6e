"""Intrusive PGD for linear elasticity with a point load moving along a polyline (seed 000 §3, §5.1).

The load position is path(s) = :func:`physar.geometry.path_point` at arc length s along a polyline of
>= 2 points; the grid of s is uniform in arc length.
"""
from __future__ import annotations

import numpy as np

from physar.errors import ConfigError
from physar.fem import check_constraints, dof_indices, factorize, point_load
from physar.geometry.path import as_path, path_length, path_point
from physar.rom._threads import blas_single_threaded
from physar.rom.pgd import pgd_linear


def load_path_matrix(space, path, points, load, radius):
    """Nodal forces of the regularised point load at `points` arc-length positions s (m) along the
    polyline `path` (>= 2 points), uniformly spaced in arc length from 0 to its length.

    Returns (s_grid, B) with B (n_dofs, points), column q = point_load(space, path_point(path, s_q), load,
    radius).
    """
    path = as_path(path, "load path")
    s = np.linspace(0.0, path_length(path), int(points))
    B = np.stack([point_load(space, x, load, radius) for x in path_point(path, s)], axis=1)
    return s, B


@blas_single_threaded
def build_moving_load_pgd(model, fixed, path, points=60, load=(0, 0, -1.0), radius=0.04,
                          max_modes=20, tol=1e-4, svd_tol=None, magnitude_range=None, n_check=0,
                          progress=None, seed=0, offset_range=None, offset_dir=None, offset_points=13,
                          check_tol=None, update=True, residual_tol=None, group_parameters=False):
    r"""PGD model :math:`u(x, s)` of :math:`K u = f(x; s)` with :math:`u = 0` on `fixed` (linear elastic
    `model`).

    The load enters as its samples at the grid points (the sparse point loads; with ``svd_tol`` a float,
    as a separated sum :math:`f(x; s) = \sum_k f_k(x)\, g_k(s)` by a truncated SVD of the sampled load matrix
    at that relative singular value tolerance: the moving point load has full rank, so the SVD only costs
    time). With ``magnitude_range=(P_lo, P_hi)`` (N) a second parameter "P", the load magnitude, is added:
    :math:`u(x; s, P) = \sum_i F_i(x)\, G_i(s)\, P / \lvert \mathtt{load} \rvert` (exact, linear elasticity).
    Stopping (seed §3): relative mode amplitude < `tol` (info["amplitudes"]); with ``n_check > 0`` an error
    estimate against full solves at `n_check` random positions s, computed after every mode
    (info["check_errors"]; info["check_error"] the final one: max over the check points of
    :math:`\lVert u_\text{PGD} - u_\text{FE} \rVert / \max \lVert u_\text{FE} \rVert`, L2 over the dofs), and
    with ``check_tol`` the enrichment also stops once that estimate is <= check_tol.
    ``progress(mode, max_modes)``. ``update`` (default): the update step of :func:`physar.rom.pgd.pgd_linear`
    after each mode (the parameter functions of all modes re-solved on the current spatial modes);
    ``residual_tol`` (default ``tol``): stop once the relative residual estimated on the grid is <= it
    (info["residuals"], one per mode; info["solves"]: solves with K in the build, the ``n_check`` full solves
    included).

    With ``offset_range=(t_lo, t_hi)`` (m) and ``offset_dir`` :math:`d` the load point is
    :math:`\mathrm{path}(s) + t\, d` (position on a surface patch, two parameters :math:`s` and :math:`t`; on
    a bent polyline :math:`d` stays fixed, it does not turn with the path): the load is sampled on the (points
    x offset_points) tensor grid and the two-parameter PGD :func:`physar.rom.pgd.pgd_linear_tensor` is run
    (the check points are then random (s, t)); ``group_parameters`` is its ``grouped`` (space separated from
    (s, t) together, ``max_modes`` then counts spatial modes).
    """
    fixed = _checked_inputs(model, fixed, points, load)
    if offset_range is not None:
        return _build_patch_load_pgd(model, fixed, path, points, load, radius, max_modes, tol,
                                     magnitude_range, n_check, progress, seed, offset_range, offset_dir,
                                     offset_points, check_tol, update, residual_tol, group_parameters)
    if not model.linear:
        raise ConfigError("intrusive PGD needs a linear material; use method='pgd_nonintrusive'")
    space = model.space
    s, B = load_path_matrix(space, path, points, load, radius)
    free = np.setdiff1d(np.arange(space.n_dofs), fixed)
    if svd_tol is None:
        f, g, r = B[free].T, None, None
    else:
        U, S, Vt = np.linalg.svd(B, full_matrices=False)
        r = max(1, int(np.sum(S > svd_tol * S[0])))
        f, g = (U[free, :r] * S[:r]).T, Vt[:r]
    K = model.tangent_stiffness()[free][:, free].tocsr()
    fac = factorize(K)
    check = None
    if n_check:
        length = float(s[-1])
        checks = np.random.default_rng(seed).uniform(0, length, int(n_check))
        Fc = np.stack([point_load(space, x, load, radius)[free] for x in path_point(path, checks)], 1)
        check = _checker(fac.solve(Fc).reshape(len(free), -1), checks[:, None])
    red, info = pgd_linear(K, f, g, s, max_modes=max_modes, tol=tol, solve=fac.solve,
                           name="s", unit="m", progress=progress, check=check, check_tol=check_tol,
                           update=update, residual_tol=residual_tol)
    info["solves"] += int(n_check)
    if n_check:
        info["check_error"] = info["check_errors"][-1]
        info["check_points"] = checks
    F = np.zeros((red.n_modes, space.n_dofs))
    F[:, free] = red.F
    from physar.rom.separated import SeparatedModel
    grids, G, names, units = list(red.grids), list(red.G), ["s"], ["m"]
    if magnitude_range is not None:
        lo, hi = map(float, magnitude_range)
        if not hi > lo:
            raise ConfigError(f"magnitude_range must be increasing, got {magnitude_range}")
        gp = np.linspace(lo, hi, 3)
        grids.append(gp)
        G.append(np.tile(gp / np.linalg.norm(load), (red.n_modes, 1)))
        names.append("P")
        units.append("N")
    out = SeparatedModel(F, grids, G, names, units,
                         {"kind": "load_position", "path": np.asarray(path, float).tolist(),
                          "load": list(map(float, load)), "radius": float(radius),
                          "material": type(model.material).__name__})
    if r is not None:
        out.metadata["svd_rank"] = info["svd_rank"] = r
    return out, info


def _checked_inputs(model, fixed, points, load) -> np.ndarray:
    """`fixed` as dof indices, after the checks a solve would make (supports, load, grid): the PGD of a singular
    K or of a zero load would otherwise run and return meaningless modes."""
    fixed = dof_indices(fixed, model.n_dofs)
    check_constraints(model.space.nodes, fixed, model.space.cells)
    whole = isinstance(points, (int, np.integer, float, np.floating)) and float(points).is_integer()
    if isinstance(points, (bool, np.bool_)) or not whole or points < 2:
        raise ConfigError(f"points (grid positions along the load path) must be an integer >= 2, got {points!r}")
    f = np.asarray(load, dtype=float)
    if f.shape != (3,) or not np.all(np.isfinite(f)) or not np.any(f):
        raise ConfigError(f"load must be a finite, non-zero force vector (fx, fy, fz) [N], got {load!r}")
    return fixed


def _checker(Uc, mus):
    r""":math:`\mathrm{check}(\mathrm{model}) = \max_k \|\mathrm{model}(\mu_k) - U_c[:, k]\| / \max_k \|U_c[:, k]\|`
    (full solves :math:`U_c` at mus)."""
    scale = np.linalg.norm(Uc, axis=0).max()

    def check(red):
        return max(np.linalg.norm(red.evaluate(m) - Uc[:, k]) for k, m in enumerate(mus)) / scale

    return check


def _build_patch_load_pgd(model, fixed, path, points, load, radius, max_modes, tol, magnitude_range, n_check,
                          progress, seed, offset_range, offset_dir, offset_points, check_tol=None, update=True,
                          residual_tol=None, group_parameters=False):
    import scipy.sparse as sp

    from physar.rom.pgd import pgd_linear_tensor
    from physar.rom.separated import SeparatedModel

    if not model.linear:
        raise ConfigError("intrusive PGD needs a linear material; use method='pgd_nonintrusive'")
    if offset_dir is None or np.linalg.norm(offset_dir) <= 0:
        raise ConfigError("offset_range needs a non-zero offset_dir (direction of the offset t)")
    lo, hi = map(float, offset_range)
    if not hi > lo:
        raise ConfigError(f"offset range must be increasing, got {list(offset_range)}")
    space = model.space
    path = as_path(path, "load path")
    length = path_length(path)
    e = np.asarray(offset_dir, float) / np.linalg.norm(offset_dir)
    s = np.linspace(0.0, length, int(points))
    t = np.linspace(lo, hi, int(offset_points))
    free = np.setdiff1d(np.arange(space.n_dofs), fixed)
    cols = [sp.csc_matrix(point_load(space, xi + ti * e, load, radius)[free][:, None])
            for xi in path_point(path, s) for ti in t]
    B = sp.hstack(cols).tocsr()
    K = model.tangent_stiffness()[free][:, free].tocsr()
    fac = factorize(K)
    check = None
    if n_check:
        checks = np.random.default_rng(seed).uniform([0.0, lo], [length, hi], (int(n_check), 2))
        Fc = np.stack([point_load(space, path_point(path, c[0]) + c[1] * e, load, radius)[free] for c in checks], 1)
        check = _checker(fac.solve(Fc).reshape(len(free), -1), checks)
    red, info = pgd_linear_tensor(K, B, [s, t], max_modes=max_modes, tol=tol, solve=fac.solve,
                                  names=["s", "t"], units=["m", "m"], progress=progress, check=check,
                                  check_tol=check_tol, residual_tol=residual_tol, grouped=group_parameters,
                                  update=(True if group_parameters else None) if update else 0)
    info["solves"] += int(n_check)
    if n_check:
        info["check_error"] = info["check_errors"][-1]
        info["check_points"] = checks
    F = np.zeros((red.n_modes, space.n_dofs))
    F[:, free] = red.F
    grids, G, names, units = list(red.grids), list(red.G), ["s", "t"], ["m", "m"]
    if magnitude_range is not None:
        plo, phi = map(float, magnitude_range)
        if not phi > plo:
            raise ConfigError(f"magnitude_range must be increasing, got {magnitude_range}")
        gp = np.linspace(plo, phi, 3)
        grids.append(gp)
        G.append(np.tile(gp / np.linalg.norm(load), (red.n_modes, 1)))
        names.append("P")
        units.append("N")
    out = SeparatedModel(F, grids, G, names, units,
                         {"kind": "load_position", "path": path.tolist(), "offset_dir": e.tolist(),
                          "load": list(map(float, load)), "radius": float(radius),
                          "material": type(model.material).__name__})
    return out, info


def _merged(a: dict, b: dict) -> dict:
    """Product of two factor dicts {j: h_j(mu_j)} (factors on the same parameter multiply)."""
    out = dict(a)
    for j, h in b.items():
        out[j] = out[j] * h if j in out else h
    return out


def _with_prescribed(problem, lifts, grids, red, names, units):
    """The full model: the prescribed modes (w, prod h) first, then the PGD modes ``red`` on the free dofs."""
    from physar.rom.separated import SeparatedModel

    n = problem.model.n_dofs
    F = [w for w, _ in lifts]
    G = [[h.get(j, np.ones(len(x))) for w, h in lifts] for j, x in enumerate(grids)]
    if red is not None:
        Fr = np.zeros((red.n_modes, n))
        Fr[:, problem.free] = red.F
        F += list(Fr)
        G = [g + list(rg) for g, rg in zip(G, red.G)]
    if not F:  # no load and nothing prescribed: u = 0
        F, G = [np.zeros(n)], [[np.zeros(len(x))] for x in grids]
    return SeparatedModel(np.array(F), grids, [np.array(g) for g in G], names, units, kinds=list(problem.kinds))


@blas_single_threaded
def build_parametric_pgd(problem, grids, names, units, max_modes=40, tol=1e-4, n_check=0, check_tol=None,
                         progress=None, seed=0, update=True, residual_tol=None):
    r"""Intrusive PGD of a linear :class:`physar.rom.problem.ParametricProblem` (any of its parameter kinds).

    With :math:`u = u_D(\mu) + u_0(\mu)`, :math:`u_D` the prescribed displacements (u_fix and each region's
    :math:`\sum_r w_r h_r(\mu_j)`, exact, kept as the first modes) and :math:`u_0 = 0` on the Dirichlet dofs:

    .. math::

        K_{ff}(\mu)\, u_0 = f_f(\mu) - K_{fd}(\mu)\, u_D(\mu), \qquad K(\mu) = \sum_m K_m \alpha_m(\mu)

    a separated operator and a separated load (products of the terms), solved by
    :func:`physar.rom.pgd.pgd_affine` on the tensor ``grids``. ``n_check`` random full solves
    (``problem(mu)``) give info["check_errors"] (max over the points of
    :math:`\|u_{\mathrm{ROM}} - u_{\mathrm{FE}}\| / \max \|u_{\mathrm{FE}}\|`,
    after each mode) and info["check_error"]; ``check_tol`` also stops the enrichment (as
    :func:`build_moving_load_pgd`); ``update`` (True: the default sweeps of pgd_affine, False: none, an
    integer: that many) and ``residual_tol`` as there. Returns (SeparatedModel, info).
    """
    from physar.rom.pgd import SeparatedTerm, pgd_affine

    model = problem.model
    if not model.linear:
        raise ConfigError("intrusive PGD needs a linear material; use method='pgd_nonintrusive'")
    grids = [np.asarray(x, float) for x in grids]
    fixed, free = problem.fixed, problem.free
    ops = problem.stiffness_terms(grids)
    lifts = problem.prescribed_terms(grids)
    loads = [SeparatedTerm(B[free], axes, h) for B, axes, h in problem.load_terms(grids)]
    for K, alpha in ops:
        Kfd = K[free][:, fixed]
        for w, h in lifts:
            r = -(Kfd @ w[fixed])
            if np.any(r):
                loads.append(SeparatedTerm(r[:, None], (), _merged(alpha, h)))
    check, info = None, {"n_prescribed_modes": len(lifts)}
    if n_check:
        rng = np.random.default_rng(seed)
        mus = rng.uniform([x[0] for x in grids], [x[-1] for x in grids], (int(n_check), len(grids)))
        Uc = np.stack([problem(m) for m in mus], 1)
        scale = np.linalg.norm(Uc, axis=0).max() or 1.0

        def check(red):
            full = _with_prescribed(problem, lifts, grids, red, names, units)
            return max(np.linalg.norm(full.evaluate(m) - Uc[:, k]) for k, m in enumerate(mus)) / scale

    red = None
    if loads and len(free):
        Kf = [SeparatedTerm(K[free][:, free].tocsr(), (), alpha) for K, alpha in ops]
        sweeps = None if update is True else int(update)
        red, pinfo = pgd_affine(Kf, loads, grids, max_modes=max_modes, tol=tol, names=names, units=units,
                                progress=progress, check=check, check_tol=check_tol, update=sweeps,
                                residual_tol=residual_tol)
        pinfo["solves"] += int(n_check)
        info.update(pinfo)
    elif check is not None:
        info["check_errors"] = [check(None)]
    if n_check:
        info["check_error"] = info["check_errors"][-1]
        info["check_points"] = mus
    out = _with_prescribed(problem, lifts, grids, red, names, units)
    out.metadata.update({"kind": "parametric", "material": type(model.material).__name__})
    return out, info
