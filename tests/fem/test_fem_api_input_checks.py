"""Bad input to the fem Python API: one clear error naming the argument and the value.

Constrained dofs (`fixed`) are read by :func:`physar.fem.dof_indices` everywhere: indices or a boolean mask,
nothing wrapped, dropped or truncated. Each test names the mutant it catches (the check removed).
"""

import numpy as np
import pytest

from physar.errors import ConfigError, SolverError
from physar.fem import (
    ElasticModel,
    FESpace,
    LinearElastic,
    LinearSolver,
    dof_indices,
    fixed_dofs,
    gravity_load,
    probe,
    solve_linear,
    solve_static,
    traction_load,
    von_mises,
)
from physar.geometry import box_mesh

L, W, E, NU, P = 1.0, 0.05, 69e9, 0.3, 100.0


@pytest.fixture(scope="module")
def beam():
    space = FESpace(box_mesh((L, W, W), (20, 2, 2)), "P2")
    model = ElasticModel(space, LinearElastic(E, NU))
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, W, W]])
    f = traction_load(space, [[L, 0, 0], [L, W, W]], [0, 0, -P])
    return space, model, fixed, f


def _tip(space, u):
    return probe(space, u, [L, W / 2, W / 2])[2]


def test_mask_and_indices_give_the_euler_bernoulli_tip(beam):
    # mutant: a boolean mask read as indices 0/1 (np.asarray(mask, int64)): only dof 1 fixed, and the solve
    # refuses with "rigid-body modes free" instead of clamping the root face
    space, model, fixed, f = beam
    mask = np.zeros(space.n_dofs, bool)
    mask[fixed] = True
    u_idx = solve_static(model, f, fixed).u
    u_mask = solve_static(model, f, mask).u
    np.testing.assert_array_equal(u_mask, u_idx)
    exact = -P * L**3 / (3 * E * W**4 / 12)  # P L^3 / (3 E I), I = W H^3 / 12
    assert _tip(space, u_mask) == pytest.approx(exact, rel=0.02)
    np.testing.assert_array_equal(solve_linear(model, f, mask), solve_linear(model, f, fixed))


@pytest.mark.parametrize("extra, shown", [(-1, "-1"), (10**7, "10000000"), ("n", None)])
def test_out_of_range_fixed_dof_is_refused(beam, extra, shown):
    # mutant: no range check in dof_indices: -1 wraps and pins the last dof (tip -2.8e-5 m instead of -9.2e-4),
    # 10**7 raises a bare IndexError, n_dofs is dropped
    space, model, fixed, f = beam
    n = space.n_dofs
    bad = n if extra == "n" else extra
    for call in (lambda: solve_static(model, f, np.r_[fixed, bad]), lambda: LinearSolver(model, np.r_[fixed, bad])):
        with pytest.raises(ConfigError) as e:
            call()
        msg = str(e.value)
        assert msg.startswith("fixed:") and (shown or str(n)) in msg and f"0..{n - 1}" in msg, msg


def test_fractional_fixed_dofs_are_refused_not_truncated(beam):
    # mutant: astype(int64) on floats: fixed + 0.6 truncated to fixed, solved silently
    _, model, fixed, f = beam
    with pytest.raises(ConfigError, match=r"fixed must be integer dof indices, got 0\.6"):
        solve_static(model, f, fixed + 0.6)
    np.testing.assert_array_equal(solve_static(model, f, fixed.astype(float)).u, solve_static(model, f, fixed).u)


def test_mask_of_wrong_length_is_refused(beam):
    # mutant: masks accepted at any length (flatnonzero of a short mask)
    space, model, _, f = beam
    with pytest.raises(ConfigError, match=rf"mask must have shape \({space.n_dofs},\).*\({space.n_dofs - 1},\)"):
        solve_static(model, f, np.ones(space.n_dofs - 1, bool))


def test_dof_indices_sorted_unique_and_mask():
    np.testing.assert_array_equal(dof_indices([5, 1, 5, 2], 6), [1, 2, 5])
    assert dof_indices([5, 1], 6).dtype == np.int64
    np.testing.assert_array_equal(dof_indices(np.array([0, 1, 0, 1, 1, 0], bool), 6), [1, 3, 4])
    assert dof_indices([], 6).size == 0
    with pytest.raises(ConfigError, match="integer dof indices or a boolean mask"):
        dof_indices(["a"], 6)


def test_nan_external_force_is_named(beam):
    # mutant: no finiteness check on f_ext: linear says "singular system", NeoHookean "inverts elements"
    _, model, fixed, f = beam
    g = f.copy()
    g[7] = np.nan
    with pytest.raises(SolverError, match=r"external force contains NaN or inf \(first at dof 7"):
        solve_static(model, g, fixed)
    with pytest.raises(SolverError, match="external force contains NaN or inf"):
        solve_linear(model, g, fixed)


def test_u0_of_wrong_shape(beam):
    # mutant: u0 unchecked: IndexError from u[fixed] = 0
    space, model, fixed, f = beam
    with pytest.raises(SolverError, match=rf"u0 must .* shape \({space.n_dofs},\), got shape \(5,\)"):
        solve_static(model, f, fixed, u0=np.zeros(5))


def test_traction_total_must_be_a_finite_3_vector(beam):
    # mutant: total unchecked: NaN accepted, [0, -1] a numpy broadcast error
    space = beam[0]
    for total in ([0, 0, np.nan], [0, -1]):
        with pytest.raises(ConfigError, match="traction load total must be a finite vector of 3 numbers"):
            traction_load(space, [[L, 0, 0], [L, W, W]], total)


def test_gravity_load_closed_form_and_checks(beam):
    # sum of the consistent body force = rho V g (independent: the box volume); mutants: scalar g or a
    # negative density accepted
    space = beam[0]
    f = gravity_load(space, 2700.0, [0, 0, -9.81]).reshape(-1, 3).sum(axis=0)
    np.testing.assert_allclose(f, [0, 0, -2700.0 * L * W * W * 9.81], rtol=1e-12, atol=1e-12)
    with pytest.raises(ConfigError, match="gravity g must be a finite vector of 3 numbers.*-9.81"):
        gravity_load(space, 2700, -9.81)
    with pytest.raises(ConfigError, match="density must be a number >= 0.*-2700"):
        gravity_load(space, -2700, [0, 0, -9.81])


def test_post_processing_checks_the_displacement(beam):
    # mutants: u of the wrong length accepted by probe (reshaped silently) / IndexError in von_mises;
    # a 2-D probe point a numpy broadcast error
    space, model, fixed, f = beam
    u = solve_static(model, f, fixed).u
    for call in (lambda: von_mises(model, u[:-3]), lambda: probe(space, u[:-3], [L, W / 2, W / 2])):
        with pytest.raises(ConfigError, match=rf"u must have shape \({space.n_dofs},\).*\({space.n_dofs - 3},\)"):
            call()
    with pytest.raises(ConfigError, match=r"probe points must have shape \(3,\) or \(p, 3\).*\(2,\)"):
        probe(space, u, [L, W / 2])


def test_model_needs_a_space_and_numeric_moduli(beam):
    # mutants: ElasticModel(mesh, ...) accepted (AttributeError later); E = "1e9" a numpy TypeError
    with pytest.raises(ConfigError, match=r"space must be a physar.fem FESpace, got TetMesh.*FESpace\(mesh"):
        ElasticModel(beam[0].mesh, LinearElastic(E, NU))
    with pytest.raises(ConfigError, match="Young's modulus E must be a number, got '1e9'"):
        LinearElastic("1e9", NU)
