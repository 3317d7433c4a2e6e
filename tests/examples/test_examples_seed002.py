"""The seed-002 notebook-style examples run in quick mode, and their numbers hold against independent
references: a scalar per-pixel 3DGS compositing loop written here, trimesh as a peer PLY reader with scipy
rotations for Eq. (3), central finite differences, the exact symplectic-Euler free fall, the closed-form
frequency of a free-free bar, the Young's modulus of a finer-grid ground truth, and the frames and 3-D motion
of a finer (8 particles per cell) MPM truth for the reconstruction."""

from __future__ import annotations

import json
import math
from pathlib import Path

import av
import matplotlib.image
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


# -- gaussians_render.py -----------------------------------------------------------------------------
def pixel_reference(mu, cov, eta, rgb, cam, bg, i, j):
    """RGB and alpha of pixel (column i, row j) by the sequential rules of the 3DGS CUDA rasteriser."""
    R, t = cam.R.numpy(), cam.t.numpy()
    items = []
    for k in range(len(mu)):
        x, y, z = R @ mu[k] + t
        J = np.array([[cam.fx / z, 0, -cam.fx * x / z**2], [0, cam.fy / z, -cam.fy * y / z**2]])
        cov2 = J @ R @ cov[k] @ R.T @ J.T + 0.3 * np.eye(2)
        items.append((z, np.array([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy]), np.linalg.inv(cov2), k))
    T, c = 1.0, np.zeros(3)
    for _z, m, Q, k in sorted(items, key=lambda it: it[0]):
        d = np.array([i + 0.5, j + 0.5]) - m
        a = min(0.99, eta[k] * math.exp(-0.5 * d @ Q @ d))
        if a < 1 / 255:
            continue
        if T * (1 - a) < 1e-4:
            break
        c += a * T * rgb[k]
        T *= 1 - a
    return c + T * bg, 1 - T


def test_gaussians_render_example(run_example):
    g, tmp_path = run_example("gaussians_render.py")
    out, cam, g0, F = g["out"], g["cam"], g["g"], g["F"].numpy()
    W, H = g["W"], g["H"]
    assert out.rgb.shape == (H, W, 3) and g["n"] >= 30
    # Eq. (3): sample covariance of the F-mapped samples
    assert g["eq3_rel_err"] < 2e-2
    # tile rasteriser vs the example's numpy renderer, and vs the scalar loop here on 21 pixels
    assert g["err_rgb"] < 1e-10 and g["err_alpha"] < 1e-10 and g["err_depth"] < 1e-10
    assert float((out.alpha > 0.9).float().mean()) > 0.05  # overlapping, opaque pixels ...
    assert float((out.alpha < 0.01).float().mean()) > 0.2  # ... and empty ones
    Rg = Rotation.from_quat(g0.quats.numpy()[:, [1, 2, 3, 0]]).as_matrix()
    S2 = np.exp(2 * g0.log_scales.numpy())
    cov = np.einsum("ij,njk,nk,nlk,ml->nim", F, Rg, S2, Rg, F)  # F R S^2 R^T F^T
    rgb = 0.28209479177387814 * g0.sh[:, 0].numpy() + 0.5
    eta = 1 / (1 + np.exp(-g0.opacity_logits.numpy()))
    covered = np.argwhere(out.alpha.numpy() > 0.05)  # (row, column)
    pixels = covered[np.random.default_rng(0).choice(len(covered), 20, replace=False)].tolist() + [[0, 0]]
    for j, i in pixels:
        c, a = pixel_reference(g0.means.numpy() @ F.T, cov, eta, rgb, cam, g["bg"].numpy(), i, j)
        assert np.abs(out.rgb[j, i].numpy() - c).max() < 1e-10
        assert abs(out.alpha[j, i].item() - a) < 1e-10
    # autograd vs central finite differences (computed by the example)
    assert len(g["grad_check"]) == 4
    for label, (ad, fd) in g["grad_check"].items():
        assert ad == pytest.approx(fd, rel=1e-4, abs=1e-7), label
        assert abs(fd) > 1e-4, label  # a real sensitivity, not 0 == 0
    # the PLY: standard 3DGS layout read by a peer reader; its covariances are F Sigma F^T
    ply = tmp_path / "gaussians_deformed.ply"
    header = ply.read_bytes()[:2000].split(b"end_header")[0].decode()
    assert "format binary_little_endian 1.0" in header and f"element vertex {g['n']}" in header
    v = trimesh.load(ply).metadata["_ply_raw"]["vertex"]["data"]
    assert np.allclose(np.column_stack([v["x"], v["y"], v["z"]]), g0.means.numpy() @ F.T, atol=1e-6)
    q = np.column_stack([v["rot_1"], v["rot_2"], v["rot_3"], v["rot_0"]])
    Rf = Rotation.from_quat(q / np.linalg.norm(q, axis=1, keepdims=True)).as_matrix()
    s2 = np.exp(2 * np.column_stack([v["scale_0"], v["scale_1"], v["scale_2"]]).astype(float))
    cov_file = np.einsum("nij,nj,nkj->nik", Rf, s2, Rf)
    assert np.abs(cov_file - cov).max() < 1e-5 * np.abs(cov).max()
    assert g["ply_cov_err"] < 1e-6
    # the PNG is the render, and the JSON has the same numbers
    png = matplotlib.image.imread(tmp_path / "render.png")
    assert png.shape[:2] == (H, W)
    assert np.abs(png[..., :3] - out.rgb.clamp(0, 1).numpy()).max() <= 1 / 255 + 1e-6
    assert json.loads((tmp_path / "gaussians_render.json").read_text())["err_rgb"] == g["err_rgb"]


# -- mpm_block.py ------------------------------------------------------------------------------------
def test_mpm_block_example(run_example):
    g, tmp_path = run_example("mpm_block.py")
    # free fall: symplectic Euler, x_n = x_0 - g dt^2 n (n + 1) / 2, lags g t^2 / 2 by exactly g dt t / 2
    sc = g["sc_fall"]
    dt, t_end = sc.time.frame_dt / sc.time.substeps, g["t_fall"][-1]
    assert g["fall_drop"] == pytest.approx(0.5 * 9.81 * t_end**2 + 0.5 * 9.81 * dt * t_end, rel=1e-6)
    assert g["fall_err"] == pytest.approx(0.5 * 9.81 * dt * t_end, rel=1e-6)
    assert g["z_com"].min() - 0.0625 > 0.1  # the block's bottom stays off the floor
    # free-free bar, nu = 0: f1 = sqrt(E / rho) / (2 L)
    assert g["f_exact"] == pytest.approx(math.sqrt(5e4 / 1000) / 0.5)
    assert g["f_mpm"] == pytest.approx(g["f_exact"], rel=0.02)
    # gradient through the simulator vs central finite differences
    assert g["grad_ad"] == pytest.approx(g["grad_fd"], rel=1e-4)
    assert abs(g["grad_fd"]) > 1e-2
    # E of the finer-grid, 27-particles-per-cell truth, from a guess 2x too soft
    assert g["E_guess"] == pytest.approx(0.5 * g["E_TRUE"])
    assert g["E_fit"] == pytest.approx(g["E_TRUE"], rel=0.03)
    assert len(g["target"][0]) > 3 * len(g["x0"])  # the target really is sampled more finely
    png = matplotlib.image.imread(tmp_path / "mpm_block.png")
    assert png.ndim == 3 and png.shape[1] > png.shape[0]
    assert json.loads((tmp_path / "mpm_block.json").read_text())["E_fit"] == g["E_fit"]


# -- recon_tiny.py -----------------------------------------------------------------------------------
def test_recon_tiny_example(run_example):
    g, tmp_path = run_example("recon_tiny.py")
    truth = g["nov"]["rgb"]  # novel action, rendered from the fine (8 particles/cell) MPM truth
    assert g["rgb_phys"].shape == g["rgb_lbs"].shape == truth.shape

    def psnr(a, b, frames):  # written here, not physar.recon.metrics
        return float(np.mean([10 * np.log10(1 / np.mean((a[f] - b[f]) ** 2)) for f in frames]))

    later = range(1, len(truth))  # frame 0 is the canonical scene, the same for both methods
    p_phys, p_lbs = psnr(g["rgb_phys"], truth, later), psnr(g["rgb_lbs"], truth, later)
    assert p_phys > p_lbs + 0.5  # learned physics predicts the unseen action better than LBS only
    assert p_phys == pytest.approx(g["psnr"]["physics"]["novel"], abs=1e-3)
    assert g["psnr"]["physics"]["pred"] > g["psnr"]["lbs"]["pred"]
    assert g["err3d"]["physics"] < 0.8 * g["err3d"]["lbs"]  # 3-D error vs the fine MPM truth positions
    assert g["mat"]["E_soft_learned_geomean"] < g["mat"]["E_stiff_learned_geomean"]  # truth: 3 vs 12 kPa
    assert g["ev"]["omega"]["object_max_abs"] == 0.0  # no actuation on the object (Eq. 6-7)
    assert len(g["gaussians"]) > 100
    with av.open(str(tmp_path / "recon_novel.mp4")) as c:
        assert sum(1 for _ in c.decode(video=0)) == len(truth)
    assert matplotlib.image.imread(tmp_path / "recon_novel.png").ndim == 3
    assert json.loads((tmp_path / "recon_tiny.json").read_text())["psnr"] == g["psnr"]
