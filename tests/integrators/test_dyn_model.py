"""The FEM dynamics model: co-rotated forces (invariance, peer with physar.fem), mass, gravity, contact."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from physar.errors import ConfigError
from physar.fem import Corotated, ElasticModel, FESpace, LinearElastic, fixed_dofs, polar
from physar.geometry import box_mesh
from physar.integrators import Ground, SolidModel, make_integrator, simulate
from physar.integrators.model import CorotatedP1Kernel, FemKernel, fast_polar


def _space(element="P1", cells=(4, 2, 2), size=(1.0, 0.3, 0.2)):
    return FESpace(box_mesh(size, cells), element)


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_corotated_forces_rigid_motion_invariance(element):
    sp_ = _space(element)
    el = ElasticModel(sp_, Corotated(1e6, 0.3), density=1000.0)
    kernel = CorotatedP1Kernel(el) if element == "P1" else FemKernel(el)
    X = sp_.nodes
    R = Rotation.from_rotvec([0.7, -1.1, 2.3]).as_matrix()
    t = np.array([0.3, -2.0, 5.0])
    u_rigid = (X @ R.T + t - X).ravel()
    scale = 1e6 * 0.06  # E x typical area: force scale [N]
    assert np.abs(kernel.force(u_rigid)).max() < 1e-9 * scale
    assert kernel.energy(u_rigid) < 1e-12 * 1e6 * 0.06
    rng = np.random.default_rng(0)
    u = 0.02 * rng.normal(size=sp_.n_dofs)
    f = kernel.force(u)
    # forces sum to zero (translation invariance) and their moment about the origin vanishes
    x = (X.ravel() + u).reshape(-1, 3)
    fr = f.reshape(-1, 3)
    assert np.abs(fr.sum(axis=0)).max() < 1e-9 * np.abs(f).max()
    assert np.abs(np.cross(x, fr).sum(axis=0)).max() < 1e-9 * np.abs(f).max()
    # rotating the deformed body rotates the forces: f(R x + t) = R f(x)
    u2 = (x @ R.T + t - X).ravel()
    np.testing.assert_allclose(kernel.force(u2).reshape(-1, 3), fr @ R.T, atol=1e-9 * np.abs(f).max())


def test_fast_kernel_matches_fem_corotated_and_linear_at_rest():
    sp_ = _space()
    el = ElasticModel(sp_, Corotated(2e6, 0.35), density=1000.0)
    k = CorotatedP1Kernel(el)
    rng = np.random.default_rng(1)
    for s in (1e-4, 0.05):
        u = s * rng.normal(size=sp_.n_dofs)
        f_ref = el.internal_force(u)
        np.testing.assert_allclose(k.force(u), f_ref, atol=1e-11 * np.abs(f_ref).max())
        assert k.energy(u) == pytest.approx(el.energy(u), rel=1e-11)
    # at rest the warped tangent is the linear-elastic stiffness (peer: physar.fem LinearElastic)
    _, K = k.force_tangent(np.zeros(sp_.n_dofs))
    K_lin = ElasticModel(sp_, LinearElastic(2e6, 0.35)).tangent_stiffness()
    assert abs(K - K_lin).max() < 1e-9 * abs(K_lin).max()
    # matrix-free product (used for Rayleigh damping) = assembled warped tangent
    u = 0.05 * rng.normal(size=sp_.n_dofs)
    v = rng.normal(size=sp_.n_dofs)
    _, K = CorotatedP1Kernel(el, tangent="warped").force_tangent(u)
    np.testing.assert_allclose(k.tangent_matvec(u, v), K @ v, atol=1e-9 * np.abs(K @ v).max())


def test_fast_polar_matches_svd():
    rng = np.random.default_rng(2)
    F = np.eye(3) + 0.4 * rng.normal(size=(500, 3, 3))
    F[:5] *= -1  # inverted elements take the SVD fallback
    R, S = fast_polar(F)
    R2, S2 = polar(F)
    np.testing.assert_allclose(R, R2, atol=1e-11)
    np.testing.assert_allclose(S, S2, atol=1e-11)


def test_gravity_and_mass_totals():
    sp_ = _space("P2")
    el = ElasticModel(sp_, Corotated(1e6, 0.3), density=800.0)
    mass = 800.0 * 1.0 * 0.3 * 0.2
    for kind in ("lumped", "consistent"):
        m = SolidModel(el, mass=kind, gravity=(0, 0, -9.81))
        assert m.f_ext.reshape(-1, 3).sum(axis=0) == pytest.approx([0, 0, -9.81 * mass], rel=1e-12, abs=1e-9)
        v = np.tile([1.0, 2.0, 0.0], sp_.n_nodes)
        assert m.energy(np.zeros(sp_.n_dofs), v)["kinetic"] == pytest.approx(0.5 * mass * 5.0, rel=1e-12)


def test_free_fall_is_exact_for_second_order_methods():
    """No elasticity acts in free fall: q_z(t) = -g t^2 / 2 (trapezoid-type methods are exact on it)."""
    sp_ = _space(cells=(2, 1, 1))
    el = ElasticModel(sp_, Corotated(1e5, 0.3), density=100.0)
    m = SolidModel(el, gravity=(0, 0, -9.81))
    for method in ("midpoint", "genalpha", "trbdf2", "theta"):
        s = simulate(m, make_integrator(method), 0.05, 20)
        np.testing.assert_allclose(s.q[2::3], -0.5 * 9.81 * 1.0**2, rtol=1e-9)
        np.testing.assert_allclose(s.q[0::3], 0.0, atol=1e-10)


def test_pinned_nodes_stay_and_ground_carries_the_weight():
    # a soft block resting on a penalty ground settles where the contact forces carry its weight
    sp_ = _space(cells=(3, 3, 2), size=(0.2, 0.2, 0.1))
    el = ElasticModel(sp_, Corotated(1e5, 0.3), density=500.0)
    weight = 500.0 * 0.2 * 0.2 * 0.1 * 9.81
    m = SolidModel(el, gravity=(0, 0, -9.81), ground=Ground(z0=0.0, stiffness=2e4), rayleigh=(5.0, 0.0))
    s = simulate(m, make_integrator("be"), 0.02, 100)
    fg = m._ground(s.q)[0]
    assert fg[2::3].sum() == pytest.approx(weight, rel=1e-3)
    assert np.abs(s.v).max() < 1e-3
    # pinned: the same block hanging from its top face, pinned nodes do not move
    fixed = fixed_dofs(sp_, box=[[0, 0, 0.1], [0.2, 0.2, 0.1]])
    m2 = SolidModel(el, fixed, gravity=(0, 0, -9.81))
    s2 = simulate(m2, make_integrator("si"), 0.01, 5)
    assert np.all(s2.q[fixed] == 0) and np.all(s2.v[fixed] == 0)
    assert s2.q[2::3].min() < 0


def test_bad_inputs():
    el = ElasticModel(_space(), Corotated(1e6, 0.3), density=1000.0)
    with pytest.raises(ConfigError, match="mass"):
        SolidModel(el, mass="diagonal")
    with pytest.raises(ConfigError, match="Rayleigh"):
        SolidModel(el, rayleigh=(-1, 0))
    with pytest.raises(ConfigError, match="ground stiffness"):
        Ground(0.0, -1.0)
    with pytest.raises(ConfigError, match="unknown method"):
        make_integrator("rk4")
    with pytest.raises(ConfigError, match=r"\[0, 1\]"):
        make_integrator("genalpha", r=1.5)
    with pytest.raises(ConfigError, match="time step"):
        simulate(SolidModel(el), make_integrator("be"), -1.0, 3)


def test_fast_kernel_exact_tangent_matches_fem_and_finite_differences():
    sp_ = _space(cells=(3, 2, 2))
    el = ElasticModel(sp_, Corotated(1e6, 0.3), density=1000.0)
    k = CorotatedP1Kernel(el, tangent="exact")
    rng = np.random.default_rng(4)
    X = sp_.nodes
    Rm = Rotation.from_rotvec([0.3, 1.2, -0.4]).as_matrix()
    u = (X @ Rm.T - X).ravel() + 0.03 * rng.normal(size=sp_.n_dofs)  # large rotation + strain
    _, K = k.force_tangent(u)
    K_ref = el.tangent_stiffness(u)  # physar.fem Corotated, exact dR terms
    assert abs(K - K_ref).max() < 1e-8 * abs(K_ref).max()
    d = rng.normal(size=sp_.n_dofs)
    eps = 1e-6
    fd = (k.force(u + eps * d) - k.force(u - eps * d)) / (2 * eps)
    np.testing.assert_allclose(K @ d, fd, atol=1e-6 * np.abs(fd).max())
