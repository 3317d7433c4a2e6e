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

__all__ = [
    "TET_FACES",
    "BoundarySurface",
    "TetMesh",
    "TriMesh",
    "boundary_surface",
    "box_mesh",
    "in_box",
    "read_mesh",
    "select_boundary_faces",
    "select_nodes",
    "tet_signed_volumes",
    "write_mesh",
]
