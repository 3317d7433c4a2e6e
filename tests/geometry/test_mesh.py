import numpy as np
import pytest

from physar.errors import MeshError, PhysarError
from physar.geometry import (
    TetMesh,
    TriMesh,
    box_mesh,
    read_mesh,
    select_boundary_faces,
    select_nodes,
    write_mesh,
)


def test_box_mesh_volume_and_boundary_area():
    m = box_mesh((2.0, 0.5, 0.25), (8, 3, 2))
    assert m.n_cells == 6 * 8 * 3 * 2
    assert m.volumes.min() > 0
    assert np.isclose(m.volumes.sum(), 2.0 * 0.5 * 0.25, rtol=1e-12)
    b = m.boundary()
    area = 2 * (2.0 * 0.5 + 2.0 * 0.25 + 0.5 * 0.25)
    assert np.isclose(b.mesh.face_areas().sum(), area, rtol=1e-12)
    # outward orientation: divergence theorem, ∮ x·n dA = 3 V
    c = b.face_centroids()
    n = b.mesh.face_normals(normalize=False) / 2
    assert np.isclose(np.sum(c * n), 3 * 0.25, rtol=1e-12)
    # node map points at the right volume nodes
    assert np.allclose(m.points[b.node_map], b.mesh.points)


def test_validation_names_the_element():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]])
    with pytest.raises(MeshError, match="element 1 is inverted"):
        TetMesh(pts, [[0, 1, 2, 3], [0, 2, 1, 3]])
    with pytest.raises(MeshError, match="element 0 is degenerate"):
        TetMesh(pts, [[0, 1, 2, 2]])
    bad = pts.copy()
    bad[2, 1] = np.nan
    with pytest.raises(MeshError, match="point 2"):
        TetMesh(bad, [[0, 1, 2, 3]])
    with pytest.raises(MeshError, match="outside"):
        TetMesh(pts, [[0, 1, 2, 7]])
    fixed = TetMesh.reoriented(pts, [[0, 1, 2, 3], [0, 2, 1, 3]])
    assert (fixed.volumes > 0).all()
    with pytest.raises(MeshError):
        TriMesh(pts, [[0, 1, 9]])


@pytest.mark.parametrize("suffix", [".vtu", ".xdmf", ".msh", ".mesh"])
def test_roundtrip_formats(tmp_path, suffix):
    m = box_mesh((1, 1, 1), (2, 2, 2))
    f = tmp_path / f"m{suffix}"
    write_mesh(f, m, point_data={"u": m.points * 2})
    r = read_mesh(f)
    assert isinstance(r, TetMesh)
    assert np.allclose(r.points, m.points) and np.array_equal(r.cells, m.cells)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".physar-")]


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj", ".off"])
def test_tet_mesh_to_a_surface_format_is_refused(tmp_path, suffix):
    """A surface format would silently drop the tetrahedra: a clear error, and no file."""
    with pytest.raises(PhysarError, match="surfaces only"):
        write_mesh(tmp_path / f"m{suffix}", box_mesh((1, 1, 1), (1, 1, 1)))
    assert not list(tmp_path.iterdir())


def test_read_errors(tmp_path):
    with pytest.raises(PhysarError, match="not found"):
        read_mesh(tmp_path / "missing.vtu")
    junk = tmp_path / "junk.vtu"
    junk.write_text("this is not a mesh")
    with pytest.raises(MeshError, match="cannot read mesh"):
        read_mesh(junk)


def test_selection():
    m = box_mesh((1, 1, 1), (4, 4, 4))
    nodes = select_nodes(m, box=[[0, 0, 0], [0, 1, 1]])
    assert len(nodes) == 25 and np.allclose(m.points[nodes, 0], 0)
    top = select_nodes(m, where=lambda x: x[:, 2] > 0.99)
    assert len(top) == 25
    b = m.boundary()
    faces = select_boundary_faces(b, box=[[1, 0, 0], [1, 1, 1]])
    assert len(faces) == 2 * 16
    assert np.isclose(b.mesh.face_areas()[faces].sum(), 1.0)
