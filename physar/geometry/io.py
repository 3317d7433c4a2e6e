"""Mesh I/O through meshio (VTU, XDMF, Gmsh .msh, Medit .mesh, PLY, OBJ, STL, OFF).

Writes go through :func:`physar.output.atomic_path` (an XDMF file with its ``.h5`` companion), so a failed or
interrupted write never leaves a half-written output; :func:`check_mesh_destination` checks an output path
before any work.
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from physar.errors import MeshError, PhysarError, PhysarWarning
from physar.geometry.mesh import TetMesh, TriMesh, tet_signed_volumes
from physar.geometry.regions import MeshTags
from physar.output import atomic_path, check_destination

TAG_KEYS = ("gmsh:physical", "medit:ref", "cell_tags")  # meshio cell_data names of region tags, by priority


def _block_tags(m, i: int) -> np.ndarray | None:
    """Integer tags of cell block i from the first of TAG_KEYS present, or None."""
    for key in TAG_KEYS:
        data = m.cell_data.get(key)
        if data is not None and i < len(data) and data[i] is not None and len(data[i]) == len(m.cells[i].data):
            t = np.asarray(data[i]).astype(np.int64).ravel()
            return None if len(t) and (t < 0).all() else t  # -1: an untagged gmsh entity (_read_gmsh_api)
    return None


VOLUME_FORMATS = {".vtu", ".xdmf", ".xmf", ".msh", ".mesh", ".vtk"}
SURFACE_FORMATS = {".ply", ".obj", ".stl", ".off", ".vtu", ".vtk", ".msh", ".mesh", ".xdmf"}

# corner nodes of each linear cell type (meshio/VTK node order: corners first, also for higher orders)
_CORNERS = {"tetra": 4, "hexahedron": 8, "wedge": 6, "pyramid": 5, "triangle": 3, "quad": 4}
_PLURAL = {"tetra": "tetrahedra", "hexahedron": "hexahedra", "wedge": "wedges (prisms)", "pyramid": "pyramids",
           "triangle": "triangles", "quad": "quadrilaterals", "polygon": "polygons"}
# faces (local corner ids) of the cells split into tetrahedra
_CELL_FACES = {
    "hexahedron": [[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]],
    "wedge": [[0, 1, 2], [3, 4, 5], [0, 1, 4, 3], [1, 2, 5, 4], [2, 0, 3, 5]],
    "pyramid": [[0, 1, 2, 3], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]],
}


def _base_type(t: str) -> str | None:
    """The linear cell type of a meshio cell type ("tetra" of "tetra10"); None for lines and vertices, and the
    type itself (unknown) for anything else."""
    if t.startswith(("line", "vertex")):
        return None
    if t.startswith("polygon"):
        return "polygon"
    for base in ("tetra", "hexahedron", "wedge", "pyramid", "triangle", "quad"):
        if t == base or (t.startswith(base) and t[len(base):].isdigit()):
            return base
    return t


def _split_polygons(conn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of convex polygons (n, k): each split along the diagonals from its smallest node index (the same
    diagonal as a neighbour cell's split of a shared quadrilateral); returns (triangles, polygon of each)."""
    conn = np.asarray(conn, np.int64)
    n, k = conn.shape
    first = np.argmin(conn, axis=1)
    rolled = np.take_along_axis(conn, (first[:, None] + np.arange(k)) % k, axis=1)
    tris = np.stack([np.stack([rolled[:, 0], rolled[:, j], rolled[:, j + 1]], axis=1) for j in range(1, k - 1)],
                    axis=1)  # (n, k-2, 3)
    return tris.reshape(-1, 3), np.repeat(np.arange(n), k - 2)


def _split_cells(conn: np.ndarray, cell_type: str, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedra of hexahedra, wedges or pyramids (corner nodes, VTK order), positively oriented, and the cell of
    each. A conforming split: each cell is a cone from its smallest global node over the triangles of its faces
    that do not hold that node, and every quadrilateral face is cut along the diagonal through its smallest node,
    so two cells sharing a face cut it the same way (no gaps, no overlaps)."""
    conn = np.asarray(conn, np.int64)
    apex = conn.min(axis=1)
    tets, owner = [], []
    for face in _CELL_FACES[cell_type]:
        tris, which = _split_polygons(conn[:, face])
        keep = (tris != apex[which, None]).all(axis=1)
        tets.append(np.column_stack([apex[which][keep], tris[keep]]))
        owner.append(which[keep])
    tets, owner = np.concatenate(tets), np.concatenate(owner)
    order = np.argsort(owner, kind="stable")
    tets, owner = tets[order], owner[order]
    neg = tet_signed_volumes(points, tets) < 0
    tets[neg, 2], tets[neg, 3] = tets[neg, 3].copy(), tets[neg, 2].copy()
    return tets, owner


def _blocks(m, path: Path) -> tuple[list, list, list]:
    """(volume blocks, surface blocks, warnings) of a meshio mesh: each block (connectivity, tags or None) of
    linear tetrahedra or triangles; hexahedra, wedges and pyramids are split into tetrahedra, quadrilaterals and
    polygons into triangles, higher-order cells keep their corner nodes. A cell type that cannot be split is one
    MeshError naming the file, the type and the count."""
    points = np.asarray(m.points, float)
    vol, surf, notes = [], [], []
    counts: dict = {}
    for i, c in enumerate(m.cells):
        base = _base_type(c.type)
        if base is None or len(c.data) == 0:
            continue
        if base not in _CORNERS and base != "polygon":
            raise MeshError(f"{path}: {len(c.data)} cells of type {c.type!r} cannot be read (physar reads "
                            "tetrahedra, hexahedra, wedges, pyramids, triangles, quadrilaterals and polygons)")
        tags = _block_tags(m, i)
        conn = np.asarray(c.data, np.int64)
        conn = conn[:, :_CORNERS[base]] if base in _CORNERS else conn
        key = (c.type, base)
        if base in ("tetra", "triangle"):
            (vol if base == "tetra" else surf).append((conn, tags))
            n_new = len(conn)
        elif base in _CELL_FACES:
            tets, owner = _split_cells(conn, base, points)
            vol.append((tets, None if tags is None else tags[owner]))
            n_new = len(tets)
        else:
            tris, owner = _split_polygons(conn)
            surf.append((tris, None if tags is None else tags[owner]))
            n_new = len(tris)
        old = counts.get(key, (0, 0))
        counts[key] = (old[0] + len(conn), old[1] + n_new)
    for (t, base), (n_old, n_new) in counts.items():
        is_vol = base in ("tetra", *_CELL_FACES)
        if t != base and base in _CORNERS:
            msg = (f"{path}: {n_old} second-order {t} cells read as linear {_PLURAL[base]} (corner nodes only; "
                   "physar builds its own P2 nodes)")
            notes.append((is_vol, msg))
        if base not in ("tetra", "triangle"):
            into = "tetrahedra" if base in _CELL_FACES else "triangles"
            notes.append((is_vol, f"{path}: split {n_old} {_PLURAL[base]} into {n_new} {into}"))
    return vol, surf, notes


def _names(m) -> dict:
    """Region names of a meshio mesh: its ``field_data`` entries {name: [tag, dim]} (the gmsh convention, also
    what :func:`write_mesh` stores in VTU FieldData and XDMF Information). Entries that are not one or two
    integers with a dimension 0..3 (e.g. ParaView's float ``TimeValue``) are other field data, not names."""
    names = {}
    for name, v in (getattr(m, "field_data", None) or {}).items():
        v = np.asarray(v)
        if v.dtype.kind not in "iu" or v.size not in (1, 2):
            continue
        v = v.ravel()
        dim = int(v[1]) if v.size > 1 else 3
        if 0 <= dim <= 3:
            names[str(name)] = (int(v[0]), dim)
    return names


def _msh_volume_entities(path: Path) -> int | None:
    """Number of volumes in the ``$Entities`` section of a Gmsh 4 file (the model's, whether or not their
    elements were saved); None for Gmsh 2 files (no such section) or an unreadable header."""
    try:
        with open(path, "rb") as f:
            binary, size_t = False, 8
            for _ in range(100_000):  # header sections only: $Entities comes before $Nodes
                line = f.readline()
                if not line or line.startswith((b"$Nodes", b"$Elements")):
                    return None
                if line.startswith(b"$MeshFormat"):
                    head = f.readline().split()
                    binary, size_t = head[1:2] == [b"1"], int(head[2]) if len(head) > 2 else 8
                elif line.startswith(b"$Entities"):
                    if binary:
                        raw = f.read(4 * size_t)
                        return int(np.frombuffer(raw, dtype=f"<u{size_t}")[3])
                    return int(f.readline().split()[3])
    except (OSError, ValueError, IndexError, TypeError):
        return None
    return None


_DIM_OF = {"triangle": 2, "quad": 2, "polygon": 2}
_GROUP_WORD = {2: "surface", 1: "curve", 0: "point"}


def _check_gmsh_groups(m, path: Path, surf: list, kind: str) -> None:
    """MeshError when a .msh has no volume cells because gmsh saved only the elements of physical groups and
    none of them is a volume (gmsh's default ``Mesh.SaveAll=0``: the tetrahedra are simply not written).

    Applies when every saved element carries a physical tag > 0 (with SaveAll=1 elements outside groups are
    saved with tag 0) and no group has dimension 3. For ``kind="tet"`` that is enough; for ``kind="auto"``
    the file must also show that it came from a 3-D model: a Gmsh 4 ``$Entities`` section listing volumes, or
    saved triangles that form an open surface with named surface groups ($PhysicalNames of dimension 2) or
    with nodes not in one plane (a part of a solid's boundary). A closed surface without volumes in
    ``$Entities`` (any gmsh 2 file) is a complete surface model, named groups or not, and is read as a surface
    with its tags (:func:`read_mesh`)."""
    phys = m.cell_data.get("gmsh:physical")
    if phys is None or kind not in ("tet", "auto"):
        return
    by_dim: dict = {}
    for block, t in zip(m.cells, phys, strict=False):
        t = np.asarray(t if t is not None else [0]).ravel()
        if not len(block.data):
            continue
        if len(t) != len(block.data) or not (t > 0).all():
            return  # elements outside physical groups were saved: nothing was dropped
        dim = 1 if block.type.startswith("line") else 0 if block.type.startswith("vertex") else \
            _DIM_OF.get(_base_type(block.type) or "")
        if dim is None:
            return  # a volume cell type
        by_dim.setdefault(dim, set()).update(np.unique(t).tolist())
    names = _names(m)
    if not by_dim or any(d == 3 for _, d in names.values()):
        return
    if kind == "auto":
        evidence = bool(_msh_volume_entities(path))
        if not evidence:
            from physar.geometry.tetra import boundary_edge_count, is_flat

            named = any(d == 2 for _, d in names.values())
            part = TriMesh(np.asarray(m.points, float), np.concatenate([f for f, _ in surf]), name=path.name) \
                if surf else None
            # an open surface with named groups, or one whose nodes are not in one plane: part of a solid's
            # boundary. A closed one is a whole solid's boundary, named faces or not: a surface model, which
            # tetrahedralize fills, carrying its tags to the volume mesh's boundary
            is_open = part is None or boundary_edge_count(part) > 0
            evidence = is_open and (named or (part is not None and not is_flat(part)))
        if not evidence:
            return
    groups = []
    for dim in sorted(by_dim, reverse=True):
        named = {i: n for n, (i, d) in names.items() if d == dim}
        items = [repr(named[i]) if i in named else str(i) for i in sorted(by_dim[dim])]
        groups.append(f"{_GROUP_WORD[dim]} group{'s' if len(items) > 1 else ''} {', '.join(items)}")
    raise MeshError(f"{path}: no tetrahedra: gmsh saved only the elements of physical groups ({'; '.join(groups)}"
                    "; no volume group); add a volume physical group or set Mesh.SaveAll=1")


def _mesh_tags(vol: list, surf: list, names: dict, remap: np.ndarray | None) -> MeshTags | None:
    """MeshTags of the tetrahedron and triangle blocks (None when they carry no tags and there are no names)."""
    any_tag = any(t is not None for _, t in vol)
    cell_tags = [t if t is not None else np.zeros(len(c), np.int64) for c, t in vol]
    faces, face_tags = [], []
    for f, t in surf:
        if t is None:
            continue
        if remap is not None:
            f = remap[f]
            keep = (f >= 0).all(axis=1)
            f, t = f[keep], t[keep]
        faces.append(f)
        face_tags.append(t)
        any_tag = True
    if not any_tag and not names:
        return None
    return MeshTags(
        cell_tags=np.concatenate(cell_tags) if any(t is not None for _, t in vol) else None,
        face_nodes=np.concatenate(faces) if faces else np.zeros((0, 3), np.int64),
        face_tags=np.concatenate(face_tags) if face_tags else np.zeros(0, np.int64),
        names=names,
    )


def _tri_mesh(points: np.ndarray, surf: list, names: dict, path: Path, zero_untagged: bool) -> TriMesh:
    """TriMesh of a file's triangle blocks with their region tags (``face_tags``; -1 for the faces of a block
    without tags, and for tag 0 when ``zero_untagged``: gmsh's and Medit's "no group") and the names of surface
    groups (dim 2) as ``tag_names``; no tags when no face has one."""
    faces = np.concatenate([f for f, _ in surf])
    tags = None
    if any(t is not None for _, t in surf):
        tags = np.concatenate([t if t is not None else np.full(len(f), -1, np.int64) for f, t in surf])
        tags = np.where(tags <= 0, -1, tags) if zero_untagged else tags
        tags = tags if (tags >= 0).any() else None
    names = {n: (i, d) for n, (i, d) in names.items() if d == 2} if tags is not None else {}
    return TriMesh(points, faces, name=path.name, face_tags=tags, tag_names=names)


def _meshio():
    import meshio

    return meshio


def _read_text(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as e:
        raise MeshError(f"cannot read mesh {path}: {e.strerror}") from None


def _read_obj(path: Path):
    """Positions and faces of a Wavefront OBJ (``v`` and ``f`` lines; ``f`` entries ``v``, ``v/vt``, ``v//vn`` or
    ``v/vt/vn``, negative indices counted back from the last vertex read; texture coordinates and normals are
    ignored). Polygons become one ``polygon<k>`` block per size. Bad lines are one MeshError naming the line.
    Vertices repeated at one position (per-face or seam copies of exporters) are merged into one
    (:func:`_merge_obj_vertices`).
    Groups (``g`` and ``o`` lines; ``g`` alone is the group ``default``) are region tags 1, 2, ... in the order
    of their first line, with their names (cell_data ``cell_tags``, field_data ``{name: [tag, 2]}``; faces before
    the first group get -1); a file without groups has no tags."""
    import meshio

    pts, polys, refs, groups, group = [], {}, [], {}, -1
    for no, line in enumerate(_read_text(path), 1):
        tok = line.split("#", 1)[0].split()
        if not tok:
            continue
        try:
            if tok[0] in ("g", "o"):
                group = groups.setdefault(" ".join(tok[1:]) or "default", len(groups) + 1)
            elif tok[0] == "v":
                pts.append([float(x) for x in tok[1:4]])
                if len(pts[-1]) != 3:
                    raise ValueError("a vertex needs x y z")
            elif tok[0] == "f":
                idx = []
                for t in tok[1:]:
                    j = int(t.split("/")[0])
                    if j == 0 or -j > len(pts):
                        raise ValueError(f"vertex index {j}: 0 is not an OBJ index, and a negative one counts "
                                         f"back over the {len(pts)} vertices read so far")
                    idx.append(j - 1 if j > 0 else len(pts) + j)
                if len(idx) < 3:
                    raise ValueError("a face needs at least 3 vertices")
                polys.setdefault(len(idx), []).append((idx, group))
                refs.append((max(idx), no, line.strip()[:60]))
        except ValueError as e:
            raise MeshError(f"{path}: line {no} ({line.strip()[:60]!r}): {e}") from None
    if not pts:
        raise MeshError(f"{path}: no vertices (v lines) in the OBJ file")
    # forward indices are checked against all vertices (OBJ allows faces before their vertices)
    n = len(pts)
    bad = next((r for r in refs if r[0] >= n), None)
    if bad is not None:
        raise MeshError(f"{path}: line {bad[1]} ({bad[2]!r}): a face refers to vertex {bad[0] + 1}, the file has "
                        f"{n} vertices")
    xyz, faces = _merge_obj_vertices(path, np.asarray(pts, float), [(r, g) for rows in polys.values() for r, g in rows])
    by_size: dict[int, list] = {}
    for r, g in faces:
        by_size.setdefault(len(r), []).append((r, g))
    cells, tags = [], []
    for k, rows in sorted(by_size.items()):
        cells.append(("triangle" if k == 3 else "quad" if k == 4 else "polygon",
                      np.asarray([r for r, _ in rows], np.int64)))
        tags.append(np.asarray([g for _, g in rows], np.int64))
    if not groups:
        return meshio.Mesh(xyz, cells)
    return meshio.Mesh(xyz, cells, cell_data={"cell_tags": tags},
                       field_data={name: np.array([tag, 2]) for name, tag in groups.items()})


def _merge_obj_vertices(path: Path, xyz: np.ndarray, faces: list) -> tuple[np.ndarray, list]:
    """Vertices of an OBJ at one position merged into one (exporters repeat them per face, or per texture seam:
    without it each face is its own patch, and noise tears the surface apart), numbered in the order of their
    first ``v`` line (a file without repeats keeps its numbering). A polygon that loses corners to the merge keeps
    the others (a UV sphere's pole quad becomes a triangle); one left with fewer than 3 (zero area) is dropped,
    with one PhysarWarning. The merge is not made when it would join separate parts into a non-manifold edge or
    vertex (two objects touching at a corner or along an edge: each keeps its own vertices, as in the file)."""
    _, first, inv = np.unique(xyz, axis=0, return_index=True, return_inverse=True)
    if len(first) == len(xyz):
        return xyz, faces
    order = np.argsort(first)                      # unique rows in order of first occurrence
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    remap = rank[inv.ravel()]
    merged, dropped = [], 0
    for r, g in faces:
        q = [int(remap[v]) for v in r]
        q = [v for i, v in enumerate(q) if v != q[i - 1]] if len(set(q)) > 1 else q[:1]  # cyclic repeats out
        if len(q) >= 3:
            merged.append((q, g))
        else:
            dropped += 1
    if _joins_parts(merged, len(first)) and not _joins_parts(faces, len(xyz)):
        return xyz, faces
    if dropped:
        warnings.warn(f"{path}: {dropped} faces collapsed to a line or a point once the vertices repeated at one "
                      "position were merged (zero area): dropped", PhysarWarning, stacklevel=4)
    return xyz[np.sort(first)], merged


def _joins_parts(faces: list, n: int) -> bool:
    """Whether the polygons (fan-triangulated) have a non-manifold edge or vertex."""
    from physar.geometry.mesh import TriMesh
    from physar.geometry.quality import vertex_fans

    tri = np.asarray([(r[0], r[i], r[i + 1]) for r, _ in faces for i in range(1, len(r) - 1)], np.int64)
    if not len(tri):
        return False
    e = np.sort(tri[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    if (np.unique(e[:, 0] * np.int64(n) + e[:, 1], return_counts=True)[1] > 2).any():
        return True
    return bool((vertex_fans(TriMesh(np.zeros((n, 3)), tri)) > 1).any())


def _read_ascii_stl(path: Path):
    """Positions and triangles of an ASCII STL (``vertex`` lines, three per facet; blank lines, several solids and
    any other lines are ignored); coincident vertices are merged."""
    import meshio

    verts = []
    for no, line in enumerate(_read_text(path), 1):
        tok = line.split()
        if tok and tok[0].lower() == "vertex":
            try:
                verts.append([float(x) for x in tok[1:4]])
                if len(verts[-1]) != 3:
                    raise ValueError
            except ValueError:
                raise MeshError(f"{path}: line {no} ({line.strip()[:60]!r}): a vertex needs x y z") from None
    if not verts or len(verts) % 3:
        raise MeshError(f"{path}: {len(verts)} vertex lines in the ASCII STL file (need 3 per facet, at least one "
                        "facet)")
    pts, inv = np.unique(np.asarray(verts, float), axis=0, return_inverse=True)
    return meshio.Mesh(pts, [("triangle", inv.reshape(-1, 3))])


def _read_gmsh_api(path: Path):
    """A Gmsh .msh read through gmsh itself (any version; meshio fails on some, e.g. SaveAll=1 files): every
    element block with the physical tag of its entity (the first, when several) and the physical names."""
    import meshio

    from physar.geometry.tetra import _Gmsh

    with _Gmsh() as g:
        g.open(str(path))
        tags, coords, _ = g.model.mesh.getNodes()
        order = np.argsort(np.asarray(tags, np.int64), kind="stable")  # the file's node order (by node tag)
        tags, coords = np.asarray(tags, np.int64)[order], np.asarray(coords, float).reshape(-1, 3)[order]
        inv = np.full(int(tags.max()) + 1 if len(tags) else 1, -1, np.int64)
        inv[tags] = np.arange(len(tags))
        kinds = {(3, 4): "tetra", (3, 8): "hexahedron", (3, 6): "wedge", (3, 5): "pyramid", (2, 3): "triangle",
                 (2, 4): "quad"}
        cells, phys = [], []
        for dim, ent in g.model.getEntities():
            groups = g.model.getPhysicalGroupsForEntity(dim, ent)
            for et, _, nodes in zip(*g.model.mesh.getElements(dim, ent), strict=True):
                name, edim, order, nn, _, nprim = g.model.mesh.getElementProperties(et)
                if edim < 2:
                    continue
                base = kinds.get((edim, nprim))
                if base is None:
                    raise MeshError(f"{path}: gmsh elements {name!r} cannot be read")
                conn = inv[np.asarray(nodes, np.int64).reshape(-1, nn)]
                cells.append((base if order == 1 else f"{base}{nn}", conn))
                phys.append(np.full(len(conn), int(groups[0]) if len(groups) else -1, np.int64))
        names = {g.model.getPhysicalName(d, t): np.array([t, d]) for d, t in g.model.getPhysicalGroups()}
        names = {k: v for k, v in names.items() if k}
        has = bool(g.model.getPhysicalGroups())
    return meshio.Mesh(coords, cells,
                       cell_data={"gmsh:physical": phys} if has else {}, field_data=names)


def _read_meshio(path: Path):
    """The meshio mesh of a file, with physar's own readers for OBJ and ASCII STL (meshio fails on negative OBJ
    indices, texture/normal counts unlike the vertex count, blank lines in STL) and gmsh's for .msh files meshio
    cannot read. Every failure is one MeshError line naming the file."""
    meshio = _meshio()
    suffix = path.suffix.lower()
    if suffix == ".obj":
        return _read_obj(path)
    if suffix == ".stl":
        with open(path, "rb") as f:
            head = f.read(84)
        size = path.stat().st_size
        binary = len(head) == 84 and 84 + 50 * int.from_bytes(head[80:84], "little") == size
        if not binary and head.lstrip()[:5].lower() == b"solid":
            return _read_ascii_stl(path)
    sink = io.StringIO()
    try:  # meshio raises many types for corrupt files, and calls sys.exit for unreadable ones
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            return meshio.read(path)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - meshio raises arbitrary types
        detail = str(exc) if not isinstance(exc, SystemExit) else sink.getvalue().strip()
        detail = " ".join(detail.split()) or type(exc).__name__
    if suffix == ".msh":
        try:
            return _read_gmsh_api(path)
        except MeshError:
            raise
        except Exception as exc:  # noqa: BLE001 - gmsh raises plain Exceptions
            detail += f"; gmsh: {' '.join(str(exc).split())}"
    raise MeshError(f"cannot read mesh {path}: {detail}"[:300])


def _tet_mesh(points: np.ndarray, cells: np.ndarray, path: Path, tags: MeshTags | None) -> TetMesh:
    """TetMesh of a file's tetrahedra: a mesh written in the other orientation convention (every tetrahedron
    negative) is reoriented with a warning; a mesh with some tetrahedra inverted is one MeshError."""
    vol = tet_signed_volumes(points, cells)
    neg = vol < 0
    if neg.all():
        warnings.warn(f"{path}: all {len(cells)} tetrahedra have negative orientation (the other node-order "
                      "convention); reoriented them (swapped two nodes of each)", PhysarWarning, stacklevel=3)
        cells = cells.copy()
        cells[:, [2, 3]] = cells[:, [3, 2]]
    elif neg.any():
        scale = np.abs(vol).mean()
        bad = vol < -1e-12 * scale
        if bad.any():
            e = int(np.flatnonzero(bad)[0])
            raise MeshError(f"{path}: {int(bad.sum())} of {len(cells)} tetrahedra are inverted (negative "
                            f"orientation, e.g. element {e}) and the others are not: the mesh is tangled or "
                            "written inconsistently; regenerate it or fix it in the mesher")
    return TetMesh(points, cells, name=path.name, tags=tags)


def read_mesh(path: str | os.PathLike, kind: str = "auto") -> TetMesh | TriMesh:
    """Read a tetrahedral (`kind="tet"`) or triangle (`kind="tri"`) mesh; `auto` prefers tetrahedra.

    Hexahedra, wedges (prisms) and pyramids are split into tetrahedra (conforming: neighbours cut a shared face
    alike) and quadrilaterals and polygons into triangles, with one :class:`PhysarWarning` per cell type naming the
    file and the counts; second-order cells (tetra10, hexahedron20, triangle6, ...) are read as their corner nodes
    (physar builds P2 nodes itself), also with a warning. A file whose tetrahedra all have negative orientation
    is reoriented (warning); a mix of orientations is a MeshError.
    A tet mesh keeps the region tags of its cells and triangles (meshio cell_data "gmsh:physical",
    "medit:ref" or "cell_tags"; through splits, every piece keeps its cell's tag) and the group names
    (field_data: .msh $PhysicalNames, VTU FieldData, XDMF Information) as ``mesh.tags`` (:class:`MeshTags`).
    A surface (TriMesh) keeps the same tags of its triangles as ``face_tags`` (also through splits of
    quadrilaterals and polygons; -1 for untagged triangles: those of a block without tags, and those of gmsh
    physical tag or Medit reference 0) and the names of surface groups (dim 2) as ``tag_names``; an OBJ file's
    ``g``/``o`` groups are such tags too (see :func:`_read_obj`).
    A .msh without volume cells whose saved elements all belong to physical groups, none of them a volume
    (gmsh's default saves only the elements of physical groups), is one MeshError saying so when tetrahedra
    are asked for (``kind="tet"``, or ``"auto"`` for a file evidently from a 3-D model: see
    :func:`_check_gmsh_groups`).
    """
    path = Path(path)
    if not path.exists():
        raise PhysarError(f"mesh file not found: {path}")
    if path.is_dir():
        raise PhysarError(f"{path}: the mesh is a folder; give the mesh file")
    m = _read_meshio(path)
    vol, surf, notes = _blocks(m, path)
    points = np.asarray(m.points, dtype=float)
    if points.ndim == 2 and points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    if not vol and path.suffix.lower() == ".msh":
        _check_gmsh_groups(m, path, surf, kind)
    use_vol = kind in ("auto", "tet") and vol
    use_surf = not use_vol and kind in ("auto", "tri") and surf
    for is_vol, note in notes:
        if (is_vol and use_vol) or (not is_vol and use_surf):
            warnings.warn(note, PhysarWarning, stacklevel=2)
    if use_vol:
        cells = np.concatenate([c for c, _ in vol])
        used = np.unique(cells)
        remap = None
        if len(used) < len(points):  # drop points not used by tets (e.g. gmsh geometry points, mid-side nodes)
            remap = -np.ones(len(points), dtype=np.int64)
            remap[used] = np.arange(len(used))
            points, cells = points[used], remap[cells]
        return _tet_mesh(points, cells, path, _mesh_tags(vol, surf, _names(m), remap))
    if use_surf:
        return _tri_mesh(points, surf, _names(m), path, zero_untagged=any(k in m.cell_data for k in TAG_KEYS[:2]))
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


_NAMES_KEPT = {".msh", ".vtu", ".xdmf", ".xmf"}  # formats that store region names (others: numbers only)


def _vtu_add_names(path: Path, names: Mapping[str, tuple[int, int]]) -> None:
    """Add the region names to a VTU file meshio wrote (meshio reads VTU FieldData but writes none): one
    ``<FieldData>`` Int64 array [tag, dim] per name in the ``<UnstructuredGrid>`` element, where VTK and
    ParaView keep dataset field data and meshio.read returns it as ``field_data`` (the gmsh convention)."""
    from xml.sax.saxutils import quoteattr

    data = path.read_bytes()
    marker = b"<UnstructuredGrid>"
    at = data.find(marker)
    if at < 0:
        raise MeshError(f"{path}: cannot store the region names (no <UnstructuredGrid> element written)")
    arrays = "".join(f'<DataArray type="Int64" Name={quoteattr(str(n))} NumberOfTuples="2" format="ascii">'
                     f"{int(i)} {int(d)}</DataArray>\n" for n, (i, d) in names.items())
    at += len(marker)
    path.write_bytes(data[:at] + f"\n<FieldData>\n{arrays}</FieldData>".encode() + data[at:])


def xdmf_names_element(names: Mapping[str, tuple[int, int]]):
    """The region names ({name: (tag, dim)}) as an XDMF ``<Information>`` element (xml.etree) whose text is
    ``<main><map key="name" dim="dim">tag</map>...</main>``: the layout meshio's XDMF reader reads into
    ``field_data`` (and its own writers leave out); a Grid holds it as its first child."""
    import xml.etree.ElementTree as ET

    main = ET.Element("main")
    for n, (i, d) in names.items():
        ET.SubElement(main, "map", key=str(n), dim=str(int(d))).text = str(int(i))
    info = ET.Element("Information", Name="Information", Value=str(len(names)))
    info.text = ET.tostring(main, encoding="unicode")
    return info


def _xdmf_add_names(path: Path, names: Mapping[str, tuple[int, int]]) -> None:
    """Add the region names to an XDMF file meshio wrote: :func:`xdmf_names_element` as the first child of
    its Grid."""
    import xml.etree.ElementTree as ET

    tree = ET.parse(path)
    grid = tree.getroot().find("Domain/Grid")
    if grid is None:
        raise MeshError(f"{path}: cannot store the region names (no Domain/Grid element written)")
    grid.insert(0, xdmf_names_element(names))
    tree.write(path, encoding="utf-8", xml_declaration=False)


def write_mesh(
    path: str | os.PathLike,
    mesh: TetMesh | TriMesh,
    point_data: Mapping[str, np.ndarray] | None = None,
    cell_data: Mapping[str, np.ndarray] | None = None,
) -> Path:
    """Write `mesh` with optional nodal and per-element fields; the format follows the file suffix.  STL is
    written binary, whose coordinates are float32 (use PLY, OBJ, OFF or VTU for exact float64 round trips);
    a TetMesh needs a volume format (VTU, XDMF, Gmsh .msh, Medit .mesh). A TetMesh's tags are written as a tag
    per tetrahedron (``gmsh:physical`` in .msh, ``medit:ref`` in .mesh, else ``cell_tags``) and, when no cell
    field is given (a mesh file, not a results file), its tagged boundary triangles as a second block.
    The region names ({name: (tag, dim)}) go with them, so :func:`read_mesh` resolves the same names: .msh
    ``$PhysicalNames``, VTU ``<FieldData>`` Int64 arrays [tag, dim], XDMF ``<Information>`` maps (the layouts
    meshio reads as ``field_data``). Medit .mesh and legacy .vtk keep the numbers only: one PhysarWarning names
    the file and the regions written as numbers. A TriMesh's ``face_tags`` and ``tag_names`` are written alike
    (a tag per triangle); STL, PLY, OBJ and OFF store none: one PhysarWarning names the regions not written."""
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
    for k, v in cd.items():
        if len(v[0]) != len(conn):
            raise PhysarError(f"cell field {k!r} has {len(v[0])} rows, the mesh has {len(conn)} cells")
    pd = {k: np.asarray(v) for k, v in (point_data or {}).items()}
    for k, v in pd.items():
        if len(v) != mesh.n_points:
            raise PhysarError(f"point field {k!r} has {len(v)} rows, the mesh has {mesh.n_points} points")
    tags = getattr(mesh, "tags", None) if isinstance(mesh, TetMesh) else None
    field_data = {}
    if tags is not None:  # physical groups: a tag per tetrahedron, the tagged triangles as a second block, names
        key = {".msh": "gmsh:physical", ".mesh": "medit:ref"}.get(suffix, "cell_tags")
        tet_tags = tags.cell_tags if tags.cell_tags is not None else np.zeros(len(conn), np.int64)
        blocks = [np.asarray(tet_tags, np.int64)]
        # the tagged triangles only in a mesh file: in a results file (cell fields given) they would lie on the
        # boundary with NaN fields, drawn over the tetrahedra's faces by viewers such as ParaView
        if len(tags.face_nodes) and not cd:
            cells.append(("triangle", np.asarray(tags.face_nodes, np.int64)))
            blocks.append(np.asarray(tags.face_tags, np.int64))
        cd[key] = blocks
        if suffix == ".msh":
            cd["gmsh:geometrical"] = [b.copy() for b in blocks]
        field_data = {n: np.array([int(i), int(d)]) for n, (i, d) in tags.names.items()}
    names = tags.names if tags is not None else {}
    if isinstance(mesh, TriMesh) and mesh.face_tags is not None:  # a surface's region tags: one per triangle
        names = mesh.tag_names
        if suffix in _SURFACE_ONLY:
            what = ", ".join(repr(n) for n in sorted(names)) or \
                ", ".join(str(t) for t in np.unique(mesh.face_tags[mesh.face_tags >= 0]).tolist())
            warnings.warn(f"{path}: {path.suffix} stores no region tags: the surface's regions {what} are not "
                          "written (write .vtu, .xdmf or .msh to keep them)", PhysarWarning, stacklevel=2)
        else:
            key = {".msh": "gmsh:physical", ".mesh": "medit:ref"}.get(suffix, "cell_tags")
            t = np.asarray(mesh.face_tags, np.int64)
            cd[key] = [np.maximum(t, 0) if key != "cell_tags" else t]  # gmsh / Medit: 0 is "no group"
            if suffix == ".msh":
                cd["gmsh:geometrical"] = [np.maximum(t, 0)]
            field_data = {n: np.array([int(i), int(d)]) for n, (i, d) in names.items()}
    if field_data and suffix not in _NAMES_KEPT:
        lost = ", ".join(f"{n!r} = {i}" for n, (i, _) in sorted(names.items(), key=lambda kv: kv[1][0]))
        warnings.warn(f"{path}: {path.suffix} stores region numbers, not names: the regions {lost} are written as "
                      "numbers only (refer to them by number, or write .vtu, .xdmf or .msh to keep the names)",
                      PhysarWarning, stacklevel=2)
    if suffix == ".msh":  # both gmsh tags on every block (0: none), else meshio warns on stderr twice per write
        phys = cd.get("gmsh:physical") or [np.zeros(len(c[1]), np.int64) for c in cells]
        cd = {**cd, "gmsh:physical": phys, "gmsh:geometrical": cd.get("gmsh:geometrical") or [p.copy() for p in phys]}
    m = meshio.Mesh(mesh.points, cells, point_data=pd, cell_data=cd, field_data=field_data)
    with atomic_path(path, companions=suffix in (".xdmf", ".xmf")) as tmp:
        opts = {".stl": {"binary": True},  # binary STL: compact, standard
                ".msh": {"file_format": "gmsh22"}}.get(suffix, {})  # .msh alone: meshio writes ANSYS
        with contextlib.redirect_stdout(io.StringIO()):  # meshio prints notes (e.g. zero gmsh tags)
            m.write(tmp, **opts)
        if field_data and suffix == ".vtu":
            _vtu_add_names(Path(tmp), names)
        elif field_data and suffix in (".xdmf", ".xmf"):
            _xdmf_add_names(Path(tmp), names)
    return path
