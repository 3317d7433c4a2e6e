"""Damping analysis (seed 001 §2.1) of the implemented steppers against closed forms."""

import itertools

import numpy as np
import pytest

from physar.integrators import amplification_matrix, damping_curve, make_integrator, spectral_radius
from physar.integrators.analysis import d_backward_euler, rho_backward_euler

HW = np.logspace(-1.5, 2.5, 41)


@pytest.mark.parametrize("method", ["be", "si"])
def test_backward_euler_closed_form(method):
    """Seed Eq. 2.8-2.9: rho = 1/sqrt(1 + (h w)^2), d = ln(1 + (h w)^2)/h, to 1e-12 relative."""
    c = damping_curve(method, HW)
    # (rho's entries cancel, 1 - (h w)^2 / (1 + (h w)^2), so rho itself is good to ~eps (h w)^2)
    np.testing.assert_allclose(c["rho"], rho_backward_euler(HW), rtol=1e-11, atol=0)
    h = HW  # omega = 1
    np.testing.assert_allclose(c["d_over_omega"], d_backward_euler(HW, h), rtol=1e-12, atol=0)
    # small h w: ln(rho) ~ -(h w)^2 / 2 is known only to the round-off of rho (~eps), so the
    # relative error of d is bounded by ~eps / (h w)^2 there
    small = np.logspace(-3, -1.5, 7)
    c = damping_curve(method, small)
    err = np.abs(c["d_over_omega"] / d_backward_euler(small, small) - 1)
    assert np.all(err * small**2 < 4 * np.finfo(float).eps), err


def test_be_matrix_is_closed_form():
    x = 0.7
    T = amplification_matrix(make_integrator("be"), x)
    ref = np.array([[1.0, x], [-x, 1.0]]) / (1 + x * x)
    np.testing.assert_allclose(T, ref, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("method,kw", [("midpoint", {}), ("genalpha", {"r": 1.0}), ("theta", {"theta": 0.0})])
def test_conservative_methods_no_damping(method, kw):
    c = damping_curve(method, np.logspace(-2, 4, 13), **kw)
    np.testing.assert_allclose(c["rho"], 1.0, atol=1e-12)
    np.testing.assert_allclose(c["d_over_omega"], 0.0, atol=1e-10)


def test_midpoint_matrix_is_cayley():
    x = 2.0
    T = amplification_matrix(make_integrator("midpoint"), x)
    A = np.array([[0.0, 1.0], [-1.0, 0.0]]) * x  # h * [[0, 1], [-w^2, 0]]
    ref = np.linalg.solve(np.eye(2) - A / 2, np.eye(2) + A / 2)
    np.testing.assert_allclose(T, ref, atol=1e-14)


@pytest.mark.parametrize("r", [0.0, 0.25, 0.5, 0.75, 1.0])
def test_genalpha_rho_infinity_is_r(r):
    # the seed's T (Eq. 2.14) built independently from the coefficients (2.12)
    am, af = (2 * r - 1) / (r + 1), r / (r + 1)
    al = am - af
    be, ga = (1 - al) ** 2 / 4, 0.5 - al
    for hw in (0.3, 3.0, 30.0):
        h, w2 = hw, 1.0
        L = np.array([[1, 0, -h * h * be], [0, 1, -h * ga], [(1 - af) * w2, 0, 1 - am]])
        Rm = np.array([[1, h, h * h / 2 * (1 - 2 * be)], [0, 1, h * (1 - ga)], [-af * w2, 0, -am]])
        ref = np.linalg.solve(L, Rm)
        T = amplification_matrix(make_integrator("genalpha", r=r), hw)
        np.testing.assert_allclose(T, ref, rtol=1e-10, atol=1e-12)
    # rho -> r as h w -> inf (the gap shrinks monotonically)
    gap = [abs(spectral_radius(amplification_matrix(make_integrator("genalpha", r=r), x)) - r)
           for x in (1e2, 1e3, 1e4, 1e5, 1e6)]
    assert all(a >= b - 1e-15 for a, b in itertools.pairwise(gap)), gap
    assert gap[-1] < 2e-4, gap


def test_theta_companion_matrix_matches_eq_2_15():
    th, x = 0.5, 1.7
    T = amplification_matrix(make_integrator("theta", theta=th), x)
    # u_n = u1 + (1-th) h/2 (A u1 + A u_n) + th/3 (u1 - u2 + 2 h A u_n), A = [[0,1],[-1,0]]
    A = np.array([[0.0, 1.0], [-1.0, 0.0]]) * x
    I = np.eye(2)
    L = I - (1 - th) / 2 * A - 2 * th / 3 * A
    B1 = I + (1 - th) / 2 * A + th / 3 * I
    B2 = -th / 3 * I
    ref = np.zeros((4, 4))
    ref[:2, :2] = np.linalg.solve(L, B1)
    ref[:2, 2:] = np.linalg.solve(L, B2)
    ref[2:, :2] = I
    np.testing.assert_allclose(T, ref, atol=1e-13)


def test_damping_monotone_in_knob():
    """Fig. 2.1/2.2: smaller r (larger theta) -> more damping, at every h w."""
    hw = np.logspace(-1, 2, 7)
    g = [damping_curve("genalpha", hw, r=r)["d_over_omega"] for r in (0.0, 0.25, 0.5, 0.75, 1.0)]
    t = [damping_curve("theta", hw, theta=th)["d_over_omega"] for th in (0.0, 0.25, 0.5, 0.75, 1.0)]
    assert all(np.all(a > b) for a, b in itertools.pairwise(g))
    assert all(np.all(a < b) for a, b in itertools.pairwise(t))


def test_trbdf2_l_stable_and_second_order_damping():
    c = damping_curve("trbdf2", [1e-2, 2e-2, 1e6])
    assert c["rho"][-1] < 1e-4
    # d/w = O((h w)^3) for a second-order method vs O(h w) for BE
    assert c["d_over_omega"][1] / c["d_over_omega"][0] == pytest.approx(8.0, rel=0.05)


def test_symplectic_euler_stability_limit():
    c = damping_curve("symplectic_euler", [0.5, 1.9, 2.1])
    np.testing.assert_allclose(c["rho"][:2], 1.0, atol=1e-12)
    assert c["rho"][2] > 1.0


@pytest.mark.parametrize("bad", [0.0, -0.5, float("nan"), float("inf"), "fast"])
def test_damping_curve_refuses_h_omega_outside_its_domain(bad):
    # d/omega = -2 ln(rho) / (h omega) is 0/0 at 0 and negative (energy gain) for h omega < 0: both were
    # returned as numbers (NaN, -d). mutant caught: no domain check
    from physar.errors import ConfigError

    with pytest.raises(ConfigError, match=r"damping_curve: hw must be"):
        damping_curve("be", [0.1, bad])
    c = damping_curve("be", [0.1, 2.0])
    hw = np.array([0.1, 2.0])  # h = 1 s: omega = hw, d / omega = ln(1 + hw^2) / hw (seed Eq. 2.9)
    np.testing.assert_allclose(c["d_over_omega"], d_backward_euler(hw, 1.0) / hw, rtol=1e-10)
