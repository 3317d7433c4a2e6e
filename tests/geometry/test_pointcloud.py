"""Point-cloud PCA normals and AL/MSAL on the k-NN graph (seed 001 §3.2.1) vs closed-form shapes."""

from __future__ import annotations

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from physar.cli.denoise import register
from physar.errors import MeshError, PhysarError
from physar.geometry import pointcloud as P


def grid(n=40):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    return np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]


def sphere(n=2000, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_pca_normals_sphere_outward():
    p = sphere()
    n = P.pca_normals(p, 12)
    cosang = np.einsum("ij,ij->i", n, p)  # exact outward normal of the unit sphere is p
    assert np.degrees(np.arccos(np.clip(cosang, -1, 1))).mean() < 3.0
    assert (cosang > 0).all()


def torus(n=4000, seed=0, R=1.0, r=0.35):
    """Random points on a torus and their exact outward normals (closed form)."""
    u, v = np.random.default_rng(seed).uniform(0, 2 * np.pi, (2, n))
    pts = np.c_[(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u), r * np.sin(v)]
    return pts, np.c_[np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)]


def test_mst_orientation_consistent_on_torus_where_centroid_rule_fails():
    pts, exact = torus()
    n = P.pca_normals(pts, 12)  # default: MST propagation (Hoppe 1992)
    cosang = np.einsum("ij,ij->i", n, exact)
    assert (cosang > 0).all()  # every normal outward, inner side of the ring included
    assert np.degrees(np.arccos(cosang)).mean() < 4.0
    # the centroid rule flips the inner side (its normals point toward the centroid)
    c = np.einsum("ij,ij->i", P.pca_normals(pts, 12, orient="centroid"), exact)
    assert 0.2 < (c < 0).mean() < 0.6
    # two separate components, each with its own root; and a viewpoint outside the ring
    two = np.r_[pts, pts + [5.0, 0, 0]]
    assert (np.einsum("ij,ij->i", P.pca_normals(two, 12), np.r_[exact, exact]) > 0).all()
    vp = P.pca_normals(pts, 12, viewpoint=[0, 0, 5.0])  # nearest point is on top: outward there
    assert (np.einsum("ij,ij->i", vp, exact) > 0).all()
    with pytest.raises(PhysarError, match="orientation"):
        P.pca_normals(pts, 12, orient="random")


def test_plane_cloud_normals_restored_below_one_degree():
    rng = np.random.default_rng(0)
    clean = grid()
    noisy = clean + np.c_[np.zeros((len(clean), 2)), rng.normal(0, 0.005, len(clean))]
    before = P.pca_normals(noisy, 10, viewpoint=[0.5, 0.5, 10])
    out = P.denoise_points(noisy, "al", 40)
    after = P.pca_normals(out, 10, viewpoint=[0.5, 0.5, 10])
    ang = lambda n: np.degrees(np.arccos(np.clip(n[:, 2], -1, 1))).mean()
    assert ang(before) > 5 * ang(after)
    assert ang(after) < 1.0
    assert np.abs(out[:, 2]).mean() < np.abs(noisy[:, 2]).mean() / 3


def test_msal_sphere_radius_error_shrinks():
    rng = np.random.default_rng(1)
    p = sphere(3000)
    noisy = p * (1 + rng.normal(0, 0.01, len(p)))[:, None]
    out = P.denoise_points(noisy, "msal", 4, k=12)
    err = lambda q: np.abs(np.linalg.norm(q, axis=1) - 1).mean()  # exact distance to the unit sphere
    assert err(out) < 0.35 * err(noisy)
    # the seed's plain update (no shrinkage correction) shrinks the cloud: radius bias grows with steps
    plain = P.denoise_points(noisy, "al", 8, k=12, shrink_correction=0.0)
    corr = P.denoise_points(noisy, "al", 8, k=12)
    assert np.linalg.norm(plain, axis=1).mean() < 1 - 0.01
    assert abs(np.linalg.norm(corr, axis=1).mean() - 1) < 0.003
    assert err(corr) < 0.35 * err(noisy)


def test_ply_roundtrip_and_errors(tmp_path):
    p = sphere(100)
    P.write_ply(tmp_path / "c.ply", p)
    q, faces = P.read_ply(tmp_path / "c.ply")
    assert faces is None and np.allclose(q, p, atol=1e-6)  # float32 on disk
    with pytest.raises(MeshError, match="need more than k"):
        P.pca_normals(p[:5], 10)
    with pytest.raises(PhysarError, match="not found"):
        P.read_ply(tmp_path / "none.ply")
    with pytest.raises(PhysarError, match="'al' and 'msal'"):
        P.denoise_points(p, "taubin")


def test_cli_point_cloud(tmp_path):
    app = typer.Typer()
    register(app)
    rng = np.random.default_rng(2)
    noisy = sphere(3000) * (1 + rng.normal(0, 0.01, 3000))[:, None]
    P.write_ply(tmp_path / "in.ply", noisy)
    r = CliRunner().invoke(app, ["denoise", str(tmp_path / "in.ply"), str(tmp_path / "out.ply"),
                                 "--method", "msal", "--iterations", "2", "--k", "12", "--json"])
    assert r.exit_code == 0, r.output
    out, _ = P.read_ply(tmp_path / "out.ply")
    err = lambda q: np.abs(np.linalg.norm(q, axis=1) - 1).mean()
    assert err(out) < err(noisy)
    r = CliRunner().invoke(app, ["denoise", str(tmp_path / "in.ply"), str(tmp_path / "t.ply"), "--method", "taubin"])
    assert r.exit_code == 2 and "point clouds support --method al or msal" in r.output
    assert not (tmp_path / "t.ply").exists()
