"""physar.fem.post.nodal_stress against closed forms: a quadratic displacement field (linear strain, the P2
space holds it exactly) gives sigma = lambda tr(eps) I + 2 mu eps at every vertex, to round-off, on a distorted
mesh; a homogeneous finite deformation gives sigma = P F^T / J of the material. Element-averaged stress
(cauchy_stress + nodal_average) fails the first at the boundary."""
import numpy as np
import pytest

from physar.fem import ElasticModel, FESpace, LinearElastic, StVK, cauchy_stress, lame, nodal_average
from physar.fem.post import nodal_stress
from physar.geometry import TetMesh, box_mesh

E, NU = 70e9, 0.3
A = np.array([[1.0, -2.0, 0.5], [0.3, 0.7, -1.1], [-0.4, 0.2, 0.9]]) * 1e-4          # u = A X + Q(X)
Q = np.random.default_rng(0).normal(size=(3, 3, 3)) * 1e-3                            # u_i += Q_ijk X_j X_k


def _mesh():
    m = box_mesh((0.4, 0.1, 0.08), (6, 3, 2))
    p = m.points.copy()
    p[:, 2] += 0.02 * p[:, 0] * p[:, 1] / 0.04  # curved, non-uniform tets (still affine per element)
    return TetMesh.reoriented(p, m.cells)


def _quadratic(X):
    return X @ A.T + np.einsum("ijk,pj,pk->pi", Q, X, X)


def _exact_stress(X):
    grad = A[None] + np.einsum("ijk,pk->pij", Q + np.swapaxes(Q, 1, 2), X)   # du_i/dX_j
    eps = 0.5 * (grad + np.swapaxes(grad, 1, 2))
    lam, mu = lame(E, NU)
    return lam * np.trace(eps, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 2 * mu * eps


def test_linear_strain_field_is_recovered_exactly_at_every_vertex():
    space = FESpace(_mesh(), "P2")
    model = ElasticModel(space, LinearElastic(E, NU))
    u = _quadratic(space.nodes).ravel()
    exact = _exact_stress(space.mesh.points)
    scale = np.abs(exact).max()
    assert np.abs(nodal_stress(model, u) - exact).max() <= 1e-10 * scale
    some = np.array([0, 5, 17, space.mesh.n_points - 1])
    assert np.abs(nodal_stress(model, u, some) - exact[some]).max() <= 1e-10 * scale
    averaged = nodal_average(space, cauchy_stress(model, u).reshape(-1, 9)).reshape(-1, 3, 3)
    assert np.abs(averaged - exact).max() > 1e-3 * scale  # the element-mean mutant is not exact


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_homogeneous_finite_deformation_gives_the_material_cauchy_stress(element):
    space = FESpace(_mesh(), element)
    material = StVK(E, NU)
    model = ElasticModel(space, material)
    Fd = np.eye(3) + np.array([[0.05, 0.02, 0.0], [-0.01, 0.03, 0.04], [0.0, 0.01, -0.02]])
    u = (space.nodes @ (Fd - np.eye(3)).T).ravel()
    P = material.stress(Fd[None])[0]
    sigma = P @ Fd.T / np.linalg.det(Fd)
    got = nodal_stress(model, u)
    assert got.shape == (space.mesh.n_points, 3, 3)
    assert np.allclose(got, sigma, rtol=0, atol=1e-10 * np.abs(sigma).max())
