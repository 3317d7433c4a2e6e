import numpy as np
import pytest

from physar.fem import ElasticModel, FESpace, LinearElastic, LinearSolver, fixed_dofs, point_load
from physar.geometry import box_mesh
from physar.rom.elastic import build_moving_load_pgd

L, W, H = 1.0, 0.1, 0.1
PATH = [[0.0, W / 2, H], [L, W / 2, H]]


def _setup(cells):
    space = FESpace(box_mesh((L, W, H), cells), "P1")
    model = ElasticModel(space, LinearElastic(E=1e7, nu=0.3))
    fixed = fixed_dofs(space, box=[[-1e-9, -1, -1], [1e-9, 1, 1]])
    return space, model, fixed


@pytest.fixture(scope="module")
def rom():
    space, model, fixed = _setup((16, 2, 2))
    m, info = build_moving_load_pgd(model, fixed, PATH, points=81, load=(0, 0, -1.0), radius=0.08,
                                    max_modes=20, tol=1e-5)
    return space, model, fixed, m, info


def test_pgd_matches_full_solves(rom):
    space, model, fixed, m, info = rom
    assert m.n_modes <= 20
    solver = LinearSolver(model, fixed)
    errs, norms, ss = [], [], np.random.default_rng(1).uniform(0, L, 50)
    for s in ss:
        u = solver.solve(point_load(space, [s, W / 2, H], (0, 0, -1.0), 0.08))
        errs.append(np.linalg.norm(m.evaluate([s]) - u))
        norms.append(np.linalg.norm(u))
    errs, norms = np.array(errs), np.array(norms)
    # error relative to the largest response over the parameter domain (L2 norm)
    assert errs.max() / norms.max() < 1e-3
    # pointwise relative error away from the clamp (near it u -> 0 and the ratio is ill-conditioned)
    far = ss > 0.1 * L
    assert np.all(errs[far] / norms[far] < 1e-3), (errs / norms).max()
    a = info["amplitudes"]
    assert a[-1] < 1e-3 * a[0] and np.all(a[2:] < a[:-2])


def test_sensitivity_fd(rom):
    m = rom[3]
    for s in (0.3, 0.77):
        h = 1e-6
        fd = (m.evaluate([s + h]) - m.evaluate([s - h])) / (2 * h)
        d = m.sensitivities([s])[0]
        assert np.linalg.norm(d - fd) / np.linalg.norm(d) < 1e-5


@pytest.mark.slow
def test_two_parameter_patch_load_matches_full_solves():
    """Load point on a 1 x 0.2 m patch of the top face (s along the beam, lateral offset t: bending and
    torsion), intrusive two-parameter PGD vs full solves at 30 random (s, t). Measured 7e-4 with 30
    modes and 4e-4 with 40 (20 POD modes of the grid snapshots would reach 2e-4: the greedy sum in two
    parameters is slower than the optimal basis)."""
    Wp = 0.3
    space = FESpace(box_mesh((L, Wp, H), (16, 5, 2)), "P2")
    model = ElasticModel(space, LinearElastic(E=1e7, nu=0.3))
    fixed = fixed_dofs(space, box=[[-1e-9, -1, -1], [1e-9, 1, 1]])
    m, info = build_moving_load_pgd(model, fixed, [[0, Wp / 2, H], [L, Wp / 2, H]], points=41,
                                    load=(0, 0, -1.0), radius=0.08, max_modes=40, tol=1e-6,
                                    offset_range=(-0.1, 0.1), offset_dir=(0, 1, 0), offset_points=11, n_check=5)
    assert m.names == ["s", "t"] and m.n_modes <= 40 and info["check_error"] < 1e-3
    mus = np.random.default_rng(1).uniform([0, -0.1], [L, 0.1], (30, 2))
    U = LinearSolver(model, fixed).solve(
        np.stack([point_load(space, [a, Wp / 2 + b, H], (0, 0, -1.0), 0.08) for a, b in mus], 1))
    ref = np.linalg.norm(U, axis=0).max()
    errs = [np.linalg.norm(m.evaluate(mu) - U[:, k]) / ref for k, mu in enumerate(mus)]
    assert max(errs) < 1e-3, max(errs)
    # the offset matters: the responses at t = +0.1 and t = -0.1 differ by more than 5 % (7 % measured)
    u_plus, u_minus = m.evaluate([0.8, 0.1]), m.evaluate([0.8, -0.1])
    assert np.linalg.norm(u_plus - u_minus) > 0.05 * np.linalg.norm(u_plus)


def test_error_estimate_stops_the_enrichment():
    """Second stopping criterion (seed §3): full solves at 8 random s; the enrichment stops once their
    error is <= 1e-3 although the amplitude criterion (1e-12) is far from met; the model then holds
    2e-3 at 40 other random s (an estimate from 8 points, not a bound)."""
    space, model, fixed = _setup((16, 2, 2))
    m, info = build_moving_load_pgd(model, fixed, PATH, points=81, load=(0, 0, -1.0), radius=0.08,
                                    max_modes=20, tol=1e-12, n_check=8, check_tol=1e-3, seed=3)
    errs = info["check_errors"]
    assert len(errs) == m.n_modes < 20 and errs[-1] <= 1e-3 < errs[-2] and info["check_error"] == errs[-1]
    solver = LinearSolver(model, fixed)
    ss = np.random.default_rng(4).uniform(0, L, 40)
    U = solver.solve(np.stack([point_load(space, [s, W / 2, H], (0, 0, -1.0), 0.08) for s in ss], 1))
    e = max(np.linalg.norm(m.evaluate([s]) - U[:, k]) for k, s in enumerate(ss))
    assert e / np.linalg.norm(U, axis=0).max() < 2e-3
