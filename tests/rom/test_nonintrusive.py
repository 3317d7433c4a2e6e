"""Non-intrusive PGD (seed 000 §5.3) vs full nonlinear solves; separated fit vs closed forms; Dask."""
import os

import numpy as np
import pytest

from physar.errors import ConfigError
from physar.fem import ElasticModel, FESpace, LinearElastic, NeoHookean, StVK, fixed_dofs
from physar.geometry import box_mesh
from physar.rom.nonintrusive import (
    MovingLoadProblem,
    SnapshotRunner,
    build_moving_load_nonintrusive,
    nonintrusive_pgd,
    separated_fit,
)

L, W, H = 1.0, 0.1, 0.1
PATH = [[0.0, W / 2, H], [L, W / 2, H]]
R = 0.1


def _beam(material):
    space = FESpace(box_mesh((L, W, H), (10, 1, 1)), "P2")
    fixed = fixed_dofs(space, box=[[-1e-9, -1, -1], [1e-9, 1, 1]])
    return space, ElasticModel(space, material), fixed


@pytest.mark.parametrize("p", [2, 3])
def test_separated_fit_recovers_closed_form(p):
    rng = np.random.default_rng(0)
    axes = [np.linspace(0, 1, 7 + j) for j in range(p)]
    # T = sum of 3 separable terms with known factors
    T = 0
    for k in range(3):
        f = rng.normal(size=40)
        gs = [np.cos((k + 1) * a + j) for j, a in enumerate(axes)]
        T = T + np.einsum("z," + ",".join("abc"[:p]) + "->z" + "abc"[:p], f, *gs)
    F, G, rels = separated_fit(T, max_modes=20, fit_tol=1e-10)
    rebuilt = sum(np.einsum("z," + ",".join("abc"[:p]) + "->z" + "abc"[:p], F[i], *[g[i] for g in G])
                  for i in range(F.shape[0]))
    assert np.linalg.norm(rebuilt - T) / np.linalg.norm(T) < 1e-8
    assert rels[-1] < 1e-8


def test_nonintrusive_closed_form_two_parameters():
    x = np.linspace(0, 1, 50)

    def bb(mu):
        return np.tanh(mu[1] * np.sin(np.pi * x)) * np.exp(-((x - mu[0]) / 0.4) ** 2)

    rom, info = nonintrusive_pgd(bb, [(0, 1), (0.5, 2)], ["a", "b"], tol=1e-3, max_points=33)
    rng = np.random.default_rng(1)
    errs = [np.linalg.norm(rom.evaluate(m) - bb(m)) / np.linalg.norm(bb(m))
            for m in rng.uniform([0, 0.5], [1, 2], (30, 2))]
    assert max(errs) < 1e-2 and info["error_estimate"] <= 1e-3
    assert info["n_solves"] == np.prod([g.size for g in info["grids"]])


@pytest.mark.parametrize("material", [StVK(E=1e7, nu=0.3), NeoHookean(E=1e7, nu=0.3)], ids=["stvk", "neohookean"])
def test_nonlinear_beam_moving_load_matches_full_solves(material):
    space, model, fixed = _beam(material)
    load = (0, 0, -60.0)  # tip deflection ~ 17 % of the length: geometrically nonlinear
    rom, info = build_moving_load_nonintrusive(model, fixed, PATH, load=load, radius=R, tol=2e-3)
    assert info["error_estimate"] <= 2e-3
    full = MovingLoadProblem(model, fixed, PATH, load, R)
    lin = MovingLoadProblem(ElasticModel(space, LinearElastic(E=1e7, nu=0.3)), fixed, PATH, load, R)
    ss = np.random.default_rng(2).uniform(0, L, 8)
    U = [full([s]) for s in ss]
    scale = max(np.linalg.norm(u) for u in U)
    for s, u in zip(ss, U):
        e = np.linalg.norm(rom.evaluate([s]) - u)
        assert e / scale <= 1e-2
        if s > 0.2 * L:
            assert e / np.linalg.norm(u) <= 1e-2
    # the problem is really nonlinear: the linear response differs by more than the tolerance
    s_tip = ss.argmax()
    assert np.linalg.norm(lin([ss[s_tip]]) - U[s_tip]) / np.linalg.norm(U[s_tip]) > 0.05


@pytest.mark.slow
def test_stvk_two_parameters_position_and_magnitude():
    _, model, fixed = _beam(StVK(E=1e7, nu=0.3))
    rom, info = build_moving_load_nonintrusive(model, fixed, PATH, load=(0, 0, -1.0), radius=R,
                                               magnitude_range=(10.0, 60.0), tol=2e-3)
    assert info["error_estimate"] <= 2e-3
    full = MovingLoadProblem(model, fixed, PATH, (0, 0, -1.0), R, magnitude=True)
    mus = np.random.default_rng(3).uniform([0, 10], [L, 60], (10, 2))
    U = [full(m) for m in mus]
    scale = max(np.linalg.norm(u) for u in U)
    assert max(np.linalg.norm(rom.evaluate(m) - u) for m, u in zip(mus, U)) / scale <= 1e-2


def _max_blas_threads():
    import numpy  # noqa: F401  (load numpy's BLAS in the worker)
    from threadpoolctl import threadpool_info

    return max(i["num_threads"] for i in threadpool_info())


@pytest.mark.slow
def test_dask_local_cluster_and_scheduler_match_serial():
    from distributed import LocalCluster

    _, model, fixed = _beam(StVK(E=1e7, nu=0.3))
    bb = MovingLoadProblem(model, fixed, PATH, (0, 0, -60.0), R)
    pts = [(s,) for s in np.linspace(0, L, 6)]
    serial = SnapshotRunner(bb).run(pts)
    with SnapshotRunner(bb, workers=2) as runner:
        par = runner.run(pts)
        # one BLAS/OpenMP thread per worker process, set before the libraries load
        envs = runner.client.run(lambda: (os.environ.get("OPENBLAS_NUM_THREADS"), os.environ.get("OMP_NUM_THREADS")))
        assert len(envs) == 2 and all(e == ("1", "1") for e in envs.values()), envs
        threads = runner.client.run(_max_blas_threads)
        assert all(n == 1 for n in threads.values()), threads
    for a, b in zip(serial, par):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    with (LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None) as cluster,
          SnapshotRunner(bb, scheduler=cluster.scheduler_address) as runner):
        par = runner.run(pts)
    for a, b in zip(serial, par):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)


def test_bad_inputs():
    with pytest.raises(ConfigError, match="1 to 3 parameters"):
        nonintrusive_pgd(lambda m: m, [(0, 1)] * 4, list("abcd"))
    with pytest.raises(ConfigError, match="range must be increasing"):
        nonintrusive_pgd(lambda m: m, [(1, 0)], ["a"])
    with pytest.raises(ConfigError, match="workers must be >= 1"):
        SnapshotRunner(lambda m: m, workers=0)
