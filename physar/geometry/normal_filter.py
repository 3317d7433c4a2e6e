"""Two-stage feature-aware denoising: bilateral filtering of face normals, a feature-weighted Taubin
smoothing of the positions (normal and tangential), then a vertex update that fits the filtered normals; the
amount of normal filtering and its range width are chosen from the mesh alone, by Stein's unbiased estimate of
the face-tilt error (SURE) with the mesh's own noise estimate.

Why a method beside AL/MSAL (seed 001 §3.2.1): AL moves a vertex only along its normal, so the tangential
part of random-direction noise (the literature's protocol, :func:`physar.geometry.quality.add_noise`)
stays and sharp edges stay jagged (issue 20 measurements: 1.4-1.8x a tuned Taubin or normal filter).

Stage 1, bilateral filter of face normals (Zheng, Fu, Au & Tai, IEEE TVCG 2011), per face i over the faces
j sharing a vertex with i::

    n_i <- normalize( Σ_j A_j W_s(|c_i - c_j|) W_r(|g_i - g_j|) n_j ),
    W_s(x) = exp(-x² / 2σ_s²),   W_r(x) = exp(-x² / 2σ_r²)

A_j face area, c_j centroid, σ_s = mean centroid distance of neighbouring faces, σ_r (0.2 or 0.35, below), g = n (or, with
``guided=True``, the mean normal of the most consistent neighbouring patch, after Zhang et al., "Guided mesh
normal filtering", 2015: H_j = max_{k∈P_j} |n_k - m_j|; it measured worse here, so it is off by default).

Stage 2, feature-weighted Taubin λ|μ smoothing (Taubin, SIGGRAPH 1995; λ = 0.5, μ = -0.53) of the positions,
with edge weights from the filtered vertex normals ν_i (area-weighted averages of the stage-1 normals)::

    x <- x + λ L x,  x <- x + μ L x,   (L x)_i = Σ_j w_ij (x_j - x_i) / Σ_j w_ij,
    w_ij = exp(-|ν_i - ν_j|² / 2σ_w²),  σ_w = 0.4

It moves vertices tangentially too (it regularises the sampling the noise disturbed, which AL cannot), and
across a sharp edge the weights vanish, so the two sides are smoothed separately.

Stage 3, vertex update (Sun, Rosin, Martin & Langbein, IEEE TVCG 2007), 10 times::

    x_i <- x_i + (1/|F_i|) Σ_{f∋i} n_f n_fᵀ (c_f - x_i)

every face plane (through its centroid, with its stage-1 normal) pulls the vertex along that normal: planes
become flat and a vertex on an edge is pulled onto the intersection of the planes of both sides. Last, one
global offset along the vertex normals restores the enclosed volume of the input, δ = (V(q̂) - V(q)) / A(q),
as in :func:`physar.geometry.denoise.al_iterate`.

Automatic amount of filtering (a user has no clean mesh to tune against): the stage-1 iteration count k and
the range width σ_r ∈ {0.2, 0.35} are chosen by Stein's unbiased risk estimate (SURE; Stein 1981, Monte-Carlo
form of Ramani, Blu & Unser, IEEE TIP 2008) of the face-tilt error of the result q = f(y) of the noisy mesh y::

    R = mean |A (q - x)|²,   (A d)_{f,ij} = n_f · (d_i - d_j)  over the three edges (i, j) of every face f,
    SURE = mean |A (q - y)|² - 2σ² + 2σ² bᵀAᵀA (f(y + εb) - f(y)) / (ε · 3m),   b ~ N(0, I)

(x the unknown clean mesh, m faces, n_f the face normals of a lightly smoothed y, fixed; A(q - x) is what tilts
a face, hence its normal error). It assumes i.i.d. isotropic noise of std σ per coordinate, σ =
:data:`SURE_NOISE_FACTOR` · σ_e / :data:`MAD_RATIO` from :func:`noise_scale` (one-ring heights minus a local
quadric fit, so curvature is not counted as noise; σ_e ≈ 0.29 σ_n for random-direction noise on remeshed spheres,
tori, boxes and cylinders, 0.31-0.33 on pymeshlab's bone and airplane; the factor 1.0 was the best of 0.85, 0.92
and 1.0 there, `benchmarks/bench_denoise.py --calibrate`, none of them a benchmark mesh). One probe b
(seeded) for all (k, σ_r), so the comparison between them is not blurred by sampling; the finite-difference step
ε = :data:`EPS_FD` σ = 0.1 σ (a smaller one, 0.01 σ, made the estimate jump between neighbouring k where the
filter is far from linear: σ_r = 0.2 beyond 40 iterations at 0.3 ē). k runs over :data:`CHECKPOINTS` for each
σ_r until ``patience`` counts in a row bring no lower estimate; the (σ_r, k) of the lowest estimate is kept.
Unlike the discrepancy principle (``rule="discrepancy"``: the first k whose residual rms_i((q̂_i - x_i)·n_i)
reaches ``discrepancy`` · σ_e / 0.29, the previous default), SURE weighs the noise removed against the shape
removed, so it stops early on detailed scans and late on flat CAD faces. It costs two evaluations per (σ_r, k)
(the probe), about 4x the discrepancy rule. Everything is vectorised (scipy.sparse, np.bincount).
Units: positions in metres; σ_r, σ_w dimensionless (distances between unit vectors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from physar.errors import PhysarError
from physar.geometry.mesh import TriMesh


@dataclass(frozen=True)
class NormalFilterSettings:
    """Parameters of :func:`normal_filter_denoise` (module doc)."""

    sigma_r: float | None = None  # stage 1: range kernel width; None: chosen among sigma_r_candidates
    sigma_r_candidates: tuple[float, ...] = (0.2, 0.35)  # rule "sure" picks one (0.35: Zheng et al.'s default)
    normal_iterations: int | None = None  # stage 1 iterations; None: discrepancy principle
    guided: bool = False  # True: range kernel on guidance normals (Zhang et al. 2015)
    smooth_iterations: int = 10  # stage 2: feature-weighted Taubin λ|μ pairs
    sigma_w: float = 0.4  # stage 2: width of the feature weights on filtered vertex normals
    vertex_iterations: int = 10  # stage 3 iterations
    discrepancy: float = 0.95  # rule "discrepancy": target residual / estimated noise std (normal component)
    max_normal_iterations: int = 100
    preserve_volume: bool = True
    rule: str = "sure"  # automatic stage-1 count: "sure" (face-tilt risk estimate) or "discrepancy"
    patience: int = 3  # rule "sure": stop after this many checkpoints without a lower risk


# σ_e / σ_n of :func:`noise_scale` for i.i.d. random-direction vertex noise; bench_denoise.py --calibrate.
MAD_RATIO = 0.29
RULES = ("sure", "discrepancy")
# rule "sure": the noise std it assumes, as a fraction of σ_e / MAD_RATIO; bench_denoise.py --calibrate on the
# calibration meshes: 1.0 has the lowest geometric mean (1.04) and worst case (1.23) of error / oracle error
# over their 14 cases (0.92: 1.07 / 1.47; 0.85: 1.41 / 2.86).
SURE_NOISE_FACTOR = 1.0
EPS_FD = 0.1  # finite-difference step of the divergence probe, in units of the noise std
CHECKPOINTS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 25, 30, 40, 50, 65, 80, 100)


def noise_scale(mesh: TriMesh) -> float:
    """σ_e (m): robust scale of the one-ring heights left after a local quadric fit (module doc).

    Per vertex i with unit normal n_i and tangent axes (t1, t2): h_ij = (q_j - q_i)·n_i ≈ c_0 + a x² + b x y
    + c y², (x, y) = ((q_j - q_i)·t1, (q_j - q_i)·t2) scaled by the ring's rms edge length, fitted by least
    squares (batched 4 x 4 normal equations); σ_e = 1.4826 median |r_ij| over the residuals of vertices with at
    least 6 neighbours (all vertices if there are none). c_0 absorbs the vertex's own noise and the quadric the
    surface's curvature, so σ_e measures the neighbours' noise, not shape (the seed's ring-median MAD,
    :func:`physar.geometry.denoise.noise_scales`, also picks up curvature that varies within a ring).
    """
    from physar.geometry.denoise import SurfaceOps, directed_edges
    from physar.geometry.quality import vertex_normals_arrays

    ops = SurfaceOps.from_mesh(mesh)
    src, dst = directed_edges(ops.edges)
    q = mesh.points
    npts = len(q)
    n = vertex_normals_arrays(q, mesh.faces)
    a = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = _unit(np.cross(n, a))
    t2 = np.cross(n, t1)
    d = q[dst] - q[src]
    x, y, h = (np.einsum("ij,ij->i", d, b[src]) for b in (t1, t2, n))
    deg = np.bincount(src, minlength=npts)
    s = np.sqrt(np.bincount(src, weights=x * x + y * y, minlength=npts) / np.maximum(deg, 1))[src]
    s = np.where(s > 0, s, 1.0)
    phi = np.stack([np.ones_like(x), (x / s) ** 2, (x / s) * (y / s), (y / s) ** 2], axis=1)
    lhs = np.empty((npts, 4, 4))
    rhs = np.empty((npts, 4))
    for u in range(4):  # the 4 x 4 normal equations of every vertex at once (loops over terms, not vertices)
        rhs[:, u] = np.bincount(src, weights=phi[:, u] * h, minlength=npts)
        for v in range(u, 4):
            lhs[:, u, v] = lhs[:, v, u] = np.bincount(src, weights=phi[:, u] * phi[:, v], minlength=npts)
    lhs += 1e-9 * np.eye(4)
    beta = np.linalg.solve(lhs, rhs[..., None])[..., 0]
    r = h - np.einsum("ij,ij->i", phi, beta[src])
    use = deg[src] >= 6
    return 1.4826 * float(np.median(np.abs(r[use] if use.any() else r)))


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
                   iterations: int, guided: bool = False) -> np.ndarray:
    """Stage 1: ``iterations`` bilateral filter passes over unit face normals (joint, on guidance normals, with
    ``guided``; module doc)."""
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
    """Stage 3: fit the vertices to the face normals nf (Sun et al. 2007, module doc)."""
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


def _check(st: NormalFilterSettings) -> None:
    for name in ("sigma_r", "sigma_w", "discrepancy"):
        v = getattr(st, name)
        if v is None and name == "sigma_r":
            continue
        if not (np.isfinite(v) and v > 0):
            raise PhysarError(f"{name} must be a finite number > 0, got {v}")
    if not st.sigma_r_candidates or not all(np.isfinite(v) and v > 0 for v in st.sigma_r_candidates):
        raise PhysarError(f"sigma_r_candidates must be numbers > 0, got {st.sigma_r_candidates}")
    if st.rule not in RULES:
        raise PhysarError(f"rule must be one of {', '.join(RULES)}, got {st.rule!r}")
    for name in ("normal_iterations", "smooth_iterations", "vertex_iterations", "max_normal_iterations", "patience"):
        v = getattr(st, name)
        if v is not None and (isinstance(v, bool) or int(v) != v or not 0 <= v <= 100_000):
            raise PhysarError(f"{name} must be an integer within 0..100000, got {v}")


def residual_normal_rms(q0: np.ndarray, q: np.ndarray, faces: np.ndarray) -> float:
    """rms over vertices of (q0_i - q_i)·n_i, n_i the unit (area-weighted) vertex normals of q (m)."""
    from physar.geometry.quality import vertex_normals_arrays

    n = vertex_normals_arrays(q, faces)
    return float(np.sqrt(np.mean(np.einsum("ij,ij->i", q0 - q, n) ** 2)))


class FaceTilt:
    """Linear map d (npts, 3) -> (3 m,): n_f·(d_i - d_j) over the three edges (i, j) of every face f, with
    fixed unit face normals n_f; |A d|² is the face-tilt part of a displacement error d (module doc)."""

    def __init__(self, faces: np.ndarray, normals: np.ndarray):
        self.i = faces.ravel()
        self.j = faces[:, [1, 2, 0]].ravel()
        self.n = np.repeat(normals, 3, axis=0)

    def __call__(self, d: np.ndarray) -> np.ndarray:
        return np.einsum("ij,ij->i", self.n, d[self.i] - d[self.j])


def sure_tilt(tilt: FaceTilt, y: np.ndarray, q: np.ndarray, qp: np.ndarray, ap: np.ndarray, eps: float,
              sigma: float) -> float:
    """Monte-Carlo SURE of mean |A(q - x)|² (m²) from the noisy y, the result q = f(y), the result qp =
    f(y + eps b) for one probe b and ap = A b (module doc)."""
    div = float(ap @ tilt(qp - q)) / (eps * len(ap))
    return float(np.mean(tilt(q - y) ** 2)) - 2.0 * sigma**2 + 2.0 * sigma**2 * div


def normal_filter_denoise(mesh: TriMesh, settings: NormalFilterSettings | None = None,
                          progress=None, info: dict | None = None) -> TriMesh:
    """Denoise a triangle surface: bilateral normal filter, feature-weighted Taubin, vertex update (module doc).

    With ``normal_iterations=None`` the stage-1 iteration count (and with ``sigma_r=None`` the range width)
    follows ``rule`` (SURE by default). Returns a mesh with the same faces; `progress(k, q)` is called after each
    evaluated stage-1 iteration count k; `info`, if given, receives the chosen ``sigma_r``, ``normal_iterations``
    and (rule "sure") the list ``risk`` of (σ_r, k, estimate in m²).
    """
    from physar.geometry.denoise import SurfaceOps, directed_edges

    st = settings or NormalFilterSettings()
    _check(st)
    ops = SurfaceOps.from_mesh(mesh)  # validates the surface
    q0 = mesh.points.astype(float)
    origin = q0.mean(axis=0)
    _, v0, _ = ops.geometry((q0 - origin).astype(np.float32))
    src, dst = directed_edges(ops.edges)
    ff = _face_graph(mesh)
    nf, area, cen = _face_geometry(q0, mesh.faces)

    def reconstruct(y: np.ndarray, nfk: np.ndarray, k: int, sr: float) -> np.ndarray:  # stages 2-3 after k
        w = feature_weights(mesh.faces, nfk, area, src, dst, len(y), st.sigma_w)
        q = taubin_weighted(y, w, st.smooth_iterations)
        n2, a2, c2 = _face_geometry(q, mesh.faces)  # stage 1 again, on the smoothed surface, ceil(k/2) times
        n2 = filter_normals(n2, a2, c2, ff, sr, (k + 1) // 2, st.guided)
        return update_vertices(q, mesh.faces, n2, st.vertex_iterations)

    counts = [c for c in CHECKPOINTS if c <= st.max_normal_iterations] or [st.max_normal_iterations]
    if st.normal_iterations is not None:
        k = st.normal_iterations
        sr = st.sigma_r if st.sigma_r is not None else st.sigma_r_candidates[-1]
        q = reconstruct(q0, filter_normals(nf, area, cen, ff, sr, k, st.guided), k, sr)
        if progress is not None:
            progress(st.normal_iterations, q)
    elif st.rule == "discrepancy":
        target = st.discrepancy * noise_scale(mesh) / MAD_RATIO
        q, done = q0, 0
        sr = st.sigma_r if st.sigma_r is not None else st.sigma_r_candidates[-1]
        for k in counts:
            nf = filter_normals(nf, area, cen, ff, sr, k - done, st.guided)
            done = k
            q = reconstruct(q0, nf, k, sr)
            if progress is not None:
                progress(k, q)
            if residual_normal_rms(q0, q, mesh.faces) >= target:
                break
    else:  # Stein's unbiased estimate of the face-tilt risk (module doc), over k and the σ_r candidates
        sigma = SURE_NOISE_FACTOR * noise_scale(mesh) / MAD_RATIO
        probe = np.random.default_rng(0).standard_normal(q0.shape)
        eps = EPS_FD * sigma
        sr0 = st.sigma_r if st.sigma_r is not None else max(st.sigma_r_candidates)
        qref = reconstruct(q0, filter_normals(nf, area, cen, ff, sr0, 1, st.guided), 1, sr0)
        tilt = FaceTilt(mesh.faces, _face_geometry(qref, mesh.faces)[0])  # normals not those of the noisy input
        ap = tilt(probe)
        yp = q0 + eps * probe
        nfp0, areap, cenp = _face_geometry(yp, mesh.faces)
        best, q = np.inf, q0
        for sr in st.sigma_r_candidates if st.sigma_r is None else (st.sigma_r,):
            nfk, nfp, done, since, low = nf, nfp0, 0, 0, np.inf
            for k in counts:
                nfk = filter_normals(nfk, area, cen, ff, sr, k - done, st.guided)
                nfp = filter_normals(nfp, areap, cenp, ff, sr, k - done, st.guided)
                done = k
                qk = reconstruct(q0, nfk, k, sr)
                qp = reconstruct(yp, nfp, k, sr)
                if progress is not None:
                    progress(k, qk)
                risk = sure_tilt(tilt, q0, qk, qp, ap, eps, sigma)
                if info is not None:
                    info.setdefault("risk", []).append((sr, k, risk))
                if risk < best:
                    best, q = risk, qk
                    if info is not None:
                        info.update(sigma_r=sr, normal_iterations=k)
                if risk < low:
                    low, since = risk, 0
                else:
                    since += 1
                    if since >= st.patience:
                        break
    if st.preserve_volume and v0 is not None:
        n, vol, area_tot = ops.geometry((q - origin).astype(np.float32))
        if area_tot:
            q = q + ((v0 - vol) / area_tot) * n.astype(float)
    return mesh.with_points(q)
