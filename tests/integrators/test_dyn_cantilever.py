"""Physical verification: a co-rotated cantilever's bending frequency and Rayleigh modal decay."""

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from physar.fem import Corotated, ElasticModel, FESpace, fixed_dofs, solve_static, traction_load
from physar.geometry import box_mesh
from physar.integrators import SolidModel, make_integrator, simulate
from physar.integrators.analysis import dominant_frequency, euler_bernoulli_cantilever_omega

L, B, E, NU, RHO = 1.0, 0.05, 1e6, 0.3, 1000.0


def beam(cells, element="P2", rayleigh=(0.0, 0.0)):
    sp_ = FESpace(box_mesh((L, B, B), cells), element)
    el = ElasticModel(sp_, Corotated(E, NU), density=RHO)
    fixed = fixed_dofs(sp_, box=[[0, 0, 0], [0, B, B]])
    model = SolidModel(el, fixed, rayleigh=rayleigh)
    # initial shape: static deflection under a small tip load (tip ~ 0.5 % of L), then released
    f = traction_load(sp_, [[L, 0, 0], [L, B, B]], [0, 0, -2e-4])
    q0 = solve_static(el, f, fixed, steps=1, tol=1e-7).u
    tip = np.flatnonzero(np.all(np.isclose(sp_.nodes, [L, B, B]), axis=1))[0]
    return model, q0, 3 * tip + 2


def first_mode(model):
    lin = model.linearize(np.zeros(model.n_dofs), np.zeros(model.n_dofs))
    w2, phi = spla.eigsh(lin.K, k=2, M=model.mass_ff, sigma=0, which="LM")
    return np.sqrt(w2), phi


def run(model, q0, tip, periods, per_period, method="midpoint", w=1.6):
    h = 2 * np.pi / w / per_period
    zs, qs = [], []

    def cb(k, s):
        zs.append(s.q[tip])
        qs.append(s.q[model.free])

    simulate(model, make_integrator(method), h, int(periods * per_period), q0, None, callback=cb)
    return h, np.array(zs), np.array(qs)


@pytest.mark.parametrize("cells,tol_eb", [((10, 1, 1), 0.03)])
def test_cantilever_first_bending_frequency(cells, tol_eb):
    model, q0, tip = beam(cells)
    w_fe, _ = first_mode(model)
    w_eb = euler_bernoulli_cantilever_omega(E, RHO, L, B, B)
    h, z, _ = run(model, q0, tip, periods=8, per_period=40)
    w_sim = dominant_frequency(z, h)
    # midpoint: no damping, period error (h w)^2 / 12 ~ 0.2 %
    assert abs(w_sim / w_eb - 1) < tol_eb, (w_sim, w_eb)
    assert min(abs(w_sim / w - 1) for w in w_fe) < 0.006, (w_sim, w_fe)
    # zero-crossing period as a second estimate
    s = np.sign(z - z.mean())
    idx = np.flatnonzero(s[1:] != s[:-1])
    tc = idx + (z.mean() - z[idx]) / (z[idx + 1] - z[idx])
    w_zc = np.pi / (np.diff(tc).mean() * h)
    assert abs(w_zc / w_sim - 1) < 0.01
    # no artificial damping: the amplitude of the last period equals the first
    n = 40
    assert np.ptp(z[-n:]) == pytest.approx(np.ptp(z[:n]), rel=0.02)


def test_rayleigh_damping_gives_modal_decay():
    alpha, beta = 0.15, 0.01
    model, q0, tip = beam((10, 1, 1), rayleigh=(alpha, beta))
    w_fe, phi = first_mode(model)
    # the mode the tip load excites most
    Mq = model.mass_ff @ q0[model.free]
    j = int(np.argmax(np.abs(phi.T @ Mq)))
    w, p = w_fe[j], phi[:, j]
    zeta = alpha / (2 * w) + beta * w / 2
    h, _z, qs = run(model, q0, tip, periods=6, per_period=40, w=w)
    a = qs @ (model.mass_ff @ p)  # modal coordinate
    t = h * np.arange(len(a))
    # peaks of |a|: envelope e^{-zeta w t}
    k = np.flatnonzero((np.abs(a[1:-1]) > np.abs(a[:-2])) & (np.abs(a[1:-1]) >= np.abs(a[2:]))) + 1
    slope = np.polyfit(t[k], np.log(np.abs(a[k])), 1)[0]
    assert slope == pytest.approx(-zeta * w, rel=0.03), (slope, -zeta * w)


@pytest.mark.slow
def test_cantilever_frequency_finer_mesh():
    model, q0, tip = beam((20, 2, 2))
    w_eb = euler_bernoulli_cantilever_omega(E, RHO, L, B, B)
    h, z, _ = run(model, q0, tip, periods=8, per_period=40)
    assert abs(dominant_frequency(z, h) / w_eb - 1) < 0.01
