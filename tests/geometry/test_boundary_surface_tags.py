"""`boundary_surface` of a tagged TetMesh carries the surface region tags onto its TriMesh (one per face, in the
surface's own face order) and the names of the surface groups on it.

References independent of physar: the box's geometry (a boundary triangle's group follows from where its
centroid lies: x = 0 'clamp', x = L 'load', else 'rest'), gmsh as the mesher and writer of a volume .msh with an
interior tagged surface, meshio as the reader of the written boundary, and a hand-built two-tetrahedron mesh.
The comment of each test names the mutants it catches.
"""

from __future__ import annotations

import importlib.util

import meshio
import numpy as np
import pytest
from _gmsh_beam import NAMES, H, L, W, gmsh_beam_surface  # tests/_gmsh_beam.py

from physar.geometry.io import read_mesh, write_mesh
from physar.geometry.mesh import TetMesh, boundary_surface
from physar.geometry.regions import MeshTags
from physar.geometry.tetra import tetrahedralize

gmsh_needed = pytest.mark.skipif(importlib.util.find_spec("gmsh") is None, reason="needs the gmsh package")


def _tag_by_position(points, faces) -> np.ndarray:
    """The group of each beam boundary triangle from its centroid: 1 at x = 0, 2 at x = L, 3 elsewhere."""
    x = np.asarray(points)[np.asarray(faces)].mean(axis=1)[:, 0]
    return np.where(np.isclose(x, 0, atol=1e-12), 1, np.where(np.isclose(x, L, atol=1e-12), 2, 3))


# mutants caught: tags not carried (face_tags None), names not carried, tags in another order than the faces
# (sorted by vertex key, or in the order of mesh.tags), the wrong tag given to unmatched faces
@gmsh_needed
def test_boundary_of_tetrahedralized_beam_keeps_groups(tmp_path):
    gmsh_beam_surface(tmp_path / "beam.msh")
    m = tetrahedralize(read_mesh(tmp_path / "beam.msh"), size=0.01)
    s = boundary_surface(m).mesh
    want = _tag_by_position(s.points, s.faces)
    assert (want == 1).any() and (want == 2).any()
    assert s.face_tags is not None and s.face_tags.tolist() == want.tolist()
    assert s.tag_names == NAMES
    # the written boundary, read by meshio, keeps them (region tags per triangle and the names)
    out = meshio.read(write_mesh(tmp_path / "boundary.vtu", s))
    (tri,) = [c.data for c in out.cells if c.type == "triangle"]
    assert np.concatenate(out.cell_data["cell_tags"]).tolist() == _tag_by_position(out.points, tri).tolist()
    assert {k: np.asarray(v).ravel()[:2].tolist() for k, v in out.field_data.items()} == \
        {k: list(v) for k, v in NAMES.items()}


def _gmsh_two_part_beam(path):
    """The beam [0, L] x [0, W] x [0, H] as two volumes joined at x = L/2 (OpenCASCADE fragment), meshed in 3D and
    written by gmsh (Gmsh 2.2): surface groups 'clamp' (x = 0, 1), 'load' (x = L, 2), 'rest' (sides, 3) and the
    interior face 'interface' (x = L/2, 4); volume group 'body' (tag 1, dim 3: the same number as 'clamp')."""
    from physar.geometry.tetra import _Gmsh

    with _Gmsh() as g:
        g.model.add("beam2")
        a = g.model.occ.addBox(0, 0, 0, L / 2, W, H)
        b = g.model.occ.addBox(L / 2, 0, 0, L / 2, W, H)
        g.model.occ.fragment([(3, a)], [(3, b)])
        g.model.occ.synchronize()
        x = {t: g.model.occ.getCenterOfMass(2, t)[0] for _, t in g.model.getEntities(2)}
        groups = {n: [t for t, c in x.items() if np.isclose(c, v)] for n, v in
                  (("clamp", 0), ("load", L), ("interface", L / 2))}
        sides = [t for t in x if not any(t in ts for ts in groups.values())]
        for name, ts, tag in (("clamp", groups["clamp"], 1), ("load", groups["load"], 2), ("rest", sides, 3),
                              ("interface", groups["interface"], 4)):
            g.model.addPhysicalGroup(2, ts, tag, name=name)
        g.model.addPhysicalGroup(3, [t for _, t in g.model.getEntities(3)], 1, name="body")
        g.option.setNumber("Mesh.MeshSizeMax", 0.01)
        g.option.setNumber("Mesh.MshFileVersion", 2.2)
        g.model.mesh.generate(3)
        g.write(str(path))
    return path


# mutants caught: the tags of interior faces carried (the 'interface' triangles at x = L/2 are no boundary face:
# a mutant taking the tagged triangles instead of the boundary ones, or tagging by position in mesh.tags), names of
# volume groups or of groups absent from the boundary kept ('body', 'interface'); the tag numbers of dim 3
@gmsh_needed
def test_gmsh_volume_file_interior_group_not_on_boundary(tmp_path):
    m = read_mesh(_gmsh_two_part_beam(tmp_path / "beam2.msh"))
    assert isinstance(m, TetMesh) and 4 in m.tags.face_tags.tolist()  # the interface is tagged in the file
    bs = boundary_surface(m)
    s = bs.mesh
    assert s.face_tags.tolist() == _tag_by_position(s.points, s.faces).tolist()
    assert s.tag_names == NAMES
    assert not np.isclose(s.points[s.faces].mean(axis=1)[:, 0], L / 2).any()


# mutants caught: a face matched only with its vertices in the same order (the rotated and the reversed triangle
# missed), the last of a twice-tagged triangle's tags taken (the docstring says the first), an interior tagged face
# carried, an untagged face not -1, a mesh without tags given tags
def test_hand_built_two_tetrahedra():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    cells = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])  # share the face (1, 2, 3)
    plain = TetMesh.reoriented(pts, cells, name="two")
    s0 = boundary_surface(plain).mesh
    assert s0.face_tags is None and s0.tag_names == {}
    tags = MeshTags(face_nodes=np.array([[3, 2, 1], [2, 0, 1], [1, 3, 0], [4, 3, 1], [4, 3, 1], [3, 2, 4]]),
                    face_tags=np.array([9, 5, 6, 7, 8, 0]),
                    names={"inner": (9, 2), "base": (5, 2), "front": (6, 2), "b": (7, 2), "c": (8, 2),
                           "solid": (5, 3), "zero": (0, 2)})
    m = TetMesh.reoriented(pts, cells, name="two", tags=tags)
    bs = boundary_surface(m)
    s = bs.mesh
    by_vertices = {frozenset([0, 1, 2]): 5, frozenset([0, 1, 3]): 6, frozenset([1, 3, 4]): 7,
                   frozenset([2, 3, 4]): 0}
    want = [by_vertices.get(frozenset(f), -1) for f in bs.faces_global.tolist()]
    assert len(want) == 6 and want.count(-1) == 2  # faces (0, 2, 3) and (1, 2, 4) untagged
    assert s.face_tags.tolist() == want
    assert s.tag_names == {"base": (5, 2), "front": (6, 2), "b": (7, 2), "zero": (0, 2)}
