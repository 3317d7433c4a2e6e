"""Mesh I/O through meshio (VTU, XDMF, Gmsh .msh, Medit .mesh, PLY, OBJ, STL, OFF).

Writes go through :func:`physar.output.atomic_path` (an XDMF file with its ``.h5`` companion), so a failed or
interrupted write never leaves a half-written output; :func:`check_mesh_destination` checks an output path
before any work.
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from physar.errors import MeshError, PhysarError
from physar.geometry.mesh import TetMesh, TriMesh
from physar.geometry.regions import MeshTags
from physar.output import atomic_path, check_destination

TAG_KEYS = ("gmsh:physical", "medit:ref", "cell_tags")  # meshio cell_data names of region tags, by priority


def _block_tags(m, i: int) -> np.ndarray | None:
    """Integer tags of cell block i from the first of TAG_KEYS present, or None."""
    for key in TAG_KEYS:
        data = m.cell_data.get(key)
        if data is not None and i < len(data) and data[i] is not None and len(data[i]) == len(m.cells[i].data):
            return np.asarray(data[i]).astype(np.int64).ravel()
    return None


def _mesh_tags(m, remap: np.ndarray | None) -> MeshTags | None:
    """MeshTags of the tetra and triangle blocks of a meshio mesh (None when it carries no tags)."""
    cell_tags, faces, face_tags, any_tag, n_tets = [], [], [], False, 0
    for i, c in enumerate(m.cells):
        t = _block_tags(m, i)
        if c.type in ("tetra", "tetra10"):
            n_tets += len(c.data)
            cell_tags.append(t if t is not None else np.zeros(len(c.data), np.int64))
            any_tag |= t is not None
        elif c.type in ("triangle", "triangle6") and t is not None:
            f = np.asarray(c.data[:, :3], np.int64)
            if remap is not None:
                f = remap[f]
                keep = (f >= 0).all(axis=1)
                f, t = f[keep], t[keep]
            faces.append(f)
            face_tags.append(t)
            any_tag = True
    names = {}
    for name, v in (getattr(m, "field_data", None) or {}).items():
        v = np.asarray(v).ravel()
        if v.size >= 1:
            names[str(name)] = (int(v[0]), int(v[1]) if v.size > 1 else 3)
    if not any_tag and not names:
        return None
    return MeshTags(
        cell_tags=np.concatenate(cell_tags) if cell_tags and any(len(t) for t in cell_tags) else None,
        face_nodes=np.concatenate(faces) if faces else np.zeros((0, 3), np.int64),
        face_tags=np.concatenate(face_tags) if face_tags else np.zeros(0, np.int64),
        names=names,
    )

VOLUME_FORMATS = {".vtu", ".xdmf", ".xmf", ".msh", ".mesh", ".vtk"}
SURFACE_FORMATS = {".ply", ".obj", ".stl", ".off", ".vtu", ".vtk", ".msh", ".mesh", ".xdmf"}


def _meshio():
    import meshio

    return meshio


def read_mesh(path: str | os.PathLike, kind: str = "auto") -> TetMesh | TriMesh:
    """Read a tetrahedral (`kind="tet"`) or triangle (`kind="tri"`) mesh; `auto` prefers tetrahedra.

    Second-order tetrahedra (tetra10) are read as their four corner nodes (physar builds P2 nodes itself).
    A tet mesh keeps the region tags of its tetrahedra and triangles (meshio cell_data "gmsh:physical",
    "medit:ref" or "cell_tags") and the group names (field_data) as ``mesh.tags`` (:class:`MeshTags`).
    """
    path = Path(path)
    if not path.exists():
        raise PhysarError(f"mesh file not found: {path}")
    meshio = _meshio()
    sink = io.StringIO()
    try:  # meshio raises many types for corrupt files, and calls sys.exit for unreadable ones
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            m = meshio.read(path)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - meshio raises arbitrary types
        detail = str(exc) if not isinstance(exc, SystemExit) else sink.getvalue().strip()
        detail = " ".join(detail.split()) or type(exc).__name__
        raise MeshError(f"cannot read mesh {path}: {detail}"[:300]) from None
    tets = [c.data[:, :4] for c in m.cells if c.type in ("tetra", "tetra10")]
    tris = [c.data[:, :3] for c in m.cells if c.type in ("triangle", "triangle6")]
    points = np.asarray(m.points, dtype=float)
    if points.ndim == 2 and points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    if kind in ("auto", "tet") and tets:
        cells = np.concatenate(tets)
        used = np.unique(cells)
        remap = None
        if len(used) < len(points):  # drop points not used by tets (e.g. gmsh geometry points)
            remap = -np.ones(len(points), dtype=np.int64)
            remap[used] = np.arange(len(used))
            points, cells = points[used], remap[cells]
        return TetMesh(points, cells, name=path.name, tags=_mesh_tags(m, remap))
    if kind in ("auto", "tri") and tris:
        return TriMesh(points, np.concatenate(tris), name=path.name)
    want = {"auto": "tetrahedra or triangles", "tet": "tetrahedra", "tri": "triangles"}.get(kind, kind)
    found = sorted({c.type for c in m.cells}) or ["no cells"]
    raise MeshError(f"{path}: expected {want}, found {', '.join(found)}")


_SURFACE_ONLY = {".stl", ".ply", ".obj", ".off"}


def check_mesh_destination(path: str | os.PathLike, *, volume: bool = True, inputs: Iterable = (),
                           kind: str = "mesh") -> Path:
    """Check ``path`` as the destination of a tetrahedral (``volume``) or surface mesh before any work:
    a suffix :func:`write_mesh` writes for that kind, and :func:`physar.output.check_destination`'s checks
    (existing folder, unwritable or file parent, same file as one of ``inputs``). One ConfigError line."""
    return check_destination(path, inputs=inputs, kind=kind,
                             suffixes=sorted(VOLUME_FORMATS if volume else SURFACE_FORMATS))


def write_mesh(
    path: str | os.PathLike,
    mesh: TetMesh | TriMesh,
    point_data: Mapping[str, np.ndarray] | None = None,
    cell_data: Mapping[str, np.ndarray] | None = None,
) -> Path:
    """Write `mesh` with optional nodal and per-element fields; the format follows the file suffix.  STL is
    written binary, whose coordinates are float32 (use PLY, OBJ, OFF or VTU for exact float64 round trips);
    a TetMesh needs a volume format (VTU, XDMF, Gmsh .msh, Medit .mesh)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if isinstance(mesh, TetMesh) and suffix in _SURFACE_ONLY:
        raise PhysarError(f"{path}: {path.suffix} stores surfaces only, not a tetrahedral mesh; use .vtu, .xdmf, "
                          ".msh or .mesh (or write its boundary surface)")
    check_mesh_destination(path, volume=isinstance(mesh, TetMesh))
    meshio = _meshio()
    conn = mesh.cells if isinstance(mesh, TetMesh) else mesh.faces
    if suffix == ".ply" and mesh.n_points < 2 ** 31:
        conn = np.asarray(conn, dtype=np.int32)  # PLY has no 64-bit integers (meshio would warn and cast)
    cells = [("tetra" if isinstance(mesh, TetMesh) else "triangle", conn)]
    cd = {k: [np.asarray(v)] for k, v in (cell_data or {}).items()}
    pd = {k: np.asarray(v) for k, v in (point_data or {}).items()}
    for k, v in pd.items():
        if len(v) != mesh.n_points:
            raise PhysarError(f"point field {k!r} has {len(v)} rows, the mesh has {mesh.n_points} points")
    m = meshio.Mesh(mesh.points, cells, point_data=pd, cell_data=cd)
    with atomic_path(path, companions=suffix in (".xdmf", ".xmf")) as tmp:
        m.write(tmp, **({"binary": True} if suffix == ".stl" else {}))  # binary STL: compact, standard
    return path
