"""An OBJ written as a triangle soup (every face with its own three `v` lines, as some exporters write per-face
normals or seams) reads as one connected surface: the repeated positions are one vertex. Before, each face was
its own patch: `physar noise` tore the sphere apart and `physar denoise` returned it unchanged.

Reference: trimesh's icosphere (642 vertices, 1280 faces, watertight), written as a soup here."""

from __future__ import annotations

import numpy as np
import trimesh

from physar.geometry.io import read_mesh


def _soup(path, mesh):
    lines = []
    for f in mesh.faces:
        for v in mesh.vertices[f]:
            lines.append(f"v {float(v[0])!r} {float(v[1])!r} {float(v[2])!r}")
    for i in range(len(mesh.faces)):
        lines.append(f"f {3 * i + 1}//1 {3 * i + 2}//1 {3 * i + 3}//1")
    path.write_text("vn 0 0 1\n" + "\n".join(lines) + "\n")
    return path


# mutant caught: no merge (3840 points, every edge in one face)
def test_soup_reads_as_the_connected_sphere(tmp_path):
    ico = trimesh.creation.icosphere(subdivisions=3)
    m = read_mesh(_soup(tmp_path / "s.obj", ico), kind="tri")
    assert (m.n_points, m.n_faces) == (len(ico.vertices), len(ico.faces)) == (642, 1280)
    e = np.sort(m.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    assert (np.unique(e, axis=0, return_counts=True)[1] == 2).all()  # closed: every edge in two faces
    got = {frozenset(map(tuple, np.round(m.points[f], 12))) for f in m.faces}
    want = {frozenset(map(tuple, np.round(ico.vertices[f], 12))) for f in ico.faces}
    assert got == want


def test_file_without_repeats_keeps_its_numbering(tmp_path):
    ico = trimesh.creation.icosphere(subdivisions=1)
    ico.export(tmp_path / "i.obj")
    m = read_mesh(tmp_path / "i.obj", kind="tri")
    np.testing.assert_allclose(m.points, ico.vertices, atol=1e-7)  # trimesh writes 8 decimals
    np.testing.assert_array_equal(m.faces, ico.faces)
