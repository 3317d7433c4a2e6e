"""Gradients through >= 20 MPM substeps equal central finite differences (rel. 1e-3), incl. at F = I.

The Hencky law (used by the von Mises / Drucker-Prager materials) differentiates through wp.svd3, whose
adjoint is finite but not exact at exactly repeated singular values, so it is not in the F = I test.
"""

import numpy as np
import pytest
import torch
import warp as wp

from physar.mpm import build_model, parse_scene
from physar.mpm.model import stress_kernel
from physar.mpm.neural import NeuralResidual
from physar.mpm.torch_bridge import Params, simulate


@pytest.fixture(scope="module")
def setup():
    sc = parse_scene({
        "grid": {"size": 1.0, "resolution": 8},
        "time": {"frame_dt": 0.01, "substeps": 10, "frames": 2},
        "gravity": {"g": [0, 0, -9.81]},
        "body": [{"shape": "box", "min": [0.35, 0.35, 0.3], "max": [0.6, 0.6, 0.55], "E": 2e3, "nu": 0.3,
                  "particles_per_cell": 1, "velocity": [0.3, -0.2, 0.1]}],
    })
    model, x0, v0 = build_model(sc)
    n = model.n_particles
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    nets = NeuralResidual(latent_dim=8, stress_scale=200.0, F_scale=1e-3)
    for m in (nets.elastic.l3, nets.plastic.l3):  # leave the zero init so that all weights get gradients
        torch.nn.init.normal_(m.weight, std=0.3)
    base = {
        "E": torch.tensor(2e3 * (1 + 0.2 * rng.random(n))),
        "nu": torch.tensor(0.25 + 0.1 * rng.random(n)),
        "omega": torch.tensor(rng.random(n)),
        "l_e": torch.tensor(0.3 * rng.standard_normal((n, 8))),
        "l_p": torch.tensor(0.3 * rng.standard_normal((n, 8))),
    }
    x_ref = torch.tensor(x0 + 0.02 * rng.standard_normal((n, 3)))
    w = torch.tensor(rng.standard_normal((n, 3)))
    return model, x0, v0, nets, base, x_ref, w


def _loss(setup, vals, checkpoint=True):
    model, x0, v0, nets, _base, x_ref, w = setup
    p = Params(E=vals["E"], nu=vals["nu"], omega=vals["omega"], x_ref=x_ref, v_ref=None, l_e=vals["l_e"],
               l_p=vals["l_p"], kp=50.0, kd=2.0)
    _xs, (x, v, _C, _F, _Jp) = simulate(model, x0, v0, p, frames=2, nets=nets, checkpoint=checkpoint)
    return (w * x).sum() + 0.1 * (w * v).sum()


@pytest.mark.parametrize("name,eps", [("E", 1.0), ("nu", 1e-5), ("omega", 1e-5), ("l_e", 1e-5), ("l_p", 1e-5)])
def test_parameter_gradient_matches_central_difference(setup, name, eps):
    _model, _x0, _v0, _nets, base, _x_ref, _w = setup
    vals = {k: v.clone().requires_grad_(k == name) for k, v in base.items()}
    loss = _loss(setup, vals)
    loss.backward()
    g = vals[name].grad
    d = torch.tensor(np.random.default_rng(1).standard_normal(tuple(base[name].shape)))
    with torch.no_grad():
        lp = _loss(setup, {**base, name: base[name] + eps * d})
        lm = _loss(setup, {**base, name: base[name] - eps * d})
    fd = (lp - lm) / (2 * eps)
    ad = (g * d).sum()
    assert abs(ad - fd) < 1e-3 * abs(fd), (float(ad), float(fd))


def test_network_weight_gradients_match_central_difference(setup):
    _model, _x0, _v0, nets, base, _x_ref, _w = setup
    nets.zero_grad()
    loss = _loss(setup, base)
    loss.backward()
    for mod in (nets.elastic, nets.plastic):
        for par in (mod.l1.weight, mod.l2.weight, mod.l3.weight):
            d = torch.randn_like(par)
            ad = (par.grad * d).sum()
            eps = 1e-5
            with torch.no_grad():
                par += eps * d
                lp = _loss(setup, base)
                par -= 2 * eps * d
                lm = _loss(setup, base)
                par += eps * d
            fd = (lp - lm) / (2 * eps)
            assert abs(ad - fd) < 1e-3 * abs(fd), (float(ad), float(fd))


def test_checkpointed_and_plain_gradients_agree(setup):
    _model, _x0, _v0, _nets, base, _x_ref, _w = setup
    grads = []
    for ck in (True, False):
        vals = {k: v.clone().requires_grad_(k == "E") for k, v in base.items()}
        _loss(setup, vals, checkpoint=ck).backward()
        grads.append(vals["E"].grad)
    assert torch.allclose(grads[0], grads[1], rtol=1e-10, atol=0)


def test_checkpointed_gradient_with_per_frame_references(setup):
    # x_ref given per frame by a callable: the checkpointed frame is re-run in backward after the frame
    # loop has moved on, so it must use its own frame's reference (the plain graph is the reference).
    model, x0, v0, _nets, base, x_ref, w = setup
    refs = [x_ref, x_ref + 0.05, x_ref - 0.05]
    grads = []
    for ck in (True, False):
        E = base["E"].clone().requires_grad_(True)
        p = Params(E=E, nu=base["nu"], omega=base["omega"], x_ref=lambda f: (refs[f], None), kp=50.0, kd=2.0)
        _xs, (x, _v, _C, _F, _Jp) = simulate(model, x0, v0, p, frames=3, checkpoint=ck, fused=False)
        (w * x).sum().backward()
        grads.append(E.grad)
    assert torch.allclose(grads[0], grads[1], rtol=1e-10, atol=0)


@pytest.mark.parametrize("elastic", [0, 1, 2])  # Hencky (3) uses svd3: see module docstring
def test_stress_gradient_finite_and_correct_at_identity(elastic):
    # d tau / dF at F = I (repeated singular values) vs central differences of the same kernel.
    rng = np.random.default_rng(2)
    G = rng.standard_normal((3, 3))

    def tau_of(Fnp, grad=False):
        F = wp.array(Fnp[None], dtype=wp.mat33d, requires_grad=grad)
        args = [wp.array([1.0], dtype=wp.float64), wp.array([1e4], dtype=wp.float64),
                wp.array([0.3], dtype=wp.float64), wp.array([elastic], dtype=wp.int32),
                wp.array([0], dtype=wp.int32), wp.zeros(1, dtype=wp.vec4d), wp.zeros(1, dtype=wp.vec3d),
                wp.zeros(1, dtype=wp.float64)]  # no fibre: the isotropic expert law
        tau = wp.zeros(1, dtype=wp.mat33d, requires_grad=grad)
        tape = wp.Tape()
        with tape:
            wp.launch(stress_kernel, 1, inputs=[F, *args[:1], *args[1:]], outputs=[tau])
        return F, tau, tape

    F, tau, tape = tau_of(np.eye(3), grad=True)
    tape.backward(grads={tau: wp.array(G[None], dtype=wp.mat33d)})
    ad = F.grad.numpy()[0]
    assert np.all(np.isfinite(ad))
    eps = 1e-6
    D = rng.standard_normal((3, 3))
    fd = (np.sum(G * tau_of(np.eye(3) + eps * D)[1].numpy()[0]) -
          np.sum(G * tau_of(np.eye(3) - eps * D)[1].numpy()[0])) / (2 * eps)
    assert abs(np.sum(ad * D) - fd) < 1e-5 * max(1.0, abs(fd))
