"""Real-time data assimilation on a SeparatedModel (seed 000 §4).

Solves mu* = argmin 1/2 ||u_obs - C u(mu)||^2 + 1/2 alpha ||mu - mu_prior||^2 by Levenberg-Marquardt
with the analytic sensitivities du/dmu_j, inside parameter bounds, and reports the Gauss-Newton
covariance sigma^2 (J^T J + alpha I)^-1 with sigma^2 = residual^2 / max(m - p, 1).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physar.errors import PhysarError


@dataclass
class AssimilationResult:
    params: np.ndarray     # estimate, parameter units
    residual: float        # ||u_obs - C u(mu)|| (m)
    iterations: int
    std: np.ndarray        # Gauss-Newton standard deviation per parameter
    covariance: np.ndarray


def _lm(model, y, mu0, lo, hi, alpha, prior, max_iter, tol):
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


def assimilate(model, observed, mu0=None, bounds=None, alpha=0.0, prior=None, max_iter=50,
               tol=1e-10, restart_residual=None, n_starts=7):
    """Estimate the parameters from observed displacements (model.set_observation must match).

    ``restart_residual``: if the relative residual ||r||/||u_obs|| stays above it, a coarse
    multi-start over ``n_starts`` points per parameter is run and the best result kept.
    """
    y = np.asarray(observed, float).ravel()
    if not np.all(np.isfinite(y)):
        raise PhysarError("observed displacements contain NaN or inf")
    lo, hi = (np.array(b, float) for b in zip(*(bounds or model.ranges)))
    mu0 = (lo + hi) / 2 if mu0 is None else np.asarray(mu0, float)
    prior = mu0 if prior is None else np.asarray(prior, float)
    mu, r, cost, it = _lm(model, y, mu0, lo, hi, alpha, prior, max_iter, tol)
    if restart_residual is not None and np.linalg.norm(r) > restart_residual * np.linalg.norm(y):
        axes = [np.linspace(a, b, n_starts) for a, b in zip(lo, hi)]
        for start in np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, lo.size):
            m2, r2, c2, i2 = _lm(model, y, start, lo, hi, alpha, prior, max_iter, tol)
            it += i2
            if c2 < cost:
                mu, r, cost = m2, r2, c2
    J = model.sensitivities(mu, observed=True).T
    dof = max(y.size - mu.size, 1)
    sigma2 = (r @ r) / dof
    A = J.T @ J + alpha * np.eye(mu.size)
    cov = sigma2 * np.linalg.pinv(A)
    return AssimilationResult(mu, float(np.linalg.norm(r)), it, np.sqrt(np.abs(np.diag(cov))), cov)


__all__ = ["assimilate", "AssimilationResult"]


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


__all__.append("observation_matrix")
