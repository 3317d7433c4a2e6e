"""Seed 002 rules of the reconstruction's rig, checked against the seed's statements written out by hand:
the omega = 0 surface layer and the object never actuated (§4.2, Eq. 7), every bone whose LBS impact reaches
the object simulated (§4.2; two hands), the body's Young's modulus learned (§4.3), the Eq. 11 regulariser
with the configured weights, and the stability bound of a PD force held over a frame (Alg. 2)."""

import math

import numpy as np
import pytest
import torch

from physar.errors import ConfigError
from physar.mpm import torch_bridge as tb
from physar.recon import scene as S
from physar.recon.train import Physics, Rig, TrainConfig, load_dataset, physics_regulariser, simulate_clip


@pytest.fixture(scope="module")
def data(tiny_scene):
    return load_dataset(tiny_scene)


def _capsule_sd(X, a, b, r):
    """Signed distance to the capsule [a, b] of radius r (written out: distance to the clamped axis point)."""
    ab = b - a
    s = np.clip((X - a) @ ab / (ab @ ab), 0, 1)
    return np.linalg.norm(X - (a + s[:, None] * ab), axis=1) - r


@pytest.mark.parametrize("ppc, layer", [(8, None), (8, 0.004), (27, None)])
def test_omega_is_zero_on_the_surface_layer_and_learnable_inside(data, ppc, layer):
    """omega_i = 0 for body particles within the layer of the surface (seed §4.2: the exterior surface of the
    body is never actuated), learnable (> 0) deeper inside.  Mutant caught: every body particle gated on
    (the inside test without the layer)."""
    rig = Rig(data.meta, TrainConfig(particles_per_cell=ppc, surface_layer=layer, material_grid=(0, 0, 0)))
    body = rig.body  # the body's surface: the union of the capsules (the elbow's overlap included)
    sd = np.min([_capsule_sd(rig.Xh, body.heads[i].numpy(), body.tails[i].numpy(), float(body.radii[i]))
                 for i in range(body.skeleton.n_bones) if body.radii[i] > 0], axis=0)
    depth = 0.5 * rig.h if layer is None else layer
    om = Physics.init(rig).omega(rig).detach().numpy()
    assert np.all(om[:rig.no] == 0.0)
    assert np.all(om[rig.no:][sd >= -depth] == 0.0) and np.all(om[rig.no:][sd < -depth] > 0.0)
    assert 0 < np.sum(sd >= -depth) < rig.nh  # both kinds present


def test_object_receives_no_pd_force_whatever_its_references(data):
    """Object particles move only through contact (seed §4.2): one simulated frame is identical whether the
    object's PD references are the rest shape or 10 cm away.  Mutant caught: omega > 0 on the object."""
    rig = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0)))
    kin = rig.kinematics(data.rotations, data.root_t)
    ph = Physics.init(rig)
    p = ph.params(rig)
    o = torch.as_tensor(rig.origin)
    x = torch.cat([torch.as_tensor(rig.Xo), kin["ref"][0]]) - o
    v = torch.cat([torch.zeros(rig.no, 3, dtype=torch.float64), kin["vref"][1]])  # body moving: force != 0
    out = []
    for shift in (0.0, 0.1):
        p.x_ref = torch.cat([torch.as_tensor(rig.Xo) - o + shift, kin["ref"][1] - o])
        p.v_ref = torch.cat([torch.full((rig.no, 3), shift, dtype=torch.float64), kin["vref"][1]])
        _, (xs, *_rest) = tb.simulate(rig.model, x, v, p, 1)
        out.append(xs.numpy())
    assert np.array_equal(out[0], out[1])
    assert np.abs(out[0][rig.no:] - x.numpy()[rig.no:]).max() > 1e-4  # the body did move


def test_reaching_bones_by_point_to_box_distance():
    """A bone is simulated when its posed capsule comes within the margin of the object: distance from the bone
    axis to the box minus the radius <= margin, by hand for boxes under both forearms (rest-pose axes along x at
    z = 1.42 m, radius 0.04 m).  Left box 5 mm below the left forearm: reached at rest; right box 30 mm below
    the right forearm: reached once the 'flat' press lowers it by 40 mm (frame 2), not at 20 mm.  The upper
    arms (radius 0.05 m, ending 70 mm short of the boxes in x, 45+ mm above) never come within 10 mm.
    Mutants caught: radius not subtracted, only the first frame looked at, one bone per scene."""
    body = S.humanoid(1.7)
    z = 1.42 - 0.04
    left = (np.array([0.55, -0.05, z - 0.005 - 0.1]), np.array([0.72, 0.05, z - 0.005]))
    right = (np.array([-0.72, -0.05, z - 0.03 - 0.1]), np.array([-0.55, 0.05, z - 0.03]))
    poses = S.press_poses(body, np.array([0.0, 0.02, 0.04]))
    rot, root = poses["rotations"], poses["root_translation"]
    assert S.reaching_bones(body, rot, root, [left, right], 0.01) == ["forearm.L", "forearm.R"]
    assert S.reaching_bones(body, rot[:2], root[:2], [left, right], 0.01) == ["forearm.L"]
    assert S.reaching_bones(body, rot[:1], root[:1], [right], 0.01) == []
    # the margin is measured from the capsule's surface: 30 mm away needs a margin >= 30 mm at rest
    assert S.reaching_bones(body, rot[:1], root[:1], [right], 0.031) == ["forearm.R"]
    assert S.reaching_bones(body, rot[:1], root[:1], [right], 0.029) == []


def test_rig_simulates_the_reaching_bones_of_its_clip(data):
    """Given the clip's poses the rig adds every reaching bone that stays in the MPM domain to scene.json's list
    and records it in its meta (a saved model rebuilds the same particles).  Mutant caught: reaching bones
    ignored by the rig, or added although they leave the domain."""
    cfg = TrainConfig(material_grid=(0, 0, 0))
    reach = S.reaching_bones(S.humanoid(data.meta["body"]["height"]), data.rotations, data.root_t,
                             S.object_boxes(data.meta), data.meta["sim"]["size"] / data.meta["sim"]["resolution"])
    rig = Rig(data.meta, cfg, poses=(data.rotations, data.root_t))
    assert "forearm.R" in reach and "forearm.R" in rig.meta["body"]["simulated_bones"]
    # the right upper arm reaches within a cell of the pillow but its shoulder end (x = -0.20 m at rest) lies
    # outside the MPM domain [origin_x, origin_x + size]: it stays kinematic (its particles would be clamped)
    ox, size = data.meta["sim"]["origin"][0], data.meta["sim"]["size"]
    assert "upperarm.R" in reach and not ox <= -0.20 * data.meta["body"]["height"] / 1.7 <= ox + size
    assert "upperarm.R" not in rig.meta["body"]["simulated_bones"]
    again = Rig(rig.meta, cfg)
    assert np.array_equal(again.Xh, rig.Xh)


def test_body_modulus_gradient_matches_finite_differences(data):
    """d/d log E_body of a weighted sum of simulated object positions (3 frames) equals the central difference:
    the body's E is a learned parameter of the simulator (seed §4.3)."""
    rig = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0)))
    kin = rig.kinematics(data.rotations, data.root_t)
    ph = Physics.init(rig)
    w = torch.linspace(-1.0, 1.0, rig.no, dtype=torch.float64)[:, None] * torch.tensor([1.0, 0.5, 2.0],
                                                                                        dtype=torch.float64)

    def loss(z):
        ph.log_E_human = z
        return sum((w * xo).sum() for _, xo, *_ in simulate_clip(rig, ph, kin, 3))

    z0 = ph.log_E_human.detach().clone()
    z = z0.clone().requires_grad_(True)
    loss(z).backward()
    d = torch.linspace(0.5, 1.5, rig.nh, dtype=torch.float64)
    eps = 1e-3
    with torch.no_grad():
        fd = (loss(z0 + eps * d) - loss(z0 - eps * d)) / (2 * eps)
    assert abs(fd) > 1e-6
    assert float(z.grad @ d) == pytest.approx(float(fd), rel=2e-3)


def test_physics_regulariser_is_eq11_with_the_configured_weights(data):
    """R = lambda_law (||E_theta||_2 + ||P_theta||_2) + lambda_omega ||omega||_2 + lambda_feat (||l_e||_2 +
    ||l_p||_2): fresh residual networks output 0, so R = lambda_omega ||omega|| + lambda_feat (||l_e|| + ||l_p||)
    by hand.  Mutants caught: the omega or latent terms dropped, a weight swapped."""
    cfg = TrainConfig(material_grid=(0, 0, 0), residual=True, lambda_omega=0.3, lambda_feat=0.07, lambda_law=5.0)
    rig = Rig(data.meta, cfg)
    ph = Physics.init(rig)
    n = rig.no + rig.nh
    F = torch.eye(3, dtype=torch.float64).repeat(n, 1, 1) * 1.01
    om = ph.omega(rig).detach().numpy()
    exp = 0.3 * np.linalg.norm(om) + 0.07 * (np.linalg.norm(ph.l_e.numpy()) + np.linalg.norm(ph.l_p.numpy()))
    assert float(physics_regulariser(ph, rig, F).detach()) == pytest.approx(exp, rel=1e-12)


def test_held_pd_force_refuses_an_unstable_gain(data):
    """Held over a frame h, the PD velocity update has the factor 1 - omega kd h (omega <= 2): kd >= 1/h is
    refused in one line (Alg. 2 with the synthetic truth's 110 1/s at 30 fps); per-substep forces accept it."""
    h = 1.0 / data.meta["fps"]
    with pytest.raises(ConfigError, match="kd"):
        Rig(data.meta, TrainConfig(kd=1.01 / h))
    Rig(data.meta, TrainConfig(kd=0.99 / h))
    Rig(data.meta, TrainConfig(kd=110.0, kp=3.0e3, pd_hold=False))
    assert math.isclose(Rig(data.meta, TrainConfig()).kp, 200.0)  # seed App. A.3 gains by default
