"""Tetrahedralisation of closed surfaces (gmsh) and tet quality, against closed forms."""
import numpy as np
import pytest

from physar.errors import MeshError
from physar.geometry import TetMesh, TriMesh, box_mesh, read_mesh, write_mesh
from physar.geometry.tetra import (
    boundary_edge_count,
    default_size,
    l_bracket_surface,
    plate_with_hole_surface,
    tet_quality,
    tetrahedralize,
)


def test_tet_quality_closed_forms():
    # regular tetrahedron: every dihedral arccos(1/3) = 70.5288 deg, radius ratio 1
    reg = TetMesh.reoriented(np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float),
                             np.array([[0, 1, 2, 3]]))
    q = tet_quality(reg)
    assert q["min_dihedral"][0] == pytest.approx(np.degrees(np.arccos(1 / 3)), abs=1e-9)
    assert q["radius_ratio"][0] == pytest.approx(1.0, abs=1e-12)
    # corner tetrahedron (0, e1, e2, e3): dihedrals 90 deg on the axes, arccos(1/sqrt 3) = 54.7356 deg on
    # the slanted edges; r_in = 3 V / A = 0.5 / (1.5 + sqrt(3)/2), R = sqrt(3)/2.
    # Catches: max instead of min dihedral (90), the angle between normals without pi - (125.26), R or r_in wrong.
    cor = TetMesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float), np.array([[0, 1, 2, 3]]))
    q = tet_quality(cor)
    assert q["min_dihedral"][0] == pytest.approx(np.degrees(np.arccos(1 / np.sqrt(3))), abs=1e-9)
    r_in = 0.5 / (1.5 + np.sqrt(3) / 2)
    assert q["radius_ratio"][0] == pytest.approx(3 * r_in / (np.sqrt(3) / 2), rel=1e-12)


def _surface_area(mesh: TetMesh) -> float:
    return float(mesh.boundary().mesh.face_areas().sum())


def test_l_bracket_volume_area_and_quality_exact():
    """Flat faces: the tet mesh must have the exact volume and area of the union of the two boxes.
    Catches: meshing the convex hull (volume 0.1*0.04*0.1 = 4e-4), losing the web or the flange, a
    sliver-producing mesher (min dihedral < 10 deg: TetGen gave 5.5 deg here)."""
    Lx, Hz, D, T = 0.1, 0.1, 0.04, 0.02
    surf = l_bracket_surface(Lx, Hz, D, T, size=0.01)
    assert boundary_edge_count(surf) == 0
    m = tetrahedralize(surf)
    vol = Lx * D * T + (Hz - T) * T * D
    assert m.volumes.sum() == pytest.approx(vol, rel=1e-9)
    profile = Lx * T + (Hz - T) * T  # L-shaped profile area
    perimeter = 2 * (Lx + Hz)
    assert _surface_area(m) == pytest.approx(2 * profile + perimeter * D, rel=1e-9)
    assert tet_quality(m)["min_dihedral"].min() > 10.0


def test_plate_with_hole_volume_and_size():
    """Volume L W T - pi r^2 T up to the faceting of the hole (inscribed polygon: relative hole-area
    error ~ (2 pi / n)^2 / 6 for n facets, < 2 % here); the default size follows the bounding box.
    Catches: a plate without the hole (+6.7 % volume), a size that is ignored (edge length off by 2x)."""
    L, W, T, r = 0.2, 0.1, 0.01, 0.02
    surf = plate_with_hole_surface(L, W, T, r, size=0.004)
    m = tetrahedralize(surf)
    hole = np.pi * r**2 * T
    assert m.volumes.sum() == pytest.approx(L * W * T - hole, abs=0.02 * hole)
    assert default_size(surf) == pytest.approx(T / 2)
    e = m.points[m.cells[:, [0, 1, 0, 2, 0, 3, 1, 2, 1, 3, 2, 3]].reshape(-1, 2)]
    mean_edge = np.linalg.norm(e[:, 1] - e[:, 0], axis=1).mean()
    assert 0.5 * T / 2 < mean_edge < 1.5 * T / 2
    m2 = tetrahedralize(surf, size=T / 4)
    assert m2.n_cells > 4 * m.n_cells  # halving h: about 8x the elements


def test_open_surface_is_a_one_line_error():
    """Removing one triangle of a closed surface leaves exactly its 3 edges on the boundary."""
    s = box_mesh((1, 1, 1), (2, 2, 2)).boundary().mesh
    open_s = TriMesh(s.points, s.faces[1:], name="part.stl")
    with pytest.raises(MeshError, match=r"^part\.stl: surface is not closed \(3 boundary edges\)"):
        tetrahedralize(open_s)


def test_self_intersecting_surface_is_an_error():
    a = box_mesh((1, 1, 1), (1, 1, 1)).boundary().mesh
    two = TriMesh(np.vstack([a.points, a.points + 0.5]), np.vstack([a.faces, a.faces + a.n_points]), name="two.stl")
    with pytest.raises(MeshError, match=r"^two\.stl: gmsh could not mesh the volume \(self-intersecting"):
        tetrahedralize(two, 0.2)


@pytest.mark.parametrize("suffix", [".stl", ".obj", ".ply", ".off"])
def test_surface_file_round_trip(tmp_path, suffix):
    """A box surface written in each surface format and tetrahedralised has the box volume (exact)."""
    s = box_mesh((0.3, 0.1, 0.05), (3, 1, 1)).boundary().mesh
    p = write_mesh(tmp_path / f"part{suffix}", s)
    m = tetrahedralize(read_mesh(p, kind="tri"))
    assert m.volumes.sum() == pytest.approx(0.3 * 0.1 * 0.05, rel=1e-6)  # float32 STL coordinates
