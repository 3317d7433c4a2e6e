"""Which deformation gradient shapes the object's Gaussians after the physics (TrainConfig.render_deformation):
the simulator's F (seed Eq. 4; after a plastic return map, the elastic part only) or the total deformation of the
object's particles, the least-squares fit over lattice neighbours (as the Eq. 9 flow stage renders)."""

import numpy as np
import pytest
import torch

from physar.recon.train import Physics, Rig, TrainConfig, load_dataset, object_deformation, simulate_clip


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


def test_positions_mode_renders_the_total_deformation_and_state_mode_the_simulators(data):
    """render_deformation = "positions": F_obj of every frame equals the least-squares deformation of the yielded
    object positions (independent numpy fit, 1e-9); "state": F_obj is the simulator's own F, which differs from
    that fit (MPM's F is integrated from grid velocities), while the positions are the same in both modes.
    "none": F_obj = I. Mutants caught: the option ignored (either way), the positions mode fitting the rest
    lattice (F = I)."""
    out = {}
    for mode in ("state", "positions", "none"):
        rig = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0), render_deformation=mode))
        kin = rig.kinematics(data.rotations, data.root_t)
        ph = Physics.init(rig)
        out[mode] = [(xo.numpy(), Fo.numpy()) for _, xo, Fo, *_ in simulate_clip(rig, ph, kin, 4, grad=False)]
    pairs = rig.pairs.numpy()
    moved = 0.0
    for (xs, Fs), (xp, Fp) in zip(out["state"], out["positions"], strict=True):
        np.testing.assert_array_equal(xs, xp)
        ref = _lstsq_deformation(rig.Xo, xp, pairs)
        np.testing.assert_allclose(Fp, ref, atol=1e-9)
        assert np.abs(Fs - ref).max() > 1e-4
        moved = max(moved, np.abs(ref - np.eye(3)).max())
    assert moved > 1e-3  # the object deformed: F = I would not pass
    for (xs, _), (xn, Fn) in zip(out["state"], out["none"], strict=True):  # "none": rigid Gaussians, same motion
        np.testing.assert_array_equal(xs, xn)
        np.testing.assert_array_equal(Fn, np.broadcast_to(np.eye(3), Fn.shape))


def test_one_rendering_rule_for_simulated_and_per_frame_motions(data):
    """object_deformation: "none" gives I whatever the motion; "state" gives the simulator's F when there is one
    and the least-squares F of the positions for a per-frame fit (no simulator F); "positions" always the
    least-squares F. Mutant caught: "state" ignoring the simulator's F, "none" falling back to neighbours."""
    x = torch.as_tensor(Rig(data.meta, TrainConfig(material_grid=(0, 0, 0))).Xo) * 1.1  # a 10 % dilation: F = 1.1 I
    Fs = torch.full((len(x), 3, 3), 7.0, dtype=torch.float64)
    for mode, with_state, want in (("none", True, "I"), ("none", False, "I"), ("state", True, "state"),
                                   ("state", False, "lsq"), ("positions", True, "lsq")):
        rig = Rig(data.meta, TrainConfig(material_grid=(0, 0, 0), render_deformation=mode))
        F = object_deformation(rig, x, Fs if with_state else None).numpy()
        ref = {"I": np.broadcast_to(np.eye(3), F.shape), "state": Fs.numpy(),
               "lsq": np.broadcast_to(1.1 * np.eye(3), F.shape)}[want]
        np.testing.assert_allclose(F, ref, atol=1e-9, err_msg=f"{mode} {with_state}")
