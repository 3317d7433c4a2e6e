"""Region tags of a surface file: read into ``TriMesh.face_tags``/``tag_names`` and carried by ``tetrahedralize``
to the boundary triangles of the tetrahedral mesh (``TetMesh.tags``).

References are independent of physar: gmsh's own model (the triangles gmsh meshed on each named face, read
through the gmsh API), meshio as writer and reader of VTU files, hand-written OBJ / Gmsh 2.2 text, and closed
forms (face areas, the coordinates of the box's faces). The comment of each test names the mutants it catches.
"""

from __future__ import annotations

import importlib.util
import warnings

import meshio
import numpy as np
import pytest
from _gmsh_beam import NAMES, H, L, W, gmsh_beam_surface  # tests/_gmsh_beam.py

from physar.errors import MeshError, PhysarWarning
from physar.geometry.io import read_mesh, write_mesh
from physar.geometry.mesh import TetMesh, TriMesh, boundary_surface, row_keys
from physar.geometry.tetra import tetrahedralize

gmsh_needed = pytest.mark.skipif(importlib.util.find_spec("gmsh") is None, reason="needs the gmsh package")


def _coord_set(points, faces) -> set:
    x = np.round(np.asarray(points)[np.asarray(faces)], 12)
    return {frozenset(map(tuple, t.tolist())) for t in x}


def _read_quiet(path, **kw):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m = read_mesh(path, **kw)
    return m, [str(w.message) for w in rec if issubclass(w.category, PhysarWarning)]


def _areas(points, faces):
    x = np.asarray(points)[np.asarray(faces)]
    return 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)


# ------------------------------------------------------------------------------------------- TriMesh itself
# mutants caught: no check of face_tags (a wrong length stored silently), float tags accepted, tag names not
# normalised to (int, int); with_points dropping the tags; positional construction broken
def test_trimesh_tags_are_validated_and_optional():
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    plain = TriMesh(pts, faces, "tet")  # positional, as everywhere before
    assert plain.face_tags is None and plain.tag_names == {} and plain.name == "tet"
    m = TriMesh(pts, faces, name="tet", face_tags=[5, 5, 6, -1], tag_names={"top": np.array([6, 2])})
    assert m.face_tags.dtype == np.int64 and m.face_tags.tolist() == [5, 5, 6, -1]
    assert m.tag_names == {"top": (6, 2)} and not m.face_tags.flags.writeable
    assert "regions top" in repr(m)
    moved = m.with_points(pts + 1.0)
    assert moved.face_tags.tolist() == [5, 5, 6, -1] and moved.tag_names == {"top": (6, 2)}
    with pytest.raises(MeshError) as e:
        TriMesh(pts, faces, name="part.stl", face_tags=[1, 2, 3])
    assert str(e.value) == "part.stl: face_tags must be 4 integers (one per face), got shape (3,) dtype int64"
    with pytest.raises(MeshError, match=r"^part.stl: face_tags must be 4 integers .* dtype float64$"):
        TriMesh(pts, faces, name="part.stl", face_tags=[1.0, 2.0, 3.0, 4.0])
    with pytest.raises(MeshError, match=r"^part.stl: tag_names\['top'\] must be \(tag, dim\), two integers, got 6$"):
        TriMesh(pts, faces, name="part.stl", face_tags=[1, 1, 1, 1], tag_names={"top": 6})


# ------------------------------------------------------------------------------------------- reading
# mutants caught: tags dropped by read_mesh (face_tags None), names not carried (tag_names {}), a closed
# surface with named groups refused as "gmsh saved only the elements of physical groups" (the old rule), tags
# given to the wrong faces (compared with gmsh's own triangles of each group)
@gmsh_needed
@pytest.mark.parametrize("version", [2.2, 4.1])
def test_msh_surface_keeps_its_groups(tmp_path, version):
    f = tmp_path / f"beam{version}.msh"
    ref = gmsh_beam_surface(f, version)
    s, notes = _read_quiet(f)
    assert isinstance(s, TriMesh) and not notes
    assert s.tag_names == NAMES
    for name, (tag, _) in NAMES.items():
        assert _coord_set(s.points, s.faces[s.face_tags == tag]) == ref[name]
    assert sum(len(r) for r in ref.values()) == s.n_faces


# mutants caught: the quadrilaterals' tags not repeated for their two triangles (tags of the wrong length or
# order), names of other dimensions (the volume group 'body') kept as surface names
def test_quads_and_triangles_keep_tags_through_the_split(tmp_path):
    pts = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0], [0, 0, 1]], float)
    quads = np.array([[0, 1, 2, 3]])  # area 2
    tris = np.array([[0, 1, 4], [0, 4, 3]])  # areas 1 and 0.5
    f = tmp_path / "s.msh"  # meshio writes the names as $PhysicalNames (its VTU writer writes no field data)
    tags = [np.array([4, 9]), np.array([7])]
    meshio.Mesh(pts, [("triangle", tris), ("quad", quads)], cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
                field_data={"base": np.array([7, 2]), "side": np.array([4, 2]), "body": np.array([1, 3])}
                ).write(f, file_format="gmsh22")
    s, notes = _read_quiet(f, kind="tri")
    assert any("split 1 quadrilaterals into 2 triangles" in n for n in notes)
    area = _areas(s.points, s.faces)
    assert {t: float(area[s.face_tags == t].sum()) for t in np.unique(s.face_tags)} == {4: 1.0, 7: 2.0, 9: 0.5}
    assert s.tag_names == {"base": (7, 2), "side": (4, 2)}


# mutants caught: OBJ groups ignored, a repeated group name given a new tag, "g" without a name not the group
# "default", faces before the first group given a group's tag, quads of a group losing the tag when split
def test_obj_groups_are_tags(tmp_path):
    f = tmp_path / "part.obj"
    f.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\n"
                 "f 1 2 5\n"  # before any group
                 "o top cap\nf 1 5 4\n"
                 "g\nf 2 3 5\n"
                 "g top cap\nf 1 2 3 4\n")
    s, _ = _read_quiet(f)
    assert s.tag_names == {"top cap": (1, 2), "default": (2, 2)}
    by_tag = {int(t): _coord_set(s.points, s.faces[s.face_tags == t]) for t in np.unique(s.face_tags)}
    p = s.points
    assert by_tag[-1] == _coord_set(p, [[0, 1, 4]])
    assert by_tag[2] == _coord_set(p, [[1, 2, 4]])
    assert len(by_tag[1]) == 3 and np.isclose(_areas(p, s.faces[s.face_tags == 1]).sum(), 0.5 + 1.0)
    plain = tmp_path / "plain.obj"
    plain.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    m, _ = _read_quiet(plain)
    assert m.face_tags is None and m.tag_names == {}


# mutants caught: the closed-surface exception applied to open surfaces (the named open patch below must still be
# refused: gmsh dropped the volume), or not applied (the closed named one refused)
def test_named_closed_msh22_is_a_surface_model_open_one_is_refused(tmp_path):
    nodes = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    tris = [(0, 2, 1), (0, 1, 3), (1, 2, 3), (0, 3, 2)]

    def msh(path, tris):
        lines = ["$MeshFormat", "2.2 0 8", "$EndMeshFormat", "$PhysicalNames", "2", '2 1 "base"', '2 2 "skin"',
                 "$EndPhysicalNames", "$Nodes", "4"] + [f"{i + 1} {x} {y} {z}" for i, (x, y, z) in enumerate(nodes)]
        lines += ["$EndNodes", "$Elements", str(len(tris))]
        lines += [f"{k + 1} 2 2 {1 if k == 0 else 2} 1 {a + 1} {b + 1} {c + 1}" for k, (a, b, c) in enumerate(tris)]
        path.write_text("\n".join(lines + ["$EndElements"]) + "\n")
        return path

    s, _ = _read_quiet(msh(tmp_path / "closed.msh", tris))
    assert isinstance(s, TriMesh) and s.face_tags.tolist() == [1, 2, 2, 2]
    assert s.tag_names == {"base": (1, 2), "skin": (2, 2)}
    with pytest.raises(MeshError, match=r"open.msh: no tetrahedra: .*\(surface groups 'base', 'skin'; no volume"):
        read_mesh(msh(tmp_path / "open.msh", tris[:3]))


# mutants caught: gmsh physical tag 0 (and Medit reference 0: "no group", what meshio writes for an untagged
# mesh) taken as a region: a surface written without groups would come back with region 0 (and a write of it
# to STL would warn about a region that never existed)
@pytest.mark.parametrize("suffix,key", [(".msh", "gmsh:physical"), (".mesh", "medit:ref")])
def test_tag_zero_of_gmsh_and_medit_is_no_group(tmp_path, suffix, key):
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    tris = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    for tags, want in (([0, 0, 5, 5], [-1, -1, 5, 5]), ([0, 0, 0, 0], None)):
        cd = {key: [np.array(tags)]} | ({"gmsh:geometrical": [np.array(tags)]} if suffix == ".msh" else {})
        f = tmp_path / f"s{suffix}"
        meshio.Mesh(pts, [("triangle", tris)], cell_data=cd).write(f, **({"file_format": "gmsh22"} if
                                                                          suffix == ".msh" else {}))
        s, _ = _read_quiet(f, kind="tri")
        assert (s.face_tags.tolist() if s.face_tags is not None else None) == want


# mutants caught: a TriMesh's tags not written (meshio, an independent reader, sees no cell data / no names), or
# written without warning into a format that cannot hold them
def test_write_surface_tags(tmp_path):
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    s = TriMesh(pts, faces, name="t", face_tags=[1, 2, 2, 3], tag_names={"a": (1, 2), "b": (2, 2)})
    for suffix, key in ((".vtu", "cell_tags"), (".msh", "gmsh:physical")):
        f = write_mesh(tmp_path / f"t{suffix}", s)
        m = meshio.read(f)
        assert np.concatenate(m.cell_data[key]).tolist() == [1, 2, 2, 3]
        assert {k: np.asarray(v).ravel().tolist()[:2] for k, v in m.field_data.items()} == {"a": [1, 2], "b": [2, 2]}
        back, _ = _read_quiet(f)
        assert back.face_tags.tolist() == [1, 2, 2, 3] and back.tag_names == s.tag_names
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        write_mesh(tmp_path / "t.stl", s)
    msgs = [str(w.message) for w in rec if issubclass(w.category, PhysarWarning)]
    assert msgs == [(f"{tmp_path / 't.stl'}: .stl stores no region tags: the surface's regions 'a', 'b' are not "
                     "written (write .vtu, .xdmf or .msh to keep them)")]


# ------------------------------------------------------------------------------------------- tetrahedralize
def _boundary_tags(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray]:
    """The boundary faces of `mesh` (volume node ids) and the tag each carries in mesh.tags (-99: none)."""
    fg = boundary_surface(mesh).faces_global
    n = mesh.n_points
    kb = row_keys(np.sort(fg, axis=1), n)
    kt = row_keys(np.sort(mesh.tags.face_nodes, axis=1), n)
    assert len(np.unique(kt)) == len(kt)  # each triangle tagged once
    order = np.argsort(kt)
    at = np.searchsorted(kt, kb, sorter=order).clip(0, max(len(kt) - 1, 0))
    found = kt[order[at]] == kb
    return fg, np.where(found, mesh.tags.face_tags[order[at]], -99)


# mutants caught: tags not carried by tetrahedralize (mesh.tags None), names not carried, every patch given the
# tag of the first input face (the wrong rule), a boundary face left untagged, a tag on the wrong end
@gmsh_needed
def test_tetrahedralize_tags_the_beam_ends(tmp_path):
    f = tmp_path / "beam.msh"
    gmsh_beam_surface(f)
    s, _ = _read_quiet(f)
    m = tetrahedralize(s, size=0.01)
    assert m.tags is not None and m.tags.names == NAMES and m.tags.cell_tags is None
    fg, tags = _boundary_tags(m)
    x = m.points[fg][:, :, 0]
    on0, onL = np.isclose(x, 0, atol=1e-12).all(axis=1), np.isclose(x, L, atol=1e-12).all(axis=1)
    assert (tags != -99).all(), f"{int((tags == -99).sum())} boundary faces untagged"
    assert (tags[on0] == 1).all() and (tags[onL] == 2).all() and (tags[~on0 & ~onL] == 3).all()
    assert on0.any() and onL.any()
    # the tagged areas are the faces' (closed form), the names resolve to them
    area = _areas(m.points, fg)
    assert area[tags == 1].sum() == pytest.approx(W * H, rel=1e-12)
    assert area[tags == 3].sum() == pytest.approx(2 * L * (W + H), rel=1e-12)
    rows, _ = m.tags.resolve("load")
    assert np.allclose(m.points[rows][:, :, 0], L)


def _box_surface(n=8):
    """The closed surface of [0, 1] x [0, 1] x [0, 0.2], each face an n x n grid of quads split in two (hand
    built), outward oriented; the top face z = 0.2 tagged 2 where x > 0.5, every other face tagged 1."""
    size = np.array([1.0, 1.0, 0.2])
    s = np.linspace(0, 1, n + 1)
    U, V = (g.ravel() for g in np.meshgrid(s, s, indexing="ij"))
    i, j = (g.ravel() for g in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    a = i * (n + 1) + j
    quads = np.r_[np.c_[a, a + n + 1, a + n + 2], np.c_[a, a + n + 2, a + 1]]
    pts, faces = [], []
    for axis in range(3):
        u, v = [k for k in range(3) if k != axis]
        for side in (0, 1):
            p = np.zeros((len(U), 3))
            p[:, u], p[:, v], p[:, axis] = U * size[u], V * size[v], side * size[axis]
            faces.append(quads + len(pts) * len(U))
            pts.append(p)
    uniq, inv = np.unique(np.round(np.concatenate(pts), 12), axis=0, return_inverse=True)
    faces = inv.ravel()[np.concatenate(faces)]
    x = uniq[faces]
    c = x.mean(axis=1)
    inward = np.einsum("fi,fi->f", np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), c - size / 2) < 0
    faces[inward] = faces[inward][:, ::-1]
    tags = np.where(np.isclose(c[:, 2], 0.2) & (c[:, 0] > 0.5), 2, 1)
    return TriMesh(uniq, faces, name="slab", face_tags=tags, tag_names={"pad": (2, 2), "rest": (1, 2)})


# mutants caught: the tag boundary not made a patch boundary (the discrete curve of _tag_edges left out: the top face
# is one patch, remeshed across x = 0.5, and its triangles straddle the line or all take one tag), the wrong patch
# rule (the first face's tag), untagged faces kept as tag -1
def test_tag_boundary_across_a_flat_face_is_kept_exactly():
    s = _box_surface()
    m = tetrahedralize(s, size=0.08)
    fg, tags = _boundary_tags(m)
    assert (tags != -99).all()
    x = m.points[fg]
    top = np.isclose(x[:, :, 2], 0.2).all(axis=1)
    lo, hi = x[:, :, 0].min(axis=1), x[:, :, 0].max(axis=1)
    assert not (top & (lo < 0.5 - 1e-9) & (hi > 0.5 + 1e-9)).any()  # no triangle straddles x = 0.5
    assert (tags[top & (lo >= 0.5 - 1e-12)] == 2).all() and (tags[top & (hi <= 0.5 + 1e-12)] == 1).all()
    assert (tags[~top] == 1).all()
    assert _areas(m.points, fg[tags == 2]).sum() == pytest.approx(0.5, rel=1e-12)  # the pad: 0.5 x 1 m
    # untagged input faces (negative) stay untagged; the others keep their tags
    part = TriMesh(s.points, s.faces, face_tags=np.where(s.face_tags == 2, 2, -1), tag_names={"pad": (2, 2)})
    mp = tetrahedralize(part, size=0.08)
    assert set(np.unique(mp.tags.face_tags).tolist()) == {2}
    assert _areas(mp.points, mp.tags.face_nodes).sum() == pytest.approx(0.5, rel=1e-12)


# mutants caught: tags attached to an untagged surface's mesh, or the tagged path changing the mesh where the tag
# boundaries are sharp edges anyway (the beam's ends: the same patches, so the same tetrahedra)
@gmsh_needed
def test_untagged_surface_meshes_as_before(tmp_path):
    f = tmp_path / "beam.msh"
    gmsh_beam_surface(f)
    s, _ = _read_quiet(f)
    plain = tetrahedralize(TriMesh(s.points, s.faces, name="beam"), size=0.01)
    tagged = tetrahedralize(s, size=0.01)
    assert plain.tags is None
    assert plain.n_cells == tagged.n_cells and np.array_equal(plain.points, tagged.points)


# mutants caught: a tagged region on a curved surface (the cap z > 0.25 of a sphere, a smooth patch boundary)
# left without tags or straddled: every remeshed triangle of the cap lies within one mesh size of the input cap
# and the cap's area is the input's within the chordal error
def test_cap_of_a_sphere():
    trimesh = pytest.importorskip("trimesh")
    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    c = ico.triangles_center
    tags = np.where(c[:, 2] > 0.25, 7, 3)
    s = TriMesh(np.asarray(ico.vertices), np.asarray(ico.faces), face_tags=tags, tag_names={"cap": (7, 2)})
    m = tetrahedralize(s, size=0.1)
    fg, got = _boundary_tags(m)
    assert (got != -99).all() and set(np.unique(got).tolist()) == {3, 7}
    assert m.tags.names == {"cap": (7, 2)}
    cap_in = _areas(ico.vertices, ico.faces[tags == 7]).sum()
    assert _areas(m.points, fg[got == 7]).sum() == pytest.approx(cap_in, rel=0.03)
    z = m.points[fg][:, :, 2]
    z_seam = np.asarray(ico.vertices)[np.asarray(ico.faces)[tags == 7]][:, :, 2].min()
    assert (z[got == 7].min(axis=1) >= z_seam - 1e-9).all()  # no cap triangle reaches below the input cap
