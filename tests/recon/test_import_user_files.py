"""Files as users' tools write them: unpadded frame numbers in mask names, SMPL / SMPL+H / SMPL-X pose layouts.

References: the frame number written into each file (masks), scipy's Rodrigues formula on the raw axis-angle
values (poses).
"""

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from physar.errors import ConfigError
from physar.mpm.io import read_trajectory, write_particles_ply
from physar.recon.importer import load_smpl
from physar.recon.masks import read_masks


def test_masks_with_unpadded_frame_numbers_are_read_in_frame_order(tmp_path):
    # a segmenter writing mask_1.png ... mask_12.png: frame i's object covers i + 1 columns. Catches: names
    # sorted as text (mask_1, mask_10, mask_11, mask_12, mask_2, ...: frames 10-12 read as frames 2-4)
    H, W = 8, 16
    for i in range(12):
        lab = np.zeros((H, W), np.uint8)
        lab[:, : i + 1] = 2
        lab[0, -1] = 1  # a person pixel
        Image.fromarray(lab, mode="L").save(tmp_path / f"mask_{i + 1}.png")
    files, masks = read_masks(tmp_path, [1], [2])
    assert [f.name for f in files] == [f"mask_{i + 1}.png" for i in range(12)]
    assert [int(masks[i][1].sum()) for i in range(12)] == [(i + 1) * H for i in range(12)]


def test_particle_frames_with_unpadded_numbers_are_read_in_frame_order(tmp_path):
    # another tool's trajectory frame_0.ply ... frame_10.ply; frame i's particle at x = i. Catches: text order
    for i in range(11):
        x = np.array([[float(i), 0.0, 0.0]])
        write_particles_ply(tmp_path / f"frame_{i}.ply", x, np.zeros_like(x), np.zeros(1, np.int32))
    assert [f["x"][0, 0] for f in read_trajectory(tmp_path)] == [float(i) for i in range(11)]


def _aa(rng, F, J):
    return rng.uniform(-0.6, 0.6, (F, 3 * J))


def _matrices(aa):
    F = len(aa)
    return Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(F, -1, 3, 3)


@pytest.mark.parametrize("layout", ["smpl", "smplx", "amass_smpl", "amass_smplh", "amass_smplx", "stage_ii"])
def test_pose_layouts_give_the_rodrigues_rotations(tmp_path, layout):
    # joints 0..21 (root to the wrists: the joints retargeted) against scipy's Rodrigues. Catches: the root's 3
    # values of an AMASS 'poses' vector read as a body joint (every joint shifted by one), stage-ii names ignored
    rng = np.random.default_rng(3)
    F = 4
    root, body = _aa(rng, F, 1), _aa(rng, F, {"smpl": 23, "amass_smpl": 23}.get(layout, 21))
    hands = _aa(rng, F, {"amass_smplh": 30, "amass_smplx": 33}.get(layout, 0))
    t = rng.normal(size=(F, 3))
    fields = {"smpl": {"global_orient": root, "body_pose": body, "transl": t},
              "smplx": {"global_orient": root, "body_pose": body, "transl": t, "betas": np.zeros(10)},
              "stage_ii": {"root_orient": root, "pose_body": body, "trans": t, "mocap_frame_rate": np.array(120.0)}}
    d = fields.get(layout, {"poses": np.concatenate([root, body, hands], 1), "trans": t})
    np.savez(tmp_path / "p.npz", **d)
    out = load_smpl(tmp_path / "p.npz")
    np.testing.assert_allclose(out["rotations"][:, 0], _matrices(root)[:, 0], atol=1e-6)
    np.testing.assert_allclose(out["rotations"][:, 1:22], _matrices(body)[:, :21], atol=1e-6)
    np.testing.assert_allclose(out["transl"], t)


def test_a_whole_pose_in_body_pose_is_refused(tmp_path):
    # (F, 72) in body_pose: the root's 3 values first would shift every joint by one; it was cut to 23 joints
    rng = np.random.default_rng(4)
    np.savez(tmp_path / "p.npz", global_orient=_aa(rng, 2, 1), body_pose=_aa(rng, 2, 24), transl=np.zeros((2, 3)))
    with pytest.raises(ConfigError, match=r"p\.npz: field 'body_pose' has 24 joints .*belongs in 'poses'"):
        load_smpl(tmp_path / "p.npz")


@pytest.mark.parametrize("width", [72, 156, 165])
def test_whole_pose_vectors_keep_smpl_hands_apart(tmp_path, width):
    # SMPL (72): joints 22, 23 (the hands) from the vector; SMPL+H (156) / SMPL-X (165): the values after joint
    # 21 are fingers / jaw / eyes, so SMPL's hands stay identity (they took the jaw and an eye, or two fingers)
    rng = np.random.default_rng(5)
    p = rng.uniform(-0.6, 0.6, (3, width))
    np.savez(tmp_path / "p.npz", poses=p, trans=np.zeros((3, 3)))
    R = load_smpl(tmp_path / "p.npz")["rotations"]
    want = _matrices(p[:, 66:72])[:, :2] if width == 72 else np.tile(np.eye(3), (3, 2, 1, 1))
    np.testing.assert_allclose(R[:, 22:24], want, atol=1e-9)


def test_json_frame_missing_a_field_is_named(tmp_path):
    import json

    frames = [{"global_orient": [0, 0, 0], "body_pose": [0] * 69, "transl": [0, 0, 1]} for _ in range(3)]
    del frames[1]["transl"]
    (tmp_path / "p.json").write_text(json.dumps(frames))
    with pytest.raises(ConfigError, match=r"p\.json: frame 1 lacks field 'transl'"):
        load_smpl(tmp_path / "p.json")


# betas of a shape no model has (review: (3, 3, 3) imported silently) and a text file saved as .npz (numpy's
# message advised unpickling "if you trust the file") are one line each; (10,), (1, 10) and (F, 16) pass.
# mutants caught: the betas shape unchecked, numpy's pickle message passed through
def test_betas_shape_and_text_npz(tmp_path):
    from physar.errors import ConfigError

    F = 4
    base = {"global_orient": np.zeros((F, 3)), "body_pose": np.zeros((F, 69)), "transl": np.zeros((F, 3))}
    for betas in (np.zeros(10), np.zeros((1, 10)), np.zeros((F, 16))):
        np.savez(tmp_path / "ok.npz", **base, betas=betas)
        assert load_smpl(tmp_path / "ok.npz")["rotations"].shape[0] == F
    for bad in (np.zeros((3, 3, 3)), np.zeros((F + 1, 10)), np.zeros((F, 0))):
        np.savez(tmp_path / "b.npz", **base, betas=bad)
        with pytest.raises(ConfigError, match=r"b.npz: field 'betas' has shape"):
            load_smpl(tmp_path / "b.npz")
    (tmp_path / "t.npz").write_text("global_orient 0 0 0\n")
    with pytest.raises(ConfigError) as e:
        load_smpl(tmp_path / "t.npz")
    assert "numpy could only unpickle it, which is refused" in str(e.value) and "trust" not in str(e.value)
