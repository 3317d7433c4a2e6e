"""The fused frame adjoint (physar.mpm.adjoint) against central finite differences and the generic tape path."""

import numpy as np
import pytest
import torch

from physar.mpm import build_model, parse_scene
from physar.mpm.adjoint import FusedFrame
from physar.mpm.torch_bridge import Params, simulate


def _setup(material):
    sc = parse_scene({
        "grid": {"size": 1.0, "resolution": 8},
        "time": {"frame_dt": 0.01, "substeps": 10, "frames": 2},
        "gravity": {"g": [0, 0, -9.81]},
        "body": [{"shape": "box", "min": [0.35, 0.35, 0.3], "max": [0.6, 0.6, 0.55], "E": 2e3, "nu": 0.3,
                  "particles_per_cell": 8, "velocity": [0.3, -0.2, -0.3], "material": material, "yield_stress": 50.0}],
        "collider": [{"shape": "box", "center": [0.45, 0.45, 0.19], "size": [0.6, 0.6, 0.2],
                      "velocity": [0.3, 0.1, 0], "boundary": "slip", "friction": 0.3}],
    })
    model, x0, v0 = build_model(sc)
    n = model.n_particles
    rng = np.random.default_rng(0)
    base = {"E": torch.tensor(2e3 * (1 + 0.2 * rng.random(n))), "nu": torch.tensor(0.25 + 0.1 * rng.random(n)),
            "omega": torch.tensor(rng.random(n)), "v0": torch.tensor(v0)}
    x_ref = torch.tensor(x0 + 0.02 * rng.standard_normal((n, 3)))
    w = torch.tensor(rng.standard_normal((n, 3)))
    return model, x0, base, x_ref, w


def _loss(model, x0, vals, x_ref, w, fused=True, threads=None):
    if threads is not None:
        model._fused = FusedFrame(model, threads=threads)
    p = Params(E=vals["E"], nu=vals["nu"], omega=vals["omega"], x_ref=x_ref, kp=50.0, kd=2.0)
    _, (x, v, _C, F, _Jp) = simulate(model, x0, vals["v0"], p, frames=2, fused=fused)
    return (w * x).sum() + 0.1 * (w * v).sum() + 0.01 * F.sum()


@pytest.mark.parametrize("material", ["fixed_corotated", "snow"])
def test_fused_gradients_match_central_difference(material):
    # 20 substeps in frictional contact with a moving collider, PD actuation on: dL/d(E, nu, omega, v0) vs
    # central differences of the forward-only run (rel. 1e-3), with the two-thread split.
    model, x0, base, x_ref, w = _setup(material)
    rng = np.random.default_rng(1)
    for name, eps in (("E", 1.0), ("nu", 1e-6), ("omega", 1e-6), ("v0", 1e-6)):
        vals = {k: v.clone().requires_grad_(k == name) for k, v in base.items()}
        _loss(model, x0, vals, x_ref, w, threads=2).backward()
        d = torch.tensor(rng.standard_normal(tuple(base[name].shape)))
        with torch.no_grad():
            lp = _loss(model, x0, {**base, name: base[name] + eps * d}, x_ref, w)
            lm = _loss(model, x0, {**base, name: base[name] - eps * d}, x_ref, w)
        fd = (lp - lm) / (2 * eps)
        ad = (vals[name].grad * d).sum()
        assert abs(ad - fd) < 1e-3 * abs(fd), (name, float(ad), float(fd))


def test_fused_equals_generic_tape_path():
    model, x0, base, x_ref, w = _setup("von_mises")
    grads = []
    for fused, threads in ((True, 1), (True, 2), (False, None)):
        vals = {k: v.clone().requires_grad_(True) for k, v in base.items()}
        _loss(model, x0, vals, x_ref, w, fused=fused, threads=threads).backward()
        grads.append({k: vals[k].grad for k in vals})
    for g in grads[:2]:
        for k in g:
            assert torch.allclose(g[k], grads[2][k], rtol=1e-9, atol=1e-12 * float(grads[2][k].abs().max())), k
