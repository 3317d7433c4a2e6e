"""Tangent = finite difference of the internal force; objectivity; equilibrium of internal forces."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from physar.fem import ElasticModel, FESpace, make_material
from physar.geometry import box_mesh

MATERIALS = {
    "linear": {"E": 1e6, "nu": 0.3},
    "stvk": {"E": 1e6, "nu": 0.3},
    "neohookean": {"E": 1e6, "nu": 0.3},
    "neohookean_incompressible": {"C1": 2e5, "kappa": 5e6},
    "corotated": {"E": 1e6, "nu": 0.3},
}
NONLINEAR = [m for m in MATERIALS if m != "linear"]


def small_model(name, element="P2"):
    space = FESpace(box_mesh((1.0, 0.5, 0.4), (2, 1, 1)), element)
    return ElasticModel(space, make_material(name, **MATERIALS[name]))


@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("name", list(MATERIALS))
def test_tangent_equals_finite_difference(name, element):
    model = small_model(name, element)
    rng = np.random.default_rng(1)
    u = 0.05 * rng.standard_normal(model.n_dofs)
    K = model.tangent_stiffness(u).toarray()
    h = 1e-6
    fd = np.empty_like(K)
    for j in range(model.n_dofs):
        e = np.zeros(model.n_dofs)
        e[j] = h
        fd[:, j] = (model.internal_force(u + e) - model.internal_force(u - e)) / (2 * h)
    assert np.abs(K - fd).max() <= 1e-6 * np.abs(K).max()
    assert np.allclose(K, K.T, atol=1e-9 * np.abs(K).max())  # hyperelastic: symmetric tangent


@pytest.mark.parametrize("name", list(MATERIALS))
def test_force_is_energy_gradient(name):
    model = small_model(name, "P1")
    rng = np.random.default_rng(2)
    u = 0.05 * rng.standard_normal(model.n_dofs)
    d = rng.standard_normal(model.n_dofs)
    h = 1e-6
    fd = (model.energy(u + h * d) - model.energy(u - h * d)) / (2 * h)
    assert np.isclose(fd, model.internal_force(u) @ d, rtol=1e-6)


@pytest.mark.parametrize("name", NONLINEAR)
def test_rigid_motion_gives_no_internal_force(name):
    model = small_model(name)
    X = model.space.nodes
    R = Rotation.from_rotvec([0.4, -0.9, 1.3]).as_matrix()
    u = (X @ R.T + np.array([0.3, -0.2, 0.1]) - X).ravel()
    f = model.internal_force(u)
    scale = np.abs(model.internal_force(0.01 * np.random.default_rng(3).standard_normal(model.n_dofs))).max()
    assert np.abs(f).max() < 1e-10 * scale
    assert abs(model.energy(u)) < 1e-10


@pytest.mark.parametrize("name", list(MATERIALS))
def test_internal_forces_sum_to_zero(name):
    model = small_model(name)
    u = 0.05 * np.random.default_rng(4).standard_normal(model.n_dofs)
    f = model.internal_force(u).reshape(-1, 3)
    assert np.abs(f.sum(axis=0)).max() < 1e-9 * np.abs(f).max()


def test_linear_is_small_strain_limit_of_all_materials():
    """At tiny strain every law gives the linear-elastic force (same E, nu)."""
    lin = small_model("linear")
    u = 1e-7 * np.random.default_rng(5).standard_normal(lin.n_dofs)
    f_lin = lin.internal_force(u)
    for name in ("stvk", "neohookean", "corotated"):
        f = small_model(name).internal_force(u)
        assert np.abs(f - f_lin).max() < 1e-5 * np.abs(f_lin).max()
    from physar.fem import NeoHookeanIncompressible

    nh = ElasticModel(lin.space, NeoHookeanIncompressible.from_E_nu(1e6, 0.3))
    assert np.abs(nh.internal_force(u) - f_lin).max() < 1e-5 * np.abs(f_lin).max()
