"""The Warp CPU backend of the co-rotated P1 kernel and the fast SI path (warm-started, single-thread
rotated PCG) against independent references: physar.fem's assembled Corotated forces and linear-elastic
stiffness, closed forms under a rigid rotation, and the numpy kernel with direct CHOLMOD solves."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from physar.errors import ConfigError
from physar.fem import Corotated, ElasticModel, FESpace, LinearElastic, fixed_dofs
from physar.geometry import box_mesh
from physar.integrators import SolidModel, make_integrator, simulate
from physar.integrators.linalg import SparseSolver
from physar.integrators.model import CorotatedP1Kernel

pytest.importorskip("warp")


def _elastic(cells=(4, 2, 2), size=(1.0, 0.3, 0.2), E=2e6, nu=0.35):
    sp_ = FESpace(box_mesh(size, cells), "P1")
    return sp_, ElasticModel(sp_, Corotated(E, nu), density=1000.0)


def test_warp_forces_energy_match_fem_corotated_including_inverted():
    sp_, el = _elastic()
    k = CorotatedP1Kernel(el, backend="warp")
    rng = np.random.default_rng(1)
    for s in (1e-4, 0.05, 0.2):  # 0.2: some elements inverted -> the SVD polar fallback
        u = s * rng.normal(size=sp_.n_dofs)
        f_ref = el.internal_force(u)
        np.testing.assert_allclose(k.force(u), f_ref, atol=1e-11 * np.abs(f_ref).max())
        assert k.energy(u) == pytest.approx(el.energy(u), rel=1e-11)
    F = k._F(u)
    assert np.any(np.linalg.det(F) <= 0)  # the fallback was exercised


def test_warp_warped_tangent_under_rigid_rotation_is_rotated_linear_stiffness():
    """At u = rigid rotation Q, every element's R = Q: K = blockdiag(Q) K_lin blockdiag(Q)ᵀ with K_lin the
    linear-elastic stiffness of physar.fem (closed form); the matrix-free product and node frames agree."""
    sp_, el = _elastic()
    k = CorotatedP1Kernel(el, tangent="warped", backend="warp")
    Q = Rotation.from_rotvec([0.4, -1.3, 0.9]).as_matrix()
    X = sp_.nodes
    u = (X @ Q.T - X).ravel()
    f, K = k.force_tangent(u)
    K_lin = ElasticModel(sp_, LinearElastic(2e6, 0.35)).tangent_stiffness()
    BQ = sp.block_diag([Q] * len(X), format="csr")
    ref = BQ @ K_lin @ BQ.T
    assert abs(K - ref).max() < 1e-10 * abs(ref).max()
    assert np.abs(f).max() < 1e-9 * 2e6 * 0.06
    v = np.random.default_rng(3).normal(size=sp_.n_dofs)
    np.testing.assert_allclose(k.tangent_matvec(u, v), ref @ v, atol=1e-10 * np.abs(ref @ v).max())
    Rn = k.node_rotations(u)
    np.testing.assert_allclose(Rn, np.broadcast_to(Q, Rn.shape), atol=1e-12)


def test_warp_and_numpy_tangents_agree_on_a_deformed_state():
    sp_, el = _elastic(cells=(5, 2, 3))
    rng = np.random.default_rng(4)
    u = 0.03 * rng.normal(size=sp_.n_dofs)
    for tangent in ("warped", "exact"):
        fn, Kn = CorotatedP1Kernel(el, tangent).force_tangent(u)
        fw, Kw = CorotatedP1Kernel(el, tangent, backend="warp").force_tangent(u)
        np.testing.assert_allclose(fw, fn, atol=1e-12 * np.abs(fn).max())
        assert abs(Kw - Kn).max() < 1e-12 * abs(Kn).max()


def _hinged_beam(backend, cells=(10, 2, 2), tangent="warped"):
    """A soft bar 1 x 0.1 x 0.1 m hinged on its top edge at x = 0, released horizontally: it swings down."""
    sp_ = FESpace(box_mesh((1.0, 0.1, 0.1), cells), "P1")
    el = ElasticModel(sp_, Corotated(2e5, 0.3), density=1000.0)
    fixed = fixed_dofs(sp_, box=[[0, 0, 0.1], [0, 0.1, 0.1]])
    return SolidModel(el, fixed, gravity=(0, 0, -9.81), tangent=tangent, backend=backend)


@pytest.mark.parametrize("method,tangent", [("si", "warped"), ("be", "exact")])
def test_fast_path_swing_matches_numpy_direct(method, tangent):
    """The swing (rotation past 60°): warp kernel + warm-started single-thread rotated PCG against the
    numpy kernel with a direct CHOLMOD solve of every step."""
    ref_model = _hinged_beam("numpy", tangent=tangent)
    ref = simulate(ref_model, make_integrator(method, linear_solver="direct", tol=1e-10), 1 / 30, 15)
    model = _hinged_beam("warp", tangent=tangent)
    integ = make_integrator(method, linear_solver="pcg", linear_rtol=1e-10, tol=1e-10, warm_start=True)
    s = simulate(model, integ, 1 / 30, 15)
    tip = np.flatnonzero(np.isclose(model.space.nodes[:, 0], 1.0))
    drop = -ref.q[3 * tip + 2].mean()
    assert drop > 0.85  # the free end fell by more than sin 60° of the 1 m bar
    assert np.abs(s.q - ref.q).max() < 1e-7 * np.abs(ref.q).max()
    assert np.abs(s.v - ref.v).max() < 1e-6 * np.abs(ref.v).max()
    assert integ.solver.n_factorizations < 15 / 3 and integ.solver.n_cg_iterations > 0
    assert integ._guess  # the warm start was in use


def test_cg_warm_start_guess_and_bad_guess():
    rng = np.random.default_rng(2)
    n = 80
    B = sp.random(n, n, density=0.1, random_state=3)
    A = (B @ B.T + sp.eye(n) * 5).tocsr()
    b = rng.normal(size=n)
    x_ref = SparseSolver().solve(A, b)
    s = SparseSolver("pcg", rtol=1e-12)
    s.solve(A, b)  # factor A: later solves are CG
    A2 = (A + 0.5 * sp.diags(rng.uniform(0, 1, n))).tocsr()
    x2 = SparseSolver().solve(A2, b)
    it0 = s.n_cg_iterations
    np.testing.assert_allclose(s.solve(A2, b, x0=x2), x2, rtol=1e-10, atol=1e-12)
    assert s.n_cg_iterations - it0 <= 1  # exact guess: (at most) one iteration
    for bad in (1e6 * x_ref, np.full(n, np.nan), np.zeros(n + 1)):  # ignored guesses
        np.testing.assert_allclose(s.solve(A2, b, x0=bad), x2, rtol=1e-9, atol=1e-11)
    with pytest.raises(ConfigError, match="threads"):
        SparseSolver("pcg", threads=0)


def test_backend_errors():
    _, el = _elastic()
    with pytest.raises(ConfigError, match="backend"):
        CorotatedP1Kernel(el, backend="cuda")
    with pytest.raises(ConfigError, match="backend"):
        SolidModel(el, backend="torch")


def test_pcg_matches_scipy_cg_and_flags_indefinite():
    """The written-out PCG against scipy.sparse.linalg.cg (peer): same solution, same iteration count
    to within one; an indefinite matrix is reported as not converged."""
    import scipy.sparse.linalg as spla

    from physar.integrators.linalg import pcg

    rng = np.random.default_rng(5)
    n = 120
    B = sp.random(n, n, density=0.05, random_state=6)
    A = (B @ B.T + sp.diags(rng.uniform(0.1, 10, n))).tocsr()
    b = rng.normal(size=n)
    d = A.diagonal()

    def prec(r):
        return r / d

    x, its, ok = pcg(A, b, prec, 1e-10, 500)
    count = []
    x_ref, info = spla.cg(A, b, rtol=1e-10, atol=0.0, maxiter=500, callback=count.append,
                          M=spla.LinearOperator((n, n), matvec=prec, dtype=float))
    assert ok and info == 0
    np.testing.assert_allclose(x, x_ref, rtol=1e-8, atol=1e-10 * np.abs(x_ref).max())
    assert abs(its - len(count)) <= 1
    assert np.linalg.norm(b - A @ x) <= 1e-10 * np.linalg.norm(b)
    _, _, ok = pcg(sp.diags(np.r_[np.ones(n - 1), -1.0]).tocsr(), np.ones(n), lambda r: r, 1e-10, 50)
    assert not ok


def test_solid_model_linearization_warp_free_pattern_matches_numpy():
    """SolidModel with the warp backend assembles the warped tangent straight into the free-dof pattern
    from its second linearisation on: the Newton matrix equals the numpy kernel's (restricted full K)."""
    sp_, el = _elastic(cells=(5, 2, 3))
    fixed = fixed_dofs(sp_, box=[[0, 0, 0], [0, 0.3, 0.2]])
    rng = np.random.default_rng(7)
    mods = {b: SolidModel(el, fixed, tangent="warped", backend=b, rayleigh=(0.2, 0.01)) for b in ("numpy", "warp")}
    for _ in range(2):
        u = 0.03 * rng.normal(size=sp_.n_dofs)
        v = rng.normal(size=sp_.n_dofs)
        lins = {b: m.linearize(u, v) for b, m in mods.items()}
        A = {b: mods[b].system_matrix(lins[b], 1.0, 0.05, 0.0025) for b in mods}
        assert abs(A["warp"] - A["numpy"]).max() < 1e-12 * abs(A["numpy"]).max()
        np.testing.assert_allclose(lins["warp"].f, lins["numpy"].f, atol=1e-12 * np.abs(lins["numpy"].f).max())
    assert mods["warp"].kernel._wk.has_slots(("free", id(mods["warp"]._fp)))


NEWTON = """
[dynamics.newton]
linear_solver = "pcg"
linear_rtol = 1e-12
tangent = "warped"
"""


def test_config_backend_warp_matches_numpy(tmp_path, drop_config):
    """[dynamics] backend = "warp": a cube dropped on the penalty ground, same energies as numpy."""
    from physar.integrators.config import build_simulation, load_dynamics_config, run_simulation

    energy = {}
    for backend in ("numpy", "warp"):
        path = tmp_path / f"{backend}.toml"
        path.write_text(drop_config("si", f'backend = "{backend}"', NEWTON))
        sim = build_simulation(load_dynamics_config(path))
        assert sim.model.kernel.backend == backend
        energy[backend] = np.array([r["total"] for r in run_simulation(sim).energy])
    np.testing.assert_allclose(energy["warp"], energy["numpy"], rtol=1e-9)
    path = tmp_path / "bad.toml"
    path.write_text(drop_config("si", 'backend = "cuda"', NEWTON))
    with pytest.raises(Exception, match="backend"):
        load_dynamics_config(path)
