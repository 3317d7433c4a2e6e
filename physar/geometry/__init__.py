"""Geometry layer: meshes, generation, I/O (meshio), boundary extraction, selection, surface denoising."""

from physar.geometry.denoise import anisotropic_laplacian, msal, taubin_smooth, two_stage_denoise
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
from physar.geometry.quality import add_noise, mean_edge_length, vertex_normals
from physar.geometry.regions import MeshTags
from physar.geometry.tetra import l_bracket_surface, plate_with_hole_surface, tet_quality, tetrahedralize

__all__ = [
    "TET_FACES",
    "BoundarySurface",
    "MeshTags",
    "TetMesh",
    "TriMesh",
    "add_noise",
    "anisotropic_laplacian",
    "boundary_surface",
    "box_mesh",
    "in_box",
    "l_bracket_surface",
    "mean_edge_length",
    "msal",
    "path_length",
    "path_point",
    "plate_with_hole_surface",
    "read_mesh",
    "select_boundary_faces",
    "select_nodes",
    "taubin_smooth",
    "tet_quality",
    "tet_signed_volumes",
    "tetrahedralize",
    "two_stage_denoise",
    "vertex_normals",
    "write_mesh",
]
