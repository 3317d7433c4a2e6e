"""SeparatedModel evaluation: precomputed piecewise cubics vs scipy, sensitivities vs finite differences."""
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from physar.assimilation import _lm_generic, assimilate
from physar.errors import PhysarError
from physar.rom import SeparatedModel


def _model(p, n=19, m=90, seed=0):
    rng = np.random.default_rng(seed)
    grids = [np.sort(np.concatenate([[0.0, 1.0], rng.uniform(0, 1, 20 + 5 * j)])) for j in range(p)]
    G = [np.array([np.cos((i % 5 + 1) * x + j) + 0.1 * i for i in range(n)]) for j, x in enumerate(grids)]
    return SeparatedModel(rng.normal(size=(n, m)), grids, G, [f"p{j}" for j in range(p)])


@pytest.mark.parametrize("p", [1, 2, 3])
def test_coefficients_match_scipy_spline(p):
    model = _model(p)
    rng = np.random.default_rng(1)
    for _ in range(20):
        mu = rng.uniform(-0.05, 1.05, p)  # includes extrapolation beyond both ends
        vals = [CubicSpline(x, g, axis=1)(m) for x, g, m in zip(model.grids, model.G, mu)]
        ders = [CubicSpline(x, g, axis=1).derivative()(m) for x, g, m in zip(model.grids, model.G, mu)]
        c, dc = model.coefficients(mu)
        np.testing.assert_allclose(c, np.prod(vals, axis=0), rtol=1e-12, atol=1e-12)
        for j in range(p):
            ref = ders[j] * np.prod([vals[k] for k in range(p) if k != j], axis=0)
            np.testing.assert_allclose(dc[j], ref, rtol=1e-12, atol=1e-12)
    # knots themselves (interval bisection at the boundaries)
    for j, x in enumerate(model.grids):
        mu = np.full(p, 0.5)
        for xk in (x[0], x[5], x[-1]):
            mu[j] = xk
            c, _ = model.coefficients(mu)
            ref = np.prod([CubicSpline(xx, g, axis=1)(m) for xx, g, m in zip(model.grids, model.G, mu)],
                          axis=0)
            np.testing.assert_allclose(c, ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("p", [1, 2, 3])
def test_sensitivities_equal_finite_differences(p):
    model = _model(p)
    model.set_observation(dofs=np.arange(0, 90, 3))
    rng = np.random.default_rng(2)
    for _ in range(5):
        mu = rng.uniform(0.05, 0.95, p)
        for observed in (False, True):
            S = model.sensitivities(mu, observed=observed)
            for j in range(p):
                h = 1e-6
                e = np.eye(p)[j] * h
                fd = (model.evaluate(mu + e, observed=observed) - model.evaluate(mu - e, observed=observed)) / (2 * h)
                assert np.linalg.norm(S[j] - fd) / np.linalg.norm(S[j]) < 1e-5


@pytest.mark.parametrize("p", [1, 2])
def test_fast_lm_agrees_with_generic_lm(p):
    """The reduced (QR) LM path and the plain LM on evaluate/sensitivities find the same minimiser."""
    model = _model(p, n=8, m=60)
    model.set_observation(dofs=np.arange(60))
    rng = np.random.default_rng(3)
    for _ in range(5):
        mu_true = rng.uniform(0.2, 0.8, p)
        y = model.evaluate(mu_true, observed=True) + rng.normal(0, 1e-3, 60)
        mu0 = mu_true + rng.uniform(-0.05, 0.05, p)
        fast = assimilate(model, y, mu0=mu0)
        lo, hi = np.zeros(p), np.ones(p)
        mu_g, r_g, _, _ = _lm_generic(model, y, mu0, lo, hi, 0.0, mu0, 50, 1e-12)
        np.testing.assert_allclose(fast.params, mu_g, atol=1e-7)
        assert abs(fast.residual - np.linalg.norm(r_g)) < 1e-9


def test_observation_shape_error():
    model = _model(1)
    model.set_observation(dofs=[0, 1, 2])
    with pytest.raises(PhysarError, match="observed values"):
        assimilate(model, np.zeros(4))
