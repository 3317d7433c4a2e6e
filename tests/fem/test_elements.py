"""Patch test and element-level checks against closed forms."""

import numpy as np
import pytest

from physar.fem import ElasticModel, FESpace, LinearElastic, fixed_dofs, solve_static
from physar.geometry import TetMesh, box_mesh


def distorted_box(seed=0):
    m = box_mesh((1.0, 0.8, 0.6), (4, 3, 3))
    pts = m.points.copy()
    interior = np.all((pts > 1e-9) & (pts < np.array([1.0, 0.8, 0.6]) - 1e-9), axis=1)
    rng = np.random.default_rng(seed)
    pts[interior] += 0.05 * rng.uniform(-1, 1, (interior.sum(), 3))
    return TetMesh(pts, m.cells)


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_patch_linear_field_reproduced(element):
    """A linear displacement imposed on the boundary is reproduced inside to 1e-10 (distorted mesh)."""
    space = FESpace(distorted_box(), element)
    model = ElasticModel(space, LinearElastic(2.0e5, 0.3))
    A = np.array([[1e-3, 2e-3, -1e-3], [0.5e-3, -2e-3, 1e-3], [3e-3, 1e-3, 2e-3]])
    c = np.array([1e-3, -2e-3, 0.5e-3])
    exact = (space.nodes @ A.T + c).ravel()
    lo, hi = space.nodes.min(0), space.nodes.max(0)
    on_bnd = np.any(np.isclose(space.nodes, lo) | np.isclose(space.nodes, hi), axis=1)
    fixed = fixed_dofs(space, where=lambda x: on_bnd)
    # inhomogeneous Dirichlet: solve for the correction with f = -K u_D
    uD = np.zeros(space.n_dofs)
    uD[fixed] = exact[fixed]
    f = -model.internal_force(uD)
    du = solve_static(model, f, fixed).u
    u = uD + du
    interior = np.setdiff1d(np.arange(space.n_dofs), fixed)
    assert len(interior) > 0
    assert np.abs(u - exact).max() < 1e-10


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_mass_matrix_total_and_lumped(element):
    space = FESpace(distorted_box(1), element)
    model = ElasticModel(space, LinearElastic(1.0, 0.3), density=2700.0)
    vol = 1.0 * 0.8 * 0.6
    ones_x = np.zeros(space.n_dofs)
    ones_x[0::3] = 1.0
    for lumped in (False, True):
        M = model.mass_matrix(lumped=lumped)
        assert np.isclose(ones_x @ M @ ones_x, 2700.0 * vol, rtol=1e-12)
    assert model.mass_matrix(lumped=True).diagonal().min() > 0  # HRZ keeps P2 masses positive
    # consistent mass gives the first moment exactly: ∫ rho x dV = rho V / 2
    x = np.zeros(space.n_dofs)
    x[0::3] = space.nodes[:, 0]
    if element == "P2":
        M = model.mass_matrix()
        assert np.isclose(x @ M @ np.where(np.arange(space.n_dofs) % 3 == 0, 1.0, 0.0), 2700 * vol * 0.5, rtol=1e-12)


def test_pattern_and_coo_assembly_agree():
    from physar.fem import StVK

    space = FESpace(distorted_box(2), "P2")
    model = ElasticModel(space, StVK(1e6, 0.3))
    u = 0.01 * np.random.default_rng(0).standard_normal(space.n_dofs)
    K1 = model.tangent_stiffness(u)  # first assembly: COO
    K2 = model.tangent_stiffness(u)  # later assemblies: cached CSR pattern + bincount
    assert abs(K1 - K2).max() <= 1e-12 * abs(K1).max()
