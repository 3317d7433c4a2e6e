"""Anisotropic fibre term of the MPM constitutive model (issue 8): Psi_f = (E_f/8)(|F a0|^2 - 1)^2.

References are independent of the Warp code: central finite differences of the numpy energy, closed forms of
uniaxial stretch, rotations (objectivity), the closed-form axial frequency of a clamped bar with stiffness
E + E_f, and central finite differences of the forward simulation for the gradients.
"""

import dataclasses

import numpy as np
import pytest
import torch
import warp as wp

from physar.errors import ConfigError
from physar.mpm import MPMSolver, build_model, diagnostics, parse_scene
from physar.mpm.adjoint import FusedFrame
from physar.mpm.model import elastic_energy_density, stress_kernel
from physar.mpm.torch_bridge import Params, simulate


def _tau(F, E, nu, elastic, fiber, fiber_E):
    """Kirchhoff stress (N, 3, 3) from the Warp kernel used by the solver (no hardening)."""
    n = len(F)
    tau = wp.zeros(n, dtype=wp.mat33d)
    a = lambda v, dt: wp.array(np.ascontiguousarray(v, dtype=np.float64), dtype=dt)
    wp.launch(stress_kernel, n,
              inputs=[a(F, wp.mat33d), a(np.ones(n), wp.float64), a(np.broadcast_to(E, (n,)), wp.float64),
                      a(np.broadcast_to(nu, (n,)), wp.float64),
                      wp.array(np.broadcast_to(elastic, (n,)).astype(np.int32), dtype=wp.int32),
                      wp.zeros(n, dtype=wp.int32), wp.zeros(n, dtype=wp.vec4d), a(fiber, wp.vec3d),
                      a(np.broadcast_to(fiber_E, (n,)), wp.float64)],
              outputs=[tau])
    return tau.numpy().copy()


def _unit(a):
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def _random_F(rng, n, scale=0.25):
    F = np.eye(3) + scale * rng.standard_normal((n, 3, 3))
    F[np.linalg.det(F) < 0] *= -1.0  # det F > 0
    return F


@pytest.mark.parametrize("elastic", [0, 1, 2, 3])
def test_kirchhoff_stress_is_energy_derivative(elastic):
    # tau = (dPsi/dF) F^T with dPsi/dF by central differences of the numpy energy (isotropic law + fibre term);
    # random F, random fibre directions and moduli, two particles without fibre (zero direction).
    rng = np.random.default_rng(0)
    n = 40
    F = _random_F(rng, n)
    E = 1e4 * (1 + rng.random(n))
    nu = 0.1 + 0.3 * rng.random(n)
    a0 = _unit(rng.standard_normal((n, 3)))
    Ef = 3e4 * rng.random(n)
    a0[:2], Ef[:2] = 0.0, 0.0
    el = np.full(n, elastic)
    tau = _tau(F, E, nu, el, a0, Ef)
    eps = 1e-6
    P = np.zeros((n, 3, 3))
    for i in range(3):
        for j in range(3):
            D = np.zeros((3, 3))
            D[i, j] = eps
            P[:, i, j] = (elastic_energy_density(F + D, E, nu, el, a0, Ef)
                          - elastic_energy_density(F - D, E, nu, el, a0, Ef)) / (2 * eps)
    tau_fd = P @ np.transpose(F, (0, 2, 1))
    err = np.linalg.norm(tau - tau_fd, axis=(1, 2)) / np.linalg.norm(tau_fd, axis=(1, 2))
    print("max rel err", err.max())
    assert err.max() < 1e-6
    # the fibre term really contributes (the test would fail if the kernel ignored it)
    tau_iso = _tau(F, E, nu, el, a0, 0.0)
    assert np.linalg.norm(tau - tau_iso) > 0.1 * np.linalg.norm(tau)
    assert np.abs(tau[:2] - tau_iso[:2]).max() == 0.0  # no fibre -> exactly the isotropic law


@pytest.mark.parametrize("e", [1e-4, 1e-2, 0.2, -0.1])
def test_uniaxial_stretch_along_vs_across_fibre(e):
    # F = diag(1 + e, 1, 1): fibre along x -> I4 = (1+e)^2, tau_11 gains (E_f/2)((1+e)^2 - 1)(1+e)^2 exactly;
    # fibre along y (or z) -> I4 = 1, no fibre stress.  Small e: the difference is E_f e (1 + O(e)).
    E, nu, Ef = 1e4, 0.3, 5e4
    F = np.diag([1 + e, 1.0, 1.0])[None].repeat(3, 0)
    a0 = np.eye(3)
    tau = _tau(F, E, nu, 0, a0, Ef)
    exact = 0.5 * Ef * ((1 + e) ** 2 - 1) * (1 + e) ** 2
    d = tau[0] - tau[1]
    assert abs(d[0, 0] - exact) < 1e-10 * Ef * abs(e)
    assert np.abs(d - np.diag([d[0, 0], 0, 0])).max() < 1e-10 * Ef * abs(e)  # only tau_11 changes
    assert np.abs(tau[1] - tau[2]).max() < 1e-10 * E  # across: isotropic response, y or z alike
    assert abs(d[0, 0] - Ef * e) <= 3 * Ef * e * e + 1e-10 * Ef
    iso = _tau(F, E, nu, 0, a0, 0.0)
    assert np.abs(tau[1] - iso[1]).max() < 1e-10 * E
    if abs(e) < 1e-3:  # nu = 0: the total small-strain uniaxial stiffness along the fibre is E + E_f
        t0 = _tau(F[:1], E, 0.0, 0, a0[:1], Ef)[0, 0, 0]
        assert abs(t0 / e - (E + Ef)) < 3 * abs(e) * (E + Ef)


@pytest.mark.parametrize("elastic", [0, 1, 2, 3])
def test_stress_is_objective(elastic):
    # tau(Q F) = Q tau(F) Q^T for rotations Q (a0 lives in the rest frame and is not rotated)
    rng = np.random.default_rng(3)
    n = 20
    F = _random_F(rng, n)
    a0 = _unit(rng.standard_normal((n, 3)))
    Ef = 2e4 * (0.5 + rng.random(n))
    Q, _ = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    Q[np.linalg.det(Q) < 0] *= -1.0
    t1 = _tau(F, 1e4, 0.3, elastic, a0, Ef)
    t2 = _tau(Q @ F, 1e4, 0.3, elastic, a0, Ef)
    ref = Q @ t1 @ np.transpose(Q, (0, 2, 1))
    assert np.abs(t2 - ref).max() < 1e-9 * np.abs(t1).max()


def _bar_scene(fiber, fiber_E):
    E, rho, L = 1e4, 1000.0, 0.5
    return parse_scene({
        "grid": {"size": 1.0, "resolution": 32},
        "time": {"frame_dt": 0.01, "substeps": 10, "frames": 40},
        "gravity": {"g": [0, 0, 0]},
        "boundary": {"ground": "slip", "walls": "sticky"},
        "body": [{"shape": "box", "min": [0.0, 0.375, 0.375], "max": [L, 0.5, 0.5], "E": E, "nu": 0.0,
                  "density": rho, "fiber": fiber, "fiber_E": fiber_E}],
    }), E, rho, L


@pytest.mark.parametrize("direction", ["along", "across"])
def test_clamped_bar_frequency_with_fibres(direction):
    # bar along x clamped at the sticky wall x = 0, nu = 0, first axial mode: f1 = sqrt(E_axial / rho) / (4 L)
    # with E_axial = E + E_f for fibres along the bar and E for fibres across it (same setup as
    # tests/mpm/test_forward.py::test_clamped_bar_first_axial_frequency).
    Ef = 1e4
    sc, E, rho, L = _bar_scene([1, 0, 0] if direction == "along" else [0, 1, 0], Ef)
    model, x, _ = build_model(sc)
    assert np.allclose(model.fiber_E, Ef)
    v = np.zeros_like(x)
    v[:, 0] = 0.05 * np.sin(np.pi * x[:, 0] / (2 * L))
    solver = MPMSolver(model)
    a, b = model.state(x, v), model.state(x, v)
    d0 = diagnostics(model, a.numpy())
    u, ee = [0.0], [d0["elastic_energy"]]
    for _ in range(sc.time.frames):
        a, b = solver.simulate_frame(a, b)
        u.append(a.x.numpy()[:, 0].mean() - x[:, 0].mean())
        ee.append(diagnostics(model, a.numpy())["elastic_energy"])
    u = np.asarray(u)
    t = np.arange(len(u)) * sc.time.frame_dt
    s = np.sign(u[1:])
    idx = np.where(s[1:] * s[:-1] < 0)[0] + 1
    tz = [t[i] + (t[i + 1] - t[i]) * u[i] / (u[i] - u[i + 1]) for i in idx]
    assert len(tz) >= 1, "the bar must swing back through its rest position"
    f = 1 / (2 * tz[0])
    E_ax = E + Ef if direction == "along" else E
    f_exact = np.sqrt(E_ax / rho) / (4 * L)
    print(direction, "f_measured", f, "f_exact", f_exact, "max elastic / initial kinetic",
          max(ee) / d0["kinetic_energy"])
    assert abs(f - f_exact) < 0.05 * f_exact, (f, f_exact)
    # energy report includes the fibre energy: at the turning point the kinetic energy is (mostly) elastic
    # energy; without the fibre term the along-fibre report would show E / (E + E_f) = 1/2 of it
    assert 0.85 < max(ee) / d0["kinetic_energy"] < 1.02


def _setup():
    sc = parse_scene({
        "grid": {"size": 1.0, "resolution": 8},
        "time": {"frame_dt": 0.01, "substeps": 10, "frames": 2},
        "gravity": {"g": [0, 0, -9.81]},
        "body": [{"shape": "box", "min": [0.35, 0.35, 0.3], "max": [0.6, 0.6, 0.55], "E": 2e3, "nu": 0.3,
                  "particles_per_cell": 8, "velocity": [0.3, -0.2, -0.3],
                  "velocity_gradient": [[0.5, 0.2, 0], [0, -0.3, 0.4], [0.1, 0, 0.6]]}],
        "collider": [{"shape": "box", "center": [0.45, 0.45, 0.19], "size": [0.6, 0.6, 0.2],
                      "velocity": [0.3, 0.1, 0], "boundary": "slip", "friction": 0.3}],
    })
    model, x0, v0 = build_model(sc)
    n = model.n_particles
    rng = np.random.default_rng(0)
    fiber = rng.standard_normal((n, 3))  # heterogeneous directions (normalised by the model)
    fiber_E = 2e4 * (0.5 + rng.random(n))
    fiber[:3], fiber_E[:3] = 0.0, 0.0  # some particles without fibre
    model = dataclasses.replace(model, fiber=fiber, fiber_E=fiber_E)
    return model, x0, v0, rng


def test_fused_and_generic_paths_equal_plain_forward_with_fibres():
    model, x0, v0, _ = _setup()
    iso = dataclasses.replace(model, fiber=None, fiber_E=None)
    solver = MPMSolver(model)
    a, b = model.state(x0, v0), model.state(x0, v0)
    a, b = solver.simulate_frame(a, b)
    x_plain = a.x.numpy().copy()
    p = Params(E=torch.tensor(model.E), nu=torch.tensor(model.nu))
    with torch.no_grad():
        for fused, threads in ((True, 1), (True, 2), (False, None)):
            if threads is not None:
                model._fused = FusedFrame(model, threads=threads)
            _, (x, *_rest) = simulate(model, x0, v0, p, frames=1, fused=fused)
            assert np.abs(x.numpy() - x_plain).max() < 1e-10, (fused, threads)
        _, (x_iso, *_rest) = simulate(iso, x0, v0, p, frames=1)
    assert np.abs(x_iso.numpy() - x_plain).max() > 1e-6  # the fibres change the motion (by ~9e-6 m here)


def _loss(model, x0, vals, w, fused=True):
    p = Params(E=vals["E"], nu=vals["nu"], fiber_E=vals["fiber_E"])
    _, (x, v, _C, F, _Jp) = simulate(model, x0, vals["v0"], p, frames=2, fused=fused)
    return (w * x).sum() + 0.1 * (w * v).sum() + 0.01 * F.sum()


def test_gradients_with_fibres_match_central_difference():
    # dL/d(E, nu, v0, fiber_E) through 20 substeps in frictional contact with a moving collider (fused path,
    # two threads) vs central differences (rel. 1e-3); the generic tape path gives the same gradients (rel. 1e-9).
    model, x0, v0, rng = _setup()
    model._fused = FusedFrame(model, threads=2)
    n = model.n_particles
    w = torch.tensor(rng.standard_normal((n, 3)))
    base = {"E": torch.tensor(2e3 * (1 + 0.2 * rng.random(n))), "nu": torch.tensor(0.25 + 0.1 * rng.random(n)),
            "v0": torch.tensor(v0), "fiber_E": torch.tensor(model.fiber_E)}
    grads = {}
    for fused in (True, False):
        vals = {k: v.clone().requires_grad_(True) for k, v in base.items()}
        _loss(model, x0, vals, w, fused=fused).backward()
        grads[fused] = {k: vals[k].grad for k in vals}
    for name, eps in (("E", 1.0), ("nu", 1e-6), ("v0", 1e-6), ("fiber_E", 1.0)):
        d = torch.tensor(rng.standard_normal(tuple(base[name].shape)))
        if name == "fiber_E":
            d[base["fiber_E"] == 0] = 0.0  # stays 0 where there is no fibre direction
        with torch.no_grad():
            lp = _loss(model, x0, {**base, name: base[name] + eps * d}, w)
            lm = _loss(model, x0, {**base, name: base[name] - eps * d}, w)
        fd = (lp - lm) / (2 * eps)
        ad = (grads[True][name] * d).sum()
        print(name, float(ad), float(fd))
        assert abs(ad - fd) < 1e-3 * abs(fd), (name, float(ad), float(fd))
        g, ref = grads[True][name], grads[False][name]
        assert torch.allclose(g, ref, rtol=1e-9, atol=1e-12 * float(ref.abs().max())), name


def test_isotropic_default_and_energy():
    # no fibre arguments = zeros; fibre energy (E_f/8)(I4 - 1)^2 added to the reported energy density
    model, *_ = _setup()
    iso = dataclasses.replace(model, fiber=None, fiber_E=None)
    assert iso.fiber.shape == (model.n_particles, 3) and not iso.anisotropic and model.anisotropic
    assert np.allclose(np.linalg.norm(model.fiber[3:], axis=1), 1.0)
    e = 0.1
    F = np.diag([1 + e, 1.0, 1.0])[None]
    psi = elastic_energy_density(F, np.array([1e4]), np.array([0.0]), np.array([0]), np.array([[1.0, 0, 0]]),
                                 np.array([2e4]))
    assert np.isclose(psi[0], 0.5 * 1e4 * e * e + 2e4 / 8 * ((1 + e) ** 2 - 1) ** 2, rtol=1e-12)
    assert np.isclose(elastic_energy_density(F, np.array([1e4]), np.array([0.0]), np.array([0]))[0],
                      0.5 * 1e4 * e * e, rtol=1e-12)


def test_bad_fibre_input_raises_config_error():
    model, *_ = _setup()
    n = model.n_particles
    rep = lambda **kw: dataclasses.replace(model, **kw)
    with pytest.raises(ConfigError, match="'fiber' must be"):
        rep(fiber=np.ones((n, 2)))
    with pytest.raises(ConfigError, match="'fiber' must be"):
        rep(fiber=np.full((n, 3), np.nan))
    with pytest.raises(ConfigError, match="'fiber_E' must be"):
        rep(fiber_E=np.ones(n + 1))
    with pytest.raises(ConfigError, match=">= 0"):
        rep(fiber_E=-np.ones(n))
    with pytest.raises(ConfigError, match="zero 'fiber' direction"):
        rep(fiber=np.zeros((n, 3)), fiber_E=np.ones(n))
    body = {"shape": "box", "min": [0.1] * 3, "max": [0.2] * 3}
    with pytest.raises(ConfigError, match="fiber"):
        parse_scene({"body": [{**body, "fiber_E": 1e3}]})
    with pytest.raises(ConfigError, match="fiber_E"):
        parse_scene({"body": [{**body, "fiber": [1, 0, 0], "fiber_E": -1.0}]})
