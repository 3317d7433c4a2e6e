"""Loads, stresses and solver paths against closed forms."""


import numpy as np
import pytest

from physar.errors import ConfigError, SolverError
from physar.fem import (
    ElasticModel,
    FESpace,
    LinearElastic,
    LinearSolver,
    StVK,
    factorize,
    fixed_dofs,
    gravity_load,
    nodal_average,
    point_load,
    solve_static,
    traction_load,
    von_mises,
)
from physar.geometry import box_mesh


def test_uniaxial_tension_stress_is_force_over_area():
    """A bar pulled by F with sliding (roller) supports: sigma_xx = F / A everywhere, von Mises = F / A."""
    L, b, h, F = 2.0, 0.2, 0.1, 5000.0
    space = FESpace(box_mesh((L, b, h), (6, 2, 2)), "P1")
    model = ElasticModel(space, LinearElastic(1e9, 0.3))
    fixed = np.concatenate([
        fixed_dofs(space, box=[[0, 0, 0], [0, b, h]], components="x"),
        fixed_dofs(space, box=[[0, 0, 0], [L, 0, h]], components="y"),
        fixed_dofs(space, box=[[0, 0, 0], [L, b, 0]], components="z"),
    ])
    f = traction_load(space, [[L, 0, 0], [L, b, h]], [F, 0, 0])
    u = solve_static(model, f, fixed).u
    vm = von_mises(model, u)
    assert np.allclose(vm, F / (b * h), rtol=1e-9)
    assert np.allclose(nodal_average(space, vm), F / (b * h), rtol=1e-9)
    # elongation F L / (E A)
    assert np.isclose(u.reshape(-1, 3)[:, 0].max(), F * L / (1e9 * b * h), rtol=1e-9)


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_point_load_total_and_locality(element):
    space = FESpace(box_mesh((1.0, 0.2, 0.1), (20, 4, 2)), element)
    f = point_load(space, [0.5, 0.1, 0.1], [0, 0, -10.0], radius=0.08).reshape(-1, 3)
    assert np.allclose(f.sum(axis=0), [0, 0, -10.0], rtol=1e-12)
    loaded = np.abs(f[:, 2]) > 0
    d = np.linalg.norm(space.nodes[loaded] - [0.5, 0.1, 0.1], axis=1)
    assert d.max() < 0.08 + 0.05 * np.sqrt(2) + 1e-9  # radius plus one face diagonal
    # the force moves smoothly with the point: small shift -> small change
    f2 = point_load(space, [0.501, 0.1, 0.1], [0, 0, -10.0], radius=0.08).reshape(-1, 3)
    assert np.abs(f2 - f).sum() < 0.05 * 10.0
    with pytest.raises(ConfigError, match="radius"):
        point_load(space, [0.5, 0.1, 0.1], [0, 0, -1], radius=1e-6)


def test_self_weight_cantilever_matches_beam_theory():
    """Uniform load q = rho g A: tip deflection q L^4 / (8 E I) (+ shear term q L^2 / (2 k G A))."""
    L, b, h, E, nu, rho, g = 1.0, 0.05, 0.05, 69e9, 0.334, 2700.0, 9.81
    space = FESpace(box_mesh((L, b, h), (40, 2, 2)), "P2")
    model = ElasticModel(space, LinearElastic(E, nu), density=rho)
    f = gravity_load(space, rho, [0, 0, -g])
    assert np.isclose(f.reshape(-1, 3)[:, 2].sum(), -rho * g * L * b * h, rtol=1e-12)
    u = solve_static(model, f, fixed_dofs(space, box=[[0, 0, 0], [0, b, h]])).u
    q, I, A, G = rho * g * b * h, b * h**3 / 12, b * h, E / (2 * (1 + nu))
    k = 10 * (1 + nu) / (12 + 11 * nu)
    ref = q * L**4 / (8 * E * I) + q * L**2 / (2 * k * G * A)
    from physar.fem import probe

    tip = -probe(space, u, [L, b / 2, h / 2])[2]
    assert abs(tip - ref) / ref < 0.02


def test_superlu_fallback_matches_cholmod_and_resolve():
    space = FESpace(box_mesh((1.0, 0.1, 0.1), (10, 1, 1)), "P2")
    model = ElasticModel(space, LinearElastic(1e9, 0.3))
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, 0.1, 0.1]])
    free = np.setdiff1d(np.arange(space.n_dofs), fixed)
    K = model.tangent_stiffness()[free][:, free]
    b = np.random.default_rng(0).standard_normal(len(free))
    x1 = factorize(K, "superlu").solve(b)
    assert np.allclose(K @ x1, b, atol=1e-8 * np.abs(b).max())
    x2 = factorize(K).solve(b)
    assert np.allclose(x1, x2, rtol=1e-8, atol=1e-14)
    solver = LinearSolver(model, fixed)
    F = np.random.default_rng(1).standard_normal((space.n_dofs, 3))
    U = solver.solve(F)  # several right-hand sides, one factorisation
    for j in range(3):
        assert np.allclose(U[:, j], solver.solve(F[:, j]))


def test_load_steps_reach_the_same_solution_and_errors():
    space = FESpace(box_mesh((1.0, 0.1, 0.1), (8, 1, 1)), "P2")
    model = ElasticModel(space, StVK(1e8, 0.3))
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, 0.1, 0.1]])
    f = traction_load(space, [[1, 0, 0], [1, 0.1, 0.1]], [0, 0, -200.0])
    u1 = solve_static(model, f, fixed, steps=1).u
    u4 = solve_static(model, f, fixed, steps=4).u
    assert np.allclose(u1, u4, atol=1e-9 * np.abs(u1).max())
    with pytest.raises(SolverError, match="not converge"):
        solve_static(model, 50 * f, fixed, steps=1, max_iter=2)
    with pytest.raises(SolverError, match="not fully constrained"):
        solve_static(model, f, fixed_dofs(space, box=[[0, 0, 0], [0, 0.1, 0.1]], components="z"))


def _roller_stretch(material, d, steps=1, element="P1"):
    """Bar [0,L]x[0,b]x[0,h] on rollers (u_x = 0 at x = 0, u_y = 0 at y = 0, u_z = 0 at z = 0), end x = L
    pulled by a prescribed u_x = d. Returns the space, the solution and the x-reaction on the pulled end."""
    L, b, h = 1.0, 0.2, 0.1
    space = FESpace(box_mesh((L, b, h), (4, 2, 2)), element)
    model = ElasticModel(space, material)
    end = fixed_dofs(space, box=[[L - 1e-9, -1, -1], [L + 1, 2, 2]], components="x")
    fixed = np.unique(np.concatenate([
        fixed_dofs(space, box=[[-1, -1, -1], [1e-9, 2, 2]], components="x"),
        fixed_dofs(space, box=[[-1, -1, -1], [2, 1e-9, 2]], components="y"),
        fixed_dofs(space, box=[[-1, -1, -1], [2, 2, 1e-9]], components="z"),
        end,
    ]))
    u_d = np.zeros(space.n_dofs)
    u_d[end] = d
    u = solve_static(model, np.zeros(space.n_dofs), fixed, steps=steps, prescribed=u_d).u
    reaction = model.internal_force(u)[end].sum()
    return space, u, reaction, (L, b, h)


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_prescribed_stretch_linear_matches_uniaxial_closed_form(element):
    """Linear elasticity: u_x = d x / L, u_y = -nu d y / L, reaction E A d / L (exact for a linear field)."""
    E, nu, d = 2e9, 0.3, 1e-3
    space, u, reaction, (L, b, h) = _roller_stretch(LinearElastic(E, nu), d, element=element)
    x = space.nodes
    U = u.reshape(-1, 3)
    np.testing.assert_allclose(U[:, 0], d * x[:, 0] / L, atol=1e-12)
    np.testing.assert_allclose(U[:, 1], -nu * d * x[:, 1] / L, atol=1e-12)
    np.testing.assert_allclose(reaction, E * b * h * d / L, rtol=1e-9)


def test_prescribed_stretch_stvk_matches_finite_strain_closed_form():
    """St.VK under homogeneous uniaxial stretch lambda_1 = 1 + d/L with free lateral faces: S_22 = 0 gives the
    lateral Green strain E_22 = -nu E_11, and the first Piola stress P_11 = lambda_1 E_young E_11, so the
    end reaction is b h lambda_1 E_young E_11 (seed 000 §5.2 material, a 30 % stretch, 4 load steps)."""
    E, nu, d = 1e6, 0.3, 0.3
    space, u, reaction, (L, b, h) = _roller_stretch(StVK(E, nu), d, steps=4)
    lam1 = 1 + d / L
    e11 = 0.5 * (lam1**2 - 1)
    lam2 = np.sqrt(1 - 2 * nu * e11)
    U = u.reshape(-1, 3)
    x = space.nodes
    np.testing.assert_allclose(U[:, 1], (lam2 - 1) * x[:, 1], atol=1e-9)
    np.testing.assert_allclose(U[:, 2], (lam2 - 1) * x[:, 2], atol=1e-9)
    np.testing.assert_allclose(reaction, b * h * lam1 * E * e11, rtol=1e-8)


def test_prescribed_values_must_match_dofs():
    space = FESpace(box_mesh((1, 1, 1), (1, 1, 1)), "P1")
    model = ElasticModel(space, LinearElastic(1e6, 0.3))
    fixed = fixed_dofs(space, box=[[-1, -1, -1], [1e-9, 2, 2]])
    with pytest.raises(SolverError, match="prescribed displacements must have shape"):
        solve_static(model, np.zeros(space.n_dofs), fixed, prescribed=np.zeros(5))


def test_config_fix_value_prescribes_displacement():
    """[[fix]] value = [...] in a problem file: the pulled end moves by exactly that value, the rest follows
    the linear closed form u_x = d x / L."""
    from physar.fem.config import build_problem, parse_config, solve_problem

    d = 2e-3
    cfg = parse_config({
        "mesh": {"box": [1.0, 0.2, 0.1], "cells": [4, 2, 2]},
        "material": {"model": "linear", "E": 1e9, "nu": 0.25},
        "fem": {"element": "P1"},
        "fix": [
            {"box": [[-1, -1, -1], [1e-9, 2, 2]], "components": ["x"]},
            {"box": [[-1, -1, -1], [2, 1e-9, 2]], "components": ["y"]},
            {"box": [[-1, -1, -1], [2, 2, 1e-9]], "components": ["z"]},
            {"box": [[1 - 1e-9, -1, -1], [2, 2, 2]], "components": ["x"], "value": [d, 0, 0]},
        ],
    })
    res = solve_problem(build_problem(cfg))
    U = res.static.u.reshape(-1, 3)
    np.testing.assert_allclose(U[:, 0], d * res.problem.space.nodes[:, 0], atol=1e-12)
