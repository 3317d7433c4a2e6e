"""Mesh files of other tools, built by each test in tmp_path: split hexahedra/wedges, tags through splits and
writes, OBJ/STL readers, gmsh SaveAll files, inverted meshes, and the CLI. Each test is checked against an
independent reference (exact volumes and areas, hand-written triangles, gmsh's own counts); the comment of each
names the mutant of physar/geometry/io.py it catches."""

from __future__ import annotations

import warnings

import meshio
import numpy as np
import pytest
from typer.testing import CliRunner

from physar.cli.main import app
from physar.errors import MeshError, PhysarError, PhysarWarning
from physar.geometry.io import read_mesh, write_mesh
from physar.geometry.mesh import TetMesh, TriMesh, box_mesh
from physar.geometry.regions import MeshTags

H = 0.5  # hexahedron side
NX, NY, NZ = 3, 2, 2
A, B, C = NX * H, NY * H, NZ * H


def _grid(perm_seed: int | None = 0):
    """Points of an (NX+1)x(NY+1)x(NZ+1) grid and the hexahedra (VTK order) of the box, with node ids shuffled
    (so a cell's local node 0 is not its smallest global node: the split must use global ids)."""
    ijk = np.array([(i, j, k) for k in range(NZ + 1) for j in range(NY + 1) for i in range(NX + 1)])
    pts = ijk * H

    def nid(i, j, k):
        return i + (NX + 1) * (j + (NY + 1) * k)

    hexes = np.array([[nid(i, j, k), nid(i + 1, j, k), nid(i + 1, j + 1, k), nid(i, j + 1, k),
                       nid(i, j, k + 1), nid(i + 1, j, k + 1), nid(i + 1, j + 1, k + 1), nid(i, j + 1, k + 1)]
                      for k in range(NZ) for j in range(NY) for i in range(NX)])
    if perm_seed is not None:
        perm = np.random.default_rng(perm_seed).permutation(len(pts))  # new id of old node
        new_pts = np.empty_like(pts, dtype=float)
        new_pts[perm] = pts
        pts, hexes = new_pts, perm[hexes]
    return pts.astype(float), hexes


def _read_warned(path, **kw):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m = read_mesh(path, **kw)
    return m, [str(w.message) for w in rec if issubclass(w.category, PhysarWarning)]


def _check_closed_box(m: TetMesh, n_boundary_tris: int, dims=(A, B, C)):
    """Positive tets, exact box volume, and a closed boundary of the exact box area with the expected count."""
    a, b, c = dims
    vol = m.volumes
    assert (vol > 0).all()
    assert vol.sum() == pytest.approx(a * b * c, rel=1e-12)
    bnd = m.boundary()
    faces = bnd.mesh.faces
    # a non-conforming split leaves the two halves of a shared quad unmatched: extra "boundary" triangles
    assert len(faces) == n_boundary_tris
    assert bnd.mesh.face_areas().sum() == pytest.approx(2 * (a * b + b * c + c * a), rel=1e-12)
    edges = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()  # closed: every boundary edge in exactly two boundary triangles


N_BOUNDARY_QUADS = 2 * (NX * NY + NY * NZ + NZ * NX)


# mutants caught: the split cone/diagonal chosen per cell by local node 0 (conn[:, 0]) instead of the smallest
# global node -> unmatched internal faces (boundary count and closedness fail); the per-tet orientation fix in
# _split_cells dropped (mixed orientation -> MeshError; mirrored hexes -> a spurious "negative orientation" note).
@pytest.mark.parametrize("mirrored", [False, True])
def test_hex_box_split_conforming(tmp_path, mirrored):
    pts, hexes = _grid()
    if mirrored:  # top face first: every hexahedron in the other handedness
        hexes = hexes[:, [4, 5, 6, 7, 0, 1, 2, 3]]
    f = tmp_path / "box.vtu"
    meshio.write(f, meshio.Mesh(pts, [("hexahedron", hexes)]))
    m, msgs = _read_warned(f)
    assert isinstance(m, TetMesh)
    assert len(msgs) == 1, msgs
    assert any(f"split {len(hexes)} hexahedra into {6 * len(hexes)} tetrahedra" in s for s in msgs), msgs
    assert m.n_cells == 6 * len(hexes) == 72
    _check_closed_box(m, 2 * N_BOUNDARY_QUADS)


# mutant caught: wedge faces/diagonals chosen locally (see above), or wedge tets not counted (3 per wedge).
def test_wedge_box_split_conforming(tmp_path):
    pts, hexes = _grid(perm_seed=1)
    # each hex cut along its (0, 2) / (4, 6) diagonal plane into two prisms
    wedges = np.concatenate([hexes[:, [0, 1, 2, 4, 5, 6]], hexes[:, [0, 2, 3, 4, 6, 7]]])
    f = tmp_path / "prisms.vtu"
    meshio.write(f, meshio.Mesh(pts, [("wedge", wedges)]))
    m, msgs = _read_warned(f)
    assert any(f"split {len(wedges)} wedges (prisms) into {3 * len(wedges)} tetrahedra" in s for s in msgs), msgs
    assert m.n_cells == 3 * len(wedges)
    # every boundary hex face gives 2 triangles (a quad cut in two, or two prism end triangles)
    _check_closed_box(m, 2 * N_BOUNDARY_QUADS)


# mutant caught: pyramids split with the wrong cone (not 2 tets each) or their base cut unlike the neighbouring
# hexahedron's face (apex/diagonal by local node) -> the shared face is unmatched
def test_pyramids_and_hex_conforming(tmp_path):
    corners = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
                       float)
    pts = np.concatenate([corners, corners[[1, 2, 6, 5]] + [1, 0, 0], [[0.5, 0.5, 0.5]]])  # 0-7, 8-11, 12 centre
    hexa = np.array([[1, 8, 9, 2, 5, 11, 10, 6]])
    faces = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    pyr = np.array([[*fc, 12] for fc in faces])
    perm = np.random.default_rng(3).permutation(len(pts))
    new = np.empty_like(pts)
    new[perm] = pts
    f = tmp_path / "pyr.vtu"
    meshio.write(f, meshio.Mesh(new, [("pyramid", perm[pyr]), ("hexahedron", perm[hexa])]))
    m, msgs = _read_warned(f)
    assert any("split 6 pyramids into 12 tetrahedra" in s for s in msgs), msgs
    assert any("split 1 hexahedra into 6 tetrahedra" in s for s in msgs), msgs
    assert m.n_cells == 18
    _check_closed_box(m, 2 * 10, dims=(2.0, 1.0, 1.0))


def _tet10(ref: TetMesh):
    """Points and tetra10 cells (VTK edge order) of a linear mesh: the midside nodes appended after its nodes."""
    local = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]
    cells = np.array(ref.cells)
    e = np.sort(np.stack([cells[:, [i, j]] for i, j in local], axis=1), axis=2)  # (m, 6, 2)
    uniq, inv = np.unique(e.reshape(-1, 2), axis=0, return_inverse=True)
    mid = ref.points[uniq].mean(axis=1)
    n = ref.n_points
    return np.concatenate([ref.points, mid]), np.hstack([cells, n + inv.reshape(-1, 6)]), uniq, n


# mutants caught: higher-order cells not cut to their corners (conn[:, :4] dropped -> refused), the unused midside
# nodes kept, or the tagged triangle6 faces not remapped after dropping them
def test_second_order_tet10_with_tagged_triangle6(tmp_path):
    ref = _small_box()
    pts, t10, edges, n = _tet10(ref)
    fg = ref.boundary().faces_global
    tri = fg[(ref.points[fg][..., 0] == 0).all(axis=1)]
    key = {tuple(ed): n + i for i, ed in enumerate(edges.tolist())}
    tri6 = np.array([[*t, *(key[tuple(sorted((t[i], t[j])))] for i, j in ((0, 1), (1, 2), (2, 0)))] for t in tri])
    cell_x = ref.points[ref.cells].mean(axis=1)[:, 0]
    ctag = np.where(cell_x < 0.5, 3, 4)
    f = tmp_path / "p2.vtu"
    perm = np.random.default_rng(4).permutation(len(pts))  # midside and corner nodes interleaved
    new = np.empty_like(pts)
    new[perm] = pts
    meshio.write(f, meshio.Mesh(new, [("tetra10", perm[t10]), ("triangle6", perm[tri6])],
                                cell_data={"cell_tags": [ctag, np.full(len(tri6), 8)]}))
    m, msgs = _read_warned(f)
    assert any("second-order tetra10" in s for s in msgs), msgs
    assert m.n_points == ref.n_points  # midside nodes dropped
    np.testing.assert_array_equal(m.points[m.cells], ref.points[ref.cells])
    np.testing.assert_array_equal(m.points[m.tags.face_nodes], ref.points[tri])
    np.testing.assert_array_equal(m.tags.cell_tags, ctag)
    np.testing.assert_array_equal(m.tags.face_tags, 8)


# mutant caught: `tags[owner]` replaced by tags repeated/tiled (np.resize(tags, len(tets))) or dropped.
def test_hex_tags_carried_to_pieces(tmp_path):
    pts, hexes = _grid(perm_seed=2)
    hex_x = pts[hexes].mean(axis=1)[:, 0]
    hex_tags = np.where(hex_x < A / 2, 1, 2)
    f = tmp_path / "tagged.vtu"
    meshio.write(f, meshio.Mesh(pts, [("hexahedron", hexes)], cell_data={"cell_tags": [hex_tags]}))
    m, _ = _read_warned(f)
    assert m.tags is not None and m.tags.cell_tags is not None
    tet_x = m.points[m.cells].mean(axis=1)[:, 0]
    # NX = 3 hexes of side 0.5 in x: mid plane at x = 0.75 cuts the middle hex column; use the hex column instead
    column = np.floor(tet_x / H).astype(int)
    expect = np.where((column + 0.5) * H < A / 2, 1, 2)
    np.testing.assert_array_equal(m.tags.cell_tags, expect)
    for t in (1, 2):
        assert (m.tags.cell_tags == t).sum() == 6 * (hex_tags == t).sum()


OBJ = """\
# quad, negative indices, vt/vn counts unlike the vertex count
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vn 0 0 1
f 1/1/1 2/2/1 3/3/1 4/1/1
v 0 0 1
f -1//1 -5//1 -4//1
f 2/3 3/2 -1/1
"""


def _tri_sets(m: TriMesh):
    return sorted(sorted(map(tuple, m.points[f].round(12).tolist())) for f in m.faces)


# mutants caught: negative OBJ indices ignored (j - 1 for all j) or counted from the end of the file; the quad
# dropped or cut along the other diagonal is also caught (the triangle sets differ).
def test_obj_negative_indices_and_vt_vn(tmp_path):
    f = tmp_path / "s.obj"
    f.write_text(OBJ)
    m, msgs = _read_warned(f)
    assert isinstance(m, TriMesh)
    assert any("split 1 quadrilaterals into 2 triangles" in s for s in msgs), msgs
    p = {1: (0, 0, 0), 2: (1, 0, 0), 3: (1, 1, 0), 4: (0, 1, 0), 5: (0, 0, 1)}
    expected = [(1, 2, 3), (1, 3, 4), (5, 1, 2), (2, 3, 5)]  # quad cut through its smallest node 1
    want = sorted(sorted(tuple(float(c) for c in p[i]) for i in tri) for tri in expected)
    assert _tri_sets(m) == want
    # the quad's halves keep its orientation (+z)
    quad = [i for i, fc in enumerate(m.faces) if np.allclose(m.points[fc][:, 2], 0)]
    assert len(quad) == 2
    assert (m.face_normals()[quad][:, 2] > 0.99).all()


# mutant caught: polygons (k > 4) of the OBJ reader dropped or fanned from the wrong node (not the smallest)
def test_obj_polygons(tmp_path):
    f = tmp_path / "poly.obj"
    f.write_text("v 0 0 0\nv 2 0 0\nv 3 1 0\nv 1 2 0\nv -1 1 0\nv 1 -1 0\nf 3 4 5 1 2\nf 1 6 2\n")
    m, msgs = _read_warned(f)
    assert any("split 1 polygons into 3 triangles" in s for s in msgs), msgs
    # pentagon 3-4-5-1-2 fanned from node 1: (1,2,3), (1,3,4), (1,4,5)
    p = {1: (0, 0, 0), 2: (2, 0, 0), 3: (3, 1, 0), 4: (1, 2, 0), 5: (-1, 1, 0), 6: (1, -1, 0)}
    want = sorted(sorted(tuple(float(c) for c in p[i]) for i in t) for t in [(1, 2, 3), (1, 3, 4), (1, 4, 5), (1, 6, 2)])
    assert _tri_sets(m) == want
    assert (m.face_normals()[:, 2] > 0.99).all()
    assert m.face_areas().sum() == pytest.approx(6.0)  # shoelace area of the pentagon (5) + triangle (1)


@pytest.mark.parametrize("bad, lineno", [("f 1 0 2", 6), ("f 1 -7 2", 6), ("v 1 2", 6), ("f 1 x 2", 6)])
def test_obj_bad_line_names_file_and_line(tmp_path, bad, lineno):
    f = tmp_path / "bad.obj"
    f.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n\n# c\n" + bad + "\n")
    with pytest.raises(PhysarError) as ei:
        read_mesh(f)
    msg = str(ei.value)
    assert str(f) in msg and f"line {lineno}" in msg and "\n" not in msg


# mutant caught (a real bug, fixed): a forward index past the last vertex reported without its line number
def test_obj_forward_index_past_end(tmp_path):
    f = tmp_path / "fwd.obj"
    f.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\nv 1 1 1\n")
    with pytest.raises(MeshError, match="vertex 9") as ei:
        read_mesh(f)
    assert str(f) in str(ei.value) and "line 5" in str(ei.value) and "4 vertices" in str(ei.value)


STL = """solid tet
facet normal 0 0 -1
 outer loop
  vertex 0 0 0
  vertex 0 1 0
  vertex 1 0 0
 endloop
endfacet
facet normal 0 -1 0
 outer loop
  vertex 0 0 0
  vertex 1 0 0
  vertex 0 0 1
 endloop
endfacet
facet normal -1 0 0
 outer loop
  vertex 0 0 0
  vertex 0 0 1
  vertex 0 1 0
 endloop
endfacet
facet normal 1 1 1
 outer loop
  vertex 1 0 0
  vertex 0 1 0
  vertex 0 0 1
 endloop
endfacet

endsolid tet
"""


# mutant caught: vertices not merged (np.unique dropped: 12 points) or the blank line / ASCII detection broken
def test_ascii_stl_blank_line_before_endsolid(tmp_path):
    f = tmp_path / "tet.stl"
    f.write_text(STL)
    m = read_mesh(f)
    assert isinstance(m, TriMesh)
    assert m.n_points == 4 and m.n_faces == 4
    assert m.face_areas().sum() == pytest.approx(1.5 + np.sqrt(3) / 2, rel=1e-12)
    assert sorted(map(tuple, m.points.tolist())) == [(0, 0, 0), (0, 0, 1), (0, 1, 0), (1, 0, 0)]
    edges = np.sort(m.faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    assert (np.unique(edges, axis=0, return_counts=True)[1] == 2).all()


# mutant caught: the gmsh fallback / physical tags lost (groups[0] -> -1), or gmsh's untagged entities read as tag 0
def test_gmsh_saveall_msh(tmp_path):
    pytest.importorskip("gmsh")
    from physar.geometry.tetra import _Gmsh

    f = tmp_path / "box.msh"
    with _Gmsh() as g:
        g.model.add("b")
        g.model.occ.addBox(0, 0, 0, 1, 0.5, 0.25)
        g.model.occ.synchronize()
        g.model.addPhysicalGroup(3, [1], 5)
        xmin = [t for d, t in g.model.getEntities(2)
                if np.allclose(g.model.occ.getCenterOfMass(2, t)[0], 0)]
        g.model.addPhysicalGroup(2, xmin, 7)
        g.option.setNumber("Mesh.MeshSizeMax", 0.2)
        g.option.setNumber("Mesh.SaveAll", 1)
        g.model.mesh.generate(3)
        n_tets = len(g.model.mesh.getElementsByType(4)[0])
        n_tri_tagged = sum(len(g.model.mesh.getElements(2, t)[1][0]) for t in xmin)
        g.write(str(f))
    m, _ = _read_warned(f)
    assert isinstance(m, TetMesh)
    assert m.n_cells == n_tets
    assert m.volumes.sum() == pytest.approx(0.125, rel=1e-9)
    assert m.tags is not None
    np.testing.assert_array_equal(m.tags.cell_tags, 5)
    on7 = m.tags.face_tags == 7
    assert on7.sum() == n_tri_tagged
    assert np.allclose(m.points[m.tags.face_nodes[on7]][..., 0], 0)


# mutant caught: unknown cell types skipped silently (or read as their first nodes) instead of one MeshError line
def test_unsplittable_type_refused(tmp_path):
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    faces = [np.array([0, 2, 1]), np.array([0, 1, 3]), np.array([1, 2, 3]), np.array([0, 3, 2])]
    f = tmp_path / "poly.vtu"
    meshio.write(f, meshio.Mesh(pts, [("polyhedron", [faces])]))
    with pytest.raises(MeshError) as ei:
        read_mesh(f)
    msg = str(ei.value)
    assert str(f) in msg and "polyhedron" in msg and "cannot be read" in msg and "\n" not in msg


def _small_box():
    return box_mesh((1.0, 0.5, 0.25), (3, 2, 1))


# mutant caught: the reorientation skipped (TetMesh then refuses) or done without a warning
def test_all_inverted_reoriented(tmp_path):
    ref = _small_box()
    cells = np.array(ref.cells)[:, [0, 1, 3, 2]]
    f = tmp_path / "inv.vtu"
    meshio.write(f, meshio.Mesh(ref.points, [("tetra", cells)]))
    m, msgs = _read_warned(f)
    assert any("negative orientation" in s and str(f) in s for s in msgs), msgs
    assert (m.volumes > 0).all()
    assert m.volumes.sum() == pytest.approx(0.125, rel=1e-12)


# mutant caught: the mixed-orientation check dropped (all reoriented, or TetMesh's own error without the file)
def test_mixed_orientation_refused(tmp_path):
    ref = _small_box()
    cells = np.array(ref.cells)
    cells[::2] = cells[::2][:, [0, 1, 3, 2]]
    f = tmp_path / "mixed.vtu"
    meshio.write(f, meshio.Mesh(ref.points, [("tetra", cells)]))
    with pytest.raises(MeshError) as ei:
        read_mesh(f)
    msg = str(ei.value)
    assert str(f) in msg and "inverted" in msg and "\n" not in msg


def _tagged_box() -> TetMesh:
    ref = _small_box()
    x = ref.points[ref.cells].mean(axis=1)[:, 0]
    bnd = ref.boundary()
    fg = bnd.faces_global
    on_x0 = (ref.points[fg][..., 0] == 0).all(axis=1)
    tags = MeshTags(cell_tags=np.where(x < 0.5, 1, 2), face_nodes=fg[on_x0],
                    face_tags=np.full(int(on_x0.sum()), 9), names={"left": (1, 3), "right": (2, 3), "x0": (9, 2)})
    return TetMesh(ref.points, ref.cells, tags=tags)


# mutants caught: tags not written (cd[key] dropped), the wrong meshio key per format, .msh written as ANSYS
@pytest.mark.parametrize("suffix", [".msh", ".vtu", ".mesh", ".xdmf"])
def test_write_mesh_round_trip_keeps_tags(tmp_path, suffix):
    m = _tagged_box()
    f = write_mesh(tmp_path / f"t{suffix}", m)
    if suffix == ".msh":
        assert f.read_bytes().startswith(b"$MeshFormat\n2.2 ")  # gmsh 2.2 (binary), not ANSYS
    back, _ = _read_warned(f)
    np.testing.assert_allclose(back.points, m.points)
    np.testing.assert_array_equal(back.cells, m.cells)
    np.testing.assert_array_equal(back.tags.cell_tags, m.tags.cell_tags)
    assert sorted(map(tuple, np.sort(back.tags.face_nodes[back.tags.face_tags == 9], axis=1).tolist())) == \
        sorted(map(tuple, np.sort(m.tags.face_nodes, axis=1).tolist()))
    if suffix == ".msh":  # only gmsh stores group names (meshio writes no field_data to VTU or Medit)
        assert back.tags.names.get("x0") == (9, 2)


# A results file (a cell field given) keeps the per-tet tags but not the tagged boundary triangles, which viewers
# would draw over the tetrahedra's faces with NaN fields. mutant caught: the triangles written with the fields
@pytest.mark.parametrize("suffix", [".msh", ".vtu"])
def test_results_file_with_a_cell_field_keeps_tet_tags_without_the_face_block(tmp_path, suffix):
    import meshio

    m = _tagged_box()
    f = write_mesh(tmp_path / f"cf{suffix}", m, point_data={"u": np.zeros((m.n_points, 3))},
                   cell_data={"s": np.arange(m.n_cells, dtype=float)})
    raw = meshio.read(f)
    assert [c.type for c in raw.cells] == ["tetra"]
    np.testing.assert_array_equal(raw.cell_data["s"][0], np.arange(m.n_cells))
    back, _ = _read_warned(f)
    np.testing.assert_allclose(back.points, m.points)
    x = back.points[back.cells].mean(axis=1)[:, 0]
    np.testing.assert_array_equal(back.tags.cell_tags, np.where(x < 0.5, 1, 2))


runner = CliRunner()


def _cli(*args):
    return runner.invoke(app, [str(a) for a in args])


# mutants caught: split counts per block overwritten instead of summed ("split 6 hexahedra"), a warning per
# block instead of per type; an error printed with a traceback or exit code 1
def test_cli_convert_hex_and_mixed(tmp_path):
    pts, hexes = _grid()
    half = len(hexes) // 2
    src = tmp_path / "hex.vtu"  # two hexahedron blocks (a triangle between keeps them apart): one warning line
    blocks = [("hexahedron", hexes[:half]), ("triangle", hexes[:1, :3]), ("hexahedron", hexes[half:])]
    meshio.write(src, meshio.Mesh(pts, blocks))
    assert [c.type for c in meshio.read(src).cells] == ["hexahedron", "triangle", "hexahedron"]
    r = _cli("mesh", "convert", src, "--out", tmp_path / "out.vtu")
    assert r.exit_code == 0, r.output
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and "split 12 hexahedra into 72 tetrahedra" in warn[0], r.stderr
    assert read_mesh(tmp_path / "out.vtu").n_cells == 72

    ref = _small_box()
    cells = np.array(ref.cells)
    cells[1::3] = cells[1::3][:, [0, 1, 3, 2]]
    bad = tmp_path / "mixed.vtu"
    meshio.write(bad, meshio.Mesh(ref.points, [("tetra", cells)]))
    r = _cli("mesh", "convert", bad, "--out", tmp_path / "o2.vtu")
    assert r.exit_code == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "inverted" in lines[0], r.stderr
    assert "Traceback" not in r.output
    assert not (tmp_path / "o2.vtu").exists()
