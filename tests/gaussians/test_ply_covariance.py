"""3DGS PLY layout (round trip, a hand-written standard file, trimesh as a peer reader, malformed files)
and the physics-aware covariance of seed 002, Eq. 3, against sample statistics."""

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from physar.errors import PhysarError
from physar.gaussians import Gaussians, covariance, load_ply, quat_to_rotmat, rotmat_to_quat, save_ply
from physar.gaussians.ply import attribute_names

# property order of graphdeco-inria/gaussian-splatting GaussianModel.construct_list_of_attributes (degree 3)
STANDARD_DEG3 = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
                 + [f"f_rest_{i}" for i in range(45)]
                 + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def _random(n=50, deg=3, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return Gaussians(torch.randn(n, 3, generator=gen), torch.randn(n, 4, generator=gen),
                     torch.randn(n, 3, generator=gen) - 3, torch.randn(n, generator=gen),
                     torch.randn(n, (deg + 1) ** 2, 3, generator=gen))


@pytest.mark.parametrize("deg", [0, 1, 3])
def test_round_trip_is_exact_in_float32(tmp_path, deg):
    g = _random(deg=deg)
    save_ply(tmp_path / "g.ply", g)
    h = load_ply(tmp_path / "g.ply")
    assert h.sh_degree == deg
    for k, v in g.tensors().items():
        assert torch.equal(getattr(h, k), v), k
    assert [p.name for p in (tmp_path).iterdir()] == ["g.ply"]  # no temp file left


def test_header_matches_standard_layout(tmp_path):
    save_ply(tmp_path / "g.ply", _random(n=3))
    raw = (tmp_path / "g.ply").read_bytes()
    header = raw[: raw.index(b"end_header\n")].decode().splitlines()
    assert header[1] == "format binary_little_endian 1.0"
    assert "element vertex 3" in header
    props = [h.split() for h in header if h.startswith("property")]
    assert all(p[1] == "float" for p in props)
    assert [p[2] for p in props] == STANDARD_DEG3 == attribute_names(3)
    assert len(raw) - raw.index(b"end_header\n") - len(b"end_header\n") == 3 * 62 * 4


def test_reads_a_hand_written_standard_file_with_channel_major_f_rest(tmp_path):
    n = 4
    data = np.zeros((n, 62), dtype="<f4")
    data[:, 0:3] = np.arange(n * 3).reshape(n, 3)
    data[:, 6:9] = [[0.1, 0.2, 0.3]] * n
    # f_rest_j: channel c = j // 15, SH coefficient k = 1 + j % 15 -> store 100 c + k
    data[:, 9:54] = [100 * (j // 15) + 1 + j % 15 for j in range(45)]
    data[:, 54] = 0.7
    data[:, 55:58] = [-1, -2, -3]
    data[:, 58:62] = [0.5, 0.5, 0.5, 0.5]
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 4\n" + "".join(
        f"property float {a}\n" for a in STANDARD_DEG3) + "end_header\n"
    (tmp_path / "std.ply").write_bytes(header.encode() + data.tobytes())
    g = load_ply(tmp_path / "std.ply")
    assert g.sh.shape == (4, 16, 3)
    assert torch.allclose(g.sh[0, 0], torch.tensor([0.1, 0.2, 0.3]))
    k, c = 5, 2
    assert g.sh[1, k, c].item() == 100 * c + k
    assert torch.allclose(g.opacity_logits, torch.full((4,), 0.7))
    assert torch.allclose(g.quats[2], torch.tensor([0.5, 0.5, 0.5, 0.5]))
    assert torch.allclose(g.log_scales[3], torch.tensor([-1.0, -2.0, -3.0]))


def test_trimesh_reads_our_file_as_a_point_cloud(tmp_path):
    g = _random(n=20, deg=1)
    save_ply(tmp_path / "g.ply", g)
    pc = trimesh.load(tmp_path / "g.ply")
    assert np.allclose(pc.vertices, g.means.numpy())
    raw = pc.metadata["_ply_raw"]["vertex"]["data"]
    assert np.allclose(raw["rot_0"], g.quats[:, 0].numpy())
    assert np.allclose(raw["f_rest_3"], g.sh[:, 1, 1].numpy())  # channel-major: G, band-1 coefficient 1
    assert np.allclose(raw["opacity"], g.opacity_logits.numpy())


def test_ascii_and_big_endian_and_extra_properties(tmp_path):
    names = attribute_names(0)
    vals = np.arange(2 * len(names), dtype=float).reshape(2, -1) / 10 + 0.05
    vals[:, names.index("rot_0")] = 1.0
    hdr = lambda fmt: (f"ply\nformat {fmt} 1.0\ncomment x\nelement vertex 2\n"
                       + "".join(f"property double {a}\n" for a in names) + "property uchar red\nend_header\n")
    ascii_body = "\n".join(" ".join(f"{v:.17g}" for v in row) + " 7" for row in vals) + "\n"
    (tmp_path / "a.ply").write_text(hdr("ascii") + ascii_body)
    rec = np.zeros(2, dtype=[(a, ">f8") for a in names] + [("red", "u1")])
    for i, a in enumerate(names):
        rec[a] = vals[:, i]
    (tmp_path / "b.ply").write_bytes(hdr("binary_big_endian").encode() + rec.tobytes())
    a, b = load_ply(tmp_path / "a.ply", dtype=torch.float64), load_ply(tmp_path / "b.ply", dtype=torch.float64)
    for k in a.tensors():
        assert torch.equal(getattr(a, k), getattr(b, k))
    assert np.allclose(a.means.numpy(), vals[:, :3])


def test_malformed_files_raise_clear_errors(tmp_path):
    good = tmp_path / "g.ply"
    save_ply(good, _random(n=5, deg=0))
    raw = good.read_bytes()
    cases = {
        "trunc.ply": (raw[:-10], "truncated"),
        "notply.ply": (b"hello\n" + raw, "not a PLY"),
        "nohdr.ply": (raw[: raw.index(b"end_header")], "end_header"),
        "missing.ply": (raw.replace(b"property float opacity\n", b""), "opacity"),
        "list.ply": (raw.replace(b"end_header", b"element face 0\nproperty list uchar int vertex_indices\n"
                                                 b"end_header"), "list property"),
    }
    for name, (content, msg) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(PhysarError, match=msg) as e:
            load_ply(tmp_path / name)
        assert name in str(e.value) or msg in str(e.value)
    with pytest.raises(PhysarError, match="not found"):
        load_ply(tmp_path / "absent.ply")
    bad = _random(n=3, deg=0)
    bad.means[1, 2] = float("nan")
    with pytest.raises(PhysarError, match="NaN"):
        save_ply(tmp_path / "nan.ply", bad)
    assert not (tmp_path / "nan.ply").exists()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_quaternion_conventions_against_scipy():
    q = torch.randn(100, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    qn = (q / q.norm(dim=1, keepdim=True)).numpy()
    ref = Rotation.from_quat(qn[:, [1, 2, 3, 0]]).as_matrix()  # scipy is scalar-last
    assert np.allclose(quat_to_rotmat(q).numpy(), ref, atol=1e-12)
    back = rotmat_to_quat(torch.tensor(ref)).numpy()
    assert np.allclose(np.abs((back * qn).sum(1)), 1.0, atol=1e-12)  # same rotation up to sign


def test_eq3_covariance_equals_covariance_of_transformed_samples():
    gen = torch.Generator().manual_seed(2)
    n_g, n_s = 4, 400_000
    q = torch.randn(n_g, 4, dtype=torch.float64, generator=gen)
    s = torch.tensor([[0.1, 0.2, 0.05], [0.3, 0.3, 0.01], [1.0, 0.5, 0.2], [0.02, 0.02, 0.02]],
                     dtype=torch.float64)
    F = torch.eye(3, dtype=torch.float64) + 0.4 * torch.randn(n_g, 3, 3, dtype=torch.float64, generator=gen)
    sigma = covariance(q, s, F)
    Rm = torch.tensor(Rotation.from_quat((q / q.norm(dim=1, keepdim=True)).numpy()[:, [1, 2, 3, 0]])
                      .as_matrix())
    for i in range(n_g):
        z = torch.randn(n_s, 3, dtype=torch.float64, generator=gen)
        x = (z * s[i]) @ Rm[i].T  # samples of the canonical Gaussian N(0, R S S^T R^T)
        y = x @ F[i].T  # deformed by F
        emp = (y.T @ y) / n_s
        scale = torch.linalg.matrix_norm(sigma[i], ord=2)
        assert torch.linalg.matrix_norm(emp - sigma[i], ord=2) < 0.02 * scale
    assert torch.allclose(sigma, sigma.transpose(1, 2))
    assert torch.allclose(covariance(q, s), Rm @ torch.diag_embed(s**2) @ Rm.transpose(1, 2), atol=1e-14)


def test_sh_basis_is_orthonormal_on_the_sphere():
    """The degree-3 real SH basis used for view-dependent colour satisfies int Y_i Y_j dOmega = delta_ij
    (quadrature: Gauss-Legendre in cos(theta) x uniform in phi, exact for these polynomials)."""
    from physar.gaussians.sh import sh_basis

    x, w = np.polynomial.legendre.leggauss(12)
    phi = np.arange(16) * 2 * np.pi / 16
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = torch.tensor(np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3))
    wq = torch.tensor((w[:, None] * np.full(16, 2 * np.pi / 16)[None]).reshape(-1))
    Y = sh_basis(3, dirs)
    gram = (Y * wq[:, None]).T @ Y
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=1e-12)
