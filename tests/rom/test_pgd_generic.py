import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from physar.errors import PhysarError
from physar.rom import SeparatedModel, pgd_linear, pgd_linear_tensor


def _problem(n=200):
    # 1-D Laplacian (SPD) with a moving regularised point load as right-hand side
    K = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr() * n
    x = np.linspace(0, 1, n)
    grid = np.linspace(0.1, 0.9, 81)
    B = np.exp(-((x[:, None] - grid[None, :]) / 0.05) ** 2)  # (n, n_grid)
    U, S, Vt = np.linalg.svd(B, full_matrices=False)
    r = np.searchsorted(-S / S[0], -1e-12)
    return K, (U[:, :r] * S[:r]).T, Vt[:r], grid, x


def test_pgd_matches_direct_solves():
    K, f, g, grid, x = _problem()
    model, info = pgd_linear(K, f, g, grid, max_modes=20, tol=1e-6)
    assert model.n_modes <= 20
    rng = np.random.default_rng(0)
    lu = spla.splu(K.tocsc())
    errs = []
    for s in rng.uniform(0.1, 0.9, 50):
        u = lu.solve(np.exp(-((x - s) / 0.05) ** 2))
        errs.append(np.linalg.norm(model.evaluate([s]) - u) / np.linalg.norm(u))
    assert max(errs) < 1e-3
    a = info["amplitudes"]
    assert a[-1] < 1e-2 * a[0]
    assert np.all(a[2:] < a[:-2])  # decreasing (greedy PGD amplitudes may alternate by one)


def test_sensitivities_equal_finite_differences():
    K, f, g, grid, _ = _problem()
    model, _ = pgd_linear(K, f, g, grid, max_modes=10)
    for s in (0.23, 0.5, 0.71):
        h = 1e-6
        fd = (model.evaluate([s + h]) - model.evaluate([s - h])) / (2 * h)
        d = model.sensitivities([s])[0]
        assert np.linalg.norm(d - fd) / np.linalg.norm(d) < 1e-5
    model.set_observation(dofs=[3, 50, 120])
    np.testing.assert_allclose(model.evaluate([0.4], observed=True), model.evaluate([0.4])[[3, 50, 120]])


def test_save_load_roundtrip_and_errors(tmp_path):
    K, f, g, grid, _ = _problem(50)
    model, _ = pgd_linear(K, f, g, grid, max_modes=5)
    p = tmp_path / "m.npz"
    model.metadata["material"] = "linear"
    model.save(p)
    m2 = SeparatedModel.load(p)
    np.testing.assert_array_equal(m2.evaluate([0.3]), model.evaluate([0.3]))
    assert m2.metadata["material"] == "linear"
    np.savez(tmp_path / "bad.npz", format_version=np.array(99))
    with pytest.raises(PhysarError, match="version 99"):
        SeparatedModel.load(tmp_path / "bad.npz")


def test_pgd_tensor_two_parameters_matches_direct_solves():
    """Two-parameter intrusive PGD (position s and width t of the load, not separable in s, t)."""
    n = 200
    K = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr() * n
    x = np.linspace(0, 1, n)
    s, t = np.linspace(0.1, 0.9, 41), np.linspace(0.04, 0.08, 9)

    def load(a, b):
        return np.exp(-((x - a) / b) ** 2)

    B = np.stack([load(a, b) for a in s for b in t], 1)
    model, info = pgd_linear_tensor(K, B, [s, t], max_modes=40, tol=1e-6, names=["s", "t"])
    lu = spla.splu(K.tocsc())
    mus = np.random.default_rng(0).uniform([0.1, 0.04], [0.9, 0.08], (30, 2))
    U = [lu.solve(load(*m)) for m in mus]
    ref = max(np.linalg.norm(u) for u in U)
    errs = [np.linalg.norm(model.evaluate(m) - u) / ref for m, u in zip(mus, U)]
    assert max(errs) < 1e-3, max(errs)
    assert model.names == ["s", "t"] and model.n_modes <= 40
    a = info["amplitudes"]
    assert a[-1] < 1e-3 * a[0]
    # sensitivities of the two-parameter model equal finite differences
    m, h = np.array([0.37, 0.061]), 1e-6
    d = model.sensitivities(m)
    for j in range(2):
        e = np.eye(2)[j] * h
        fd = (model.evaluate(m + e) - model.evaluate(m - e)) / (2 * h)
        assert np.linalg.norm(d[j] - fd) / np.linalg.norm(d[j]) < 1e-5
