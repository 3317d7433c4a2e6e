"""Bad input to the integrators Python API, and the explicit stepper's blow-up checks.

References: a one-dof oscillator (stability limit h < 2 / omega, exact for symplectic Euler), the dense
generalized eigenproblem of a small 3-D model (scipy.linalg.eigh), and symplectic Euler's exact free fall
x_n = x_0 - g h^2 n (n + 1) / 2. Each test names the mutant it catches.
"""

import numpy as np
import pytest
import scipy.linalg as sl

from physar.errors import ConfigError, SolverError
from physar.fem import Corotated, ElasticModel, FESpace
from physar.geometry import box_mesh
from physar.integrators import (
    LinearDynamics,
    SolidModel,
    explicit_step_limit,
    make_integrator,
    simulate,
    steppers,
)

G = 9.81


@pytest.fixture(scope="module")
def cube():
    """The probe's case: a free 0.1 m cube, E = 1 MPa, under gravity (h = 0.01 s is ~11x the limit)."""
    em = ElasticModel(FESpace(box_mesh((0.1, 0.1, 0.1), (2, 2, 2)), "P1"), Corotated(1e6, 0.3), density=1000)
    return SolidModel(em, gravity=[0, 0, -G])


def test_one_dof_limit_is_two_over_omega():
    # q'' + (k/m) q = 0: symplectic Euler is stable iff h omega < 2 (one dof: the estimate is exact)
    m, k = 2.0, 50.0
    omega = np.sqrt(k / m)
    model = LinearDynamics([[m]], [[k]])
    assert explicit_step_limit(model) == pytest.approx(2 / omega, rel=1e-12)
    q = simulate(model, make_integrator("symplectic_euler"), 0.01, 100, q0=[1.0]).q[0]
    assert q == pytest.approx(np.cos(omega * 1.0), abs=0.05)  # O(h omega) phase error of a first-order method


def test_step_beyond_the_limit_is_refused_upfront(cube):
    # mutant: no stability check in simulate: q ~ 1e261 after 100 steps (finite) with ~900 RuntimeWarnings
    with pytest.raises(SolverError, match=r"h = 0.01 s is beyond the explicit stability limit 2/omega_max = "
                                          r"0.000\d+ s .*use h < "):
        simulate(cube, make_integrator("symplectic_euler"), 0.01, 100)


def test_limit_estimate_against_dense_eigenvalues(cube):
    # lower bound of omega_max (so never a false refusal for a linear model) and within 2 % of it
    q, v = cube.initial_state()
    K = cube.linearize(q, v).K.toarray()
    w2 = sl.eigh(0.5 * (K + K.T), cube.mass_ff.toarray(), eigvals_only=True).max()
    exact = 2 / np.sqrt(w2)
    est = explicit_step_limit(cube)
    assert exact <= est <= 1.02 * exact


def test_runaway_is_caught_after_the_fact(cube, monkeypatch):
    # mutant: only NaN/inf checked after each step: with the upfront estimate defeated, 100 steps end finite
    # at ~1e261 m and are returned
    monkeypatch.setattr(steppers, "explicit_step_limit", lambda *a, **k: np.inf)
    with pytest.raises(SolverError, match=r"blew up at step (\d+) \(t = .* s\): it grows geometrically.*reduce h"):
        simulate(cube, make_integrator("symplectic_euler"), 0.01, 100)


def test_stable_free_fall_is_not_flagged(cube):
    # below the limit: symplectic Euler's exact free fall z_n = -g h^2 n (n + 1) / 2 (no false blow-up)
    h, n = 0.9 * explicit_step_limit(cube), 300
    q = simulate(cube, make_integrator("symplectic_euler"), h, n).q.reshape(-1, 3)
    np.testing.assert_allclose(q[:, 2], -G * h * h * n * (n + 1) / 2, rtol=1e-9)
    np.testing.assert_allclose(q[:, :2], 0.0, atol=1e-12)


def test_fixed_dofs_checked_and_mask_read_as_mask():
    # mutants: fixed=[-1] wraps / [5] dropped silently (the dof stays free); a mask read as indices 0/1
    M, K = np.diag([1.0, 2.0, 4.0]), np.diag([1.0, 1.0, 1.0])
    for bad, shown in (([-1], "-1"), ([5], "5")):
        with pytest.raises(ConfigError, match=rf"fixed: dof index {shown} is out of range 0..2"):
            LinearDynamics(M, K, fixed=bad)
    np.testing.assert_array_equal(LinearDynamics(M, K, fixed=[False, True, True]).free, [0])
    np.testing.assert_array_equal(LinearDynamics(M, K, fixed=[1, 2]).free, [0])


def test_solid_model_fixed_and_gravity(cube):
    em = cube.elastic
    with pytest.raises(ConfigError, match=rf"fixed: dof index 1000000 is out of range 0..{em.n_dofs - 1}"):
        SolidModel(em, fixed=[10**6])
    with pytest.raises(ConfigError, match=r"gravity must be a finite vector \(gx, gy, gz\).*-9.81"):
        SolidModel(em, gravity=-9.81)
    mask = np.zeros(em.n_dofs, bool)
    mask[[0, 4, 8]] = True
    np.testing.assert_array_equal(SolidModel(em, fixed=mask).fixed, [0, 4, 8])


@pytest.mark.parametrize("m", [-1.0, 0.0])
def test_mass_must_be_positive(m):
    # mutant: M = -1 accepted (the solution grows as exp(t)) or M = 0 (division by zero)
    with pytest.raises(ConfigError, match=rf"M must be positive definite: M\[0, 0\] = {m:g}"):
        LinearDynamics([[m]], [[1.0]])
