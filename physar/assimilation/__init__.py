r"""Real-time data assimilation on a SeparatedModel (seed 000 §2.2, §4).

Solves (seed Eq. 2 with an optional Tikhonov term)

.. math::

    \mu^\star = \arg\min_\mu \tfrac12 \lVert u_\text{obs} - C u(\mu) \rVert^2
    + \tfrac12 \alpha \lVert \mu - \mu_\text{prior} \rVert^2

by Levenberg-Marquardt with the analytic sensitivities :math:`\partial u / \partial \mu_j` (seed §4), inside
parameter bounds, and reports the Gauss-Newton covariance :math:`\sigma^2 (J^\top J + \alpha I)^{-1}` with
:math:`\sigma^2 = \lVert r \rVert^2 / \max(m - p, 1)`.

Fast path (the online loop): with :math:`u(\mu) = F^\top c(\mu)` and the thin QR :math:`C F^\top = Q R`
precomputed by ``SeparatedModel.set_observation``,

.. math::

    \lVert y - C F^\top c \rVert^2 = \lVert z - R c \rVert^2 + \lVert (I - Q Q^\top) y \rVert^2,
    \qquad z = Q^\top y,

so each LM iteration works on :math:`k \le` n_modes numbers whatever the number of observations, and
:math:`J = -R\, \partial c / \partial \mu`. The mode coefficients :math:`c(\mu)`,
:math:`\partial c / \partial \mu` come from precomputed piecewise-cubic coefficients (no scipy objects in the
loop).

Multi-start only when the fit is bad by a statistical test (issue 19): :math:`u(\mu)` stays in
:math:`\operatorname{span}(C F^\top)` for every :math:`\mu`, so with
:math:`y = C u_\text{true} + \text{noise}` the part of the residual a restart can change is the in-span
residual :math:`e = z - R c` (:math:`k` = dimension of the span, :math:`k - p` degrees of freedom at the
optimum) and the part orthogonal to the span,
:math:`\lVert (I - Q Q^\top) y \rVert^2` (:math:`m - k` degrees of freedom), is noise (plus model error)
whatever :math:`\mu` is. With a known noise :math:`\sigma` the test is chi-square,
:math:`\lVert e \rVert^2 / \sigma^2 > \chi^2_{1-a}(k - p)`; without it :math:`\sigma^2` is estimated from the
orthogonal part, which a wrong minimum does not inflate, and the test is the exact F test
:math:`(\lVert e \rVert^2 / (k - p)) / \hat\sigma^2 > F_{1-a}(k - p, m - k)`. ``model_error`` (relative) adds
:math:`(\mathtt{model\_error}\, \lVert y \rVert)^2 / m` to :math:`\sigma^2` so that noise-free data with the
small bias of the reduced model (discretisation, truncation) do not fail the test; this makes the test
conservative.
"""
from __future__ import annotations

import functools
import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from physar.errors import PhysarError, PhysarWarning


@dataclass
class AssimilationResult:
    r"""The outcome of one estimate (:func:`assimilate`, :meth:`Assimilator.step`).

    Attributes:
        params: (p,) estimate :math:`\mu^\star`, in the parameters' units.
        residual: :math:`\lVert u_\text{obs} - C u(\mu^\star) \rVert`, m.
        iterations: Levenberg-Marquardt iterations, those of the multi-start included.
        std: (p,) standard deviation of each parameter, the square roots of the diagonal of ``covariance``.
        covariance: (p, p) Gauss-Newton covariance :math:`\sigma^2 (J^\top J + \alpha I)^{-1}`.
        time_us: wall time of the estimate, µs.
        restarted: whether the coarse multi-start was run.
        fit_ratio: fit test of the estimate, statistic / critical value at the false-alarm rate (> 1: a fit
            worse than noise and model error explain); nan where no test was made.
    """

    params: np.ndarray     # estimate, parameter units
    residual: float        # ||u_obs - C u(mu)|| (m)
    iterations: int
    std: np.ndarray        # Gauss-Newton standard deviation per parameter
    covariance: np.ndarray
    time_us: float = field(default=0.0)  # wall time of the estimate (µs)
    restarted: bool = field(default=False)  # the coarse multi-start was run
    # fit test of the returned estimate: statistic / critical value at the false-alarm rate (> 1: the fit
    # is worse than noise and model error explain); nan where no test was made
    fit_ratio: float = field(default=math.nan)


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
    r"""LM on the reduced residual :math:`e(\mu) = z - R\, c(\mu)`; returns (mu, c, dc, cost, iterations).

    cost excludes the constant :math:`\|(I - Q Q^\top)\, y\|^2`; the Marquardt damping scales
    :math:`\operatorname{diag}(J^\top J)`.
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


@functools.lru_cache(maxsize=256)
def _critical(false_alarm, d1, d2):
    """Critical value of the fit statistic per degree of freedom: chi2_{1-a}(d1) / d1 (d2 = 0, known
    noise) or F_{1-a}(d1, d2) (noise estimated with d2 degrees of freedom)."""
    from scipy import special

    if d2 == 0:
        return float(special.chdtri(d1, false_alarm)) / d1
    return float(special.fdtri(d1, d2, 1.0 - false_alarm))


def _fit_ratio(cost, d1, perp, d2, yy, m, noise, model_error, false_alarm):
    r"""Statistic / critical value of the fit test (module docstring); nan when it cannot be made.

    cost: squared residual the parameters can change (d1 = its dimension - p degrees of freedom);
    perp: squared residual they cannot change (d2 degrees of freedom, used when ``noise`` is None);
    yy = :math:`\|y\|^2` over m observations (the model-error term)."""
    if not false_alarm or d1 < 1:
        return math.nan
    s2 = (model_error * model_error) * yy / m
    if noise is not None:
        s2 += noise * noise
        d2 = 0
    elif d2 >= 1:
        s2 += perp / d2
    else:
        return math.nan
    if s2 <= 0.0:
        return math.inf if cost > 0.0 else 0.0
    return cost / d1 / s2 / _critical(float(false_alarm), int(d1), int(d2))


def _check_nonneg(name, value, what):
    if value is not None and not 0 <= value < np.inf:
        raise PhysarError(f"{name} ({what}) must be a finite number >= 0, got {value}")


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
               tol=1e-10, restart_residual=None, n_starts=7, *, false_alarm=1e-3, noise=None,
               model_error=0.01):
    r"""Estimate the parameters from observed displacements (model.set_observation must match).

    ``mu0``: the start, all parameters (an array) or some of them (a mapping name -> value over
    ``model.names``; the others start at the centre of their range).

    Multi-start: a coarse grid of ``n_starts`` points per parameter is run, and the best result kept, when
    the fit fails a statistical test (module docstring) at the false-alarm rate ``false_alarm`` (the
    probability of a restart on a correct fit; default 1e-3, i.e. the 0.999 quantile; 0 or None: never).
    ``noise``: standard deviation of the observation noise (m) if known; None: estimated from the part of
    the observations that no parameter value can explain (models with an observation QR; without one
    the test needs ``noise``). ``model_error``: relative error of the model on the observations, added
    to the noise (default 0.01). ``result.fit_ratio`` > 1 says the returned fit still fails the test.

    ``restart_residual`` (deprecated): the previous rule, multi-start when
    :math:`\lVert r \rVert / \lVert u_\text{obs} \rVert` stays above it; it fired on about half the frames at
    1 % noise (issue 19). When given it decides the restart (with a DeprecationWarning) and ``fit_ratio`` is
    still reported. ``alpha``, ``restart_residual``, ``noise`` and ``model_error`` must be finite and >= 0.

    A :class:`~physar.errors.PhysarWarning` says when the returned fit leaves more than ``UNEXPLAINED``
    (half) of :math:`\lVert u_\text{obs} \rVert^2` in the residual: the model then explains less of the
    observations than it leaves unexplained, and the estimate is not to be trusted.
    """
    t0 = time.perf_counter()
    y = np.asarray(observed, float).ravel()
    if not np.all(np.isfinite(y)):
        raise PhysarError("observed displacements contain NaN or inf")
    if not 0 <= alpha < np.inf:
        raise PhysarError(f"alpha (Tikhonov weight) must be a finite number >= 0, got {alpha}")
    _check_nonneg("restart_residual", restart_residual, "relative residual")
    _check_nonneg("noise", noise, "standard deviation of the observation noise, m")
    _check_nonneg("model_error", model_error, "relative model error")
    if false_alarm is not None and not 0 <= false_alarm < 1:
        raise PhysarError(f"false_alarm (probability of a restart on a correct fit) must be in [0, 1), got "
                          f"{false_alarm}")
    if restart_residual is not None:
        warnings.warn("restart_residual (a fixed relative residual) is deprecated: it restarted on about half "
                      "the frames at 1 % noise. Leave it None: the multi-start then runs when the fit fails "
                      "a chi-square test (false_alarm=1e-3; noise=sigma in m if known, else estimated).",
                      DeprecationWarning, stacklevel=2)
    lo, hi = _bounds(model, bounds)
    mu0 = _start(model, mu0, lo, hi)
    prior = mu0 if prior is None else np.asarray(prior, float)
    fast = getattr(model, "_obs_qr", None) is not None and hasattr(model, "_coeffs")
    restarted = False
    m, p = y.size, lo.size
    with np.errstate(over="ignore"):
        yy = float(y @ y)
    if not math.isfinite(yy):
        raise PhysarError(f"observed displacements too large: their largest magnitude is {np.abs(y).max():.3g} m")
    if fast:
        Qt, R = model.observation_qr
        Fobs = model._obs
        if Fobs.shape[1] != y.size:
            raise PhysarError(f"{y.size} observed values, the observation operator has {Fobs.shape[1]}")
        z = Qt @ y
        k = z.size  # dimension of span(C F^T) (QR columns, min(m, n_modes))
        perp = max(yy - float(z @ z), 0.0)

        def ratio(c):
            e = z - R @ c
            return _fit_ratio(float(e @ e), k - p, perp, m - k, yy, m, noise, model_error, false_alarm)

        mu, c, dc, cost, it = _lm_fast(model, z, mu0, lo, hi, alpha, prior, max_iter, tol)
        fit = ratio(c)
        if restart_residual is not None:
            r = y - c @ Fobs
            bad = np.sqrt(r @ r) > restart_residual * np.sqrt(yy)
        else:
            bad = fit > 1.0
        if bad:
            restarted = True
            for start in _grid(lo, hi, n_starts):
                m2, c2, dc2, cost2, i2 = _lm_fast(model, z, start, lo, hi, alpha, prior, max_iter, tol)
                it += i2
                if cost2 < cost:
                    mu, c, dc, cost = m2, c2, dc2, cost2
            fit = ratio(c)
        r = y - c @ Fobs
        Jr = R @ dc.T
        A = Jr.T @ Jr
    else:
        def ratio(r):
            return _fit_ratio(float(r @ r), m - p, 0.0, 0, yy, m, noise, model_error, false_alarm)

        mu, r, cost, it = _lm_generic(model, y, mu0, lo, hi, alpha, prior, max_iter, tol)
        fit = ratio(r)
        if restart_residual is not None:
            bad = np.linalg.norm(r) > restart_residual * np.sqrt(yy)
        else:
            bad = fit > 1.0
        if bad:
            restarted = True
            for start in _grid(lo, hi, n_starts):
                m2, r2, c2, i2 = _lm_generic(model, y, start, lo, hi, alpha, prior, max_iter, tol)
                it += i2
                if c2 < cost:
                    mu, r, cost = m2, r2, c2
            fit = ratio(r)
        J = model.sensitivities(mu, observed=True).T
        A = J.T @ J
    if alpha:
        A = A + alpha * np.eye(mu.size)
    rr = float(r @ r)
    if rr > UNEXPLAINED * yy:
        warnings.warn(PhysarWarning(
            f"the fit leaves {_pct(rr, yy)} of the squared norm of the observed displacements unexplained "
            f"(residual {math.sqrt(rr):.3g} m, observations {math.sqrt(yy):.3g} m): the model at this estimate "
            "explains less than half of them (a wrong minimum, observations in another unit or of other points, "
            "another body or load, or noise above the signal); do not trust this estimate"), stacklevel=2)
    sigma2 = rr / max(y.size - mu.size, 1)
    cov = sigma2 * _inv_small(A)
    std = np.sqrt(np.abs(np.diag(cov)))
    return AssimilationResult(mu, float(np.sqrt(rr)), it, std, cov,
                              (time.perf_counter() - t0) * 1e6, restarted, fit)


#: fraction of :math:`\lVert u_\text{obs} \rVert^2` left in the squared residual above which :func:`assimilate`
#: warns: the fit then explains less of the observations than it leaves unexplained (a coefficient of
#: determination about zero, :math:`1 - \lVert r \rVert^2 / \lVert u_\text{obs} \rVert^2`, below 1/2), i.e.
#: the observations are mostly something the model cannot produce for any parameter value in its ranges
#: (another unit, points in the deformed instead of the reference configuration, another body or load) or
#: noise larger than the signal. Ordinary noise on a good fit leaves a few percent.
UNEXPLAINED = 0.5


def _pct(rr, yy) -> str:
    """rr / yy as a percentage ("all" when yy is 0)."""
    return f"{100 * rr / yy:.3g} %" if yy > 0 else "all"


def _grid(lo, hi, n_starts):
    axes = [np.linspace(a, b, n_starts) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, lo.size)


class Assimilator:
    """Frame-by-frame estimation with warm start from the previous frame (seed 000 §4).

    ``step(observed)`` returns an :class:`AssimilationResult`; the estimate becomes the start (and,
    with ``alpha > 0``, the Tikhonov prior) of the next frame. Other keywords (``false_alarm``, ``noise``,
    ``model_error``, ...) go to :func:`assimilate`; the multi-start runs when the fit fails its test (a
    load jump to a wrong local minimum), not on ordinary noisy frames.
    """

    def __init__(self, model, bounds=None, alpha=0.0, restart_residual=None, n_starts=7, mu0=None,
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
    """Sparse :math:`C` (3 p, n_dofs) with :math:`C u` = displacements interpolated at reference `points` (m),
    row :math:`3k + i`."""
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


def read_observations(path, body_size=None) -> tuple[np.ndarray, np.ndarray]:
    """OBS.csv with a header x,y,z,ux,uy,uz (reference point, m; measured displacement, m).

    Read as UTF-8 with or without a byte-order mark (an Excel export); lines starting with ``#`` and empty
    lines are skipped. Every data row must have as many values as the header (a longer row is not cut to
    fit), each of the six a finite number. With ``body_size`` (m, e.g. the diagonal of the bounding box of
    the model's mesh) a displacement larger than the body itself is refused: it is not a displacement of
    the body (wrong unit, a column shifted, an overflowed value), and a fit to it would report nonsense.
    Errors name the file, its line and the column.
    """
    from pathlib import Path

    from physar.errors import ConfigError

    path = Path(path)
    if not path.exists():
        raise ConfigError(f"observation file not found: {path}")
    import csv

    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            rows = [(reader.line_num, r) for r in reader]
    except (UnicodeDecodeError, csv.Error):
        raise ConfigError(f"{path}: not a text CSV file (need a header x,y,z,ux,uy,uz)") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the observation file ({exc.strerror or exc})") from None
    rows = [(n, r) for n, r in rows if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ConfigError(f"{path}: empty observation file")
    header = [h.strip().lower() for h in rows[0][1]]
    cols = ["x", "y", "z", "ux", "uy", "uz"]
    missing = [c for c in cols if c not in header]
    if missing:
        raise ConfigError(f"{path}: missing column(s) {', '.join(missing)} (need a header x,y,z,ux,uy,uz)")
    twice = [c for c in cols if header.count(c) > 1]
    if twice:  # which of the two would be read is arbitrary
        raise ConfigError(f"{path}: column(s) {', '.join(twice)} given twice in the header")
    idx = [header.index(c) for c in cols]
    data = []
    for n, r in rows[1:]:
        if len(r) != len(header):
            raise ConfigError(f"{path}: line {n}: {len(r)} values, the header has {len(header)} columns "
                              f"({','.join(header)}): {r}")
        vals = []
        for c, k in zip(cols, idx):
            try:
                v = float(r[k])
            except ValueError:
                raise ConfigError(f"{path}: line {n}, column {c}: {r[k].strip()!r} is not a number") from None
            if not math.isfinite(v):
                raise ConfigError(f"{path}: line {n}, column {c}: {r[k].strip()} is not a finite number")
            vals.append(v)
        if body_size is not None and math.hypot(*vals[3:]) > body_size:
            c = cols[3 + int(np.argmax(np.abs(vals[3:])))]
            raise ConfigError(
                f"{path}: line {n}, column {c}: displacement ({', '.join(f'{v:g}' for v in vals[3:])}) m is "
                f"larger than the body itself ({body_size:.3g} m, the diagonal of its bounding box); "
                "displacements must be in m")
        data.append(vals)
    data = np.array(data).reshape(-1, 6)
    if len(data) == 0:
        raise ConfigError(f"{path}: no observation rows")
    return data[:, :3], data[:, 3:]


__all__ = ["AssimilationResult", "Assimilator", "assimilate", "observation_matrix", "read_observations"]
