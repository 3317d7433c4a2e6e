"""Meshes store private read-only copies: the caller's arrays stay theirs; box_mesh cells are integers.

Each test names the mutant it catches.
"""

import numpy as np
import pytest

from physar.errors import MeshError
from physar.geometry import TetMesh, TriMesh, box_mesh


def test_tetmesh_leaves_the_callers_points_writable():
    # mutant: np.asarray + setflags(write=False) on the caller's float64 array: P[:, 0] *= 2 raises
    m0 = box_mesh((1.0, 0.1, 0.1), (4, 1, 1))
    P, C = m0.points.copy(), m0.cells.copy()
    m = TetMesh(P, C)
    P[:, 0] *= 2
    C[0] = C[1]
    assert m.points[:, 0].max() == 1.0  # the mesh kept its own copy
    np.testing.assert_array_equal(m.cells, m0.cells)
    assert not m.points.flags.writeable and not m.cells.flags.writeable
    assert m.volumes.sum() == pytest.approx(1.0 * 0.1 * 0.1, rel=1e-12)


def test_trimesh_leaves_the_callers_arrays_writable():
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]], np.int64)
    s = TriMesh(P, F)
    P[0] = 5.0
    F[0, 0] = 2
    assert s.points[0].tolist() == [0.0, 0.0, 0.0] and s.faces[0].tolist() == [0, 1, 2]
    assert not s.points.flags.writeable and not s.faces.flags.writeable


def test_read_only_input_is_shared_not_copied():
    m0 = box_mesh((1.0, 1.0, 1.0), (1, 1, 1))
    assert TetMesh(m0.points, m0.cells).points is m0.points


@pytest.mark.parametrize("cells", [(2.5, 2, 2), (2, 0, 2), (2, 2), (2, 2, np.nan), ("2", 2, 2)])
def test_box_cells_must_be_positive_integers(cells):
    # mutant: np.asarray(cells, dtype=int): 2.5 silently becomes 2
    with pytest.raises(MeshError, match="box cells must be three positive integers"):
        box_mesh((1, 1, 1), cells)


def test_box_cells_count_closed_form():
    # 6 Kuhn tetrahedra per hexahedron; integer-valued floats are integers
    assert box_mesh((1, 1, 1), (2.0, 3, 4)).cells.shape == (6 * 2 * 3 * 4, 4)
