"""Point-cloud denoising: PCA normals on the k-NN graph and the AL / MSAL update (seed 001 §3.2.1).

Normals: for each point, the eigenvector of the smallest eigenvalue of the covariance of its k nearest
neighbours (seed 001 §3.2.1 footnote 1). Orientation: each normal is flipped to point away from the
cloud centroid (or towards a given `viewpoint`), which is consistent for star-shaped closed scans and
single-view scans; it is not an MST propagation. The AL/MSAL update of :mod:`physar.geometry.denoise`
then runs over the symmetric k-NN graph.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from physar.errors import MeshError, PhysarError
from physar.geometry.denoise import (
    G_DEFAULT,
    KAPPA,
    MAD,
    MSAL_FIDELITY,
    MSAL_XI,
    Progress,
    al_iterate,
    directed_edges,
    msal_lambda,
    scales_of,
)


def _check_cloud(points: np.ndarray, k: int) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise MeshError(f"point cloud must have shape (n, 3), got {p.shape}")
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


def pca_normals(points: np.ndarray, k: int = 10, viewpoint: np.ndarray | None = None) -> np.ndarray:
    """Unit PCA normals from k nearest neighbours, oriented away from the centroid (or toward viewpoint)."""
    p = _check_cloud(points, k)
    _, idx = cKDTree(p).query(p, k + 1)
    nb = p[idx] - p[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vec = np.linalg.eigh(cov)  # ascending eigenvalues, batched
    n = vec[:, :, 0]
    ref = (p - p.mean(axis=0)) if viewpoint is None else (np.asarray(viewpoint, float)[None, :] - p)
    flip = np.einsum("ij,ij->i", n, ref) < 0
    n[flip] *= -1
    return n


def denoise_points(
    points: np.ndarray, method: str = "msal", iterations: int | None = None, k: int = 10,
    tau: float = 0.5, xi: float = MSAL_XI, fidelity: float = MSAL_FIDELITY, kappa: float = KAPPA,
    g: str = G_DEFAULT, shrink_correction: float = 1.0, progress: Progress = None,
) -> np.ndarray:
    """AL (constant τ, λ = 0) or MSAL (τ = ξ^k, λ_i = fidelity · σ_i / max σ) on the k-NN graph.

    Same update, edge-stopping function and robust scales as :mod:`physar.geometry.denoise` (seed 001
    §3.2.1), with PCA normals and the same optional shrinkage correction; no volume correction (a point
    cloud encloses no defined volume).
    Returns the (n, 3) denoised points (m).
    """
    p = _check_cloud(points, k)
    edges = knn_edges(p, k)
    geometry = lambda q32: (pca_normals(q32.astype(np.float64), k), None, None)  # centred positions
    if method not in ("al", "msal"):
        raise PhysarError(f"point clouds support methods 'al' and 'msal', got {method!r}")
    it = (10 if method == "al" else 8) if iterations is None else int(iterations)
    if it < 1:
        raise PhysarError(f"iterations must be >= 1, got {it}")
    if method == "al":
        return al_iterate(p, geometry, edges, np.full(it, tau), 0.0, kappa, g, False, progress,
                          shrink_correction=shrink_correction)
    if not (0 < xi < 1) or not (0 <= fidelity <= 1):
        raise PhysarError(f"MSAL needs 0 < xi < 1 and 0 <= fidelity <= 1, got xi={xi}, fidelity={fidelity}")
    sig_e, sig_i = scales_of(p, pca_normals(p, k), edges)
    lam = fidelity * msal_lambda(sig_i)
    return al_iterate(p, geometry, edges, xi ** np.arange(it, dtype=float), lam, kappa, g, False, progress,
                      sigma_e=sig_e, shrink_correction=shrink_correction)


def read_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a PLY file: (points, faces) with faces None for a point cloud (trimesh loader, no pickle)."""
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
    return pts, (np.asarray(faces, dtype=np.int64) if faces is not None and len(faces) else None)


def write_ply(path: str | os.PathLike, points: np.ndarray) -> Path:
    """Write a binary PLY point cloud atomically (temp file + rename)."""
    import trimesh

    path = Path(path)
    p = _check_cloud(points, 0)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        data = trimesh.PointCloud(p).export(file_type="ply")
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as exc:
        raise PhysarError(f"{path}: cannot write ({exc})") from None
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


__all__ = ["MAD", "denoise_points", "knn_edges", "knn_graph", "pca_normals", "read_ply", "write_ply"]
