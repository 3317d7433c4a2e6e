"""A flat surface (all points in one plane: a square of two triangles, a 2-D gmsh mesh) given where a closed
surface is tetrahedralised says that it is flat and that a volume needs a closed 3-D surface, through
physar.geometry.tetra.check_closed / tetrahedralize and the CLI (`physar fem solve` with a [mesh] file, the
command that tetrahedralises a surface). The planes and offsets are built by hand (exact distances)."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
from typer.testing import CliRunner

from physar.cli.main import app
from physar.errors import MeshError
from physar.geometry.io import write_mesh
from physar.geometry.mesh import TriMesh, box_mesh
from physar.geometry.tetra import FLAT_RTOL, check_closed, is_flat, tetrahedralize

SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
TWO = np.array([[0, 1, 2], [0, 2, 3]])


def _rotation(seed: int = 3) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q


def _pyramid(h: float, scale: float = 1.0) -> TriMesh:
    """Four side triangles of a square pyramid of apex height h (open: the base's 4 edges have one face);
    its vertices are off their best-fit plane by at most h * (4/5) (centroid at h/5)."""
    pts = np.r_[SQUARE, [[0.5, 0.5, h]]] * scale
    return TriMesh(pts, np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]), name="pyramid")


def test_is_flat_against_hand_planes():
    R = _rotation()
    tilted = TriMesh(SQUARE @ R.T + [2.0, -1.0, 0.5], TWO, name="tilted")
    assert is_flat(TriMesh(SQUARE, TWO)) and is_flat(tilted)
    diag = np.sqrt(2.0)
    # apex off the plane: the max distance to the best-fit plane (z = h/5 by symmetry) is 4h/5
    assert not is_flat(_pyramid(1e-3))
    assert not is_flat(_pyramid(2 * FLAT_RTOL * diag / 0.8))
    assert is_flat(_pyramid(0.5 * FLAT_RTOL * diag / 0.8))
    # relative, not absolute: a micrometre part 10 % high is not flat, a kilometre-wide tilted plane written
    # in float32 (round-off ~6e-8 relative) is
    assert not is_flat(_pyramid(0.1, scale=1e-6))
    big = (SQUARE * 1000.0) @ R.T + 1234.5
    assert is_flat(TriMesh(big.astype(np.float32).astype(float), TWO))
    # unused points do not count (a surface file may carry points no face uses)
    assert is_flat(TriMesh(np.r_[SQUARE, [[0.3, 0.3, 5.0]]], TWO))


# mutants caught: the flat branch removed (the old "not closed" text), `n and` dropped (a closed flat "pillow"
# called flat), the tolerance absolute instead of relative (the float32 kilometre plane above)
def test_check_closed_messages():
    with pytest.raises(MeshError) as ei:
        check_closed(TriMesh(SQUARE, TWO), "sq.stl")
    msg = str(ei.value)
    assert msg.startswith("sq.stl: the surface is flat") and "one plane" in msg and "closed 3-D surface" in msg
    assert "(4 boundary edges)" not in msg and "4 boundary edges" in msg and "\n" not in msg
    with pytest.raises(MeshError, match=r"^pyr: surface is not closed \(4 boundary edges\)"):
        check_closed(_pyramid(0.5), "pyr")  # open, not flat: the old message
    s = box_mesh((1, 2, 3), (1, 1, 1)).boundary().mesh
    check_closed(s, "box")  # closed: no error
    # a closed surface whose points all lie in one plane (two triangulations of the square glued along its
    # edges) is closed, never "flat"
    pillow = TriMesh(SQUARE, np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]), name="pillow")
    check_closed(pillow, "pillow")


def test_tetrahedralize_flat_2d_gmsh_mesh(tmp_path):
    """A 2-D gmsh mesh (points with two coordinates, read with z = 0) of a 2 x 1 rectangle."""
    from physar.geometry.io import read_mesh

    xy = np.array([[x, y] for y in (0.0, 0.5, 1.0) for x in (0.0, 1.0, 2.0)])
    tri = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [3, 4, 7], [3, 7, 6], [4, 5, 8], [4, 8, 7]])
    f = tmp_path / "plane.msh"
    meshio.write(f, meshio.Mesh(xy, [("triangle", tri)]), file_format="gmsh22")
    surf = read_mesh(f)
    assert isinstance(surf, TriMesh)
    with pytest.raises(MeshError, match=r"^plane\.msh: the surface is flat .*8 boundary edges.*closed 3-D surface"):
        tetrahedralize(surf, source="plane.msh")


PROBLEM = """[mesh]
file = "{name}"
[material]
model = "linear"
E = 1e7
nu = 0.3
[[fix]]
plane = {{point = [0, 0, 0], normal = [1, 0, 0]}}
"""


@pytest.mark.parametrize("flat", [True, False])
def test_cli_flat_surface_file(tmp_path, flat):
    surf = TriMesh(SQUARE @ _rotation().T, TWO) if flat else _pyramid(0.5)
    write_mesh(tmp_path / "part.stl", surf)  # binary STL: float32 coordinates
    (tmp_path / "p.toml").write_text(PROBLEM.format(name="part.stl"))
    out = tmp_path / "res.vtu"
    r = CliRunner().invoke(app, ["fem", "solve", str(tmp_path / "p.toml"), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "part.stl" in lines[0], r.output
    msg = lines[0].split("part.stl:", 1)[1]  # the tmp path holds the test's name
    if flat:
        assert "the surface is flat" in msg and "closed 3-D surface" in msg
    else:
        assert "surface is not closed (4 boundary edges)" in msg and "flat" not in msg
    assert not out.exists()
