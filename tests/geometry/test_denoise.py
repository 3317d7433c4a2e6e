"""AL / MSAL mesh denoising (seed 001 §3.2.1) against closed-form references (plane, cube)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import typer
from typer.testing import CliRunner

from physar.cli.denoise import register
from physar.errors import MeshError, PhysarError
from physar.geometry import denoise as D
from physar.geometry import quality as Q
from physar.geometry.io import read_mesh, write_mesh
from physar.geometry.mesh import TriMesh
from physar.geometry.pointcloud import read_ply


def plane(n=30):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    pts = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    i = i.ravel()
    f = np.r_[np.c_[i, i + 1, i + n + 1], np.c_[i, i + n + 1, i + n]]
    return TriMesh(pts, f)


def cube(size=0.1):
    t = trimesh.creation.box(extents=(1, 1, 1)).subdivide_to_size(size)
    return TriMesh(np.asarray(t.vertices), np.asarray(t.faces))


def sharp_faces(clean: TriMesh) -> np.ndarray:
    """Faces with a vertex on a cube edge (two coordinates at +-0.5): exact for the unit cube."""
    on = (np.isclose(np.abs(clean.points), 0.5).sum(axis=1) >= 2)
    return np.flatnonzero(on[clean.faces].any(axis=1))


def test_plane_restored_below_one_degree():
    clean = plane()
    noisy = Q.add_noise(clean, 0.2, seed=1, direction="normal")
    assert Q.normal_angle_error(noisy, clean) > 5.0
    for method, it in [("al", 30), ("laplacian", 30)]:
        out = D.denoise(noisy, method, it)
        assert Q.normal_angle_error(out, clean) < 1.0, method
    # distance to the exact plane z = 0 shrinks by > 3x
    out = D.anisotropic_laplacian(noisy, 30)
    assert np.abs(out.points[:, 2]).mean() < np.abs(noisy.points[:, 2]).mean() / 3


def test_cube_edges_not_rounded_more_than_taubin():
    clean = cube()
    noisy = Q.add_noise(clean, 0.2, seed=0, direction="normal")
    sf = sharp_faces(clean)
    al = D.anisotropic_laplacian(noisy, 10)
    ms = D.msal(noisy, 2)
    tb = D.taubin_smooth(noisy, 10)
    e_tb = Q.normal_angle_error(tb, clean, sf)
    assert Q.normal_angle_error(al, clean, sf) <= e_tb
    assert Q.normal_angle_error(ms, clean, sf) <= e_tb
    assert Q.normal_angle_error(al, clean) < Q.normal_angle_error(noisy, clean) / 2
    assert abs(Q.volume_change(al, clean)) < 0.02


def test_metrics_against_closed_form():
    clean = cube(0.25)
    shifted = clean.with_points(clean.points * 1.1)  # scaled cube: volume 1.331, offsets known
    assert Q.signed_volume(clean) == pytest.approx(1.0)
    assert Q.volume_change(shifted, clean) == pytest.approx(0.331)
    d = Q.surface_distances(shifted, clean)
    # a corner (0.55,0.55,0.55) is 0.05*sqrt(3) from the unit cube
    assert d["hausdorff"] == pytest.approx(0.05 * np.sqrt(3), rel=1e-6)
    assert 0.05 <= d["mean"] <= 0.05 * np.sqrt(3)
    n = Q.vertex_normals(plane(5))
    assert np.allclose(np.abs(n[:, 2]), 1.0)


def test_noise_is_seeded_and_scaled():
    clean = plane(40)
    a = Q.add_noise(clean, 0.3, seed=3)
    b = Q.add_noise(clean, 0.3, seed=3)
    assert np.array_equal(a.points, b.points)
    std = a.points[:, 2].std()
    assert std == pytest.approx(0.3 * Q.mean_edge_length(clean), rel=0.1)
    r = Q.add_noise(clean, 0.3, seed=3, direction="random")
    assert r.points[:, 0].std() > 0


def test_empty_and_non_manifold_errors():
    with pytest.raises(MeshError, match="empty"):
        D.msal(TriMesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int)))
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1.0]])
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])  # edge (0,1) in three faces
    with pytest.raises(MeshError, match=r"non-manifold edge \(0, 1\)"):
        D.anisotropic_laplacian(TriMesh(pts, f))
    with pytest.raises(PhysarError, match="unknown denoising method"):
        D.denoise(plane(3), "bilateral")
    with pytest.raises(PhysarError, match="iterations"):
        D.msal(plane(3), 0)


def test_progress_callback():
    calls = []
    D.msal(Q.add_noise(plane(8), 0.2), 3, progress=lambda k, q: calls.append(k))
    assert calls == [0, 1, 2]


def test_cli_noise_then_denoise(tmp_path):
    app = typer.Typer()
    register(app)
    run = CliRunner()
    src = tmp_path / "cube.obj"
    write_mesh(src, cube(0.2))
    noisy, out = tmp_path / "noisy.ply", tmp_path / "out.off"
    r = run.invoke(app, ["noise", str(src), str(noisy), "--sigma", "0.2", "--seed", "0", "--json"])
    assert r.exit_code == 0, r.output
    r = run.invoke(app, ["denoise", str(noisy), str(out), "--method", "al", "--iterations", "5", "--json"])
    assert r.exit_code == 0, r.output
    clean = read_mesh(src, kind="tri")
    noisy_mesh = TriMesh(*read_ply(noisy))
    assert Q.normal_angle_error(read_mesh(out, kind="tri"), clean) < Q.normal_angle_error(noisy_mesh, clean)
    r = run.invoke(app, ["denoise", str(tmp_path / "missing.obj"), str(out)])
    assert r.exit_code == 2 and "not found" in r.output
    r = run.invoke(app, ["denoise", str(src), str(tmp_path / "x.stl"), "--method", "nope"])
    assert r.exit_code == 2 and "unknown denoising method" in r.output
    assert not (tmp_path / "x.stl").exists()
