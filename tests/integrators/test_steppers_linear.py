"""Steppers on linear systems: convergence order vs the exact solution (matrix exponential), energy."""

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from physar.integrators import LinearDynamics, make_integrator, simulate

# damped 2-DOF system M q'' + D q' + K q = 0, D = 0.1 M + 0.02 K
M2 = np.diag([1.0, 2.0])
K2 = np.array([[6.0, -2.0], [-2.0, 4.0]])
D2 = 0.1 * M2 + 0.02 * K2
Q0, V0 = np.array([1.0, -0.5]), np.array([0.0, 1.0])
T_END = 2.0


def exact(t):
    n = 2
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n:, :n] = -np.linalg.solve(M2, K2)
    A[n:, n:] = -np.linalg.solve(M2, D2)
    return sla.expm(A * t) @ np.concatenate([Q0, V0])


def error(method, kw, steps):
    model = LinearDynamics(M2, K2, D2)
    s = simulate(model, make_integrator(method, **kw), T_END / steps, steps, Q0, V0)
    return np.linalg.norm(np.concatenate([s.q, s.v]) - exact(T_END))


SECOND = [("midpoint", {}), ("genalpha", {"r": 0.0}), ("genalpha", {"r": 0.5}), ("genalpha", {"r": 1.0}),
          ("theta", {"theta": 0.0}), ("theta", {"theta": 0.5}), ("theta", {"theta": 1.0}), ("trbdf2", {})]
FIRST = [("be", {}), ("si", {}), ("symplectic_euler", {})]


@pytest.mark.parametrize("method,kw", SECOND + FIRST)
def test_convergence_order(method, kw):
    n = 160
    e1, e2 = error(method, kw, n), error(method, kw, 2 * n)
    order = np.log2(e1 / e2)
    expected = 2 if (method, kw) in SECOND else 1
    assert abs(order - expected) < 0.1, (method, kw, order, e1, e2)


def chain(n=6, k=1.0):
    """Fixed-free spring chain with unequal masses: an undamped linear system with distinct frequencies."""
    K = sp.diags([np.full(n, 2 * k), np.full(n - 1, -k), np.full(n - 1, -k)], [0, 1, -1]).tolil()
    K[n - 1, n - 1] = k
    M = np.linspace(1.0, 2.0, n)
    return sp.diags(M).tocsr(), K.tocsr()


def energy(M, K, q, v):
    return 0.5 * v @ (M @ v) + 0.5 * q @ (K @ q)


@pytest.mark.parametrize("method,kw", [("midpoint", {}), ("genalpha", {"r": 1.0})])
def test_energy_conserved_over_1000_steps(method, kw):
    M, K = chain()
    model = LinearDynamics(M, K)
    rng = np.random.default_rng(3)
    q0, v0 = rng.normal(size=6), rng.normal(size=6)
    e0 = energy(M, K, q0, v0)
    worst = [0.0]

    def cb(k, s):
        worst[0] = max(worst[0], abs(energy(M, K, s.q, s.v) - e0) / e0)

    simulate(model, make_integrator(method, **kw), 0.7, 1000, q0, v0, callback=cb)  # h w up to ~1.3
    assert worst[0] < 1e-10


def test_backward_euler_modal_energy_loss():
    """BE multiplies each mode's energy by exactly 1/(1 + (h w)^2) per step."""
    M, K = chain()
    w2, phi = sla.eigh(K.toarray(), M.toarray())  # phi^T M phi = I
    h = 0.4
    rng = np.random.default_rng(5)
    q0, v0 = rng.normal(size=6), rng.normal(size=6)
    model = LinearDynamics(M, K)
    integ = make_integrator("be")
    s = integ.init(model, q0, v0)
    Mm = M.toarray()

    def modal(s):
        a, b = phi.T @ Mm @ s.q, phi.T @ Mm @ s.v
        return 0.5 * (b * b + w2 * a * a)

    e = modal(s)
    for _ in range(10):
        s = integ.step(model, s, h)
    np.testing.assert_allclose(modal(s), e / (1 + h * h * w2) ** 10, rtol=1e-10)
