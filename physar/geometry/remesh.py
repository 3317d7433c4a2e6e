r"""A coarser, even triangulation of a surface (gmsh), for drawing: the overlay of a fine model.

:func:`remesh_surface` splits the surface into smooth patches at edges sharper than ``angle`` degrees
(gmsh's ``classifySurfaces``; sharp edges and corners are kept), re-parametrises each patch and meshes it
again with triangles of edge length about ``size`` (Frontal-Delaunay). Unlike a decimation (quadric edge
collapse), which leaves long slivers across flat faces, the new triangles are of even size everywhere, so a
field sampled at their vertices keeps its resolution over flat parts too.

:func:`size_for_faces` gives the edge length :math:`h` that yields about ``faces`` triangles on a surface of
area :math:`A`: an equilateral triangle of side :math:`h` has area :math:`\tfrac{\sqrt3}{4} h^2`, so
:math:`h = \sqrt{4 A / (\sqrt3\, n)}`.
"""
from __future__ import annotations

import numpy as np

from physar.errors import MeshError
from physar.geometry.mesh import TriMesh
from physar.geometry.tetra import _add_discrete_surface, _Gmsh


def size_for_faces(surface: TriMesh, faces: int) -> float:
    r"""Edge length [m] giving about ``faces`` even triangles on ``surface``: :math:`\sqrt{4A/(\sqrt3\,n)}`."""
    area = 0.5 * float(np.linalg.norm(surface.face_normals(normalize=False), axis=1).sum())
    if not (area > 0 and faces > 0):
        raise MeshError(f"{surface.name}: cannot size {faces} triangles on a surface of area {area:g} m^2")
    return float(np.sqrt(4.0 * area / (np.sqrt(3.0) * faces)))


def remesh_surface(surface: TriMesh, size: float, angle: float = 40.0) -> TriMesh:
    """``surface`` meshed again with triangles of edge length about ``size`` [m] (gmsh), sharp edges
    (dihedral angle above ``angle`` degrees) kept. The result's vertices lie on the input surface; the
    winding of its triangles is gmsh's (per patch), not necessarily the input's: orient it against the
    input where it matters. Raises MeshError when gmsh cannot re-parametrise a patch."""
    if not (np.isfinite(size) and size > 0):
        raise MeshError(f"{surface.name}: remesh size must be a positive length in m, got {size}")
    with _Gmsh() as gmsh:
        gmsh.model.add("physar_remesh")
        _add_discrete_surface(gmsh, surface)
        try:
            gmsh.model.mesh.classifySurfaces(np.radians(angle), True, True, np.pi)
            gmsh.model.mesh.createGeometry()
            gmsh.option.setNumber("Mesh.MeshSizeMax", float(size))
            gmsh.option.setNumber("Mesh.MeshSizeMin", float(size) / 4)
            gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
            gmsh.option.setNumber("Mesh.Algorithm", 6)          # Frontal-Delaunay: even triangles
            gmsh.model.mesh.generate(2)
        except Exception as exc:  # noqa: BLE001 - gmsh raises a bare Exception with its last error message
            raise MeshError(f"{surface.name}: gmsh could not remesh the surface: {' '.join(str(exc).split())}"[:300]) \
                from None
        tags, xyz, _ = gmsh.model.mesh.getNodes()
        _, tri = gmsh.model.mesh.getElementsByType(2)
    if len(tri) == 0:
        raise MeshError(f"{surface.name}: gmsh produced no triangles when remeshing the surface")
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    tags = np.asarray(tags, np.int64)
    lookup = np.full(int(tags.max()) + 1, -1, np.int64)
    lookup[tags] = np.arange(len(tags))
    faces = lookup[np.asarray(tri, np.int64).reshape(-1, 3)]
    keep, faces = np.unique(faces, return_inverse=True)
    return TriMesh(xyz[keep], faces.reshape(-1, 3), name=surface.name)


__all__ = ["remesh_surface", "size_for_faces"]
