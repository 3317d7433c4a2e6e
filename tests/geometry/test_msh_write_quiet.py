"""Writing an untagged mesh as Gmsh .msh prints nothing: meshio warned "Appending zeros to replace the missing
physical/geometrical tag data" on stderr at every write (review). The tags written are 0 (gmsh: no group), and
the file reads back as the same mesh. mutant caught: the zero tags not supplied (the two warnings return)."""

from __future__ import annotations

import meshio
import numpy as np

from physar.geometry.io import read_mesh, write_mesh
from physar.geometry.mesh import box_mesh


def test_untagged_msh_write_is_quiet(tmp_path, capfd):
    m = box_mesh((0.1, 0.02, 0.02), (3, 1, 1))
    write_mesh(tmp_path / "b.msh", m)
    out = capfd.readouterr()
    assert "Appending zeros" not in out.err + out.out, out
    raw = meshio.read(tmp_path / "b.msh")
    assert all((np.asarray(t) == 0).all() for t in raw.cell_data["gmsh:physical"])
    back = read_mesh(tmp_path / "b.msh")
    np.testing.assert_allclose(back.points, m.points)
    np.testing.assert_array_equal(back.cells, m.cells)
