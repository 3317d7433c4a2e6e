"""Real-time data assimilation on a SeparatedModel (seed 000 §2.2, §4).

Solves mu* = argmin 1/2 ||u_obs - C u(mu)||^2 + 1/2 alpha ||mu - mu_prior||^2 (seed Eq. 2 with an
optional Tikhonov term) by Levenberg-Marquardt with the analytic sensitivities du/dmu_j (seed §4),
inside parameter bounds, and reports the Gauss-Newton covariance sigma^2 (J^T J + alpha I)^-1 with
sigma^2 = ||r||^2 / max(m - p, 1).

Fast path (the online loop): with u(mu) = F^T c(mu) and the thin QR C F^T = Q R precomputed by
``SeparatedModel.set_observation``, ||y - C F^T c||^2 = ||z - R c||^2 + ||(I - Q Q^T) y||^2 with
z = Q^T y, so each LM iteration works on k <= n_modes numbers whatever the number of observations,
and J = -R dc/dmu. The mode coefficients c(mu), dc/dmu come from precomputed piecewise-cubic
coefficients (no scipy objects in the loop).
"""
from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from physar.errors import PhysarError


@dataclass
class AssimilationResult:
    params: np.ndarray     # estimate, parameter units
    residual: float        # ||u_obs - C u(mu)|| (m)
    iterations: int
    std: np.ndarray        # Gauss-Newton standard deviation per parameter
    covariance: np.ndarray
    time_us: float = field(default=0.0)  # wall time of the estimate (µs)
    restarted: bool = field(default=False)  # the coarse multi-start was run


def _inv_small(A):
    """Inverse of a small SPD-ish matrix; pseudo-inverse when (nearly) singular."""
    p = A.shape[0]
    if p == 1:
        a = A[0, 0]
        return np.array([[1.0 / a if a > 1e-300 else 0.0]])
    try:
        if np.linalg.cond(A) < 1e14:
            return np.linalg.inv(A)
    except np.linalg.LinAlgError:
        pass
    return np.linalg.pinv(A)


def _lm_fast(model, z, mu0, lo, hi, alpha, prior, max_iter, tol):
    """LM on the reduced residual e(mu) = z - R c(mu); returns (mu, c, dc, cost, iterations).

    cost excludes the constant ||(I - Q Q^T) y||^2; the Marquardt damping scales diag(J^T J).
    """
    R = model.observation_qr[1]
    coeffs = model._coeffs
    p = len(mu0)
    if p == 1 and not alpha:
        return _lm_fast_1(R, coeffs, z, float(mu0[0]), float(lo[0]), float(hi[0]), max_iter, tol)
    mu = np.minimum(np.maximum(np.asarray(mu0, float), lo), hi)
    c, dc = coeffs(mu.tolist())
    e = z - R @ c
    cost = e @ e
    if alpha:
        d = mu - prior
        cost += alpha * (d @ d)
    lam = 1e-3
    span = hi - lo
    it = 0
    for it in range(1, max_iter + 1):
        Jr = R @ dc.T  # (k, p) = -J
        A = Jr.T @ Jr
        g = Jr.T @ e
        if alpha:
            A = A + alpha * np.eye(p)
            g = g - alpha * (mu - prior)
        diag = np.diag(A) + 1e-300
        improved = False
        for _ in range(20):
            if p == 1:
                step = g / (A[0, 0] + lam * diag[0])
            else:
                step = np.linalg.solve(A + np.diag(lam * diag), g)
            mu_new = np.minimum(np.maximum(mu + step, lo), hi)
            c_new, dc_new = coeffs(mu_new.tolist())
            e_new = z - R @ c_new
            cost_new = e_new @ e_new
            if alpha:
                d = mu_new - prior
                cost_new += alpha * (d @ d)
            if cost_new <= cost:
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
        done = bool(np.all(np.abs(mu_new - mu) <= tol * span)) or cost_new >= cost * (1 - 1e-15)
        mu, c, dc, e, cost = mu_new, c_new, dc_new, e_new, cost_new
        lam = max(lam * 0.1, 1e-12)
        if done:
            break
    return mu, c, dc, cost, it


def _lm_fast_1(R, coeffs, z, mu, lo, hi, max_iter, tol):
    """:func:`_lm_fast` for one parameter without Tikhonov term, in Python floats."""
    mu = min(max(mu, lo), hi)
    c, dc = coeffs([mu])
    e = z - R @ c
    cost = e @ e
    lam = 1e-3
    span = tol * (hi - lo)
    it = 0
    for it in range(1, max_iter + 1):
        jr = R @ dc[0]
        A = jr @ jr + 1e-300
        g = jr @ e
        improved = False
        for _ in range(20):
            mu_new = min(max(mu + g / (A * (1.0 + lam)), lo), hi)
            c_new, dc_new = coeffs([mu_new])
            e_new = z - R @ c_new
            cost_new = e_new @ e_new
            if cost_new <= cost:
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
        done = abs(mu_new - mu) <= span or cost_new >= cost * (1 - 1e-15)
        mu, c, dc, e, cost = mu_new, c_new, dc_new, e_new, cost_new
        lam = max(lam * 0.1, 1e-12)
        if done:
            break
    return np.array([mu]), c, dc, cost, it


def _lm_generic(model, y, mu0, lo, hi, alpha, prior, max_iter, tol):
    """LM through model.evaluate/sensitivities(observed=True) (any SeparatedModel-like object)."""
    mu = np.clip(mu0, lo, hi)
    lam = 1e-3
    r = y - model.evaluate(mu, observed=True)
    cost = r @ r + alpha * np.sum((mu - prior) ** 2)
    it = 0
    for it in range(1, max_iter + 1):
        J = model.sensitivities(mu, observed=True).T  # (m, p)
        A = J.T @ J + alpha * np.eye(mu.size)
        b = J.T @ r - alpha * (mu - prior)
        improved = False
        for _ in range(20):
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-30), b)
            mu_new = np.clip(mu + step, lo, hi)
            r_new = y - model.evaluate(mu_new, observed=True)
            c_new = r_new @ r_new + alpha * np.sum((mu_new - prior) ** 2)
            if c_new < cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        dmu = np.abs(mu_new - mu)
        mu, r, cost, lam = mu_new, r_new, c_new, max(lam / 10, 1e-12)
        if np.all(dmu <= tol * (hi - lo)):
            break
    return mu, r, cost, it


def _bounds(model, bounds):
    lo, hi = (np.array(b, float) for b in zip(*(bounds or model.ranges)))
    if lo.shape != (model.n_params,) or np.any(hi < lo):
        raise PhysarError(f"bounds must be {model.n_params} increasing (lo, hi) pairs, got {bounds}")
    return lo, hi


def _start(model, mu0, lo, hi) -> np.ndarray:
    """The start vector: the centre of the ranges, ``mu0`` itself, or a partial mapping over the centre."""
    centre = (lo + hi) / 2
    if mu0 is None:
        return centre
    if isinstance(mu0, Mapping):
        names = list(getattr(model, "names", []))
        unknown = [n for n in mu0 if n not in names]
        if unknown:
            raise PhysarError(f"mu0: unknown parameter(s) {', '.join(map(str, unknown))}; the model has "
                              f"{names}")
        mu0 = np.array([float(mu0.get(n, c)) for n, c in zip(names, centre)])
    mu0 = np.asarray(mu0, float).ravel()
    if mu0.shape != lo.shape:
        raise PhysarError(f"mu0 must have {lo.size} values, got {mu0.size}")
    if not np.all(np.isfinite(mu0)):
        raise PhysarError(f"mu0 must be finite, got {mu0.tolist()}")
    return mu0


def assimilate(model, observed, mu0=None, bounds=None, alpha=0.0, prior=None, max_iter=50,
               tol=1e-10, restart_residual=None, n_starts=7):
    """Estimate the parameters from observed displacements (model.set_observation must match).

    ``mu0``: the start, all parameters (an array) or some of them (a mapping name -> value over
    ``model.names``; the others start at the centre of their range). ``restart_residual``: if the relative
    residual ||r||/||u_obs|| stays above it, a coarse multi-start over ``n_starts`` points per parameter is
    run and the best result kept. ``alpha`` and ``restart_residual`` must be finite and >= 0.
    """
    t0 = time.perf_counter()
    y = np.asarray(observed, float).ravel()
    if not np.all(np.isfinite(y)):
        raise PhysarError("observed displacements contain NaN or inf")
    if not 0 <= alpha < np.inf:
        raise PhysarError(f"alpha (Tikhonov weight) must be a finite number >= 0, got {alpha}")
    if restart_residual is not None and not 0 <= restart_residual < np.inf:
        raise PhysarError("restart_residual (relative residual) must be a finite number >= 0, got "
                          f"{restart_residual}")
    lo, hi = _bounds(model, bounds)
    mu0 = _start(model, mu0, lo, hi)
    prior = mu0 if prior is None else np.asarray(prior, float)
    fast = getattr(model, "_obs_qr", None) is not None and hasattr(model, "_coeffs")
    restarted = False
    if fast:
        Qt, R = model.observation_qr
        Fobs = model._obs
        if Fobs.shape[1] != y.size:
            raise PhysarError(f"{y.size} observed values, the observation operator has {Fobs.shape[1]}")
        z = Qt @ y
        mu, c, dc, cost, it = _lm_fast(model, z, mu0, lo, hi, alpha, prior, max_iter, tol)
        r = y - c @ Fobs
        if restart_residual is not None and np.sqrt(r @ r) > restart_residual * np.sqrt(y @ y):
            restarted = True
            axes = [np.linspace(a, b, n_starts) for a, b in zip(lo, hi)]
            for start in np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, lo.size):
                m2, c2, dc2, cost2, i2 = _lm_fast(model, z, start, lo, hi, alpha, prior, max_iter, tol)
                it += i2
                if cost2 < cost:
                    mu, c, dc, cost = m2, c2, dc2, cost2
            r = y - c @ Fobs
        Jr = R @ dc.T
        A = Jr.T @ Jr
    else:
        mu, r, cost, it = _lm_generic(model, y, mu0, lo, hi, alpha, prior, max_iter, tol)
        if restart_residual is not None and np.linalg.norm(r) > restart_residual * np.linalg.norm(y):
            restarted = True
            axes = [np.linspace(a, b, n_starts) for a, b in zip(lo, hi)]
            for start in np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, lo.size):
                m2, r2, c2, i2 = _lm_generic(model, y, start, lo, hi, alpha, prior, max_iter, tol)
                it += i2
                if c2 < cost:
                    mu, r, cost = m2, r2, c2
        J = model.sensitivities(mu, observed=True).T
        A = J.T @ J
    if alpha:
        A = A + alpha * np.eye(mu.size)
    rr = float(r @ r)
    sigma2 = rr / max(y.size - mu.size, 1)
    cov = sigma2 * _inv_small(A)
    std = np.sqrt(np.abs(np.diag(cov)))
    return AssimilationResult(mu, float(np.sqrt(rr)), it, std, cov,
                              (time.perf_counter() - t0) * 1e6, restarted)


class Assimilator:
    """Frame-by-frame estimation with warm start from the previous frame (seed 000 §4).

    ``step(observed)`` returns an :class:`AssimilationResult`; the estimate becomes the start (and,
    with ``alpha > 0``, the Tikhonov prior) of the next frame. Other keywords go to :func:`assimilate`.
    """

    def __init__(self, model, bounds=None, alpha=0.0, restart_residual=0.05, n_starts=7, mu0=None,
                 **kwargs):
        self.model = model
        self.bounds = bounds
        self.alpha = alpha
        self.restart_residual = restart_residual
        self.n_starts = n_starts
        self.mu = None if mu0 is None else np.asarray(mu0, float)
        self.kwargs = kwargs

    def step(self, observed) -> AssimilationResult:
        res = assimilate(self.model, observed, mu0=self.mu, bounds=self.bounds, alpha=self.alpha,
                         prior=self.mu if self.alpha else None, restart_residual=self.restart_residual,
                         n_starts=self.n_starts, **self.kwargs)
        self.mu = res.params
        return res

    def reset(self):
        self.mu = None


def observation_matrix(space, points):
    """Sparse C (3 p, n_dofs) with C u = displacements interpolated at reference `points` (m), row 3k+i."""
    import scipy.sparse as sp

    from physar.fem import locate, shape_functions

    pts = np.atleast_2d(np.asarray(points, float))
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise PhysarError(f"observed points must have shape (p, 3), got {pts.shape}")
    cells, L = locate(space, pts)
    N = shape_functions(space.element, L)  # (p, nen)
    nodes = space.cells[cells]  # (p, nen)
    p, nen = N.shape
    rows = (3 * np.arange(p)[:, None, None] + np.arange(3)[None, None, :]) * np.ones((1, nen, 1), int)
    cols = 3 * nodes[:, :, None] + np.arange(3)[None, None, :]
    vals = np.broadcast_to(N[:, :, None], (p, nen, 3))
    return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * p, space.n_dofs))


def read_observations(path) -> tuple[np.ndarray, np.ndarray]:
    """OBS.csv with a header x,y,z,ux,uy,uz (reference point, m; measured displacement, m)."""
    from pathlib import Path

    from physar.errors import ConfigError

    path = Path(path)
    if not path.exists():
        raise ConfigError(f"observation file not found: {path}")
    import csv

    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (UnicodeDecodeError, csv.Error):
        raise ConfigError(f"{path}: not a text CSV file (need a header x,y,z,ux,uy,uz)") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the observation file ({exc.strerror or exc})") from None
    rows = [r for r in rows if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ConfigError(f"{path}: empty observation file")
    header = [h.strip().lower() for h in rows[0]]
    cols = ["x", "y", "z", "ux", "uy", "uz"]
    missing = [c for c in cols if c not in header]
    if missing:
        raise ConfigError(f"{path}: missing column(s) {', '.join(missing)} (need a header x,y,z,ux,uy,uz)")
    idx = [header.index(c) for c in cols]
    data = []
    for i, r in enumerate(rows[1:], start=2):
        try:
            data.append([float(r[k]) for k in idx])
        except (ValueError, IndexError):
            raise ConfigError(f"{path}: line {i}: expected 6 numbers in columns {','.join(cols)}, got {r}") from None
    data = np.array(data).reshape(-1, 6)
    if len(data) == 0:
        raise ConfigError(f"{path}: no observation rows")
    if not np.all(np.isfinite(data)):
        raise ConfigError(f"{path}: NaN or inf in the observations")
    return data[:, :3], data[:, 3:]



__all__ = ["AssimilationResult", "Assimilator", "assimilate", "observation_matrix", "read_observations"]
