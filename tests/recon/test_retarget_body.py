"""SMPL poses retargeted onto mesh bodies (issue 17; seed 002 §4.1: SMPL-driven LBS): anny by joint-name
correspondence with its A-pose brought to SMPL's T-pose, and a user's SMPL model file (exact).

The sources are the test's own: SMPL's kinematic tree (joint table and parents written out from the SMPL
definition), rest joints laid out here, forward kinematics and SMPL's LBS written out in numpy, axis-angle
turned into matrices by scipy (a peer library). Camera and global orientation are random.
With the anny package but no cache (``$PHYSAR_CACHE`` or ``~/.cache/physar/anny_body.npz``), the first test
builds it once (about 2.5 min on this machine); later loads take about 0.2 s.
"""

from itertools import pairwise

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from physar.errors import PhysarError
from physar.recon import importer as I
from physar.skinning import load_body, smpl_body

JOINTS = ["pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
          "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
          "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand",
          "right_hand"]
PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
# SMPL canonical (y up, facing +z, x = left) -> recon (z up, facing -y, x = left): x -> x, y -> z, z -> -y
M = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
# the anny bone whose rest head marks each SMPL joint (toe3-1 for the foot joint, finger3-1 for the hand)
ANNY_AT = {"pelvis": "root", "spine1": "spine04", "spine2": "spine02", "spine3": "spine01", "neck": "neck01",
           "head": "head"}
for s, side in (("L", "left"), ("R", "right")):
    ANNY_AT.update({f"{side}_hip": f"upperleg01.{s}", f"{side}_knee": f"lowerleg01.{s}",
                    f"{side}_ankle": f"foot.{s}", f"{side}_foot": f"toe3-1.{s}", f"{side}_collar": f"clavicle.{s}",
                    f"{side}_shoulder": f"upperarm01.{s}", f"{side}_elbow": f"lowerarm01.{s}",
                    f"{side}_wrist": f"wrist.{s}", f"{side}_hand": f"finger3-1.{s}"})
ARM = ["shoulder", "elbow", "wrist", "hand"]


@pytest.fixture(scope="module")
def anny():
    try:
        return load_body("anny", 1.7)
    except PhysarError as e:
        pytest.skip(f"anny body unavailable: {e}")


def fk(J: np.ndarray, local: np.ndarray):
    """SMPL forward kinematics: global rotations G_j = G_p L_j and joints P_j = P_p + G_p (J_j - J_p), P_0 = J_0."""
    F = len(local)
    G, P = np.empty((F, 24, 3, 3)), np.empty((F, 24, 3))
    for j, p in enumerate(PARENTS):
        G[:, j] = local[:, j] if p < 0 else G[:, p] @ local[:, j]
        P[:, j] = J[j] if p < 0 else P[:, p] + G[:, p] @ (J[j] - J[p])
    return G, P


def random_pose(rng, F: int):
    aa = rng.normal(0, 0.5, (F, 24, 3))
    aa[:, 0] = rng.normal(0, 1.5, (F, 3))  # any global orientation
    aa[:, 22:] = 0.0  # SMPL's hand joints: anny's fingers follow the wrist
    return aa, Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(F, 24, 3, 3)


def smpl_file(path, aa, transl):
    np.savez(path, global_orient=aa[:, 0], body_pose=aa[:, 1:].reshape(len(aa), 69), betas=np.zeros((len(aa), 10)),
             transl=transl)
    return I.load_smpl(path)


def anny_tpose_joints(anny, scale=None) -> np.ndarray:
    """SMPL rest joints (SMPL axes) at anny's joints, arms laid along +-x (SMPL's T-pose) with anny's segment
    lengths; ``scale`` (24,) multiplies each joint's offset from its parent (other proportions, same directions)."""
    H = anny.skeleton.rest_global[:, :3, 3].numpy()
    at = lambda joint: H[anny.skeleton.index(ANNY_AT[joint])]
    Jb = np.array([at(j) for j in JOINTS])
    for side, sx in (("left", 1.0), ("right", -1.0)):
        for a, b in pairwise(ARM):
            ia, ib = JOINTS.index(f"{side}_{a}"), JOINTS.index(f"{side}_{b}")
            L = np.linalg.norm(at(f"{side}_{b}") - at(f"{side}_{a}"))
            Jb[ib] = Jb[ia] + [sx * L, 0.0, 0.0]
    if scale is not None:
        off = np.array([Jb[j] - Jb[p] if p >= 0 else Jb[j] for j, p in enumerate(PARENTS)]) * scale[:, None]
        for j, p in enumerate(PARENTS):
            Jb[j] = off[j] if p < 0 else Jb[p] + off[j]
    return Jb @ M  # rows: M^T x (recon -> SMPL axes)


def posed_anny_joints(anny, pose, Rc, tc) -> np.ndarray:
    """anny's heads of the bones marking SMPL's joints, posed, camera coordinates (F, 24, 3)."""
    G = anny.skeleton.pose(torch.as_tensor(pose["rotations"]), torch.as_tensor(pose["root_translation"])).numpy()
    heads = G[:, [anny.skeleton.index(ANNY_AT[j]) for j in JOINTS]][..., :3, 3]
    return heads @ Rc.T + tc


def test_anny_retarget_reproduces_the_source_joints(anny, tmp_path):
    """Random SMPL poses of a source whose rest joints are anny's with the arms in the T-pose: every one of the 24
    SMPL joints (including elbows, wrists, knuckles, toes through unmapped in-between bones) lands where the
    source's forward kinematics puts it, camera coordinates, to 1e-9 m. Mutants caught: the A-to-T correction
    C_k left out (elbows off by ~0.2 m), L_k without the conjugation by anny's rest frames Q_k, unmapped bones
    given the identity instead of their parent's rotation, left/right swapped in the map."""
    rng = np.random.default_rng(7)
    F = 5
    J = anny_tpose_joints(anny)
    aa, local = random_pose(rng, F)
    _, P = fk(J, local)
    transl = rng.normal(0, 0.5, (F, 3)) + [0, 0, 3.0]
    want = P - J[0] + transl[:, None]  # transl = the pelvis position (pelvis_offset 0)
    Rw = I.world_rotation(rng.normal(size=3))
    tw = rng.normal(size=3)
    pose = I.retarget(smpl_file(tmp_path / "p.npz", aa, transl), anny, Rw, tw)
    got = posed_anny_joints(anny, pose, Rw, tw)
    assert np.abs(got - want).max() < 1e-9


def test_anny_retarget_matches_segment_directions_of_other_proportions(anny, tmp_path):
    """A source with other proportions (each joint's offset from its parent scaled by 0.8-1.25) and the same rest
    directions: every SMPL segment (parent joint -> joint) of anny points where the source's does, to 1e-9 rad,
    while positions differ by centimetres (the body keeps its own proportions: the documented approximation)."""
    rng = np.random.default_rng(11)
    F = 4
    J = anny_tpose_joints(anny, rng.uniform(0.8, 1.25, 24))
    aa, local = random_pose(rng, F)
    _, P = fk(J, local)
    transl = rng.normal(0, 0.5, (F, 3))
    want = P - J[0] + transl[:, None]
    Rw, tw = I.world_rotation([0.0, -1.0, 0.2]), np.array([0.1, 0.2, 2.5])
    got = posed_anny_joints(anny, I.retarget(smpl_file(tmp_path / "p.npz", aa, transl), anny, Rw, tw), Rw, tw)
    unit = lambda x: x / np.linalg.norm(x, axis=-1, keepdims=True)
    cos = [(unit(got[:, j] - got[:, p]) * unit(want[:, j] - want[:, p])).sum(-1) for j, p in enumerate(PARENTS) if p >= 0]
    assert np.arccos(np.clip(np.array(cos), -1, 1)).max() < 1e-7
    assert np.abs(got - want).max() > 0.01


def fake_smpl_npz(path, anny):
    """An SMPL-layout model file built from anny's mesh (no SMPL data): v_template in SMPL axes, J_regressor =
    the mean of the 8 vertices nearest to each joint of :func:`anny_tpose_joints`' A-pose positions, weights
    = anny's summed per SMPL joint (each anny bone to its nearest ancestor marking an SMPL joint)."""
    sk = anny.skeleton
    shift = np.array([0.01, -1.1, 0.02])  # SMPL-like: the pelvis near the origin, feet at y ~ -1.1
    v = anny.vertices.numpy() @ M + shift  # recon -> SMPL axes
    H = sk.rest_global[:, :3, 3].numpy() @ M + shift
    Jreg = np.zeros((24, len(v)))
    for j, name in enumerate(JOINTS):
        near = np.argsort(np.linalg.norm(v - H[sk.index(ANNY_AT[name])], axis=1))[:8]
        Jreg[j, near] = 1 / 8
    at = {sk.index(b): JOINTS.index(j) for j, b in ANNY_AT.items() if j not in ("left_hand", "right_hand")}
    owner = []
    for k in range(sk.n_bones):
        a = k
        while a not in at:
            a = int(sk.parents[a])
        owner.append(at[a])
    W = np.zeros((len(v), 24))
    np.add.at(W, (np.repeat(np.arange(len(v)), anny.weight_indices.shape[1]),
                  np.asarray(owner)[anny.weight_indices.numpy().reshape(-1)]), anny.weight_values.numpy().reshape(-1))
    kin = np.array([[4294967295] + PARENTS[1:], list(range(24))], dtype=np.int64)
    np.savez(path, v_template=v, f=anny.faces.numpy(), weights=W, kintree_table=kin, J_regressor=Jreg)
    return v, W, Jreg @ v


def test_user_smpl_model_file_is_exact(anny, tmp_path):
    """``smpl:PATH``: a model file in SMPL's layout (built here from anny's mesh) posed by random SMPL parameters
    through load_smpl -> retarget -> the body's LBS gives, in camera coordinates, exactly SMPL's LBS written out
    here (v' = sum_j w_j (G_j (v - J_j) + P_j) + transl, pelvis_offset = J_0), to 1e-9 m. Mutants caught: SMPL's
    axes left out of Delta_k (R^T G_s instead of R^T G_s M^T), the pelvis offset dropped, the feet-on-z = 0 shift
    applied to the vertices but not to the rest frames, the template not turned into the recon axes."""
    v, W, J = fake_smpl_npz(tmp_path / "SMPL_TEST.npz", anny)
    body = load_body(f"smpl:{tmp_path / 'SMPL_TEST.npz'}")
    assert body.skeleton.names == JOINTS and float(body.vertices[:, 2].min()) == 0.0
    rng = np.random.default_rng(5)
    F = 3
    aa, local = random_pose(rng, F)
    aa[:, 22:] = rng.normal(0, 0.5, (F, 2, 3))  # the SMPL body has its own hand joints
    local = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(F, 24, 3, 3)
    G, P = fk(J, local)
    transl = rng.normal(0, 0.5, (F, 3))
    want = np.einsum("vj,fjvi->fvi", W, np.einsum("fjab,vb->fjva", G, v) - np.einsum("fjab,jb->fja", G, J)[:, :, None]
                     + P[:, :, None]) + transl[:, None]
    Rw, tw = I.world_rotation(rng.normal(size=3)), rng.normal(size=3)
    pose = I.retarget(smpl_file(tmp_path / "p.npz", aa, transl), body, Rw, tw, pelvis_offset=J[0])
    for f in range(F):
        B = body.bone_transforms(torch.as_tensor(pose["rotations"][f]), torch.as_tensor(pose["root_translation"][f]))
        got = body.skin_vertices(B).numpy() @ Rw.T + tw
        assert np.abs(got - want[f]).max() < 1e-9, f
    sized = smpl_body(tmp_path / "SMPL_TEST.npz", 1.5)
    assert float(sized.vertices[:, 2].max()) == pytest.approx(1.5)


def test_import_body_option_errors_are_one_line(tmp_path):
    """``--body`` with an unknown name or a missing SMPL file: one ConfigError line naming --body and the value
    (checked before the video is read)."""
    for spec, frag in (("robot", "--body = 'robot'"), (f"smpl:{tmp_path}/none.npz", "none.npz")):
        with pytest.raises(I.ConfigError) as e:
            I.import_body(spec, 1.7)
        assert "\n" not in str(e.value) and frag in str(e.value), str(e.value)


def test_smpl_release_extras_are_never_unpickled(anny, tmp_path):
    """A model file with an extra pickled entry (as some SMPL-X releases hold part tables) loads: only
    v_template, f, weights, kintree_table and J_regressor are read (allow_pickle=False); a file lacking one of
    them is one line naming the file and the array. Mutant caught: reading every entry of the npz (the pickled
    one raises)."""
    fake_smpl_npz(tmp_path / "base.npz", anny)
    with np.load(tmp_path / "base.npz") as z:
        arrays = {k: z[k] for k in z.files}
    extra = np.empty(1, dtype=object)
    extra[0] = {"head": 15}
    np.savez(tmp_path / "SMPLX_LIKE.npz", part2num=extra, **arrays)
    assert load_body(f"smpl:{tmp_path / 'SMPLX_LIKE.npz'}", 1.7).skeleton.names == JOINTS
    np.savez(tmp_path / "NOJ.npz", **{k: v for k, v in arrays.items() if k != "J_regressor"})
    with pytest.raises(PhysarError) as e:
        load_body(f"smpl:{tmp_path / 'NOJ.npz'}", 1.7)
    assert "\n" not in str(e.value) and "NOJ.npz" in str(e.value) and "'J_regressor'" in str(e.value)
