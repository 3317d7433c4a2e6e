"""`physar recon import` onto the default body, anny (issue 17 part 1): the tiny synthetic scene written in a user's
formats (the fixtures of test_recon_import: MP4, label PNGs, SMPL npz, camera TOML, OBJ) imported with the default
``--body``; the DATA_DIR names the body, its poses drive anny's 104 bones, and ``recon fit``'s loader and rig
build on it. Skipped when neither the anny package nor its cache is present.
With the anny package but no cache (``$PHYSAR_CACHE`` or ``~/.cache/physar/anny_body.npz``), the first test
builds it once (about 2.5 min on this machine); later loads take about 0.2 s.
"""

import json

import numpy as np
import pytest
import torch
from test_recon_import import cli, joints_camera, user  # noqa: F401 - the user's files (fixture)

from physar.errors import PhysarError
from physar.mpm.io import mp4_encoder
from physar.recon import scene as S
from physar.skinning import load_body

pytestmark = pytest.mark.skipif(mp4_encoder() is None, reason="PyAV has no MP4 encoder")


@pytest.fixture(scope="module")
def anny_dir(user):  # noqa: F811 - the imported fixture
    try:
        load_body("anny", 1.7)
    except PhysarError as e:
        pytest.skip(f"anny body unavailable: {e}")
    args = list(user["args"])
    i = args.index("--body")
    del args[i:i + 2]  # the default body
    out = user["dir"] / "data_anny"
    r = cli(*args, "--out", out, "--json")
    assert r.exit_code == 0, (r.output, r.exception)
    return out


def test_default_import_body_is_anny_and_its_forearm_follows_the_source(user, anny_dir):  # noqa: F811
    """scene.json body.model = anny; poses (F, 104, 3, 3). The capsule figure's forearms carry the source's
    shoulder-to-elbow-to-wrist directions; anny's forearm (elbow lowerarm01 -> wrist) posed by the retargeted
    poses points the same way in camera coordinates in every frame, to 1e-6 rad (the T-pose correction makes the
    directions, not the lengths, agree). A retarget without the A-to-T correction is off by tens of degrees."""
    meta = json.loads((anny_dir / "scene.json").read_text())
    assert meta["body"]["model"] == "anny"
    body = S.load_body(meta)
    sp, dy = np.load(anny_dir / "spin_poses.npz"), np.load(anny_dir / "poses.npz")
    rot = np.concatenate([sp["rotations"], dy["rotations"]])
    rt = np.concatenate([sp["root_translation"], dy["root_translation"]])
    assert rot.shape[1:] == (104, 3, 3)
    c = meta["camera"]
    G = body.skeleton.pose(torch.as_tensor(rot), torch.as_tensor(rt)).numpy()
    p = G[..., :3, 3] @ np.array(c["R"]).T + np.array(c["t"])
    cap = user["body"]
    src = joints_camera(cap, user["rot"], user["rt"], user["R"], user["t"])  # heads then tails (F, 2B, 3)
    nb = cap.skeleton.n_bones
    unit = lambda x: x / np.linalg.norm(x, axis=-1, keepdims=True)
    for side in "LR":
        k = cap.skeleton.index(f"forearm.{side}")
        want = unit(src[:, nb + k] - src[:, k])
        got = unit(p[:, body.skeleton.index(f"wrist.{side}")] - p[:, body.skeleton.index(f"lowerarm01.{side}")])
        assert np.arccos(np.clip((got * want).sum(-1), -1, 1)).max() < 1e-6, side


def test_fit_loader_and_rig_build_on_anny(anny_dir):
    """`recon fit`'s loader reads the anny DATA_DIR and its rig builds: the simulated bones (those reaching the
    object, at a 6 cm margin) own particles inside anny's mesh, the kinematic Gaussians cover the rest of the
    body; the rig's LBS of frame 0 puts the simulated particles inside the posed mesh's bounding box."""
    from physar.recon.train import Rig, TrainConfig, load_dataset

    data = load_dataset(anny_dir)
    rig = Rig(data.meta, TrainConfig(reach_margin=0.06), (data.rotations, data.root_t))
    bones = rig.meta["body"]["simulated_bones"]
    assert bones and all(b.endswith((".L", ".R")) for b in bones), bones
    assert rig.nh > 0 and rig.nb > 100
    assert (rig.body.signed_distance(torch.as_tensor(rig.Xh)) < 0).all()
    kin = rig.kinematics(data.rotations[:2], data.root_t[:2])
    B = S.bone_transforms(rig.body, data.rotations[:1], data.root_t[:1])[0]
    V = rig.body.skin_vertices(B).numpy()
    x = kin["ref"][0].numpy()
    assert np.all(x >= V.min(0) - 1e-9) and np.all(x <= V.max(0) + 1e-9)
