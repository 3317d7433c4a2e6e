"""`physar mesh convert` refuses a surface with degenerate faces (a vertex index repeated in a face, or zero area)
in one line naming the counts, as `denoise` and `fem` refuse such a surface (new-user review, seed 001); a clean
surface at any scale converts, read back by meshio.

References: a regular octahedron built here (8 faces, all of area sqrt(3)/2 r^2), with a face (0, 0, 1) added
and one edge split at its midpoint m, the two faces on one side replaced by two halves and a sliver (a, m, b)
of zero area closing the gap (a closed manifold surface: only the sliver is degenerate); files written by meshio."""

from __future__ import annotations

import itertools

import meshio
import numpy as np
from typer.testing import CliRunner

from physar.cli.main import app

runner = CliRunner()


def _octahedron(r=1.0):
    pts = r * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    faces = []
    for sx, sy, sz in itertools.product((1, -1), repeat=3):
        f = [0 if sx > 0 else 1, 2 if sy > 0 else 3, 4 if sz > 0 else 5]
        faces.append(f if sx * sy * sz > 0 else [f[0], f[2], f[1]])  # outward normals
    return pts, np.array(faces, np.int64)


def _with_sliver(pts, faces):
    """Split the edge 0 -> 2 of face (0, 2, 4) at its midpoint m: (0, m, 4), (m, 2, 4), and the sliver (2, m, 0)
    against the neighbour face holding 2 -> 0 (zero area, closed manifold). The sliver is the last face."""
    assert faces[0].tolist() == [0, 2, 4]
    m = len(pts)
    pts = np.vstack([pts, 0.5 * (pts[0] + pts[2])])
    return pts, np.vstack([faces[1:], [[0, m, 4], [m, 2, 4], [2, m, 0]]])


def _write(path, pts, faces):
    meshio.write(path, meshio.Mesh(pts, [("triangle", np.asarray(faces, np.int32))]))
    return path


def _convert(src, dst):
    return runner.invoke(app, ["mesh", "convert", str(src), "--out", str(dst)])


def _refused(r, src, dst):
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {src}: "), r.output
    assert "Traceback" not in r.output and not dst.exists()
    return lines[0]


# mutants caught: no check in convert (exit 0, the faces written); the zero-area count including the faces that
# repeat a vertex (they have zero area too: "2 of zero area")
def test_repeated_vertex_and_zero_area_faces_refused(tmp_path):
    pts, faces = _with_sliver(*_octahedron(0.05))
    src = _write(tmp_path / "mixed.ply", pts, np.vstack([faces, [[0, 0, 1]]]))
    line = _refused(_convert(src, tmp_path / "out.vtu"), src, tmp_path / "out.vtu")
    n = len(faces) + 1
    assert f"2 degenerate faces of {n}: 1 repeating a vertex index (e.g. face {n - 1}, vertices [0, 0, 1]" in line
    assert f"1 of zero area (e.g. face {n - 2}, vertices [2, 6, 0]" in line, line


# mutant caught: only faces that repeat a vertex checked (the sliver's three distinct vertices pass)
def test_zero_area_sliver_on_a_closed_surface_refused(tmp_path):
    pts, faces = _with_sliver(*_octahedron(0.05))
    src = _write(tmp_path / "sliver.ply", pts, faces)
    line = _refused(_convert(src, tmp_path / "out.stl"), src, tmp_path / "out.stl")
    assert f"1 degenerate face of {len(faces)}: 1 of zero area" in line and "remove it first" in line, line


# mutant caught: an absolute area threshold (area <= 1e-12 m^2: every face of this 1 um octahedron, 8.7e-13 m^2,
# "degenerate") instead of one relative to the mean face area
def test_clean_surface_at_any_scale_converts(tmp_path):
    for r in (1e-6, 0.05, 100.0):
        pts, faces = _octahedron(r)
        src = _write(tmp_path / "clean.ply", pts, faces)
        dst = tmp_path / "clean.vtu"
        res = _convert(src, dst)
        assert res.exit_code == 0, res.output
        back = meshio.read(dst)
        np.testing.assert_array_equal(back.cells_dict["triangle"], faces)
        np.testing.assert_allclose(back.points, pts, rtol=0, atol=0)
        dst.unlink()
