"""Named/numbered regions of a volume mesh (physical groups) and geometric node/face selectors.

:class:`MeshTags` holds what a volume mesh file says about its parts: an integer tag per tetrahedron
(gmsh ``gmsh:physical``, Medit ``medit:ref``, ``cell_tags``), tagged boundary triangles (their three
vertex ids and tag) and tag names (gmsh ``$PhysicalNames``, i.e. meshio ``field_data``: name ->
(id, dim)). :meth:`MeshTags.resolve` turns a name or an integer id into the tagged triangles and/or
tetrahedra; a missing one raises a MeshError listing the available ids and names.

The geometric selectors work on any point array (mesh vertices or FE nodes, or face vertices):
:func:`near_points` (within `tol` of listed points) and :func:`on_plane` (|(x - p) . n| <= tol).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from physar.errors import MeshError


def _some(items: list, k: int = 4) -> str:
    """The first ``k`` of ``items`` joined by commas, then ``... (n in all)`` when there are more."""
    more = f", ... ({len(items)} in all)" if len(items) > k else ""
    return ", ".join(str(i) for i in items[:k]) + more


@dataclass(frozen=True, repr=False)
class MeshTags:
    """Tags of a tet mesh: `cell_tags` (m,) or None, `face_nodes` (k, 3) vertex ids of tagged triangles
    with `face_tags` (k,), `names` {name: (id, dim)} (dim 2: triangles, 3: tetrahedra)."""

    cell_tags: np.ndarray | None = None
    face_nodes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    face_tags: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    names: dict = field(default_factory=dict)

    def available(self) -> list:
        """Tag ids present (sorted) followed by the names, e.g. [1, 2, 'top']."""
        ids = set(np.unique(self.face_tags).tolist())
        if self.cell_tags is not None:
            ids |= set(np.unique(self.cell_tags).tolist())
        return sorted(int(i) for i in ids) + sorted(self.names)

    def resolve(self, region: str | int, what: str = "region") -> tuple[np.ndarray, np.ndarray]:
        """(face rows, cell mask) of `region` (a name or an integer id; a digit string counts as an id).

        A name selects the dimension its physical group has; an id selects both the triangles and the
        tetrahedra carrying it. Raises MeshError "<what> 'x' not in mesh (available: ...)" when nothing
        carries it.
        """
        dims = (2, 3)
        if isinstance(region, str) and region in self.names:
            tag, dim = self.names[region]
            dims = (int(dim),)
        else:
            try:
                tag = int(region)
            except (TypeError, ValueError):
                tag = None
        faces = np.zeros(0, np.int64)
        cells = np.zeros(0 if self.cell_tags is None else len(self.cell_tags), bool)
        if tag is not None:
            if 2 in dims:
                faces = np.flatnonzero(self.face_tags == tag)
            if 3 in dims and self.cell_tags is not None:
                cells = self.cell_tags == tag
        if len(faces) == 0 and not cells.any():
            avail = ", ".join(repr(a) for a in self.available()) or "none: the mesh file has no tags"
            raise MeshError(f"{what} {region!r} not in mesh (available: {avail})")
        return self.face_nodes[faces], cells

    def __repr__(self) -> str:
        """One line: how many tetrahedra and triangles are tagged and with which ids, and the tag names with
        their ids (at most 4 of each list; no arrays)."""
        def tagged(tags: np.ndarray, word: str, many: str) -> str:
            count = f"{len(tags)} {word if len(tags) == 1 else many}"
            ids = np.unique(tags).tolist()
            return f"{count} tagged (ids {_some(ids)})" if ids else f"{count} tagged"

        cells = "no tetrahedron tags" if self.cell_tags is None else tagged(self.cell_tags, "tetrahedron",
                                                                            "tetrahedra")
        text = f"MeshTags({cells}, {tagged(self.face_tags, 'triangle', 'triangles')}"
        if self.names:
            text += f", names {_some([f'{k}={v[0]}' for k, v in sorted(self.names.items())])}"
        return text + ")"


def _tol(points: np.ndarray, tol: float | None) -> float:
    if tol is None:
        span = float(np.ptp(points, axis=0).max()) if len(points) else 1.0
        return 1e-9 * max(span, 1e-300)
    if not (np.isfinite(tol) and tol >= 0):
        raise MeshError(f"tol must be a non-negative length in m, got {tol}")
    return float(tol)


def near_points(points: np.ndarray, targets: Sequence[Sequence[float]], tol: float | None = None) -> np.ndarray:
    """Mask of `points` within `tol` (m; default 1e-9 of the extent: the exact points) of any target."""
    from scipy.spatial import cKDTree

    t = np.asarray(targets, float).reshape(-1, 3)
    if len(t) == 0 or len(points) == 0:
        return np.zeros(len(points), bool)
    d, _ = cKDTree(t).query(points, k=1)
    return d <= _tol(points, tol)


def on_plane(points: np.ndarray, point: Sequence[float], normal: Sequence[float],
             tol: float | None = None) -> np.ndarray:
    """Mask of `points` at distance <= `tol` (m; default 1e-9 of the extent) from the plane through
    `point` with normal `normal` (any non-zero length)."""
    n = np.asarray(normal, float)
    if not (n.shape == (3,) and np.linalg.norm(n) > 0):
        raise MeshError(f"plane normal must be a non-zero 3-vector, got {np.asarray(normal).tolist()}")
    n = n / np.linalg.norm(n)
    return np.abs((points - np.asarray(point, float)) @ n) <= _tol(points, tol)


__all__ = ["MeshTags", "near_points", "on_plane"]
