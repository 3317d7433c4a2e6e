"""`physar denoise` / `physar noise` keep a surface PLY's per-vertex colours (exactly, per vertex) and recompute
its normals on the moved vertices. The output is read back with meshio (a peer PLY reader); the reference
normals are area-weighted face normals computed here with numpy, and for a sphere centred at 0 outward means
n . x > 0."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from physar.cli.main import app

runner = CliRunner()


def _cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def _area_normals(points, faces):
    """Unit area-weighted vertex normals (sum of cross products of the incident faces), np.add.at."""
    x = points[faces]
    fn = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    n = np.zeros_like(points)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _noisy_sphere(path, *, normals=True, flip=False, binary=True, alpha=True):
    """A noisy unit icosphere (outward winding) as PLY with random uint8 colours and float32 normals of the
    noisy vertices (`flip`: pointing inward); returns (points, faces, colours, normals written)."""
    s = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(3)
    faces = np.asarray(s.faces, np.int64)
    pts = np.asarray(s.vertices, float)
    edge = np.linalg.norm(pts[faces[:, 0]] - pts[faces[:, 1]], axis=1).mean()
    d = rng.standard_normal((len(pts), 3))
    pts = pts + 0.3 * edge * rng.standard_normal((len(pts), 1)) * d / np.linalg.norm(d, axis=1, keepdims=True)
    col = rng.integers(0, 256, (len(pts), 4 if alpha else 3), dtype=np.uint8)
    pd = {k: col[:, j] for j, k in enumerate(("red", "green", "blue", "alpha")[:col.shape[1]])}
    n = (-1 if flip else 1) * _area_normals(pts, faces)
    if normals:
        pd.update({k: n[:, j].astype(np.float32) for j, k in enumerate(("nx", "ny", "nz"))})
    meshio.write(path, meshio.Mesh(pts, [("triangle", faces.astype(np.int32))], point_data=pd), binary=binary)
    return pts, faces, col, n


def _read(path):
    m = meshio.read(path)
    (tri,) = [c.data for c in m.cells if c.type == "triangle"]
    return m.points, np.asarray(tri, np.int64), m.point_data


# mutants caught: colours dropped (no point_data written), colours in the wrong order / another vertex's; normals
# copied from the input (not recomputed on the denoised vertices: off by several degrees), not unit length
def test_denoise_keeps_colours_and_recomputes_outward_normals(tmp_path):
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.ply"
    pts, faces, col, n_in = _noisy_sphere(src)
    r = _cli("denoise", src, "--out", out, "--no-render")
    assert r.exit_code == 0, r.output
    p, f, pd = _read(out)
    assert len(p) == len(pts)
    np.testing.assert_array_equal(f, faces)
    assert np.linalg.norm(p - pts, axis=1).mean() > 1e-3  # the vertices moved
    for j, k in enumerate(("red", "green", "blue", "alpha")):
        assert pd[k].dtype == np.uint8
        np.testing.assert_array_equal(pd[k], col[:, j])
    n = np.column_stack([pd["nx"], pd["ny"], pd["nz"]]).astype(float)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    assert (np.einsum("ij,ij->i", n, p) > 0).all()  # outward on a sphere centred at 0
    ref = _area_normals(p, f)
    np.testing.assert_allclose(n, ref, atol=1e-6)
    assert np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n_in, ref), -1, 1))).max() > 2  # copy would fail


# mutant caught: recomputed normals always follow the face winding (the input's inward convention lost)
def test_inward_normals_stay_inward(tmp_path):
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.ply"
    _noisy_sphere(src, flip=True)
    r = _cli("denoise", src, "--out", out, "--no-render")
    assert r.exit_code == 0, r.output
    p, f, pd = _read(out)
    n = np.column_stack([pd["nx"], pd["ny"], pd["nz"]]).astype(float)
    assert (np.einsum("ij,ij->i", n, p) < 0).all()
    np.testing.assert_allclose(n, -_area_normals(p, f), atol=1e-6)


# mutant caught: only binary PLY (structured arrays) handled: an ASCII PLY's colours (trimesh: a dict of
# columns) dropped; normals invented for an input without them
def test_ascii_ply_colours_no_normals(tmp_path):
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.ply"
    _, _, col, _ = _noisy_sphere(src, normals=False, binary=False, alpha=False)
    assert src.read_bytes().startswith(b"ply\nformat ascii")
    r = _cli("denoise", src, "--out", out, "--no-render")
    assert r.exit_code == 0, r.output
    _, _, pd = _read(out)
    assert set(pd) == {"red", "green", "blue"}
    np.testing.assert_array_equal(np.column_stack([pd["red"], pd["green"], pd["blue"]]), col)


# mutant caught: colours lost silently for an output that cannot hold them (no warning), or the write refused
def test_obj_output_warns_that_colours_are_dropped(tmp_path):
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.obj"
    _noisy_sphere(src)
    r = _cli("denoise", src, "--out", out, "--no-render")
    assert r.exit_code == 0, r.output
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and str(out) in warn[0] and "red, green, blue, alpha, nx, ny, nz" in warn[0], r.stderr
    assert out.exists()


# mutant caught: `noise` (same writer) dropping the colours
def test_noise_keeps_colours(tmp_path):
    src, out = tmp_path / "in.ply", tmp_path / "noised.ply"
    pts, _, col, _ = _noisy_sphere(src)
    r = _cli("noise", src, "--out", out, "--sigma", "0.1")
    assert r.exit_code == 0, r.output
    p, f, pd = _read(out)
    assert np.abs(p - pts).max() > 0
    np.testing.assert_array_equal(np.column_stack([pd[k] for k in ("red", "green", "blue", "alpha")]), col)
    n = np.column_stack([pd["nx"], pd["ny"], pd["nz"]]).astype(float)
    np.testing.assert_allclose(n, _area_normals(p, f), atol=1e-6)


@pytest.mark.parametrize("suffix", [".vtu"])
def test_vtu_output_carries_colours_as_point_data(tmp_path, suffix):
    """mutant caught: per-vertex data written only to PLY (the VTU output loses the colours)."""
    src, out = tmp_path / "noisy.ply", tmp_path / f"clean{suffix}"
    _, _, col, _ = _noisy_sphere(src)
    r = _cli("denoise", src, "--out", out, "--no-render")
    assert r.exit_code == 0, r.output
    pd = meshio.read(out).point_data
    np.testing.assert_array_equal(np.column_stack([pd[k] for k in ("red", "green", "blue", "alpha")]), col)
