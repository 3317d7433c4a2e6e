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


def _uv_sphere(path, nlat=6, nlon=8):
    """A UV sphere as exporters write it: a (nlat + 1) x (nlon + 1) grid of vertices (the poles repeated per
    longitude, the seam column repeated), quads only, 6 decimals."""
    lines = []
    for i in range(nlat + 1):
        th = np.pi * i / nlat
        for j in range(nlon + 1):
            ph = 2 * np.pi * j / nlon
            lines.append(f"v {np.sin(th) * np.cos(ph):.6f} {np.sin(th) * np.sin(ph):.6f} {np.cos(th):.6f}")
    idx = lambda i, j: i * (nlon + 1) + j + 1  # noqa: E731
    for i in range(nlat):
        for j in range(nlon):
            lines.append(f"f {idx(i, j)} {idx(i + 1, j)} {idx(i + 1, j + 1)} {idx(i, j + 1)}")
    path.write_text("\n".join(lines) + "\n")
    return path


# A UV sphere reads as the closed sphere (the pole quads become triangles): 2 + (nlat - 1) nlon vertices,
# every edge in two faces, V - E + F = 2; two cubes in separate objects touching at a corner keep their own
# vertices (16), as the file has them. mutants caught: collapsed quads kept as faces that repeat a vertex (refused
# "face repeats a vertex"), the merge made whatever it joins (the cubes' corner becomes non-manifold: refused)
def test_uv_sphere_and_touching_objects(tmp_path):
    m = read_mesh(_uv_sphere(tmp_path / "uv.obj"), kind="tri")
    assert m.n_points == 2 + 5 * 8
    e = np.sort(m.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    ue, cnt = np.unique(e, axis=0, return_counts=True)
    assert (cnt == 2).all() and m.n_points - len(ue) + m.n_faces == 2
    a, b = trimesh.creation.box(bounds=[[0, 0, 0], [1, 1, 1]]), trimesh.creation.box(bounds=[[1, 1, 1], [2, 2, 2]])
    text = ["o a"] + [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in a.vertices] + \
           [f"f {' '.join(str(i + 1) for i in f)}" for f in a.faces] + ["o b"] + \
           [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in b.vertices] + \
           [f"f {' '.join(str(i + 9) for i in f)}" for f in b.faces]
    (tmp_path / "cc.obj").write_text("\n".join(text) + "\n")
    m = read_mesh(tmp_path / "cc.obj", kind="tri")
    assert m.n_points == 16 and m.n_faces == 24
