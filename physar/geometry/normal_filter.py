"""Two-stage feature-aware denoising: guided filtering of face normals, a feature-weighted Taubin
smoothing of the positions (normal and tangential), then a vertex update that fits the filtered normals.

Why a method beside AL/MSAL (seed 001 §3.2.1): AL moves a vertex only along its normal, so the tangential
part of random-direction noise (the literature's protocol, :func:`physar.geometry.quality.add_noise`)
stays and sharp edges stay jagged (issue 20 measurements: 1.4-1.8x a tuned Taubin or normal filter).

Stage 1, joint bilateral filter of face normals (Zheng et al., IEEE TVCG 2011; guidance after Zhang et al.,
"Guided mesh normal filtering", Pacific Graphics 2015), per face i over the faces j sharing a vertex with i::

    n_i <- normalize( Σ_j A_j W_s(|c_i - c_j|) W_r(|g_i - g_j|) n_j ),
    W_s(x) = exp(-x² / 2σ_s²),   W_r(x) = exp(-x² / 2σ_r²)

A_j face area, c_j centroid, σ_s = mean centroid distance of neighbouring faces. The range kernel compares
*guidance* normals g: g_i is the area-weighted mean normal m_j of the most consistent patch containing face
i (patch P_j = faces sharing a vertex with face j, j a neighbour of i, with the smallest H_j = max_{k∈P_j}
|n_k - m_j|). A patch across a sharp edge is inconsistent, so faces next to an edge take their guidance
from their own side and the edge is not blurred. The guidance is recomputed in every iteration.

Stage 2, feature-weighted Taubin λ|μ smoothing (Taubin, SIGGRAPH 1995; λ = 0.5, μ = -0.53) of the positions,
with edge weights from the filtered vertex normals ν_i (area-weighted averages of stage-1 normals)::

    x <- x + λ L x,  x <- x + μ L x,   (L x)_i = Σ_j w_ij (x_j - x_i) / Σ_j w_ij,
    w_ij = exp(-|ν_i - ν_j|² / 2σ_w²)

It moves vertices tangentially too (it regularises the sampling the noise disturbed), and across a sharp
edge the weights vanish, so the two sides are smoothed separately.

Stage 3, vertex update (Sun, Rosin, Martin & Langbein, IEEE TVCG 2007), ``vertex_iterations`` times::

    x_i <- x_i + (1/|F_i|) Σ_{f∋i} n_f n_fᵀ (c_f - x_i)

every face plane (through its centroid, with its stage-1 normal) pulls the vertex along that normal: planes
become flat and a vertex on an edge is pulled onto the intersection of the planes of both sides. Last, one
global offset along the vertex normals restores the enclosed volume of the input, δ = (V(q̂) - V(q)) / A(q),
as in :func:`physar.geometry.denoise.al_iterate`.

Scale-aware defaults (a user has no clean mesh to tune against): the noise is measured on the input with
the seed's robust scale (:func:`physar.geometry.denoise.noise_scales`), ν = σ_e / ē with ē the mean edge
length, and the number of normal-filter iterations grows with ν (:func:`auto_parameters`, where the
constants come from). Everything is vectorised (scipy.sparse, np.bincount). Units: positions in metres;
σ_r, σ_w dimensionless (distances between unit vectors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from physar.errors import PhysarError
from physar.geometry.mesh import TriMesh


@dataclass(frozen=True)
class NormalFilterSettings:
    """Parameters of :func:`normal_filter_denoise`; ``None`` means the automatic, scale-aware choice."""

    sigma_r: float | None = None  # stage 1: range kernel width on guidance normals (dimensionless)
    normal_iterations: int | None = None  # stage 1 iterations
    guided: bool = True  # False: plain bilateral normal filter (range kernel on the normals themselves)
    smooth_iterations: int | None = None  # stage 2: feature-weighted Taubin λ|μ pairs
    sigma_w: float | None = None  # stage 2: width of the feature weights on filtered vertex normals
    vertex_iterations: int | None = None  # stage 3 iterations
    preserve_volume: bool = True


def noise_level(mesh: TriMesh) -> float:
    """ν = σ_e / ē: the seed's robust noise scale of the input relative to its mean edge length."""
    from physar.geometry.denoise import SurfaceOps, scales_of
    from physar.geometry.quality import mean_edge_length

    ops = SurfaceOps.from_mesh(mesh)
    n, _, _ = ops.geometry((mesh.points - mesh.points.mean(axis=0)).astype(np.float32))
    sig_e, _ = scales_of(mesh.points, n.astype(np.float64), ops.edges)
    return sig_e / mean_edge_length(mesh)


SIGMA_R = 0.45
SIGMA_W = 0.4
SMOOTH_ITERATIONS = 40
VERTEX_ITERATIONS = 10


def auto_parameters(nu: float) -> dict:
    """Settings for the measured noise level ν = σ_e / ē (the keys of :class:`NormalFilterSettings`).

    Normal-filter iterations = clip(round(45 ν), 1, 12): 4 at ν ≈ 0.1 (random-direction noise of 0.3 ē),
    3 at 0.2 ē, 1-2 at 0.1 ē. The constants were chosen once on development meshes (a noisy torus, the
    pymeshlab bunny and a gmsh CAD part at 0.3 ē; benchmarks/RESULTS.md, issue 20) and are fixed for every
    mesh; σ_r = 0.45 and σ_w = 0.4 are in the range of Zheng et al. and Zhang et al. (0.3-0.6).
    """
    return {"sigma_r": SIGMA_R, "normal_iterations": int(np.clip(np.round(45.0 * nu), 1, 12)),
            "smooth_iterations": SMOOTH_ITERATIONS, "sigma_w": SIGMA_W, "vertex_iterations": VERTEX_ITERATIONS}


def _face_graph(mesh: TriMesh) -> sparse.csr_matrix:
    """Sparse (m x m) pattern of faces sharing at least one vertex (self included), rows sorted."""
    f = mesh.faces
    m = len(f)
    inc = sparse.csr_matrix((np.ones(3 * m), (f.T.ravel(), np.tile(np.arange(m), 3))), shape=(mesh.n_points, m))
    ff = (inc.T @ inc).tocsr()
    ff.sort_indices()
    ff.data[:] = 1.0
    return ff


def _face_geometry(q: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(unit face normals (m, 3), areas (m,), centroids (m, 3))."""
    x = q[faces]
    c = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    a2 = np.linalg.norm(c, axis=1)
    return c / np.where(a2 > 0, a2, 1.0)[:, None], 0.5 * a2, x.mean(axis=1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=1), 1e-300)[:, None]


def guidance(nf: np.ndarray, area: np.ndarray, ff: sparse.csr_matrix) -> np.ndarray:
    """Guidance normals (m, 3): for each face, the mean normal of its most consistent neighbouring patch."""
    rows = np.repeat(np.arange(ff.shape[0]), np.diff(ff.indptr))
    cols = ff.indices
    mean = _unit(ff @ (area[:, None] * nf))  # m_j, area-weighted patch mean
    dev = np.linalg.norm(nf[cols] - mean[rows], axis=1)  # |n_k - m_j| for k in P_j (row j)
    h = np.maximum.reduceat(dev, ff.indptr[:-1]) if len(dev) else dev  # H_j (every row has itself)
    order = np.lexsort((h[cols], rows))  # per row i, the neighbour j with the smallest H_j first
    best = cols[order[ff.indptr[:-1]]]
    return mean[best]


def filter_normals(nf: np.ndarray, area: np.ndarray, cen: np.ndarray, ff: sparse.csr_matrix, sigma_r: float,
                   iterations: int, guided: bool = True) -> np.ndarray:
    """Stage 1: ``iterations`` joint bilateral filter passes over unit face normals (module doc)."""
    rows = np.repeat(np.arange(ff.shape[0]), np.diff(ff.indptr))
    cols = ff.indices
    dc = cen[rows] - cen[cols]
    d2 = np.einsum("ij,ij->i", dc, dc)
    off = rows != cols
    sig_s2 = float(np.sqrt(d2[off]).mean()) ** 2 if off.any() else 1.0
    base = area[cols] * np.exp(-d2 / (2.0 * sig_s2))
    for _ in range(int(iterations)):
        g = guidance(nf, area, ff) if guided else nf
        dg = g[rows] - g[cols]
        w = base * np.exp(-np.einsum("ij,ij->i", dg, dg) / (2.0 * sigma_r**2))
        nf = _unit(sparse.csr_matrix((w, cols, ff.indptr), shape=ff.shape) @ nf)
    return nf


def update_vertices(q: np.ndarray, faces: np.ndarray, nf: np.ndarray, iterations: int) -> np.ndarray:
    """Stage 2: fit the vertices to the face normals nf (Sun et al. 2007, module doc)."""
    npts = len(q)
    idx = faces.ravel()
    val = np.maximum(np.bincount(idx, minlength=npts), 1).astype(float)
    for _ in range(int(iterations)):
        cen = q[faces].mean(axis=1)
        p = np.einsum("fd,fkd->fk", nf, cen[:, None, :] - q[faces]).ravel()  # n_f·(c_f - x_i) per corner
        nrep = np.repeat(nf, 3, axis=0)
        disp = np.stack([np.bincount(idx, weights=p * nrep[:, d], minlength=npts) for d in range(3)], axis=1)
        q = q + disp / val[:, None]
    return q


def feature_weights(faces: np.ndarray, nf: np.ndarray, area: np.ndarray, src: np.ndarray, dst: np.ndarray,
                    npts: int, sigma_w: float) -> sparse.csr_matrix:
    """Row-normalised (npts x npts) weights w_ij = exp(-|ν_i - ν_j|²/2σ_w²) over directed edges (stage 2)."""
    idx = faces.ravel()
    acc = np.repeat(area[:, None] * nf, 3, axis=0)
    nv = _unit(np.stack([np.bincount(idx, weights=acc[:, d], minlength=npts) for d in range(3)], axis=1))
    d = nv[src] - nv[dst]
    w = np.exp(-np.einsum("ij,ij->i", d, d) / (2.0 * sigma_w**2))
    tot = np.bincount(src, weights=w, minlength=npts)
    return sparse.csr_matrix((w / np.maximum(tot[src], 1e-300), (src, dst)), shape=(npts, npts))


def taubin_weighted(q: np.ndarray, weights: sparse.csr_matrix, iterations: int, lam: float = 0.5,
                    mu: float = -0.53) -> np.ndarray:
    """Stage 2: ``iterations`` Taubin λ|μ pairs with the row-normalised weights (module doc)."""
    for _ in range(int(iterations)):
        q = q + lam * (weights @ q - q)
        q = q + mu * (weights @ q - q)
    return q


def resolve(settings: NormalFilterSettings, nu: float) -> dict:
    """The settings with every unset (None) entry replaced by :func:`auto_parameters` at noise level ν."""
    auto = auto_parameters(nu)
    out = {k: (auto[k] if getattr(settings, k) is None else getattr(settings, k)) for k in auto}
    if not (np.isfinite(out["sigma_r"]) and out["sigma_r"] > 0 and np.isfinite(out["sigma_w"]) and out["sigma_w"] > 0):
        raise PhysarError(f"sigma_r and sigma_w must be finite numbers > 0, got {out['sigma_r']}, {out['sigma_w']}")
    for k in ("normal_iterations", "smooth_iterations", "vertex_iterations"):
        v = out[k]
        if isinstance(v, bool) or int(v) != v or not 0 <= v <= 100_000:
            raise PhysarError(f"{k} must be an integer within 0..100000, got {v}")
        out[k] = int(v)
    return out


def normal_filter_denoise(mesh: TriMesh, settings: NormalFilterSettings | None = None,
                          progress=None) -> TriMesh:
    """Denoise a triangle surface: guided normal filter, feature-weighted Taubin, vertex update (module doc).

    Unset parameters in `settings` are chosen from the input's own noise level (:func:`auto_parameters`).
    Returns a mesh with the same faces; `progress(k, q)` is called after each of the 3 stages.
    """
    from physar.geometry.denoise import SurfaceOps, directed_edges

    settings = settings or NormalFilterSettings()
    ops = SurfaceOps.from_mesh(mesh)  # validates the surface
    p = resolve(settings, noise_level(mesh))
    q = mesh.points.astype(float).copy()
    origin = q.mean(axis=0)
    _, v0, _ = ops.geometry((q - origin).astype(np.float32))
    nf, area, cen = _face_geometry(q, mesh.faces)
    nf = filter_normals(nf, area, cen, _face_graph(mesh), p["sigma_r"], p["normal_iterations"], settings.guided)
    if progress is not None:
        progress(0, q)
    src, dst = directed_edges(ops.edges)
    q = taubin_weighted(q, feature_weights(mesh.faces, nf, area, src, dst, len(q), p["sigma_w"]),
                        p["smooth_iterations"])
    if progress is not None:
        progress(1, q)
    q = update_vertices(q, mesh.faces, nf, p["vertex_iterations"])
    if settings.preserve_volume and v0 is not None:
        n, vol, area_tot = ops.geometry((q - origin).astype(np.float32))
        if area_tot:
            q = q + ((v0 - vol) / area_tot) * n.astype(float)
    if progress is not None:
        progress(2, q)
    return mesh.with_points(q)
