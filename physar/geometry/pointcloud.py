r"""Point-cloud denoising: PCA normals on the k-NN graph and the AL / MSAL update (seed 001 §3.2.1).

Normals: for each point, the eigenvector of the smallest eigenvalue of the covariance of its k nearest
neighbours (seed 001 §3.2.1 footnote 1). Consistent orientation (``orient="mst"``, the default) follows
Hoppe, DeRose, Duchamp, McDonald & Stuetzle, "Surface reconstruction from unorganized points"
(SIGGRAPH 1992): a minimum spanning tree of the k-NN graph with edge cost :math:`1 - |n_i \cdot n_j|`
(scipy.sparse.csgraph) propagates the sign from a root,
:math:`n_j \leftarrow \operatorname{sign}(n_j \cdot n_{\mathrm{parent}})\, n_j`, so neighbouring
normals agree even where a centroid rule fails (the inner side of a torus, concave parts). The root of each
connected component is its point farthest from the cloud centroid, oriented away from the centroid (or the
point nearest a given `viewpoint`, oriented towards it). The propagation is vectorised by pointer jumping
(the sign of a point is the product of the relative signs along its tree path; :math:`\log_2(\mathrm{depth})`
passes over
all points). ``orient="centroid"`` flips each normal away from the centroid (star-shaped shapes only).
The AL/MSAL update of :mod:`physar.geometry.denoise` then runs over the symmetric k-NN graph; it uses
:math:`h_{ij} n_i`, which does not depend on the sign of :math:`n_i`, so the loop uses unoriented normals.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from physar.errors import MeshError, PhysarError
from physar.geometry.denoise import (
    G_DEFAULT,
    KAPPA,
    MAD,
    MSAL_FIDELITY,
    MSAL_XI,
    Progress,
    _check_iter,
    al_iterate,
    directed_edges,
    msal_lambda,
    scales_of,
)
from physar.output import check_destination, write_bytes


def _check_cloud(points: np.ndarray, k: int) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise MeshError(f"point cloud must have shape (n, 3), got {p.shape}")
    if int(k) != k or k < 0:
        raise MeshError(f"the number of neighbours k must be a non-negative integer, got {k}")
    if len(p) <= k:
        raise MeshError(f"point cloud has {len(p)} points; need more than k={k}")
    if not np.isfinite(p).all():
        raise MeshError("point cloud has NaN or infinite coordinates")
    return p


def knn_edges(points: np.ndarray, k: int = 10) -> np.ndarray:
    """Undirected edges (e, 2), a < b, of the symmetrised k-nearest-neighbour graph (no duplicates)."""
    p = _check_cloud(points, k)
    _, idx = cKDTree(p).query(p, k + 1)
    i = np.repeat(np.arange(len(p)), k)
    j = idx[:, 1:].ravel()
    a, b = np.minimum(i, j), np.maximum(i, j)
    key = np.unique(a * np.int64(len(p)) + b)
    return np.stack(np.divmod(key, np.int64(len(p))), axis=1)


def knn_graph(points: np.ndarray, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Symmetrised k-NN graph as directed edges (src, dst), both directions present, sorted by src."""
    return directed_edges(knn_edges(points, k))


def _unoriented_normals(p: np.ndarray, k: int, idx: np.ndarray | None = None) -> np.ndarray:
    """Smallest-eigenvalue eigenvectors of the k-NN covariances (batched eigh, no orientation).

    `idx` (n, k + 1): neighbour indices (self first) to reuse; found with a cKDTree if None."""
    if idx is None:
        _, idx = cKDTree(p).query(p, k + 1)
    nb = p[idx] - p[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vec = np.linalg.eigh(cov)  # ascending eigenvalues, batched
    return np.ascontiguousarray(vec[:, :, 0])


def orient_normals_mst(
    points: np.ndarray, normals: np.ndarray, k: int = 10, viewpoint: np.ndarray | None = None
) -> np.ndarray:
    r"""Consistently oriented copy of `normals` by MST sign propagation on the k-NN graph (Hoppe 1992).

    Tree edge cost :math:`1 - |n_i \cdot n_j|` (+1e-9, so that no edge weighs zero); per connected component, the
    root is the point farthest from the centroid, oriented away from it (or the point nearest
    `viewpoint`, oriented towards it). See the module doc.
    """
    p = _check_cloud(points, k)
    n = np.asarray(normals, dtype=float)
    if n.shape != p.shape:
        raise MeshError(f"normals must have the shape of the points {p.shape}, got {n.shape}")
    npts = len(p)
    e = knn_edges(p, k)
    cost = 1.0 - np.abs(np.einsum("ij,ij->i", n[e[:, 0]], n[e[:, 1]])) + 1e-9
    forest = csgraph.minimum_spanning_tree(sparse.csr_matrix((cost, (e[:, 0], e[:, 1])), shape=(npts, npts)))
    ncomp, label = csgraph.connected_components(forest, directed=False)
    if viewpoint is None:
        key = -np.einsum("ij,ij->i", p - p.mean(axis=0), p - p.mean(axis=0))  # farthest from the centroid
        ref = p - p.mean(axis=0)
    else:
        vp = np.asarray(viewpoint, dtype=float).reshape(3)
        key = np.einsum("ij,ij->i", p - vp, p - vp)  # nearest to the viewpoint
        ref = vp[None, :] - p
    order = np.lexsort((key, label))
    roots = order[np.searchsorted(label[order], np.arange(ncomp))]  # min key per component
    # one BFS from a virtual node joined to every root gives each point its tree parent
    fo = forest.tocoo()
    virt = npts
    rows = np.r_[fo.row, np.full(ncomp, virt)]
    cols = np.r_[fo.col, roots]
    tree = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(npts + 1, npts + 1))
    _, pred = csgraph.breadth_first_order(tree, virt, directed=False, return_predecessors=True)
    parent = pred[:npts].copy()
    parent[roots] = roots
    sign = np.sign(np.einsum("ij,ij->i", n, n[parent]))
    sign[sign == 0] = 1.0
    root_dot = np.einsum("ij,ij->i", n[roots], ref[roots])
    sign[roots] = 1.0
    while True:  # pointer jumping: log2(tree depth) passes, each over all points
        done = parent[parent] == parent
        sign = sign * np.where(parent != np.arange(npts), sign[parent], 1.0)
        parent = parent[parent]
        if done.all():
            break
    root_sign = np.where(root_dot < 0, -1.0, 1.0)
    sign *= root_sign[label]  # roots[c] is the root of component c
    return n * sign[:, None]


def pca_normals(
    points: np.ndarray, k: int = 10, viewpoint: np.ndarray | None = None, orient: str = "mst"
) -> np.ndarray:
    """Unit PCA normals from k nearest neighbours (seed 001 §3.2.1 footnote 1), oriented.

    ``orient="mst"`` (default): consistent orientation by MST propagation (:func:`orient_normals_mst`);
    ``"centroid"``: each normal away from the centroid, or towards `viewpoint` if given; ``"none"``.
    """
    p = _check_cloud(points, k)
    n = _unoriented_normals(p, k)
    if orient == "mst":
        return orient_normals_mst(p, n, k, viewpoint)
    if orient == "centroid":
        ref = (p - p.mean(axis=0)) if viewpoint is None else (np.asarray(viewpoint, float)[None, :] - p)
        n[np.einsum("ij,ij->i", n, ref) < 0] *= -1
        return n
    if orient == "none":
        return n
    raise PhysarError(f"unknown normal orientation {orient!r}; choose 'mst', 'centroid' or 'none'")


def denoise_points(
    points: np.ndarray, method: str = "msal", iterations: int | None = None, k: int = 10,
    tau: float = 0.5, xi: float = MSAL_XI, fidelity: float = MSAL_FIDELITY, kappa: float = KAPPA,
    g: str = G_DEFAULT, shrink_correction: float = 1.0, progress: Progress = None,
) -> np.ndarray:
    r"""AL (constant :math:`\tau`, :math:`\lambda = 0`) or MSAL (:math:`\tau = \xi^k`,
    :math:`\lambda_i = f \sigma_i / \max_j \sigma_j`, :math:`f` = `fidelity`) on the k-NN graph.

    Same update, edge-stopping function and robust scales as :mod:`physar.geometry.denoise` (seed 001
    §3.2.1), with PCA normals and the same optional shrinkage correction; no volume correction (a point
    cloud encloses no defined volume).
    Returns the (n, 3) denoised points (m).
    """
    if int(k) != k or k < 1:
        raise MeshError(f"point-cloud denoising needs k >= 1 neighbours, got {k}")
    p = _check_cloud(points, k)
    edges = knn_edges(p, k)
    # unoriented normals in the loop: h_ij n_i does not depend on the sign of n_i (module doc); the
    # neighbourhoods are those of the noisy data, fixed like the graph
    _, idx = cKDTree(p).query(p, k + 1)
    geometry = lambda q32: (_unoriented_normals(q32.astype(np.float64), k, idx), None, None)  # centred
    if method not in ("al", "msal"):
        raise PhysarError(f"point clouds support methods 'al' and 'msal', got {method!r}")
    it = (10 if method == "al" else 8) if iterations is None else int(iterations)
    _check_iter(it)
    if method == "al":
        return al_iterate(p, geometry, edges, np.full(it, tau), 0.0, kappa, g, False, progress,
                          shrink_correction=shrink_correction)
    if not (0 < xi < 1) or not (0 <= fidelity <= 1):
        raise PhysarError(f"MSAL needs 0 < xi < 1 and 0 <= fidelity <= 1, got xi={xi}, fidelity={fidelity}")
    sig_e, sig_i = scales_of(p, _unoriented_normals(p, k, idx), edges)
    lam = fidelity * msal_lambda(sig_i)
    return al_iterate(p, geometry, edges, xi ** np.arange(it, dtype=float), lam, kappa, g, False, progress,
                      sigma_e=sig_e, shrink_correction=shrink_correction)


_COLOUR_NAMES = (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue"))


def _vertex_columns(obj) -> dict:
    """{name: (n,) array in the file's type} of the PLY vertex properties trimesh read (its ``_ply_raw``; an
    ASCII file's columns come as (n, 1))."""
    data = (obj.metadata.get("_ply_raw", {}).get("vertex") or {}).get("data")
    if data is None:
        return {}
    if isinstance(data, np.ndarray) and data.dtype.names:
        data = {k: data[k] for k in data.dtype.names}
    out = {}
    for k, v in dict(data).items():
        v = np.asarray(v)
        if v.ndim == 2 and v.shape[1] == 1:
            v = v[:, 0]
        if v.ndim == 1:  # list properties (none on vertices in practice) are not columns
            out[str(k)] = v
    return out


def _vertex_colours(path: Path, obj, n: int) -> np.ndarray | None:
    """(n, 3) float64 RGB in [0, 1] from the vertex properties red, green, blue (or diffuse_red, ...), None
    when there are none: unsigned integers divided by their type's maximum (255 for uchar, 65535 for ushort),
    floats kept and required within [0, 1]; anything else is a PhysarError naming the property."""
    cols = _vertex_columns(obj)
    for names in _COLOUR_NAMES:
        have = [k for k in names if k in cols]
        if not have:
            continue
        if len(have) < 3:
            raise PhysarError(f"{path}: PLY vertex colours need {', '.join(names)}; the file has only "
                              f"{', '.join(have)}")
        rgb = np.empty((n, 3))
        for j, k in enumerate(names):
            c = cols[k]
            if len(c) != n:
                raise PhysarError(f"{path}: PLY vertex property {k} has {len(c)} values for {n} vertices")
            if c.dtype.kind == "u":
                rgb[:, j] = c / np.iinfo(c.dtype).max
            elif c.dtype.kind == "f":
                if not (np.isfinite(c).all() and (c >= 0).all() and (c <= 1).all()):
                    bad = c[~(np.isfinite(c) & (c >= 0) & (c <= 1))][0]
                    raise PhysarError(f"{path}: PLY vertex property {k} = {bad:g} is a float colour outside "
                                      f"[0, 1] (0-255 colours must be stored as uchar)")
                rgb[:, j] = c
            else:
                raise PhysarError(f"{path}: PLY vertex property {k} is {c.dtype}; colours must be uchar, ushort "
                                  f"or float in [0, 1]")
        return rgb
    return None


def read_ply(path: str | os.PathLike, *, colors: bool = False):
    """Read a PLY file: (points, faces) with faces None for a point cloud (trimesh loader, no pickle).

    With ``colors=True``: (points, faces, colours), ``colours`` the (n, 3) per-vertex RGB as float64 in
    [0, 1] (uchar 0-255 divided by 255, ushort by 65535, float properties kept and checked within [0, 1]),
    from the properties red, green, blue (or diffuse_red, diffuse_green, diffuse_blue), or None when the file
    has none; an alpha property is not read. Vertex order is the file's (no merging).
    """
    import trimesh

    path = Path(path)
    if not path.exists():
        raise PhysarError(f"PLY file not found: {path}")
    try:
        obj = trimesh.load(path, process=False, force=None)
    except Exception as exc:  # noqa: BLE001 - report any parser failure as one line
        raise PhysarError(f"{path}: cannot read PLY ({exc})") from None
    faces = getattr(obj, "faces", None)
    pts = np.asarray(getattr(obj, "vertices", np.zeros((0, 3))), dtype=float)
    if len(pts) == 0:
        raise MeshError(f"{path}: PLY file has no vertices")
    faces = np.asarray(faces, dtype=np.int64) if faces is not None and len(faces) else None
    if colors:
        return pts, faces, _vertex_colours(path, obj, len(pts))
    return pts, faces


def _colour_bytes(colors, n: int) -> np.ndarray:
    """(n, 3) uint8 of ``colors``: uint8 kept, floats in [0, 1] times 255 rounded; else a PhysarError."""
    c = np.asarray(colors)
    if c.shape != (n, 3):
        raise PhysarError(f"point colours must have shape ({n}, 3) (RGB per point), got {c.shape}")
    if c.dtype == np.uint8:
        return c
    if c.dtype.kind not in "iuf":
        raise PhysarError(f"point colours must be numbers (floats in [0, 1] or uint8), got {c.dtype}")
    c = c.astype(float)
    ok = np.isfinite(c) & (c >= 0) & (c <= 1)
    if not ok.all():
        i = int(np.argmax(~ok.all(axis=1)))
        raise PhysarError(f"point colours[{i}] = {c[i].tolist()} must lie in [0, 1] (or give uint8 0-255)")
    return np.round(c * 255).astype(np.uint8)


def write_ply(path: str | os.PathLike, points: np.ndarray, colors: np.ndarray | None = None) -> Path:
    """Write a binary PLY point cloud atomically (temp file + rename): float x, y, z and, when ``colors``
    (n, 3) is given (floats in [0, 1], as :func:`read_ply` returns them, or uint8 0-255), uchar red, green,
    blue (floats times 255, rounded) and alpha 255."""
    import trimesh

    path = Path(path)
    p = _check_cloud(points, 0)
    rgb = None if colors is None else _colour_bytes(colors, len(p))
    check_destination(path, suffixes=[".ply"], kind="point cloud")
    data = trimesh.PointCloud(p, colors=rgb).export(file_type="ply")
    try:
        write_bytes(path, data)
    except OSError as exc:
        raise PhysarError(f"{path}: cannot write ({exc.strerror or exc})") from None
    return path


__all__ = ["MAD", "denoise_points", "knn_edges", "knn_graph", "orient_normals_mst", "pca_normals", "read_ply",
           "write_ply"]
