"""Sparse machinery of the steppers: free-dof pattern arithmetic and the rotated-PCG linear solver."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from physar.errors import ConfigError
from physar.fem import Corotated, ElasticModel, FESpace, fixed_dofs
from physar.geometry import box_mesh
from physar.integrators import Ground, SolidModel, make_integrator, simulate
from physar.integrators.linalg import BlockRotation, SparseSolver
from physar.integrators.model import restrict


def _beam(cells=(8, 2, 2), **kw):
    sp_ = FESpace(box_mesh((1.0, 0.1, 0.1), cells), "P1")
    el = ElasticModel(sp_, Corotated(1e5, 0.3), density=1000.0)
    fixed = fixed_dofs(sp_, box=[[0, 0, 0], [0, 0.1, 0.1]])
    return SolidModel(el, fixed, **kw), sp_


def test_system_matrix_equals_sparse_sum_reference():
    """cm M + cd (alpha M + beta K) + ck (K + ground) on the free dofs, vs scipy indexing and sums."""
    model, sp_ = _beam(mass="consistent", rayleigh=(0.3, 0.01), gravity=(0, 0, -9.81),
                       ground=Ground(z0=0.02, stiffness=3e3))
    rng = np.random.default_rng(0)
    q = 0.01 * rng.normal(size=model.n_dofs)
    q[model.fixed] = 0
    lin = model.linearize(q, np.zeros(model.n_dofs))
    A = model.system_matrix(lin, 1.0, 0.1, 0.01)
    _, K = model.kernel.force_tangent(q)
    K_ff = restrict(K, model.free)
    M_ff = restrict(model.mass, model.free)
    z = sp_.nodes[:, 2] + q[2::3]
    g = np.zeros(model.n_dofs)
    g[3 * np.flatnonzero(z < 0.02) + 2] = 3e3
    G_ff = sp.diags(g[model.free])
    ref = (1.0 + 0.1 * 0.3) * M_ff + 0.1 * 0.01 * K_ff + 0.01 * (K_ff + G_ff)
    assert G_ff.nnz > 0
    assert abs(A - ref).max() < 1e-12 * abs(ref).max()
    # the same pattern at every call (CHOLMOD's symbolic analysis is reused)
    A2 = model.system_matrix(model.linearize(2 * q, q), 1.0, 0.2, 0.02)
    assert np.array_equal(A.indptr, A2.indptr) and np.array_equal(A.indices, A2.indices)


def test_node_rotations_of_a_rigid_rotation():
    model, sp_ = _beam()
    R = Rotation.from_rotvec([0.4, -1.3, 0.9]).as_matrix()
    X = sp_.nodes
    q = (X @ R.T - X).ravel()
    Rn = model.kernel.node_rotations(q)
    np.testing.assert_allclose(Rn, np.broadcast_to(R, Rn.shape), atol=1e-12)
    Q = model.frame(q)
    x = np.random.default_rng(1).normal(size=len(model.free))
    np.testing.assert_allclose(Q.mul_t(Q.mul(x)), x, atol=1e-12)  # orthogonal on the free dofs
    np.testing.assert_allclose(np.linalg.norm(Q.mul(x)), np.linalg.norm(x), rtol=1e-13)


def test_block_rotation_partially_pinned_node_keeps_identity():
    R = np.broadcast_to(Rotation.from_rotvec([0, 0, 1.0]).as_matrix(), (2, 3, 3))
    free = np.array([0, 1, 3, 4, 5])  # node 0 has z pinned
    Q = BlockRotation(R, free, 6)
    x = np.arange(1.0, 6.0)
    y = Q.mul(x)
    np.testing.assert_allclose(y[:2], x[:2])
    np.testing.assert_allclose(y[2:], R[1] @ x[2:])


def test_pcg_solver_matches_direct_on_a_spd_sequence():
    rng = np.random.default_rng(2)
    n = 60
    B = sp.random(n, n, density=0.1, random_state=3)
    A0 = (B @ B.T + sp.eye(n) * 5).tocsr()
    s_pcg, s_dir = SparseSolver("pcg", rtol=1e-12, refactor_iters=8), SparseSolver()
    for k in range(6):
        A = (A0 + k * 0.3 * sp.diags(rng.uniform(0, 1, n))).tocsr()
        b = rng.normal(size=n)
        np.testing.assert_allclose(s_pcg.solve(A, b), s_dir.solve(A, b), rtol=1e-9, atol=1e-11)
    assert s_pcg.n_factorizations < 6 and s_pcg.n_cg_iterations > 0
    with pytest.raises(ConfigError, match="pcg"):
        SparseSolver("gmres")


@pytest.mark.parametrize("method", ["si", "be", "genalpha"])
def test_pcg_trajectory_matches_direct(method):
    """A beam swinging under gravity (large rotations): rotated-PCG solves give the direct trajectory
    with a fraction of the factorisations."""
    out = {}
    for ls in ("direct", "pcg"):
        model, _ = _beam(gravity=(0, 0, -9.81), tangent="warped" if method == "si" else "exact")
        integ = make_integrator(method, linear_solver=ls, linear_rtol=1e-11, tol=1e-10)
        s = simulate(model, integ, 0.02, 25)
        out[ls] = (s.q, integ.stats)
    q_d, q_p = out["direct"][0], out["pcg"][0]
    assert np.abs(q_d[2::3]).max() > 0.3  # a large swing
    assert np.abs(q_p - q_d).max() < 1e-7 * np.abs(q_d).max()
    assert out["pcg"][1].factorizations < out["direct"][1].factorizations / 3
