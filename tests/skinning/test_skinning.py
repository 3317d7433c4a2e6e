"""Skeletons, FK, LBS (seed 002, Eq. 1), capsule humanoid, inside tests (gating mask of Eq. 7)."""

import math

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from physar.errors import PhysarError
from physar.skinning import (
    CapsuleBody,
    Skeleton,
    axis_angle_to_matrix,
    forward_kinematics,
    invert_rigid,
    lbs,
    lbs_gaussians,
    load_smpl_npz,
    procedural_humanoid,
    rigid,
    winding_number,
)

D = torch.float64
gen = torch.Generator().manual_seed(0)


def _random_rigid(n, seed):
    r = Rotation.random(n, random_state=seed).as_matrix()
    t = np.random.default_rng(seed).normal(size=(n, 3))
    return rigid(torch.tensor(r), torch.tensor(t))


def test_axis_angle_matches_scipy_and_small_angles():
    aa = torch.randn(50, 3, dtype=D, generator=gen)
    assert torch.allclose(axis_angle_to_matrix(aa), torch.tensor(Rotation.from_rotvec(aa.numpy()).as_matrix()),
                          atol=1e-12)
    tiny = torch.tensor([[1e-9, -2e-9, 0.5e-9]], dtype=D)
    assert torch.allclose(axis_angle_to_matrix(tiny), torch.tensor(Rotation.from_rotvec(tiny.numpy())
                                                                   .as_matrix()), atol=1e-15)


def test_lbs_with_identity_transforms_is_identity():
    pts = torch.randn(100, 3, dtype=D, generator=gen)
    rots = axis_angle_to_matrix(torch.randn(100, 3, dtype=D, generator=gen))
    w = torch.softmax(torch.randn(100, 5, dtype=D, generator=gen), -1)
    eye = torch.eye(4, dtype=D).expand(5, 4, 4)
    mu, R, _ = lbs(pts, w, eye, rots)
    assert torch.allclose(mu, pts, atol=1e-14) and torch.allclose(R, rots, atol=1e-14)


def test_single_rigid_bone_moves_points_rigidly():
    pts = torch.randn(200, 3, dtype=D, generator=gen)
    B = _random_rigid(4, seed=1)
    w = torch.zeros(200, 4, dtype=D)
    w[:, 2] = 1.0
    mu, _, _ = lbs(pts, w, B)
    expect = pts @ B[2, :3, :3].T + B[2, :3, 3]
    assert torch.allclose(mu, expect, atol=1e-13)
    exact = "donot_use_mm_for_euclid_dist"
    assert torch.allclose(torch.cdist(mu, mu, compute_mode=exact), torch.cdist(pts, pts, compute_mode=exact),
                          atol=1e-12)
    # the same through sparse weights (index, value) pairs
    idx = torch.tensor([[2, 0]]).expand(200, 2)
    val = torch.tensor([[1.0, 0.0]], dtype=D).expand(200, 2)
    assert torch.allclose(lbs(pts, (idx, val), B)[0], expect, atol=1e-13)


def test_fk_composes_parent_transforms():
    parents = torch.tensor([-1, 0, 1, 0, 3])
    L = _random_rigid(5, seed=2)
    G = forward_kinematics(parents, L)
    assert torch.allclose(G[2], L[0] @ L[1] @ L[2], atol=1e-12)
    assert torch.allclose(G[4], L[0] @ L[3] @ L[4], atol=1e-12)
    # batched
    Lb = torch.stack([L, _random_rigid(5, seed=3)])
    Gb = forward_kinematics(parents, Lb)
    assert torch.allclose(Gb[0], G, atol=1e-12)
    with pytest.raises(PhysarError, match="parents must precede"):
        forward_kinematics(torch.tensor([1, -1]), L[:2])


def test_skeleton_pose_rotates_child_joint_about_parent_joint():
    body = procedural_humanoid(dtype=D)
    sk = body.skeleton
    rots = torch.eye(3, dtype=D).repeat(sk.n_bones, 1, 1)
    ua = sk.index("upperarm.L")
    R = axis_angle_to_matrix(torch.tensor([0.0, math.pi / 2, 0.0], dtype=D))  # about +y
    rots[ua] = R
    G = sk.pose(rots)
    shoulder, elbow = sk.rest_global[ua, :3, 3], sk.rest_global[sk.index("forearm.L"), :3, 3]
    assert torch.allclose(G[sk.index("forearm.L"), :3, 3], shoulder + R @ (elbow - shoulder), atol=1e-12)
    assert torch.allclose(G[sk.index("head")], sk.rest_global[sk.index("head")], atol=1e-12)
    assert torch.allclose(sk.bone_transforms(sk.pose(torch.eye(3, dtype=D).repeat(sk.n_bones, 1, 1))),
                          torch.eye(4, dtype=D).expand(sk.n_bones, 4, 4), atol=1e-12)


def test_humanoid_rest_pose_and_rigid_root_motion_are_exact():
    body = procedural_humanoid(dtype=D)
    pts = body.sample_volume(2000, generator=torch.Generator().manual_seed(1), dtype=D)
    w = body.skinning_weights(pts)
    assert torch.allclose(w.sum(1), torch.ones(len(pts), dtype=D), atol=1e-14)
    assert torch.all(w[:, body.skeleton.index("root")] == 0) and torch.all(w >= 0)
    n = body.skeleton.n_bones
    rest = body.pose_points(pts, torch.eye(3, dtype=D).repeat(n, 1, 1))
    assert torch.allclose(rest, pts, atol=1e-13)
    # rotating only the root (plus a translation) moves every point rigidly, whatever the weights
    rots = torch.eye(3, dtype=D).repeat(n, 1, 1)
    R = axis_angle_to_matrix(torch.tensor([0.3, -0.2, 1.1], dtype=D))
    rots[0] = R
    t = torch.tensor([0.5, -1.0, 0.2], dtype=D)
    moved = body.pose_points(pts, rots, t)
    c = body.skeleton.rest_global[0, :3, 3]
    assert torch.allclose(moved, (pts - c) @ R.T + c + t, atol=1e-12)


def test_points_bound_to_one_bone_follow_it():
    body = procedural_humanoid(dtype=D)
    body.sigma = 0.02  # sharp falloff: the hand end is then bound to the forearm to round-off
    sk = body.skeleton
    fa = sk.index("forearm.L")
    # points around the hand end of the forearm are (numerically) bound to the forearm only
    pts = body.tails[fa] + 0.02 * torch.randn(50, 3, dtype=D, generator=gen)
    w = body.skinning_weights(pts)
    assert torch.all(w[:, fa] > 1 - 1e-12)
    rots = torch.eye(3, dtype=D).repeat(sk.n_bones, 1, 1)
    rots[sk.index("upperarm.L")] = axis_angle_to_matrix(torch.tensor([0.0, 0.0, 0.7], dtype=D))
    rots[fa] = axis_angle_to_matrix(torch.tensor([0.0, 1.2, 0.0], dtype=D))
    G = sk.pose(rots)
    B = G[fa] @ invert_rigid(sk.rest_global[fa])
    assert torch.allclose(body.pose_points(pts, rots), pts @ B[:3, :3].T + B[:3, 3], atol=1e-10)


def test_capsule_inside_matches_closed_form_and_volume():
    a, b, r = torch.tensor([0.1, -0.2, 0.3], dtype=D), torch.tensor([0.6, 0.4, 0.1], dtype=D), 0.15
    sk = Skeleton(torch.tensor([-1]), rigid(torch.eye(3, dtype=D)[None], a[None]))
    cap = CapsuleBody(sk, a[None], b[None], torch.tensor([r], dtype=D))
    p = torch.rand(200_000, 3, dtype=D, generator=gen) * 1.4 - torch.tensor([0.3, 0.6, 0.3], dtype=D)
    # closed form: cylinder part (axial coordinate in [0, L], radial distance < r) or one of the end balls
    axis = (b - a) / torch.linalg.vector_norm(b - a)
    L = torch.linalg.vector_norm(b - a).item()
    s = (p - a) @ axis
    rad = torch.linalg.vector_norm((p - a) - s[:, None] * axis, dim=1)
    expect = (((s >= 0) & (s <= L) & (rad < r)) | (torch.linalg.vector_norm(p - a, dim=1) < r)
              | (torch.linalg.vector_norm(p - b, dim=1) < r))
    got = cap.inside(p)
    assert torch.equal(got, expect)
    vol = got.double().mean().item() * 1.4**3
    assert vol == pytest.approx(math.pi * r**2 * L + 4 / 3 * math.pi * r**3, rel=0.03)


def test_gating_mask_zero_outside_humanoid():
    body = procedural_humanoid(dtype=D)
    inside_pts = body.sample_volume(500, generator=torch.Generator().manual_seed(3), dtype=D)
    pillow = torch.rand(500, 3, dtype=D, generator=gen) * 0.3 + torch.tensor([0.3, -0.6, 1.0], dtype=D)
    omega = body.inside(torch.cat([inside_pts, pillow])).double()
    assert torch.all(omega[:500] == 1) and torch.all(omega[500:] == 0)


def test_winding_number_on_sphere_against_closed_form():
    sph = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    v, f = torch.tensor(sph.vertices), torch.tensor(sph.faces)
    p = torch.rand(3000, 3, dtype=D, generator=gen) * 3 - 1.5
    rr = torch.linalg.vector_norm(p, dim=1)
    keep = (rr < 0.98) | (rr > 1.0)  # away from the chordal gap between the mesh and the sphere
    w = winding_number(p[keep], v, f)
    assert torch.allclose(w[rr[keep] < 0.98], torch.ones(1, dtype=D), atol=1e-9)
    assert torch.allclose(w[rr[keep] > 1.0], torch.zeros(1, dtype=D), atol=1e-9)
    # flipped faces give -1 inside; BodyModel.inside is orientation-agnostic via |w|
    assert torch.allclose(winding_number(torch.zeros(1, 3, dtype=D), v, f.flip(1)), -torch.ones(1, dtype=D))


def test_lbs_gaussians_covariance_is_rigid_for_one_bone():
    from physar.gaussians import Camera, Gaussians, render

    g = Gaussians.from_values(torch.randn(30, 3, dtype=D, generator=gen) * 0.2 + torch.tensor([0, 0, 3.0],
                              dtype=D), 0.02 + 0.05 * torch.rand(30, 3, dtype=D, generator=gen),
                              torch.full((30,), 0.7, dtype=D), torch.rand(30, 3, dtype=D, generator=gen),
                              quats=torch.randn(30, 4, dtype=D, generator=gen))
    R = axis_angle_to_matrix(torch.tensor([0.1, 0.2, -0.1], dtype=D))
    t = torch.tensor([0.05, -0.03, 0.1], dtype=D)
    B = torch.stack([torch.eye(4, dtype=D), rigid(R, t)])
    w = torch.zeros(30, 2, dtype=D)
    w[:, 1] = 1
    gs, F = lbs_gaussians(g, w, B)
    cam = Camera(40.0, 40.0, 12.0, 12.0, 24, 24, torch.eye(3, dtype=D), torch.zeros(3, dtype=D))
    a = render(gs, cam, F=F, colors=torch.ones(30, 3, dtype=D))
    b = render(g.transformed(R.expand(30, 3, 3), t.expand(30, 3)), cam, colors=torch.ones(30, 3, dtype=D))
    assert torch.allclose(a.alpha, b.alpha, atol=1e-12)


def test_smpl_npz_template(tmp_path):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(40, 3))
    W = rng.random((40, 4))
    W /= W.sum(1, keepdims=True)
    Jreg = rng.random((4, 40))
    Jreg /= Jreg.sum(1, keepdims=True)
    kin = np.array([[4294967295, 0, 1, 1], [0, 1, 2, 3]], dtype=np.uint32)
    np.savez(tmp_path / "m.npz", v_template=v, f=np.array([[0, 1, 2]]), weights=W, kintree_table=kin,
             J_regressor=Jreg)
    body = load_smpl_npz(tmp_path / "m.npz")
    assert body.skeleton.parents.tolist() == [-1, 0, 1, 1]
    assert np.allclose(body.skeleton.rest_global[:, :3, 3].numpy(), Jreg @ v)
    eye = torch.eye(4, dtype=D).expand(4, 4, 4)
    assert torch.allclose(body.skin_vertices(eye), body.vertices, atol=1e-14)
    with pytest.raises(PhysarError, match="pickle"):
        load_smpl_npz(tmp_path / "SMPL_NEUTRAL.pkl")
    np.savez(tmp_path / "bad.npz", v_template=v)
    with pytest.raises(PhysarError, match="lacks array 'f'"):
        load_smpl_npz(tmp_path / "bad.npz")


@pytest.mark.parametrize("bad", [0, -1.7, float("nan"), 17.0, "1.7"])
def test_procedural_humanoid_refuses_a_height_no_person_has(bad):
    # height 0 built a body of zero-length bones (NaN frames downstream); 17 (cm typed as dm) a giant.
    # mutant caught: no height check
    with pytest.raises(PhysarError, match=r"procedural_humanoid: height = .* must be a person's height in metres"):
        procedural_humanoid(bad)


def test_procedural_humanoid_scales_with_its_height():
    # the top of the head (tip at 1.60 m, radius 0.10 m for 1.7 m) scales linearly: 1.6 (1.5 / 1.7) + 0.1 (1.5 / 1.7)
    # mutant caught: the height ignored in the check's conversion (float(height) dropped for h)
    b = procedural_humanoid(1.5, dtype=torch.float64)
    top = float((b.tails[:, 2] + b.radii).max())
    assert top == pytest.approx(1.7 * 1.5 / 1.7, abs=1e-9)
