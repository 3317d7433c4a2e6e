"""Region names through mesh files, and .msh files without tetrahedra because gmsh saved only surface groups.

References are gmsh's own model (the triangles gmsh meshed on a named face, read through the gmsh API, not
through physar) and hand-written Gmsh 2.2 text. The comment of each test names the mutant of
physar/geometry/io.py it catches."""

from __future__ import annotations

import importlib.util
import warnings

import meshio
import numpy as np
import pytest

from physar.errors import MeshError, PhysarWarning
from physar.geometry.io import read_mesh, write_mesh
from physar.geometry.mesh import TetMesh, TriMesh

gmsh_needed = pytest.mark.skipif(importlib.util.find_spec("gmsh") is None, reason="needs the gmsh package")


def _coord_set(points, faces) -> set:
    """The triangles as a set of frozensets of rounded vertex coordinates (independent of node numbering)."""
    x = np.round(np.asarray(points)[np.asarray(faces)], 9)
    return {frozenset(map(tuple, t.tolist())) for t in x}


def _gmsh_box(path, *, volume_group=True, version=2.2, save_all=False, size=0.4):
    """A unit box meshed by gmsh with the face x = 0 in physical group 'clamp' (dim 2, tag 1), the face x = 1
    in 'load' (dim 2, tag 2) and, if `volume_group`, the solid in 'body' (dim 3, tag 3). Returns gmsh's own
    triangles of each face as coordinate sets and its tetrahedron count."""
    from physar.geometry.tetra import _Gmsh

    with _Gmsh() as g:
        g.model.add("box")
        g.model.occ.addBox(0, 0, 0, 1, 1, 1)
        g.model.occ.synchronize()
        faces = {}
        for _, t in g.model.getEntities(2):
            cx = g.model.occ.getCenterOfMass(2, t)[0]
            if np.isclose(cx, 0):
                faces["clamp"] = t
            elif np.isclose(cx, 1):
                faces["load"] = t
        g.model.addPhysicalGroup(2, [faces["clamp"]], 1, name="clamp")
        g.model.addPhysicalGroup(2, [faces["load"]], 2, name="load")
        if volume_group:
            g.model.addPhysicalGroup(3, [1], 3, name="body")
        g.option.setNumber("Mesh.MeshSizeMax", size)
        g.option.setNumber("Mesh.MshFileVersion", version)
        g.option.setNumber("Mesh.SaveAll", int(save_all))
        g.model.mesh.generate(3)
        tags, coords, _ = g.model.mesh.getNodes()
        xyz = dict(zip(tags.tolist(), np.asarray(coords).reshape(-1, 3).tolist(), strict=True))
        ref = {}
        for name, t in faces.items():
            _, node_tags = g.model.mesh.getElementsByType(2, t)
            ref[name] = {frozenset(tuple(np.round(xyz[n], 9)) for n in tri)
                         for tri in np.asarray(node_tags).reshape(-1, 3).tolist()}
        n_tets = len(g.model.mesh.getElementsByType(4)[0])
        g.write(str(path))
    return ref, n_tets


def _read_quiet(path, **kw):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m = read_mesh(path, **kw)
    return m, [str(w.message) for w in rec if issubclass(w.category, PhysarWarning)]


# mutants caught: VTU FieldData not added (_vtu_add_names skipped), XDMF Information not added
# (_xdmf_add_names skipped), [tag, dim] written as [dim, tag]; the 'clamp' faces must be gmsh's own triangles
@gmsh_needed
@pytest.mark.parametrize("suffix", [".vtu", ".xdmf", ".msh"])
def test_names_round_trip_msh_to_vtu_xdmf(tmp_path, suffix):
    ref, n_tets = _gmsh_box(tmp_path / "box.msh")
    m, _ = _read_quiet(tmp_path / "box.msh")
    assert isinstance(m, TetMesh) and m.n_cells == n_tets
    out = tmp_path / f"out{suffix}"
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        write_mesh(out, m)
    assert not [w for w in rec if issubclass(w.category, PhysarWarning)]  # names kept: nothing to warn about
    back, _ = _read_quiet(out)
    assert back.tags.names == {"clamp": (1, 2), "load": (2, 2), "body": (3, 3)}
    for name in ("clamp", "load"):
        faces, cells = back.tags.resolve(name)
        assert not cells.any()
        assert _coord_set(back.points, faces) == ref[name]
    faces, cells = back.tags.resolve("body")
    assert len(faces) == 0 and cells.all() and cells.sum() == n_tets
    # meshio (a peer reader) sees the same names as gmsh's $PhysicalNames convention {name: [tag, dim]}
    fd = meshio.read(out).field_data
    assert {k: np.asarray(v).ravel().tolist() for k, v in fd.items()} == \
        {"clamp": [1, 2], "load": [2, 2], "body": [3, 3]}


# mutant caught: no warning for a format that keeps numbers only (names lost silently), or one per region
@gmsh_needed
@pytest.mark.parametrize("suffix", [".mesh", ".vtk"])
def test_numbers_only_formats_warn_once(tmp_path, suffix):
    ref, _ = _gmsh_box(tmp_path / "box.msh")
    m, _ = _read_quiet(tmp_path / "box.msh")
    out = tmp_path / f"out{suffix}"
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        write_mesh(out, m)
    msgs = [str(w.message) for w in rec if issubclass(w.category, PhysarWarning)]
    assert len(msgs) == 1, msgs
    assert msgs[0].startswith(f"{out}: ") and "'clamp' = 1" in msgs[0] and "'load' = 2" in msgs[0] \
        and "'body' = 3" in msgs[0], msgs[0]
    back, _ = _read_quiet(out)
    faces, _ = back.tags.resolve(1)  # the number still selects gmsh's triangles
    assert _coord_set(back.points, faces) == ref["clamp"]
    with pytest.raises(MeshError, match="'clamp' not in mesh"):
        back.tags.resolve("clamp")


# mutant caught: every field_data entry taken as a region name (ParaView's float TimeValue becomes region 0)
def test_float_field_data_is_not_a_region(tmp_path):
    f = tmp_path / "t.vtu"  # as ParaView saves it: dataset FieldData with a TimeValue next to our [tag, dim]
    f.write_text("""<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">
<UnstructuredGrid>
<FieldData>
<DataArray type="Float64" Name="TimeValue" NumberOfTuples="1" format="ascii">0.25</DataArray>
<DataArray type="Int64" Name="part" NumberOfTuples="2" format="ascii">4 3</DataArray>
</FieldData>
<Piece NumberOfPoints="4" NumberOfCells="1">
<Points><DataArray type="Float64" NumberOfComponents="3" format="ascii">0 0 0 1 0 0 0 1 0 0 0 1</DataArray></Points>
<Cells>
<DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3</DataArray>
<DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>
<DataArray type="UInt8" Name="types" format="ascii">10</DataArray>
</Cells>
<CellData><DataArray type="Int64" Name="cell_tags" format="ascii">4</DataArray></CellData>
</Piece>
</UnstructuredGrid>
</VTKFile>
""")
    assert set(meshio.read(f).field_data) == {"TimeValue", "part"}  # meshio reads both
    m, _ = _read_quiet(f)
    assert m.tags.names == {"part": (4, 3)}


SURF_MSG = ("{f}: no tetrahedra: gmsh saved only the elements of physical groups (surface groups 'clamp', 'load'; "
            "no volume group); add a volume physical group or set Mesh.SaveAll=1")


# mutant caught: the check removed (kind="tet": "expected tetrahedra, found triangle"; kind="auto": a TriMesh of
# the two tagged faces, later "surface is not closed"), or only one of the msh versions handled
@gmsh_needed
@pytest.mark.parametrize("version", [2.2, 4.1])
def test_surface_groups_only_msh_says_why(tmp_path, version):
    f = tmp_path / f"surf{version}.msh"
    ref, n_tets = _gmsh_box(f, volume_group=False, version=version)
    assert n_tets > 0  # gmsh meshed the volume; it just did not save it
    raw = meshio.read(f)
    assert [c.type for c in raw.cells if c.type.startswith("tetra")] == []
    for kind in ("tet", "auto"):
        with pytest.raises(MeshError) as e:
            read_mesh(f, kind=kind)
        assert str(e.value) == SURF_MSG.format(f=f)
    m, _ = _read_quiet(f, kind="tri")  # the triangles are still readable as a surface when asked for
    assert isinstance(m, TriMesh) and _coord_set(m.points, m.faces) == ref["clamp"] | ref["load"]


# mutant caught: the "every saved element in a group" condition dropped (a SaveAll=1 surface model, whose
# lines and points outside groups are saved with tag 0, refused although gmsh dropped nothing)
@gmsh_needed
def test_saveall_surface_model_is_read_as_surface(tmp_path):
    from physar.geometry.tetra import _Gmsh

    f = tmp_path / "sphere.msh"
    with _Gmsh() as g:
        g.model.add("s")
        g.model.occ.addSphere(0, 0, 0, 1)
        g.model.occ.synchronize()
        g.model.addPhysicalGroup(2, [t for _, t in g.model.getEntities(2)], 1, name="skin")
        g.option.setNumber("Mesh.MeshSizeMax", 0.5)
        g.option.setNumber("Mesh.MshFileVersion", 2.2)
        g.option.setNumber("Mesh.SaveAll", 1)
        g.model.mesh.generate(2)
        n_tri = len(g.model.mesh.getElementsByType(2)[0])
        g.write(str(f))
    m, _ = _read_quiet(f, kind="auto")
    assert isinstance(m, TriMesh) and m.n_faces == n_tri


def _msh22(path, nodes, tris, names=()):
    """A hand-written ASCII Gmsh 2.2 file: triangles in physical surface group 1 (elementary entity 1)."""
    lines = ["$MeshFormat", "2.2 0 8", "$EndMeshFormat"]
    if names:
        lines += ["$PhysicalNames", str(len(names))] + [f'2 {i} "{n}"' for i, n in names] + ["$EndPhysicalNames"]
    lines += ["$Nodes", str(len(nodes))] + [f"{i + 1} {x} {y} {z}" for i, (x, y, z) in enumerate(nodes)]
    lines += ["$EndNodes", "$Elements", str(len(tris))]
    lines += [f"{k + 1} 2 2 1 1 {a + 1} {b + 1} {c + 1}" for k, (a, b, c) in enumerate(tris)]
    lines += ["$EndElements"]
    path.write_text("\n".join(lines) + "\n")
    return path


ROOF = [(0, 0, 0), (1, 0, 0), (1, 1, 0.5), (0, 1, 0.5), (0.5, 2, 0)]  # three triangles, not in one plane
TET_SURFACE = ([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)], [(0, 2, 1), (0, 1, 3), (1, 2, 3), (0, 3, 2)])


# mutants caught: "auto" refusing any file with only surface groups (the closed, unnamed surface below is a
# complete surface model), or "auto" ignoring an open non-flat patch (part of a solid's boundary)
def test_hand_written_msh22_auto_evidence(tmp_path):
    roof = _msh22(tmp_path / "roof.msh", ROOF, [(0, 1, 2), (0, 2, 3), (3, 2, 4)])
    with pytest.raises(MeshError) as e:
        read_mesh(roof, kind="auto")
    assert str(e.value) == (f"{roof}: no tetrahedra: gmsh saved only the elements of physical groups (surface "
                            "group 1; no volume group); add a volume physical group or set Mesh.SaveAll=1")

    closed = _msh22(tmp_path / "closed.msh", *TET_SURFACE)  # closed, no names, gmsh 2.2: a surface model
    m, _ = _read_quiet(closed, kind="auto")
    assert isinstance(m, TriMesh) and m.n_faces == 4
    with pytest.raises(MeshError, match=r"closed.msh: no tetrahedra: .*\(surface group 1; no volume group\)"):
        read_mesh(closed, kind="tet")  # asked for tetrahedra: say why there are none

    named = _msh22(tmp_path / "named.msh", *TET_SURFACE, names=[(1, "skin")])
    # a closed surface with a named group is a whole surface model (a CAD export with named faces): read as a
    # tagged surface, its group kept for tetrahedralize; tetrahedra asked for are still refused
    m, _ = _read_quiet(named, kind="auto")
    assert isinstance(m, TriMesh) and m.tag_names == {"skin": (1, 2)} and m.face_tags.tolist() == [1, 1, 1, 1]
    with pytest.raises(MeshError, match=r"named.msh: no tetrahedra"):
        read_mesh(named, kind="tet")

    flat = _msh22(tmp_path / "flat.msh", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2), (0, 2, 3)])
    m, _ = _read_quiet(flat, kind="auto")  # a 2-D model: read as the surface it is
    assert isinstance(m, TriMesh) and m.n_faces == 2


# mutant caught: the Gmsh 4 $Entities volume count not read (ASCII or binary): a closed, unnamed surface group
# covering a solid's whole boundary has no other evidence of the lost volume; the same file in Gmsh 2.2 has
# none at all and is read as the closed surface it holds
@gmsh_needed
@pytest.mark.parametrize("version,binary", [(4.1, 0), (4.1, 1), (2.2, 0)])
def test_msh4_volume_entities_are_the_evidence(tmp_path, version, binary):
    from physar.geometry.tetra import _Gmsh

    f = tmp_path / f"all{version}{binary}.msh"
    with _Gmsh() as g:
        g.model.add("b")
        g.model.occ.addBox(0, 0, 0, 1, 1, 1)
        g.model.occ.synchronize()
        g.model.addPhysicalGroup(2, [t for _, t in g.model.getEntities(2)], 1)
        g.option.setNumber("Mesh.MeshSizeMax", 0.5)
        g.option.setNumber("Mesh.MshFileVersion", version)
        g.option.setNumber("Mesh.Binary", binary)
        g.model.mesh.generate(3)
        n_tri = len(g.model.mesh.getElementsByType(2)[0])
        g.write(str(f))
    if version == 2.2:
        m, _ = _read_quiet(f, kind="auto")
        assert isinstance(m, TriMesh) and m.n_faces == n_tri
        return
    with pytest.raises(MeshError, match=r": no tetrahedra: .*\(surface group 1; no volume group\)"):
        read_mesh(f, kind="auto")
