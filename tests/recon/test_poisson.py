"""Learned Poisson ratio of the reconstruction (seed 002 §4.3: spatially varying E and nu; bounds
0.2 < nu < 0.4 of seed App. B): initial value, bounds, and the gradient through the differentiable MPM
against central finite differences."""

import numpy as np
import pytest
import torch

from physar.errors import ConfigError
from physar.recon.train import Physics, Rig, TrainConfig, load_dataset, load_train_config, simulate_clip


def _rig(scene, **kw):
    ds = load_dataset(scene)
    return ds, Rig(ds.meta, TrainConfig(material_grid=(2, 2, 2), **kw))


def test_initial_nu_is_the_scene_value_and_stays_in_bounds(tiny_scene):
    ds, rig = _rig(tiny_scene)
    ph = Physics.init(rig)
    assert np.allclose(ph.nu_object(rig).numpy(), ds.meta["object"]["nu"], atol=1e-12)
    with torch.no_grad():
        ph.nu_logit.copy_(torch.tensor([-50.0, 50.0] * 4, dtype=torch.float64))
    nu = ph.nu_object(rig)
    assert nu.min() >= 0.2 - 1e-12 and nu.max() <= 0.4 + 1e-12 and nu.max() - nu.min() > 0.1
    # the scene's nu outside the learned bounds starts at the nearest bound; not learning nu keeps the scene's value
    nu_scene = ds.meta["object"]["nu"]
    _, rig2 = _rig(tiny_scene, nu_min=nu_scene + 0.02, nu_max=nu_scene + 0.1)
    assert np.allclose(Physics.init(rig2).nu_object(rig2).numpy(), nu_scene + 0.02, atol=1e-3)
    _, rig3 = _rig(tiny_scene, learn_nu=False, learn_human_E=False)
    ph3 = Physics.init(rig3)
    assert ph3.nu_logit is None and len(ph3.leaves()) == 2
    assert np.all(ph3.params(rig3).nu.numpy() == ds.meta["object"]["nu"])


def test_nu_bounds_validated(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text("[train]\nnu_min = 0.4\nnu_max = 0.3\n")
    with pytest.raises(ConfigError, match="nu_min"):
        load_train_config(p)


def test_gradient_wrt_nu_matches_finite_differences(tiny_scene):
    ds, rig = _rig(tiny_scene)
    kin = rig.kinematics(ds.rotations, ds.root_t)
    ph = Physics.init(rig)
    w = torch.linspace(-1.0, 1.0, rig.no, dtype=torch.float64)[:, None] * torch.tensor([1.0, 0.5, 2.0],
                                                                                        dtype=torch.float64)

    def loss(z: torch.Tensor) -> torch.Tensor:
        ph.nu_logit = z
        out = 0.0
        for _, xo, *_ in simulate_clip(rig, ph, kin, 3):
            out = out + (w * xo).sum()
        return out

    z0 = ph.nu_logit.detach().clone() + torch.tensor([0.3, -0.2, 0.1, 0.0, -0.4, 0.2, 0.5, -0.1],
                                                      dtype=torch.float64)
    z = z0.clone().requires_grad_(True)
    loss(z).backward()
    g = z.grad.clone()
    assert torch.all(torch.isfinite(g)) and g.abs().max() > 0
    d = torch.tensor([1.0, -0.5, 0.3, 0.8, -1.0, 0.2, 0.6, -0.7], dtype=torch.float64)
    eps = 1e-4
    with torch.no_grad():
        fd = (loss(z0 + eps * d) - loss(z0 - eps * d)) / (2 * eps)
    assert abs(float(fd)) > 1e-9
    assert float(g @ d) == pytest.approx(float(fd), rel=1e-3)
