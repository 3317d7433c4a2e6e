"""Which deformation gradient shapes the object's Gaussians (TrainConfig.render_deformation), applied by
render_scene to every render of the object: "none" (I, the default), "state" (the F given: the simulator's, seed
Eq. 4, or a per-frame fit's least-squares F), "positions" (the least-squares fit over lattice neighbours). The
simulator's F itself, which the Eq. 11 regulariser evaluates, does not depend on the option."""

import numpy as np
import pytest
import torch

from physar.recon.train import (
    Appearance,
    Physics,
    Rig,
    TrainConfig,
    load_dataset,
    object_deformation,
    render_scene,
    simulate_clip,
)


@pytest.fixture(scope="module")
def data(tiny_scene):
    return load_dataset(tiny_scene)


def _lstsq_deformation(X, x, pairs):
    """Per particle i: F = argmin sum_j |(x_j - x_i) - F (X_j - X_i)|^2 over its lattice neighbours j (numpy
    least squares, written independently of Rig.deformation_from_neighbours)."""
    nb = [[] for _ in range(len(X))]
    for i, j in pairs:
        nb[i].append(j)
        nb[j].append(i)
    out = np.empty((len(X), 3, 3))
    for i, js in enumerate(nb):
        dX, dx = X[js] - X[i], x[js] - x[i]
        out[i] = np.linalg.lstsq(dX, dx, rcond=None)[0].T
    return out


def test_the_simulators_F_does_not_depend_on_the_rendering_rule(data):
    """simulate_clip yields the same positions and the same object F (the simulator's, which the Eq. 11
    regulariser evaluates) under every render_deformation; that F differs from the least-squares fit of the
    positions (MPM integrates F from grid velocities) and from I. Mutant caught: simulate_clip yielding the
    render F (the regulariser would see I under "none")."""
    out = {}
    for mode in ("state", "positions", "none"):
        rig = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0), render_deformation=mode))
        kin = rig.kinematics(data.rotations, data.root_t)
        out[mode] = [(xo.numpy(), Fo.numpy()) for _, xo, Fo, *_ in simulate_clip(rig, Physics.init(rig), kin, 4,
                                                                                 grad=False)]
    pairs = rig.pairs.numpy()
    for (xs, Fs), (xp, Fp), (xn, Fn) in zip(out["state"], out["positions"], out["none"], strict=True):
        np.testing.assert_array_equal(xs, xp)
        np.testing.assert_array_equal(xs, xn)
        np.testing.assert_array_equal(Fs, Fp)
        np.testing.assert_array_equal(Fs, Fn)
        assert np.abs(Fs - _lstsq_deformation(rig.Xo, xs, pairs)).max() > 1e-4
        assert np.abs(Fs - np.eye(3)).max() > 1e-4


def test_object_deformation_applies_the_rule(data):
    """object_deformation(x, F): "none" gives I, "state" gives F as passed, "positions" the least-squares F of x
    (checked against an independent numpy fit, 1e-9) on a sheared lattice; with F = None (per-frame positions)
    "state" too gives the least-squares F. Mutants caught: "state" replacing F, "none" passing F through,
    "positions" fitting the rest lattice, "state" drawing I for per-frame positions."""
    rig0 = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0)))
    G = np.array([[1.1, 0.2, 0.0], [0.0, 0.95, 0.1], [0.05, 0.0, 1.0]])
    x = torch.as_tensor(rig0.Xo @ G.T)
    F_given = torch.full((len(x), 3, 3), 7.0, dtype=torch.float64)
    want = {"none": np.broadcast_to(np.eye(3), F_given.shape), "state": F_given.numpy(),
            "positions": _lstsq_deformation(rig0.Xo, x.numpy(), rig0.pairs.numpy())}
    np.testing.assert_allclose(want["positions"], np.broadcast_to(G, F_given.shape), atol=1e-9)
    for mode, ref in want.items():
        rig = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0), render_deformation=mode))
        np.testing.assert_allclose(object_deformation(rig, x, F_given).numpy(), ref, atol=1e-9, err_msg=mode)
        # F = None (per-frame positions, whose F is not computed unless the rule uses it): "none" gives I, the
        # other rules the least-squares F of x
        ref_none = want["none"] if mode == "none" else want["positions"]
        np.testing.assert_allclose(object_deformation(rig, x, None).numpy(), ref_none, atol=1e-9, err_msg=mode)


def test_render_scene_renders_through_the_rule(data):
    """Under "none" a render with any object F equals the render with F = I (under "state"), and differs from
    the render with that F under "state". Mutant caught: render_scene drawing the F it is given whatever the
    option."""
    rig_n = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0), render_deformation="none"))
    rig_s = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0), render_deformation="state"))
    kin = rig_n.kinematics(data.rotations, data.root_t)
    n = rig_n.no + rig_n.nh + rig_n.nb
    g = torch.Generator().manual_seed(0)
    app = Appearance(torch.rand(n, 1, 3, generator=g), torch.full((n,), 2.0), torch.full((n, 3), np.log(0.5 * rig_n.h)))
    xo = torch.as_tensor(rig_n.Xo)
    F = torch.tensor([[1.6, 0.3, 0.0], [0.0, 0.7, 0.0], [0.0, 0.2, 1.3]], dtype=torch.float64).expand(rig_n.no, 3, 3)
    eye = torch.eye(3, dtype=torch.float64).expand(rig_n.no, 3, 3)
    args = (kin["ref"][0], kin["A_h"][0], kin["xb"][0], kin["A_b"][0])
    with torch.no_grad():
        a = render_scene(rig_n, app, xo, F, *args).rgb
        b = render_scene(rig_s, app, xo, eye, *args).rgb
        c = render_scene(rig_s, app, xo, F, *args).rgb
    torch.testing.assert_close(a, b)
    assert (a - c).abs().max() > 1e-2
