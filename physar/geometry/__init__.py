"""Geometry layer: meshes, generation, I/O (meshio), boundary extraction, selection."""

from physar.geometry.io import read_mesh, write_mesh
from physar.geometry.mesh import (
    TET_FACES,
    BoundarySurface,
    TetMesh,
    TriMesh,
    boundary_surface,
    box_mesh,
    in_box,
    select_boundary_faces,
    select_nodes,
    tet_signed_volumes,
)
from physar.geometry.path import path_length, path_point
from physar.geometry.regions import MeshTags
from physar.geometry.tetra import l_bracket_surface, plate_with_hole_surface, tet_quality, tetrahedralize

__all__ = [
    "TET_FACES",
    "BoundarySurface",
    "MeshTags",
    "TetMesh",
    "TriMesh",
    "boundary_surface",
    "box_mesh",
    "in_box",
    "l_bracket_surface",
    "path_length",
    "path_point",
    "plate_with_hole_surface",
    "read_mesh",
    "select_boundary_faces",
    "select_nodes",
    "tet_quality",
    "tet_signed_volumes",
    "tetrahedralize",
    "write_mesh",
]
