r"""Linear and nonlinear static solvers.

Linear systems :math:`K u = f` on the free dofs (:math:`u = 0` or :math:`u_D` on the fixed ones) are solved by
one of:

* ``direct``: sparse Cholesky, CHOLMOD (scikit-sparse) when available, factored once and re-solved many
  times; otherwise scipy's SuperLU with a warning. A matrix that is not positive definite (a tangent past
  a limit point) falls back to LU. Time grows as about :math:`N^{1.8}` and memory as :math:`N^{1.2}` on 3-D
  meshes.
* ``amg``: conjugate gradients preconditioned by one V-cycle of smoothed-aggregation algebraic multigrid
  (pyamg, energy-minimising prolongation smoothing), with the six rigid-body modes of elasticity
  (3 translations, 3 infinitesimal rotations :math:`\omega \times (x - \bar x)` per node) as near-nullspace;
  stops at :math:`|K u - f| \le \mathrm{rtol}\, |f|`. Time and memory grow about linearly in :math:`N`.
* ``auto``: ``amg`` from :data:`AMG_MIN_DOFS` free dofs on (measured crossover, benchmarks/RESULTS.md)
  or when the direct factor would need more than half of the available memory, else ``direct``.

`solve_static` solves :math:`R(u) = f_{\mathrm{int}}(u) - \lambda f_{\mathrm{ext}} = 0` by Newton–Raphson,
:math:`K(u)\, \Delta u = -R(u)`, with

* a line search: the full step unless it inverts elements or raises :math:`|R|` a thousandfold; then a search
  on the total potential :math:`\Pi(u) = E(u) - \lambda f_{\mathrm{ext}} \cdot u` along :math:`\Delta u`,
  :math:`\alpha` making the directional derivative :math:`g(\alpha) = \Delta u \cdot R(u + \alpha \Delta u)`
  small, :math:`|g(\alpha)| \le 0.5\, |g(0)|` (regula falsi on :math:`g`);
* automatic load-step control: :math:`\lambda` advances by :math:`\Delta\lambda \le 1/\mathrm{steps}`; a step
  that fails is retried with :math:`\Delta\lambda / 4`, a step that converges in few iterations lets
  :math:`\Delta\lambda` grow (x2); each step starts from a secant predictor;
* the stopping test :math:`|R_{\mathrm{free}}| \le \mathrm{tol} \cdot \max(\lambda |f_{\mathrm{ext}}|,
  |f_{\mathrm{int}}(u)|)` (:math:`f_{\mathrm{int}}` over all dofs, i.e. including the reactions), or, once
  Newton stagnates, :math:`|R_{\mathrm{free}}| \le 10\, \varepsilon\, \|\operatorname{diag} K_{ff}\|\, h`: the
  round-off of :math:`f_{\mathrm{int}}` (:math:`\varepsilon` machine epsilon, :math:`h` the cube root of the mean
  element volume x 6), so tiny loads and stiff materials converge.

`check_constraints` fails early, with a clear message, when the fixed dofs leave rigid-body modes free, piece by
piece of a mesh in several pieces (a second body, an unmerged crack or tet soup), or a node in no element free;
`check_solve_memory` refuses a solve whose estimated peak memory (:func:`estimate_solve_memory`: assembly,
matrix, direct factor or AMG hierarchy) exceeds the memory available, before anything is assembled.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from physar.errors import ConfigError, PhysarWarning, SolverError

try:  # pragma: no cover - depends on the platform
    from sksparse import cholmod as _cholmod
except (ImportError, OSError, ValueError):  # not installed, a broken shared library, or a numpy ABI mismatch
    _cholmod = None

_warned = False

# CHOLMOD's fill-reducing ordering, never METIS_NodeND: its GKlib replaces the SIGTERM/SIGABRT handlers for the
# length of the call and a SIGTERM landing there only aborts METIS (CHOLMOD falls back to AMD): the signal was
# lost and the run went on to exit 0; Python's handler is also put back one-shot (SA_RESETHAND). Instead: AMD
# below CHOLMOD_NESDIS_MIN_ROWS rows (where CHOLMOD's default keeps AMD on our 3-D meshes: 4,860 rows yes,
# 10,164 no), CHOLMOD's own nested dissection NESDIS (METIS's vertex separator and CAMD, no handler) above; its
# fill is METIS's (nnz(L) within 1 % at 35k and 79k rows; benchmarks/RESULTS.md 2026-11-26).
CHOLMOD_NESDIS_MIN_ROWS = 5000


def cholmod_ordering(n: int) -> str:
    """The CHOLMOD ordering for an n x n matrix: "amd" below ``CHOLMOD_NESDIS_MIN_ROWS``, else "nesdis"."""
    return "amd" if n < CHOLMOD_NESDIS_MIN_ROWS else "nesdis"

LINEAR_METHODS = ("auto", "direct", "amg")
# "auto" switches to AMG from this many free dofs on: the direct solve is faster below, AMG above (P1 and P2
# box cantilevers on a 2-core machine, benchmarks/RESULTS.md 2026-11-25).
AMG_MIN_DOFS = 150_000


def has_cholmod() -> bool:
    """Whether the CHOLMOD sparse Cholesky solver (scikit-sparse) is available; else scipy's SuperLU."""
    return _cholmod is not None


class Factor:
    """A factorisation of a sparse SPD (or, as fallback, general) matrix with `.solve(b)`."""

    def __init__(self, A: sp.spmatrix, method: str = "auto"):
        global _warned
        A = sp.csc_matrix(A)
        self.shape = A.shape
        self.method = None
        if method in ("auto", "cholmod") and _cholmod is not None:
            try:
                self._f = _cholmod.cholesky(A, ordering_method=cholmod_ordering(A.shape[0]))
                self.method = "cholmod"
            except _cholmod.CholmodNotPositiveDefiniteError:
                if method == "cholmod":
                    raise SolverError("the matrix is not positive definite") from None
        elif method == "cholmod":
            raise SolverError("CHOLMOD is not available (install scikit-sparse and libsuitesparse-dev)")
        if self.method is None:
            if _cholmod is None and not _warned and method == "auto":
                warnings.warn(
                    "CHOLMOD (scikit-sparse) not available: using scipy SuperLU, much slower on large "
                    "meshes. Install with: apt-get install libsuitesparse-dev && pip install 'physar[cholmod]'",
                    RuntimeWarning,
                    stacklevel=2,
                )
                _warned = True
            try:
                self._f = spla.splu(A)
            except RuntimeError as exc:
                raise SolverError(f"the system matrix is singular ({exc})") from None
            self.method = "superlu"

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = self._f(b) if self.method == "cholmod" else self._f.solve(b)
        if not np.all(np.isfinite(x)):
            raise SolverError("the linear solve produced NaN or inf (a singular system, or a stiffness too small for the "
                              "loads: check the supports and E, in Pa)")
        return x


def factorize(A: sp.spmatrix, method: str = "auto") -> Factor:
    """Factor a sparse matrix once; call `.solve(b)` as often as needed."""
    return Factor(A, method)


def rigid_body_modes(nodes: np.ndarray) -> np.ndarray:
    r"""The six rigid-body modes (3 translations, 3 small rotations :math:`\omega \times (x - \bar x)`) as
    columns (n_dofs, 6)."""
    x = nodes - nodes.mean(axis=0)
    n = len(nodes)
    R = np.zeros((n, 3, 6))
    for i in range(3):
        R[:, i, i] = 1.0
    # rotations about x, y, z: omega x r
    R[:, 1, 3], R[:, 2, 3] = -x[:, 2], x[:, 1]
    R[:, 0, 4], R[:, 2, 4] = x[:, 2], -x[:, 0]
    R[:, 0, 5], R[:, 1, 5] = -x[:, 1], x[:, 0]
    return R.reshape(3 * n, 6)


class AMGSolver:
    r""":math:`K x = b` by CG preconditioned with smoothed-aggregation AMG (pyamg), K SPD (n, n).

    `near_nullspace` (n, k): the modes K nearly annihilates, for elasticity the rigid-body modes of the
    free dofs (:func:`rigid_body_modes`); they span the coarse spaces, which is what makes the iteration
    count independent of the mesh size. When the dofs come in node triples (3 a, 3 a + 1, 3 a + 2) K is
    aggregated by 3x3 node blocks. `solve(b, rtol)` stops at :math:`|K x - b| \le \mathrm{rtol}\, |b|`;
    `iterations` lists the
    CG iterations of each solve. Raises SolverError if CG does not reach `rtol` in `maxiter` iterations
    (K not positive definite, or far too ill-conditioned).
    """

    def __init__(self, K: sp.spmatrix, near_nullspace: np.ndarray | None, rtol: float = 1e-10,
                 maxiter: int = 2000, node_blocks: bool = True):
        import pyamg

        K = sp.csr_matrix(K)
        n = K.shape[0]
        if node_blocks and n % 3 == 0:
            K = K.tobsr(blocksize=(3, 3))
        B = None if near_nullspace is None else np.ascontiguousarray(near_nullspace, dtype=float)
        self.K = K
        self.rtol = float(rtol)
        self.maxiter = int(maxiter)
        self.iterations: list[int] = []
        self.ml = pyamg.smoothed_aggregation_solver(
            K, B=B, smooth="energy", strength=("symmetric", {"theta": 0.0}), max_coarse=300,
            coarse_solver="splu")
        self._M = self.ml.aspreconditioner(cycle="V")

    def solve(self, b: np.ndarray, rtol: float | None = None, x0: np.ndarray | None = None) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        if b.ndim == 2:
            return np.column_stack([self.solve(b[:, j], rtol) for j in range(b.shape[1])])
        rtol = self.rtol if rtol is None else float(rtol)
        count = [0]

        def cb(_x):
            count[0] += 1

        x, info = spla.cg(self.K, b, x0=x0, rtol=rtol, atol=0.0, maxiter=self.maxiter, M=self._M, callback=cb)
        self.iterations.append(count[0])
        if info != 0 or not np.all(np.isfinite(x)):
            res = np.linalg.norm(b - self.K @ x) / max(np.linalg.norm(b), 1e-300)
            raise SolverError(f"AMG-preconditioned CG did not reach relative residual {rtol:.1e} in "
                              f"{count[0]} iterations ({res:.1e}): the matrix may not be positive definite; "
                              "use the direct solver")
        return x


def available_memory() -> int:
    """Bytes of memory available to a new allocation (MemAvailable of /proc/meminfo; 4 GiB if unknown)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:  # pragma: no cover - not Linux
        pass
    try:  # pragma: no cover - not Linux
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 4 << 30


def direct_memory_estimate(n: int, nnz: int) -> float:
    """Estimated peak bytes of a sparse Cholesky factor of a 3-D elasticity matrix (n free dofs, nnz
    entries): nested dissection fills L to :math:`O(n^{4/3})`; the constant is fitted to CHOLMOD's measured
    peak on box cantilevers (P1 and P2, benchmarks/RESULTS.md)."""
    return _FILL_BYTES * (nnz / max(n, 1)) * float(n) ** (4.0 / 3.0)


_FILL_BYTES = 0.6  # fitted (see direct_memory_estimate)


def choose_linear(linear: str, n: int, nnz: int) -> str:
    """'direct' or 'amg' for `linear` in {'auto', 'direct', 'amg'} and a system of n free dofs, nnz entries."""
    if linear not in LINEAR_METHODS:
        raise ConfigError(f"linear solver must be one of {', '.join(LINEAR_METHODS)}, got {linear!r}")
    if linear != "auto":
        return linear
    if n >= AMG_MIN_DOFS or direct_memory_estimate(n, nnz) > 0.5 * available_memory():
        return "amg"
    return "direct"


# Peak memory of a solve, measured with tracemalloc on P1 and P2 box cantilevers (2026-11-28, 9k-32k nodes):
#: assembling K: the element matrices, their COO indices and the CSR conversion, 39-53 B per element-matrix
#: entry (m (3 nen)^2 entries: 900 per P2 element, so about 45 kB per P2 element)
ASSEMBLY_BYTES_PER_ENTRY = 56.0
#: extracting K_ff = K[free][:, free] (two CSR copies): 36-40 B per entry of K
EXTRACT_BYTES_PER_NNZ = 40.0
#: a CSR matrix: a float64 value and an int32 column index per entry
CSR_BYTES_PER_NNZ = 12.0
#: the AMG hierarchy (smoothed aggregation, energy-minimising smoothing) and CG vectors: 40-74 B per entry of K_ff
AMG_BYTES_PER_NNZ = 80.0


def estimate_nnz(element: str, n_vertices: int, n_nodes: int, n_cells: int) -> int:
    r"""Estimated entries of the assembled stiffness matrix K (all dofs) of a tetrahedral mesh, from counts only.

    Nodes a, b couple when an element holds both: :math:`\mathrm{nnz} = 9\,(N + 2P)` with P the node pairs.
    With V vertices, E edges, F faces, T tetrahedra and Euler's relation for a solid, :math:`E \approx V + T`,
    :math:`F \approx E + T - V` (boundary terms dropped: 2-5 % low on compact meshes, up to 20 % on thin ones):
    P1 pairs are the edges, :math:`P = E`; P2 (N = V + E, so E is exact) pairs are :math:`3E + 9T + 3F`
    (vertex-vertex E, vertex-edge node 2E + 6T, edge-edge nodes 3 per face and 3 opposite pairs per
    tetrahedron). Measured: 1-4 % below the
    assembled nnz on box meshes of 30k-100k dofs, up to 20 % on meshes of one or two cells across
    (tests/fem/test_disconnected_pieces.py).
    """
    V, N, T = int(n_vertices), int(n_nodes), int(n_cells)
    if element == "P1":
        E = V + T
        pairs = E
    else:
        E = max(N - V, 0)
        F = max(E + T - V, 0)
        pairs = 3 * E + 9 * T + 3 * F
    return 9 * (N + 2 * pairs)


def estimate_solve_memory(space, n_free: int, linear: str = "auto", assembled: bool = False) -> dict:
    """Estimated peak memory of a static solve on `space` (an FESpace) with `n_free` free dofs, before anything is
    assembled: ``{"dofs", "nnz", "linear", "bytes", "assembly", "factor"}`` (bytes; "linear" is the solver
    :func:`choose_linear` picks with the estimated nnz).

    The phases run one after another, so the peak is the largest of: assembly (``ASSEMBLY_BYTES_PER_ENTRY`` per
    element-matrix entry; 0 when K is already `assembled`), K plus the extraction of K_ff, K plus K_ff plus the
    solver: the direct factor (:func:`direct_memory_estimate`, nested-dissection fill fitted to CHOLMOD) or the
    AMG hierarchy (``AMG_BYTES_PER_NNZ`` per entry of K_ff). Rough, within a factor of about 1.5 (the fill of
    the factor is a fit, not a symbolic analysis)."""
    n = int(space.n_dofs)
    nen = space.cells.shape[1]
    nnz = estimate_nnz(space.element, space.mesh.n_points, space.n_nodes, len(space.cells))
    nnz_ff = nnz * (n_free / max(n, 1))
    kind = choose_linear(linear, n_free, int(nnz_ff))
    factor = direct_memory_estimate(n_free, nnz_ff) if kind == "direct" else AMG_BYTES_PER_NNZ * nnz_ff
    assembly = 0.0 if assembled else ASSEMBLY_BYTES_PER_ENTRY * len(space.cells) * (3 * nen) ** 2
    K = CSR_BYTES_PER_NNZ * nnz
    peak = max(assembly, K + EXTRACT_BYTES_PER_NNZ * nnz, K + CSR_BYTES_PER_NNZ * nnz_ff + factor)
    return {"dofs": n_free, "nnz": nnz, "linear": kind, "bytes": peak, "assembly": assembly, "factor": factor}


def check_solve_memory(model, n_free: int, linear: str = "auto") -> None:
    """Refuse, with one ConfigError line, a solve whose estimated peak memory (:func:`estimate_solve_memory`)
    exceeds the memory available now (:func:`physar.output.available_memory`, the one of every check_memory),
    before anything is assembled; the line gives the dofs, the estimate, and what would need less."""
    from physar import output

    _size = output._size
    space = model.space
    est = estimate_solve_memory(space, n_free, linear, assembled=getattr(model, "_K_linear", None) is not None)
    avail = output.available_memory()
    if est["bytes"] <= avail:
        return
    hints = ["a coarser mesh"]
    if space.element == "P2":
        hints.append(f"P1 elements ([fem] element = \"P1\": about {space.mesh.n_points * 3:,} dofs)")
    if est["linear"] == "direct":
        amg = estimate_solve_memory(space, n_free, "amg", assembled=est["assembly"] == 0)["bytes"]
        hints.append(f"the iterative solver ([solver] linear = \"amg\", about {_size(amg)})")
    raise ConfigError(
        f"the {space.element} problem of {n_free:,} free dofs ({len(space.cells):,} elements, about "
        f"{est['nnz']:,} matrix entries) needs about {_size(est['bytes'])} of memory with the {est['linear']} "
        f"solver (assembly {_size(est['assembly'])}, {'factor' if est['linear'] == 'direct' else 'AMG'} "
        f"{_size(est['factor'])}), more than the {_size(avail)} available: use {' or '.join(hints)}")


_MODE_NAMES = ["translation x", "translation y", "translation z", "rotation x", "rotation y", "rotation z"]


def dof_indices(dofs, n_dofs: int, name: str = "fixed") -> np.ndarray:
    """`dofs` as sorted unique int64 dof indices in [0, `n_dofs`): the one reading of constrained dofs.

    Accepts integer indices (a list or array of any shape, or integer-valued floats such as 3.0) or a boolean
    mask of shape (`n_dofs`,), which selects the dofs where it is True. Raises ConfigError naming `name`, the
    offending value and `n_dofs` for a negative or too large index (no wrap-around, nothing dropped), a
    fractional or non-finite float, a mask of another length, or anything else (strings, None entries).
    """
    try:
        a = np.asarray(dofs)
    except (TypeError, ValueError) as e:  # ragged nesting
        raise ConfigError(f"{name} must be dof indices or a boolean mask of {n_dofs} dofs, got {dofs!r}") from e
    if a.dtype == bool:
        if a.shape != (n_dofs,):
            raise ConfigError(f"{name}: a boolean mask must have shape ({n_dofs},) (one entry per dof), "
                              f"got shape {a.shape}")
        return np.flatnonzero(a).astype(np.int64)
    if a.size == 0:
        return np.zeros(0, np.int64)
    if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise ConfigError(f"{name} must be integer dof indices or a boolean mask, got {a.dtype} values "
                          f"({a.ravel()[0].item()!r}, ...)")
    a = a.ravel()
    if np.issubdtype(a.dtype, np.floating):
        frac = ~np.isfinite(a) | (a != np.round(a))
        if frac.any():
            raise ConfigError(f"{name} must be integer dof indices, got {a[frac][0].item()!r}")
    out = (a < 0) | (a >= n_dofs)
    if out.any():
        raise ConfigError(f"{name}: dof index {a[out][0].item():.0f} is out of range 0..{n_dofs - 1} "
                          f"(the model has {n_dofs} dofs)")
    return np.unique(a.astype(np.int64))


def mesh_pieces(n_nodes: int, cells: np.ndarray) -> tuple[int, np.ndarray]:
    """The connected pieces of a mesh: elements sharing a node belong to one piece.

    Returns (number of pieces, label of each node in 0..pieces-1, -1 for a node in no element). Cost: one
    sparse connected-components pass over the element vertices (3 edges per element)."""
    from scipy.sparse.csgraph import connected_components

    cells = np.asarray(cells)
    v = cells[:, :4]  # the vertices carry the connectivity; P2 edge nodes lie in the elements of their edge
    m = len(v)
    g = sp.csr_matrix((np.ones(3 * m, np.int8), (np.repeat(v[:, 0], 3), v[:, 1:4].ravel())),
                      shape=(n_nodes, n_nodes))
    _, vlabel = connected_components(g, directed=False)
    elem_piece = vlabel[v[:, 0]]
    used, elem_piece = np.unique(elem_piece, return_inverse=True)
    label = np.full(n_nodes, -1, np.int64)
    label[cells] = elem_piece.reshape(-1, 1)
    return len(used), label


def _gram_free_modes(nodes: np.ndarray, label: np.ndarray, pieces: int, fixed: np.ndarray):
    r"""Per piece, the rigid-body modes its fixed dofs leave free: (count (pieces,), free mask (pieces, 6),
    eigenvectors (pieces, 6, 6)).

    The six modes of each piece about its own centroid, coordinates scaled by its RMS radius (so rotations and
    translations weigh alike); the Gram matrix :math:`G_c = R_c[\text{fixed}]^T R_c[\text{fixed}]` (6 x 6) of
    every piece at once (one sparse product), its eigenvalues below :math:`10^{-12} \lambda_{\max}` (a
    singular value of :math:`R_c[\text{fixed}]` below :math:`10^{-6}` of the largest) count as free."""
    inside = label >= 0
    cnt = np.bincount(label[inside], minlength=pieces).astype(float)
    cen = np.stack([np.bincount(label[inside], nodes[inside, k], pieces) for k in range(3)], 1) / cnt[:, None]
    x = np.zeros_like(nodes, dtype=float)
    x[inside] = nodes[inside] - cen[label[inside]]
    rad = np.sqrt(np.bincount(label[inside], (x[inside] ** 2).sum(1), pieces) / cnt)
    rad[rad == 0] = 1.0
    x[inside] /= rad[label[inside], None]
    fixed = fixed[inside[fixed // 3]]
    a, i = fixed // 3, fixed % 3
    r = np.zeros((len(fixed), 6))
    r[np.arange(len(fixed)), i] = 1.0
    xa = x[a]
    # rotation about axis j: (e_j x x)_i
    r[:, 3] = np.where(i == 1, -xa[:, 2], np.where(i == 2, xa[:, 1], 0.0))
    r[:, 4] = np.where(i == 0, xa[:, 2], np.where(i == 2, -xa[:, 0], 0.0))
    r[:, 5] = np.where(i == 0, -xa[:, 1], np.where(i == 1, xa[:, 0], 0.0))
    outer = (r[:, :, None] * r[:, None, :]).reshape(len(fixed), 36)
    S = sp.csr_matrix((np.ones(len(fixed)), (label[a], np.arange(len(fixed)))), shape=(pieces, len(fixed)))
    G = np.asarray(S @ outer).reshape(pieces, 6, 6)
    w, V = np.linalg.eigh(G)
    free = (w <= 1e-12 * np.maximum(w[:, -1:], 0.0)) | (w[:, -1:] <= 0)
    return free.sum(1), free, V


def _mode_names(free_k: np.ndarray, V_k: np.ndarray) -> str:
    return ", ".join(sorted({_MODE_NAMES[int(np.argmax(np.abs(V_k[:, k])))] for k in np.flatnonzero(free_k)}))


#: nodes of a free piece closer than this times the mesh size (bounding-box diagonal) to a node of another
#: piece count as coincident: the tell-tale of an unmerged mesh (a tet soup, a crack whose faces were not merged)
COINCIDENT_TOL = 1e-9


def coincident_nodes(nodes: np.ndarray, piece_nodes: np.ndarray, other_nodes: np.ndarray) -> int:
    """How many of `piece_nodes` (indices) lie within COINCIDENT_TOL x the mesh size of one of `other_nodes`."""
    from scipy.spatial import cKDTree

    if len(piece_nodes) == 0 or len(other_nodes) == 0:
        return 0
    tol = COINCIDENT_TOL * float(np.linalg.norm(np.ptp(nodes, axis=0)))
    d, _ = cKDTree(nodes[other_nodes]).query(nodes[piece_nodes], k=1, distance_upper_bound=tol * (1 + 1e-9))
    return int(np.count_nonzero(d <= tol))


def check_constraints(nodes: np.ndarray, fixed: np.ndarray, cells: np.ndarray | None = None) -> None:
    """Raise SolverError if the fixed dofs leave a rigid-body motion unconstrained (ConfigError if `fixed` is
    not a valid dof selection, see :func:`dof_indices`).

    With the elements `cells` (m, nen) node indices (pass them: without, the mesh is taken as one piece and a
    second body or an unmerged crack is missed) the test is per connected piece of the mesh (elements sharing a
    node, :func:`mesh_pieces`): each piece must be held by its own fixed dofs. The error then names how many
    pieces are free and the largest of them (elements, nodes, bounding box, free modes), and how many of its
    nodes coincide with nodes of another piece (an unmerged mesh: merge coincident nodes). A node in no element
    (no stiffness, an undefined displacement) is refused unless all its dofs are fixed. Cost: linear in the
    mesh (about 0.1 s per million elements).
    """
    nodes = np.asarray(nodes, dtype=float)
    n = len(nodes)
    fixed = dof_indices(fixed, 3 * n)
    if cells is None:
        pieces, label = 1, np.zeros(n, np.int64)
        cells = None
    else:
        cells = np.asarray(cells)
        pieces, label = mesh_pieces(n, cells)
        lone = np.flatnonzero(label < 0)
        if len(lone):
            held = np.zeros(3 * n, bool)
            held[fixed] = True
            lone = lone[~held.reshape(-1, 3)[lone].all(1)]
            if len(lone):
                a = int(lone[0])
                raise SolverError(
                    f"{len(lone)} node(s) belong to no element (node {a} at {np.round(nodes[a], 6).tolist()}): "
                    "they have no stiffness, so their displacement is undefined; remove them from the mesh "
                    "(physar's mesh readers drop such nodes)")
    if len(fixed) == 0 and pieces == 1:
        raise SolverError(
            "the model is not constrained: all 6 rigid-body modes are free; add a [[fix]] box"
        )
    count, free, V = _gram_free_modes(nodes, label, pieces, fixed)
    bad = np.flatnonzero(count > 0)
    if len(bad) == 0:
        return
    if pieces == 1:
        raise SolverError(
            f"the model is not fully constrained: {int(count[0])} rigid-body mode(s) free "
            f"({_mode_names(free[0], V[0])}); fix more nodes"
        )
    elem_piece = label[cells[:, 0]]
    n_elem = np.bincount(elem_piece, minlength=pieces)
    c = int(bad[np.argmax(n_elem[bad])])
    mine = np.flatnonzero(label == c)
    lo, hi = nodes[mine].min(0), nodes[mine].max(0)
    same = coincident_nodes(nodes, mine, np.flatnonzero((label != c) & (label >= 0)))
    what = (f"{same} of its nodes coincide with nodes of another piece (within {COINCIDENT_TOL:g} x the mesh "
            "size): an unmerged mesh, merge coincident nodes" if same else
            "no node of it coincides with another piece's")
    k = int(count[c])
    modes = "all 6 rigid-body modes free (no fixed dof)" if k == 6 else \
        f"{k} rigid-body mode(s) free ({_mode_names(free[c], V[c])})"
    raise SolverError(
        f"the mesh is in {pieces} separate pieces (elements sharing no node) and {len(bad)} of them "
        f"{'is' if len(bad) == 1 else 'are'} not fully constrained: each piece needs its own supports. The "
        f"largest free piece, {_plural(int(n_elem[c]), 'element')} and {_plural(len(mine), 'node')} in box "
        f"{np.round(lo, 6).tolist()}-{np.round(hi, 6).tolist()} m "
        f"(centroid {np.round(nodes[mine].mean(0), 6).tolist()}), "
        f"has {modes}; {what}; or hold each piece with a [[fix]] box"
    )


def _plural(k: int, word: str) -> str:
    return f"{k} {word}" + ("" if k == 1 else "s")


def _check_finite_force(f_ext: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(f_ext.reshape(len(f_ext), -1)).all(axis=1))
    if len(bad):
        raise SolverError(f"external force contains NaN or inf (first at dof {bad[0]}: {f_ext[bad[0]]})")


def _free_dofs(n: int, fixed: np.ndarray) -> np.ndarray:
    mask = np.ones(n, dtype=bool)
    mask[np.asarray(fixed, dtype=np.int64)] = False
    return np.flatnonzero(mask)


def _node_triples(free: np.ndarray) -> bool:
    """True when the free dofs are whole nodes (3 a, 3 a + 1, 3 a + 2), so K_ff has 3x3 node blocks."""
    if len(free) % 3:
        return False
    t = free.reshape(-1, 3)
    return bool(np.all(t[:, 0] % 3 == 0) and np.all(t - t[:, :1] == np.arange(3)))


class LinearSolver:
    """:math:`K u = f` with :math:`u = 0` on `fixed` for a linear model: set up once, re-solved for many
    loads.

    `linear`: 'direct' (default: one factorisation, each further load one back-substitution), 'amg' (CG
    with AMG to relative residual `rtol` per load) or 'auto' (see :func:`choose_linear`). `method` is the
    factorisation of the direct solver ('auto', 'cholmod', 'lu').
    """

    def __init__(self, model, fixed: np.ndarray, method: str = "auto", linear: str = "direct",
                 rtol: float = 1e-10):
        fixed = dof_indices(fixed, model.n_dofs)
        check_constraints(model.space.nodes, fixed, model.space.cells)
        self.n = model.n_dofs
        self.fixed = fixed
        self.free = _free_dofs(self.n, fixed)
        check_solve_memory(model, len(self.free), linear)
        K = model.tangent_stiffness()
        K_ff = K[self.free][:, self.free]
        self.linear = choose_linear(linear, len(self.free), K_ff.nnz)
        if self.linear == "direct":
            self.factor = factorize(K_ff, method)
        else:
            self.factor = AMGSolver(K_ff, rigid_body_modes(model.space.nodes)[self.free], rtol=rtol,
                                    node_blocks=_node_triples(self.free))

    def solve(self, f_ext: np.ndarray) -> np.ndarray:
        f_ext = np.asarray(f_ext, dtype=float)
        if f_ext.ndim not in (1, 2) or f_ext.shape[0] != self.n:
            raise SolverError(f"external force must have shape ({self.n},) or ({self.n}, k), got {f_ext.shape}")
        _check_finite_force(f_ext)
        squeeze = f_ext.ndim == 1
        F = f_ext.reshape(self.n, -1)
        U = np.zeros_like(F)
        U[self.free] = self.factor.solve(F[self.free]).reshape(len(self.free), -1)
        return U[:, 0] if squeeze else U


def solve_linear(model, f_ext: np.ndarray, fixed: np.ndarray, linear: str = "direct") -> np.ndarray:
    """Displacement of a linear model under `f_ext` with zero displacement on `fixed` dofs [m]."""
    return LinearSolver(model, fixed, linear=linear).solve(f_ext)


@dataclass(repr=False)
class StaticResult:
    r"""Result of a static solve: displacement and Newton history per accepted load step.

    `load_factors`: :math:`\lambda` at the end of each accepted step; `rejected_steps` /
    `rejected_iterations`: load steps cut back by the step control and the Newton iterations they cost;
    `linear_solver`: 'direct' or 'amg'; `cg_iterations`: CG iterations of each AMG solve.
    """

    u: np.ndarray
    newton_iterations: list[int] = field(default_factory=list)
    residuals: list[list[float]] = field(default_factory=list)
    converged: bool = True
    load_factors: list[float] = field(default_factory=list)
    rejected_steps: int = 0
    rejected_iterations: int = 0
    linear_solver: str = "direct"
    cg_iterations: list[int] = field(default_factory=list)

    def __repr__(self) -> str:
        """One line: dofs, convergence, load steps, Newton iterations, largest nodal displacement [m]."""
        u = np.asarray(self.u, dtype=float)
        umax = float(np.sqrt((u.reshape(-1, 3) ** 2).sum(axis=1)).max()) if u.size % 3 == 0 < u.size else np.nan
        return (f"StaticResult({u.size} dofs, {'converged' if self.converged else 'not converged'}, "
                f"{_plural(len(self.newton_iterations), 'load step')}, "
                f"{_plural(sum(self.newton_iterations), 'Newton iteration')}, "
                f"max |u| {umax:.4g} m, {self.linear_solver})")


_EPS = float(np.finfo(float).eps)
_FLOOR = 10.0  # round-off floor of |R_free|: _FLOOR ε ||diag K_ff|| h (10x the stall level measured)
_LS_ETA = 0.5        # line search: accept α once |g(α)| <= η |g(0)|
_LS_TRIALS = 10
_FULL_STEP_GROWTH = 1e3  # the full Newton step is kept while |R| grows by at most this factor
_WANDER = 1e6         # ... until |R| is this many times the best so far: then back to the best, monotone
_EASY_ITERATIONS = 5  # a load step converged within max(this, max_iter / 2) iterations doubles the next increment
_CUT = 0.25           # a failed load step is retried with this fraction of its increment
_MIN_INCREMENT = 1e-3  # ... down to this fraction of the largest increment 1/steps
_INEXACT = 1e-2       # loosest relative tolerance of an iterative (AMG) Newton solve


@dataclass
class _Attempt:
    u: np.ndarray
    history: list[float]
    converged: bool
    reason: str = ""


class _Tangent:
    """The linear solves of one static problem: K_ff x = b by 'direct' or 'amg', chosen at the first solve
    (:func:`choose_linear`) from the size of K_ff; AMG's near-nullspace are the rigid-body modes of the
    current positions X + u."""

    def __init__(self, linear: str, model, free: np.ndarray):
        self.linear = linear
        self.kind: str | None = None
        self.nodes = model.space.nodes
        self.free = free
        self.triples = _node_triples(free)
        self.cg_iterations: list[int] = []

    def solve(self, K_ff: sp.spmatrix, b: np.ndarray, u: np.ndarray, rtol: float) -> np.ndarray:
        if self.kind is None:
            self.kind = choose_linear(self.linear, K_ff.shape[0], K_ff.nnz)
        if self.kind == "direct":
            return factorize(K_ff).solve(b)
        modes = rigid_body_modes(self.nodes + u.reshape(-1, 3))[self.free]
        amg = AMGSolver(K_ff, modes, rtol=rtol, node_blocks=self.triples)
        x = amg.solve(b)
        self.cg_iterations += amg.iterations
        return x


def _line_search(model, f, u, du, free, r, rn, growth: float | None = None):
    r"""Step length :math:`\alpha` along the Newton direction :math:`\Delta u`: (u, f_int, r, |r_free|) at
    :math:`u + \alpha \Delta u`, or a reason string.

    The full step :math:`\alpha = 1` is kept unless it inverts elements (non-finite forces) or multiplies
    :math:`|R_{\mathrm{free}}|` by more than ``growth`` (default 1e3; non-monotone: on the elastica cases this
    takes 16-33 iterations where an exact line search on :math:`\Pi` crawls for 25-39, and pure Newton fails at
    :math:`\alpha = 10` with neo-Hookean). Then, for a descent direction of :math:`\Pi`
    (:math:`g(0) = \Delta u \cdot R(u) < 0`) :math:`\alpha` makes
    :math:`g(\alpha) = \Delta u \cdot R(u + \alpha \Delta u) = \mathrm{d}\Pi / \mathrm{d}\alpha` small,
    :math:`|g(\alpha)| \le \eta\, |g(0)|`, by regula falsi on :math:`g` with bisection where a trial inverts
    elements (non-finite forces); the full step is kept when :math:`g(1)` is still negative. Otherwise (tangent
    not positive definite) the first of :math:`\alpha = 1, 1/2, 1/4, \dots` that lowers :math:`|R_{\mathrm{free}}|`.
    """
    def trial(a):
        ut = u + a * du
        fi = model.internal_force(ut)
        return ut, fi, fi - f

    ut, fi, rt = trial(1.0)
    rnt = float(np.linalg.norm(rt[free]))
    if np.isfinite(rnt) and rnt <= (_FULL_STEP_GROWTH if growth is None else growth) * rn:
        return ut, fi, rt, rnt
    g0 = float(du[free] @ r[free])
    if not g0 < 0:
        a = 1.0
        for _ in range(_LS_TRIALS):
            ut, fi, rt = trial(a)
            rnt = float(np.linalg.norm(rt[free]))
            if np.isfinite(rnt) and rnt < rn:
                return ut, fi, rt, rnt
            a *= 0.5
        return ("the tangent stiffness is not positive definite and no step along the Newton direction lowers "
                "the residual: the load is past a limit point (buckling or snap-through); prescribe a "
                "displacement instead of the load, or load a slightly imperfect geometry")
    lo, glo, hi, ghi = 0.0, g0, None, None
    a, best = 1.0, None
    for _ in range(_LS_TRIALS):
        ut, fi, rt = trial(a)
        g = float(du[free] @ rt[free])
        if not np.isfinite(g):  # an element inverted: the minimum along Δu lies before a
            hi, ghi = a, None
            a = lo + 0.5 * (a - lo)
            continue
        rnt = float(np.linalg.norm(rt[free]))
        if best is None or abs(g) < best[0]:
            best = (abs(g), (ut, fi, rt, rnt))
        if abs(g) <= _LS_ETA * abs(g0) or (g < 0 and hi is None):
            return ut, fi, rt, rnt
        if g < 0:
            lo, glo = a, g
        else:
            hi, ghi = a, g
        if ghi is None:
            a = 0.5 * (lo + hi)
        else:
            a = lo - glo * (hi - lo) / (ghi - glo)
            a = min(max(a, lo + 0.1 * (hi - lo)), hi - 0.1 * (hi - lo))
    if best is not None:
        return best[1]
    return ("every trial step inverts elements (det F <= 0): the load increment is far too large for the "
            "material and mesh")


def _newton(model, f, u, free, tol, max_iter, tangent: _Tangent, h: float) -> _Attempt:
    """Newton iterations on R(u) = f_int(u) - f from `u` (fixed dofs already at their values)."""
    f_int = model.internal_force(u)
    r = f_int - f
    rn = float(np.linalg.norm(r[free]))
    fnorm = float(np.linalg.norm(f[free]))
    history = [rn]
    if not np.isfinite(rn):
        return _Attempt(u, history, False, "the start point inverts elements")
    if rn <= tol * max(fnorm, float(np.linalg.norm(f_int))):
        return _Attempt(u, history, True)
    floor = 0.0
    best, growth = (rn, u, f_int, r), None
    for _ in range(max_iter):
        K = model.tangent_stiffness(u)
        K_ff = K[free][:, free]
        floor = _FLOOR * _EPS * float(np.linalg.norm(K_ff.diagonal())) * h  # round-off of f_int [N]
        scale = max(fnorm, float(np.linalg.norm(f_int)))
        # inexact Newton (iterative solver only): |K Δu + R| <= η |R| with η = |R| / scale (keeps the
        # quadratic rate), at most 1e-2, and no smaller than needed to reach tol at this iteration
        eta = min(_INEXACT, max(rn / scale, 0.1 * tol * scale / rn, 1e-12))
        du = np.zeros_like(u)
        try:
            du[free] = -tangent.solve(K_ff, r[free], u, rtol=eta)
        except SolverError as exc:
            return _Attempt(u, history, False, str(exc))
        step = _line_search(model, f, u, du, free, r, rn, growth)
        if isinstance(step, str):
            return _Attempt(u, history, False, step)
        u, f_int, r, rn = step
        history.append(rn)
        if rn <= tol * max(fnorm, float(np.linalg.norm(f_int))):
            return _Attempt(u, history, True)
        if rn <= floor and rn > 0.5 * history[-2]:  # stagnating at the round-off of f_int
            return _Attempt(u, history, True)
        if rn < best[0]:
            best = (rn, u, f_int, r)
        elif growth is None and rn > _WANDER * best[0]:
            # watchdog: the non-monotone full steps have wandered far from the best point (|R| 1e9 times it on
            # the nearly incompressible seal, at most 5e3 on the elastica): back there, monotone from now on
            rn, u, f_int, r = best
            growth = 1.0
    scale = max(fnorm, float(np.linalg.norm(f_int)))
    stalled = len(history) > 5 and min(history[-3:]) > 0.5 * min(history[:-3])
    if stalled and (rn <= 1e3 * floor or rn <= 1e-6 * scale):
        reason = (f"the residual stalled at {rn:.2e} N (relative {rn / scale:.1e}), at the round-off of the "
                  f"internal forces (about {floor:.1e} N), above tol = {tol:.0e}: raise tol")
    elif stalled:
        reason = (f"the residual stalled at {rn:.2e} N (relative {rn / scale:.1e}) over {max_iter} "
                  "iterations: the load is near a limit point (buckling) or the material law is unstable there")
    elif rn > history[0]:
        reason = f"the residual grew from {history[0]:.2e} to {rn:.2e} N in max_iter = {max_iter} iterations"
    else:
        reason = (f"the residual fell from {history[0]:.2e} to {rn:.2e} N but not to tol = {tol:.0e} relative "
                  f"in max_iter = {max_iter} iterations: raise max_iter")
    return _Attempt(u, history, False, reason)


def _element_size(model) -> float:
    r""":math:`h = (6\, |\text{mean tet volume}|)^{1/3}` [m], the edge of a cube cut into 6 such tetrahedra."""
    _, detJ = model.space.jacobians
    return float(np.cbrt(np.mean(np.abs(detJ))))


def _warn_p1_locking(model, u: np.ndarray) -> None:
    """PhysarWarning when a nonlinear P1 model bends far: the element rotations spread by more than 0.1 rad
    about their mean while the stretches stay 3x smaller, i.e. large-deflection bending, where linear
    tetrahedra lock (their constant strain cannot bend without spurious shear)."""
    from physar.fem.materials import polar

    if model.space.element != "P1" or model.linear:
        return
    R, S = polar(model.deformation_gradient(u)[:, 0])
    Rm, _ = polar(R.mean(axis=0))
    spread = np.arccos(np.clip((np.einsum("mij,ij->m", R, Rm) - 1.0) / 2.0, -1.0, 1.0))
    strain = np.abs(np.linalg.eigvalsh(S) - 1.0).max()
    if spread.max() > 0.1 and spread.max() > 3.0 * strain:
        warnings.warn(PhysarWarning(
            f"P1 tetrahedra lock in bending: this large deflection (element rotations spread over "
            f"{np.degrees(spread.max()):.0f} deg about their mean, strains below {100 * strain:.1f} %) is "
            "too stiff, typically by tens of percent; use P2 elements"), stacklevel=3)


def solve_static(
    model,
    f_ext: np.ndarray,
    fixed: np.ndarray,
    steps: int = 1,
    u0: np.ndarray | None = None,
    tol: float = 1e-10,
    max_iter: int = 50,
    progress: Callable[[int, int], None] | None = None,
    prescribed: np.ndarray | None = None,
    linear: str = "auto",
) -> StaticResult:
    r"""Static equilibrium :math:`f_\text{int}(u) = f_\text{ext}` on the free dofs, :math:`u = u_D` on `fixed`
    (Newton, line search, automatic load steps; see the module docstring).

    `prescribed` (shape (n_dofs,), only its entries at `fixed` are used; default 0) gives :math:`u_D`, the
    Dirichlet values, e.g. a rigid rotation of a clamped lever. Load factor :math:`\lambda` runs from 0 to 1
    in increments of at most 1/`steps` (cut back on failure, grown on easy steps); each step applies
    :math:`\lambda f_\text{ext}` and :math:`\lambda u_D`. Convergence:

    .. math::

        |R_\text{free}| \le \mathtt{tol} \cdot \max(\lambda |f_\text{ext}|, |f_\text{int}(u)|, \mathtt{tiny}),

    or the round-off floor once Newton stagnates. For a linear model one solve. `linear`: 'auto' | 'direct' |
    'amg' (the linear solver, see :func:`choose_linear`). `progress(step, steps)` is called as :math:`\lambda`
    passes k / steps.
    Raises SolverError naming the cause if even a small load increment does not converge.
    """
    f_ext = np.asarray(f_ext, dtype=float)
    n = model.n_dofs
    fixed = dof_indices(fixed, n)
    if f_ext.shape != (n,):
        raise SolverError(f"external force must have shape ({n},), got {f_ext.shape}")
    _check_finite_force(f_ext)
    if steps < 1:
        raise SolverError(f"load steps must be >= 1, got {steps}")
    if linear not in LINEAR_METHODS:
        raise ConfigError(f"linear solver must be one of {', '.join(LINEAR_METHODS)}, got {linear!r}")
    if prescribed is None:
        u_d = np.zeros(n)
    else:
        u_d = np.asarray(prescribed, dtype=float)
        if u_d.shape != (n,):
            raise SolverError(f"prescribed displacements must have shape ({n},), got {u_d.shape}")
        if not np.all(np.isfinite(u_d[fixed])):
            raise SolverError("prescribed displacements contain NaN or inf")
    check_constraints(model.space.nodes, fixed, model.space.cells)
    free = _free_dofs(n, fixed)
    check_solve_memory(model, len(free), linear)
    u = np.zeros(n) if u0 is None else np.array(u0, dtype=float)
    if u.shape != (n,) or not np.all(np.isfinite(u)):
        raise SolverError(f"u0 must be a finite displacement of shape ({n},), got shape {u.shape}"
                          + ("" if u.shape != (n,) else " with NaN or inf"))
    u[fixed] = 0.0
    tangent = _Tangent(linear, model, free)
    if model.linear:
        u[fixed] = u_d[fixed]
        K = model.tangent_stiffness(u)
        r = model.internal_force(u) - f_ext
        u[free] -= tangent.solve(K[free][:, free], r[free], u, rtol=tol)
        res = np.linalg.norm((model.internal_force(u) - f_ext)[free])
        if progress:
            progress(1, 1)
        return StaticResult(u, [1], [[float(res)]], load_factors=[1.0], linear_solver=tangent.kind,
                            cg_iterations=tangent.cg_iterations)

    result = StaticResult(u)
    h = _element_size(model)
    dlam_max = 1.0 / steps
    dlam, lam, u_prev, dlam_prev, shown = dlam_max, 0.0, None, None, 0
    while lam < 1.0:
        dlam = min(dlam, 1.0 - lam)
        lam_t = 1.0 if 1.0 - (lam + dlam) < 1e-12 else lam + dlam
        start = u.copy()
        if u_prev is not None:  # secant predictor along the last converged step
            start[free] += (lam_t - lam) / dlam_prev * (u[free] - u_prev[free])
        start[fixed] = lam_t * u_d[fixed]
        att = _newton(model, lam_t * f_ext, start, free, tol, max_iter, tangent, h)
        if not att.converged and u_prev is not None:  # the predictor may overshoot: retry from u
            start = u.copy()
            start[fixed] = lam_t * u_d[fixed]
            result.rejected_iterations += len(att.history) - 1
            att = _newton(model, lam_t * f_ext, start, free, tol, max_iter, tangent, h)
        its = len(att.history) - 1
        if not att.converged:
            result.rejected_steps += 1
            result.rejected_iterations += its
            dlam = (lam_t - lam) * _CUT
            if dlam < _MIN_INCREMENT * dlam_max:
                raise SolverError(
                    f"Newton did not converge at load factor {lam_t:.3g} even with the load increment cut "
                    f"to {lam_t - lam:.2g}: {att.reason}")
            continue
        u_prev, u, dlam_prev, lam = u, att.u, lam_t - lam, lam_t
        result.newton_iterations.append(its)
        result.residuals.append(att.history)
        result.load_factors.append(lam)
        if its <= max(_EASY_ITERATIONS, max_iter // 2):
            dlam = min(2.0 * dlam_prev, dlam_max)
        while progress and shown < steps and lam >= (shown + 1) / steps - 1e-12:
            shown += 1
            progress(shown, steps)
    result.u = u
    result.linear_solver = tangent.kind or "direct"
    result.cg_iterations = tangent.cg_iterations
    _warn_p1_locking(model, u)
    return result
