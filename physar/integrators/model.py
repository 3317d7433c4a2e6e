r"""Dynamics models :math:`M \ddot q = f_{\mathrm{els}}(q) + f_{\mathrm{dmp}}(q, v) + f_{\mathrm{ext}}` (seed 001 §2,
Eq. 2.1).

:math:`q` is the nodal displacement vector (n_dofs,) [m], :math:`v = \dot q` [m/s]. A model gives the total
force :math:`f(q, v) = f_{\mathrm{els}}(q) + f_{\mathrm{dmp}}(q, v) + f_{\mathrm{ext}}` [N] and its
linearisation :math:`K = -\partial f / \partial q`, :math:`D = -\partial f / \partial v`, on the free dofs
(pinned dofs are held at constant values, with zero velocity).

* :class:`LinearDynamics`: constant matrices, :math:`f = -K q - D v + f_{\mathrm{ext}}` (the seed's analysis
  case, §2.1).
* :class:`SolidModel`: a physar.fem ElasticModel (any material, P1/P2) with lumped or consistent mass,
  Rayleigh damping :math:`D = \alpha M + \beta K(q)` (:math:`K` the current tangent), gravity :math:`M g`, pinned
  nodes and a penalty ground plane :math:`z = z_0`: :math:`f_z = k (z_0 - z)` on nodes below it. For the
  co-rotated material on P1 tetrahedra a fast element kernel is used: one polar decomposition :math:`F = R S`
  per element, force :math:`P = 2 \mu (F - R) + \lambda \operatorname{tr}(S - I)\, R` (identical to
  physar.fem's Corotated), and the stiffness-warping tangent :math:`R K^0 R^\top` per element (the
  :math:`\mathrm{d}R` terms are dropped: SPD, as in SOFA-class engines).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from physar.errors import ConfigError
from physar.fem.assembly import CSRPattern, ElasticModel
from physar.fem.materials import Corotated, lame, polar
from physar.fem.solvers import dof_indices
from physar.integrators.linalg import BlockRotation, FreePattern


@dataclass(repr=False)
class Linearization:
    r"""Total force :math:`f` (n,) at (q, v) and, on the free dofs, :math:`K = -\partial f / \partial q` and
    :math:`D = -\partial f / \partial v` (or None = 0).

    `rayleigh` = :math:`(\alpha, \beta)` when :math:`D = \alpha M + \beta K_{\mathrm{elastic}}` exactly (lets the
    model add matrices once).
    """

    f: np.ndarray
    K: sp.csr_matrix | None = None
    D: sp.csr_matrix | None = None
    scale: float = 0.0  # magnitude of the largest force term (for relative Newton tolerances)
    floor: float = 0.0  # round-off level of f [N] (absolute Newton tolerance)

    def __repr__(self):
        """One line: dofs of f, the matrices' shapes and non-zeros, scale and floor [N] (no arrays)."""
        def mat(A):
            return "none" if A is None else f"{A.shape[0]}x{A.shape[1]} ({A.nnz} non-zeros)"

        return (f"Linearization({np.size(self.f)} dofs, K {mat(self.K)}, D {mat(self.D)}, scale {self.scale:.4g} N, "
                f"floor {self.floor:.4g} N)")


class DynamicsModel:
    """Base class: subclasses set n_dofs, free, q_fixed, mass (n x n CSR) and implement force/linearize."""

    n_dofs: int
    free: np.ndarray
    q_fixed: np.ndarray
    mass: sp.csr_matrix
    linear: bool = False

    # -- to implement ---------------------------------------------------------------------------
    def force(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def linearize(self, q: np.ndarray, v: np.ndarray) -> Linearization:  # pragma: no cover
        raise NotImplementedError

    def energy(self, q: np.ndarray, v: np.ndarray) -> dict:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- shared ---------------------------------------------------------------------------------
    def system_matrix(self, lin: Linearization, cm: float, cd: float, ck: float) -> sp.csr_matrix:
        r""":math:`\mathtt{cm}\, M + \mathtt{cd}\, D + \mathtt{ck}\, K` on the free dofs."""
        A = cm * self.mass_ff
        if lin.K is not None and ck != 0:
            A = A + ck * lin.K
        if lin.D is not None and cd != 0:
            A = A + cd * lin.D
        return sp.csr_matrix(A)

    @property
    def mass_ff(self) -> sp.csr_matrix:
        if getattr(self, "_mass_ff", None) is None:
            self._mass_ff = restrict(self.mass, self.free)
        return self._mass_ff

    def frame(self, q: np.ndarray):
        """Per-node rotations at q for the rotated PCG preconditioner (None: no frame)."""
        return

    def kinetic(self, v: np.ndarray) -> float:
        return 0.5 * float(v @ (self.mass @ v))

    def initial_state(self, q0=None, v0=None) -> tuple[np.ndarray, np.ndarray]:
        q = np.array(self.q_fixed if q0 is None else q0, dtype=float)
        v = np.zeros(self.n_dofs) if v0 is None else np.array(v0, dtype=float)
        if q.shape != (self.n_dofs,) or v.shape != (self.n_dofs,):
            raise ConfigError(f"initial q and v must have shape ({self.n_dofs},), got {q.shape}, {v.shape}")
        fixed = np.setdiff1d(np.arange(self.n_dofs), self.free)
        q[fixed] = self.q_fixed[fixed]
        v[fixed] = 0.0
        return q, v


def restrict(A: sp.spmatrix, free: np.ndarray) -> sp.csr_matrix:
    """A[free][:, free] as CSR."""
    A = sp.csr_matrix(A)
    if len(free) == A.shape[0]:
        return A
    return A[free][:, free].tocsr()


class LinearDynamics(DynamicsModel):
    r""":math:`M q'' + D q' + K q = f_\text{ext}` with constant matrices (seed §2.1); all dofs free unless
    `fixed` given."""

    linear = True

    def __init__(self, M, K, D=None, f_ext=None, fixed=()):
        self.mass = sp.csr_matrix(np.atleast_2d(M) if not sp.issparse(M) else M, dtype=float)
        n = self.mass.shape[0]
        self.K = sp.csr_matrix(np.atleast_2d(K) if not sp.issparse(K) else K, dtype=float)
        self.D = None if D is None else sp.csr_matrix(np.atleast_2d(D) if not sp.issparse(D) else D, dtype=float)
        if self.K.shape != (n, n) or (self.D is not None and self.D.shape != (n, n)):
            raise ConfigError(f"M, K, D must all be {n} x {n}")
        self.n_dofs = n
        self.f_ext = np.zeros(n) if f_ext is None else np.asarray(f_ext, dtype=float)
        if self.f_ext.shape != (n,) or not np.all(np.isfinite(self.f_ext)):
            raise ConfigError(f"f_ext must be a finite array of shape ({n},), got shape {self.f_ext.shape}")
        self.free = np.setdiff1d(np.arange(n), dof_indices(fixed, n))
        m_diag = self.mass.diagonal()[self.free]
        if not np.all(m_diag > 0):  # also catches NaN
            k = int(np.flatnonzero(~(m_diag > 0))[0])
            raise ConfigError(f"M must be positive definite: M[{self.free[k]}, {self.free[k]}] = {m_diag[k]:g} "
                              "(a free dof needs a positive mass)")
        self.q_fixed = np.zeros(n)
        self._lin = None

    def __repr__(self):
        """One line: dofs (free), non-zeros of M and K, whether there is damping (no arrays)."""
        return (f"LinearDynamics({self.n_dofs} dofs, {len(self.free)} free, M {self.mass.nnz} non-zeros, "
                f"K {self.K.nnz} non-zeros, D {'none' if self.D is None else f'{self.D.nnz} non-zeros'})")

    def force(self, q, v):
        f = self.f_ext - self.K @ q
        if self.D is not None:
            f -= self.D @ v
        return f

    def linearize(self, q, v):
        if self._lin is None:
            self._lin = (restrict(self.K, self.free), None if self.D is None else restrict(self.D, self.free))
        K, D = self._lin
        f = self.force(q, v)
        return Linearization(f, K, D, float(max(np.linalg.norm(f), np.linalg.norm(self.f_ext))))

    def energy(self, q, v):
        kin = self.kinetic(v)
        el = 0.5 * float(q @ (self.K @ q))
        pot = -float(self.f_ext @ q)
        return {"kinetic": kin, "elastic": el, "potential": pot, "total": kin + el + pot}


# ---------------------------------------------------------------------------------------------------
# elastic force kernels
# ---------------------------------------------------------------------------------------------------
class FemKernel:
    r"""Any physar.fem ElasticModel: :math:`f_\text{int}`, exact tangent :math:`K(u)`, energy (assembled by
    physar.fem)."""

    name = "fem"

    def __init__(self, elastic: ElasticModel):
        self.elastic = elastic

    def force(self, u):
        return self.elastic.internal_force(u)

    def force_tangent(self, u):
        K = self.elastic.tangent_stiffness(u)
        self._last = (np.array(u, copy=True), K)
        return self.elastic.internal_force(u), K

    def tangent_matvec(self, u, v):
        last = getattr(self, "_last", None)
        if last is not None and np.array_equal(last[0], u):
            return last[1] @ v
        return self.elastic.tangent_stiffness(u) @ v

    def energy(self, u):
        return self.elastic.energy(u)


def _cofactor(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Cofactor matrices :math:`C` (m, 3, 3) and determinants (m,) of a batch :math:`a` (m, 3, 3):
    :math:`a^{-\top} = C / \det a`."""
    a00, a01, a02 = a[:, 0, 0], a[:, 0, 1], a[:, 0, 2]
    a10, a11, a12 = a[:, 1, 0], a[:, 1, 1], a[:, 1, 2]
    a20, a21, a22 = a[:, 2, 0], a[:, 2, 1], a[:, 2, 2]
    C = np.empty_like(a)
    C[:, 0, 0] = a11 * a22 - a12 * a21
    C[:, 0, 1] = a12 * a20 - a10 * a22
    C[:, 0, 2] = a10 * a21 - a11 * a20
    C[:, 1, 0] = a02 * a21 - a01 * a22
    C[:, 1, 1] = a00 * a22 - a02 * a20
    C[:, 1, 2] = a01 * a20 - a00 * a21
    C[:, 2, 0] = a01 * a12 - a02 * a11
    C[:, 2, 1] = a02 * a10 - a00 * a12
    C[:, 2, 2] = a00 * a11 - a01 * a10
    return C, a00 * C[:, 0, 0] + a01 * C[:, 0, 1] + a02 * C[:, 0, 2]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (length 3), broadcasting the others (cheaper than np.cross)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def fast_polar(F: np.ndarray, tol: float = 1e-13, max_iter: int = 12) -> tuple[np.ndarray, np.ndarray]:
    r"""Rotation :math:`R` and stretch :math:`S = R^\top F` of :math:`F = R S`, batched (m, 3, 3).

    Scaled Newton iteration :math:`R \leftarrow \tfrac12 (g R + R^{-\top} / g)`, :math:`g = |\det R|^{-1/3}`
    (Higham), vectorised with explicit cofactors and only the unconverged matrices iterated; elements with
    :math:`\det F \le 0` (inverted) or not converged fall back to physar.fem's SVD polar (which keeps
    :math:`\det R = +1`).
    """
    R = np.array(F, dtype=float, copy=True)
    C, det = _cofactor(R)
    bad = ~(det > 1e-12 * np.einsum("mij,mij->m", F, F) ** 1.5)
    act = np.flatnonzero(~bad)
    a, C, det = R[act], C[act], det[act]
    for _ in range(max_iter):
        if len(act) == 0:
            break
        g = np.abs(det) ** (-1.0 / 3.0)
        new = 0.5 * (g[:, None, None] * a + C / (det * g)[:, None, None])
        conv = np.abs(new - a).max(axis=(1, 2)) <= tol
        R[act] = new
        act, a = act[~conv], new[~conv]
        if len(act):
            C, det = _cofactor(a)
    fallback = np.flatnonzero(bad)
    if len(act):
        fallback = np.concatenate([fallback, act])
    if len(fallback):
        R[fallback] = polar(F[fallback])[0]
    S = np.swapaxes(R, 1, 2) @ F
    return R, 0.5 * (S + np.swapaxes(S, 1, 2))


class CorotatedP1Kernel:
    r"""Co-rotated linear P1 tetrahedra, vectorised (one polar decomposition per element).

    .. math::

        F = I + \sum_a u_a \otimes G_a = R S; \qquad f_a = V P G_a \quad \text{with} \quad
        P = 2 \mu (F - R) + \lambda \operatorname{tr}(S - I)\, R

    (this is exactly physar.fem's Corotated stress on P1). Tangent: 'exact' (with the :math:`dR` terms,
    quadratic Newton) or 'warped' :math:`K_e = R K^0_e R^\top` (stiffness warping, :math:`dR` dropped, always
    SPD), :math:`K^0_e = V B^\top C B`. Energy
    :math:`W = \mu \lvert S - I \rvert^2 + \frac{\lambda}{2} \operatorname{tr}(S - I)^2`.

    `backend` 'numpy' (vectorised numpy) or 'warp' (NVIDIA Warp CPU kernels for F, the polar
    decomposition, the forces, the warped element matrices summed straight into the CSR data, the
    matrix-free warped product and the node frames, see :mod:`physar.integrators.warp_kernels`; same
    equations, equal to round-off; the exact tangent's element matrices stay in numpy).
    """

    name = "corotated-p1"

    def __init__(self, elastic: ElasticModel, tangent: str = "exact", backend: str = "numpy"):
        if tangent not in ("exact", "warped"):
            raise ConfigError(f"tangent must be 'exact' or 'warped', got {tangent!r}")
        if backend not in ("numpy", "warp"):
            raise ConfigError(f"backend must be 'numpy' or 'warp', got {backend!r}")
        self.tangent = tangent
        self.backend = backend
        space = elastic.space
        if space.element != "P1" or not isinstance(elastic.material, Corotated):
            raise ConfigError("the fast co-rotated kernel needs P1 elements and the 'corotated' material")
        self.elastic = elastic
        self.lam, self.mu = lame(elastic.material.E, elastic.material.nu)
        G, wdet = elastic._quad  # (m, 1, 4, 3), (m, 1)
        self.G = np.ascontiguousarray(G[:, 0])  # (m, 4, 3)
        self.vol = np.ascontiguousarray(wdet[:, 0])  # (m,)
        self.cells = space.cells
        self.n = space.n_dofs
        self.dofs = space.cell_dofs
        lam, mu = self.lam, self.mu
        # K0_e[a i, b k] = V (lam G_ai G_bk + mu G_ak G_bi + mu δ_ik G_a·G_b)
        GG = np.einsum("maj,mbj->mab", self.G, self.G)
        K0 = (
            lam * np.einsum("mai,mbk->maibk", self.G, self.G)
            + mu * np.einsum("mak,mbi->maibk", self.G, self.G)
            + mu * np.einsum("mab,ik->maibk", GG, np.eye(3))
        ) * self.vol[:, None, None, None, None]
        # K0 as (m, a, i, b, k) = (m, 12, 12), and its 3 x 3 blocks K0[m, a, b] for the matrix-free product
        self.K0 = np.ascontiguousarray(K0.reshape(len(self.vol), 12, 12))
        self.K0ab = np.ascontiguousarray(K0.transpose(0, 1, 3, 2, 4))  # (m, a, b, i, k)
        self.GT = np.ascontiguousarray(np.swapaxes(self.G, 1, 2))  # (m, 3, 4)
        self._K2mu = np.ascontiguousarray((2 * mu * np.einsum("mab,ik->maibk", GG, np.eye(3))
                                           * self.vol[:, None, None, None, None]).reshape(-1, 12, 12))
        self._pattern = None
        self._last_R = None  # (u, R) of the last stress evaluation (reused by node_rotations)
        self._wk = None
        self._wk_R = None
        if backend == "warp":
            try:
                from physar.integrators.warp_kernels import WarpCorotatedP1
            except ImportError as exc:  # pragma: no cover - warp is in the ml extra
                raise ConfigError(f"backend 'warp' needs warp-lang (pip install 'physar[ml]'): {exc}") from None
            self._wk = WarpCorotatedP1(self.cells, self.G, self.vol, lam, mu, self.n // 3)

    def _F(self, u):
        ue = u.reshape(-1, 3)[self.cells]  # (m, 4, 3)
        F = np.matmul(np.swapaxes(ue, 1, 2), self.G)  # Σ_a u_a ⊗ G_a
        F[:, 0, 0] += 1.0
        F[:, 1, 1] += 1.0
        F[:, 2, 2] += 1.0
        return F

    def _stress(self, F, u=None):
        R, S = fast_polar(F)
        if u is not None:
            self._last_R = (np.array(u, copy=True), R)
        trD = np.trace(S, axis1=1, axis2=2) - 3.0
        P = 2 * self.mu * (F - R) + self.lam * trD[:, None, None] * R
        return R, S, P

    def _warp_eval(self, u):
        """F, R (cached for u) and element forces fe (m, 4, 3) by the warp kernel; elements where the
        Newton polar does not apply (inverted, near singular) are redone here as in :func:`fast_polar`."""
        F, R, fe, bad = self._wk.stress_forces(u)
        if len(bad):
            Rb, Sb = fast_polar(F[bad])  # falls back to the SVD polar for these
            R[bad] = Rb  # R is the warp buffer: the node frames and matvecs see the fix
            trD = np.trace(Sb, axis1=1, axis2=2) - 3.0
            P = 2 * self.mu * (F[bad] - Rb) + self.lam * trD[:, None, None] * Rb
            fe[bad] = np.matmul(self.G[bad], np.swapaxes(P, 1, 2)) * self.vol[bad, None, None]
        self._last_R = (np.array(u, copy=True), R.copy())
        self._wk_R = self._last_R  # the rotations the warp buffer holds
        return F, R, fe

    def _scatter(self, fe):
        return np.bincount(self.dofs.ravel(), weights=fe.ravel(), minlength=self.n)

    def _nodal(self, P):
        # f_a = V P G_a for every element: (m, 4, 3)
        return np.matmul(self.G, np.swapaxes(P, 1, 2)) * self.vol[:, None, None]

    def force(self, u):
        if self._wk is not None:
            return self._scatter(self._warp_eval(u)[2])
        _, _, P = self._stress(self._F(u), u)
        return self._scatter(self._nodal(P))

    def rotations(self, u) -> np.ndarray:
        """Element rotations :math:`R` (m, 3, 3) of the polar decomposition :math:`F(u) = R S` (cached for the
        last u)."""
        last = self._last_R
        if last is not None and np.array_equal(last[0], u):
            return last[1]
        if self._wk is not None:
            self._warp_eval(u)
            return self._last_R[1]
        R, _ = fast_polar(self._F(u))
        self._last_R = (np.array(u, copy=True), R)
        return R

    def node_rotations(self, u) -> np.ndarray:
        """Per-node rotations (n_nodes, 3, 3): polar factor of the volume-weighted sum of the element
        rotations around each node (the frame of the rotated preconditioner, see linalg.BlockRotation)."""
        if self._wk is not None:
            self._sync_warp(u)
            Rn, acc, bad = self._wk.node_frames()
            Rn = Rn.copy()
            if len(bad):
                Rn[bad] = fast_polar(acc[bad])[0]
            return Rn
        R = self.rotations(u) * self.vol[:, None, None]
        nn = self.n // 3
        acc = np.zeros((nn, 9))
        for a in range(self.cells.shape[1]):
            for c in range(9):
                acc[:, c] += np.bincount(self.cells[:, a], weights=R[:, c // 3, c % 3], minlength=nn)
        acc = acc.reshape(nn, 3, 3)
        used = np.zeros(nn, dtype=bool)
        used[self.cells.ravel()] = True
        acc[~used] = np.eye(3)
        return fast_polar(acc)[0]

    def _warped(self, R):
        r""":math:`K_e = \operatorname{blockdiag}(R)\, K^0 \operatorname{blockdiag}(R)^\top`, i.e.
        :math:`K_e[a, b] = R K^0_{ab} R^\top`, as (m, 12, 12), dof order (a, i)."""
        m = len(R)
        X = np.matmul(self.K0.reshape(m, 48, 3), np.swapaxes(R, 1, 2))  # [m, (a, j, b), l]
        return np.matmul(R[:, None], X.reshape(m, 4, 3, 12)).reshape(m, 12, 12)

    def _exact(self, R, S):
        r"""Exact element tangent (m, 12, 12): the warped part plus the :math:`\mathrm{d}R` terms of the
        co-rotated :math:`P`:

        .. math::

            \mathrm{d}P = 2\mu (\mathrm{d}F - \mathrm{d}R) + \lambda \operatorname{tr}(R^\top \mathrm{d}F)\, R
            + \lambda \operatorname{tr}(S - I)\, \mathrm{d}R, \qquad \mathrm{d}R = R\, [w]_\times,

            w = (\operatorname{tr}(S)\, I - S)^{-1} \operatorname{axial}(R^\top \mathrm{d}F - \mathrm{d}F^\top R);

        for :math:`\mathrm{d}F = e_k \otimes G_b`:
        :math:`\operatorname{axial}(\dots) = G_b \times (R^\top e_k)`, so

        .. math::

            K[ai, bk] = V \big(2\mu\, \delta_{ik}\, G_a \cdot G_b + \lambda\, g_{ai}\, g_{bk}
            + (\lambda \operatorname{tr}(S - I) - 2\mu)\, (R\, (w_{bk} \times G_a))_i\big), \qquad g_a = R G_a.
        """
        m = len(R)
        G, V = self.G, self.vol
        trS = S[:, 0, 0] + S[:, 1, 1] + S[:, 2, 2]
        A = -S
        A[:, 0, 0] += trS
        A[:, 1, 1] += trS
        A[:, 2, 2] += trS
        C, det = _cofactor(A)  # A symmetric: A⁻¹ = C / det
        Minv = C / det[:, None, None]
        cr = _cross(G[:, :, None, :], R[:, None, :, :]).reshape(m, 12, 3)  # (b, k): G_b x R[k, :]
        w = np.matmul(cr, Minv)  # rows w_bk (Minv symmetric)
        wxg = _cross(w[:, None, :, :], G[:, :, None, :])  # (m, a, (b, k), 3) = w_bk x G_a
        c = (self.lam * (trS - 3.0) - 2 * self.mu) * V
        Rw = np.matmul(wxg.reshape(m, 48, 3), np.swapaxes(R, 1, 2)) * c[:, None, None]  # [a, (b, k), i]
        K = np.ascontiguousarray(Rw.reshape(m, 4, 12, 3).transpose(0, 1, 3, 2)).reshape(m, 12, 12)
        g = np.matmul(G, np.swapaxes(R, 1, 2)).reshape(m, 12)
        K += (self.lam * V)[:, None, None] * (g[:, :, None] * g[:, None, :])
        K += self._K2mu
        return K

    def _sync_warp(self, u):
        """Make the warp buffer hold the rotations at u (the cached ones when u is the last point)."""
        last = self._last_R
        if last is not None and np.array_equal(last[0], u):
            if self._wk_R is not last:
                self._wk.set_rotations(last[1])
                self._wk_R = last
        else:
            self._warp_eval(u)

    def force_tangent(self, u):
        if self._pattern is None:
            self._pattern = CSRPattern(self.dofs, self.n)
        if self._wk is not None:
            F, R, fe = self._warp_eval(u)
            f = self._scatter(fe)
            pat = self._pattern
            if self.tangent == "warped":
                if not self._wk.has_slots("full"):
                    self._wk.set_slots("full", pat.slot, pat.nnz)
                data = self._wk.warped_assemble("full").copy()
                return f, sp.csr_matrix((data, pat.indices, pat.indptr), shape=(self.n, self.n))
            S = np.matmul(np.swapaxes(R, 1, 2), F)
            return f, pat.assemble(self._exact(R, 0.5 * (S + np.swapaxes(S, 1, 2))))
        R, S, P = self._stress(self._F(u), u)
        f = self._scatter(self._nodal(P))
        Ke = self._warped(R) if self.tangent == "warped" else self._exact(R, S)
        return f, self._pattern.assemble(Ke)

    def force_tangent_free(self, u, fp):
        """(f_int, data of the warped tangent on the free-dof pattern `fp`), assembled by the warp kernel
        straight into the restricted pattern (no full matrix); None when this kernel cannot (numpy
        backend, exact tangent, or fp not built from this kernel's pattern)."""
        if self._wk is None or self.tangent != "warped" or self._pattern is None:
            return None
        if not fp.matches_pattern(self._pattern.indptr, self._pattern.indices):
            return None
        name = ("free", id(fp))
        if not self._wk.has_slots(name):
            inv = np.full(self._pattern.nnz, -1, dtype=np.int64)
            inv[fp.sel] = np.arange(len(fp.sel))
            self._wk.set_slots(name, inv[self._pattern.slot], len(fp.sel))
        _, _, fe = self._warp_eval(u)
        return self._scatter(fe), self._wk.warped_assemble(name).copy()

    def tangent_matvec(self, u, v):
        r"""Warped tangent times :math:`v`, matrix-free:
        :math:`\sum_e \operatorname{blockdiag}(R)\, K^0_e \operatorname{blockdiag}(R)^\top v_e`."""
        if self._wk is not None:
            self._sync_warp(u)
            return self._wk.warped_matvec(v)
        R = self.rotations(u)
        ve = v.reshape(-1, 3)[self.cells]  # (m, 4, 3)
        w = np.matmul(ve, R).reshape(-1, 12, 1)  # Rᵀ v_b, as rows
        y = np.matmul(self.K0, w).reshape(-1, 4, 3)
        return self._scatter(np.matmul(y, np.swapaxes(R, 1, 2)))

    def energy(self, u):
        if self._wk is not None:
            F, R, _ = self._warp_eval(u)
            S = np.matmul(np.swapaxes(R, 1, 2), F)
            S = 0.5 * (S + np.swapaxes(S, 1, 2))
        else:
            _, S = fast_polar(self._F(u))
        D = S - np.eye(3)
        W = self.mu * np.einsum("mij,mij->m", D, D) + 0.5 * self.lam * np.trace(D, axis1=1, axis2=2) ** 2
        return float(self.vol @ W)


def make_kernel(elastic: ElasticModel, kernel: str = "auto", tangent: str = "exact", backend: str = "numpy"):
    """'auto': the fast co-rotated P1 kernel when it applies, else physar.fem assembly; 'fem'; 'corotated-p1'.

    `tangent` ('exact' | 'warped') and `backend` ('numpy' | 'warp') apply to the co-rotated P1 kernel only.
    """
    if backend not in ("numpy", "warp"):
        raise ConfigError(f"backend must be 'numpy' or 'warp', got {backend!r}")
    if kernel == "fem":
        return FemKernel(elastic)
    if kernel == "corotated-p1":
        return CorotatedP1Kernel(elastic, tangent, backend)
    if kernel != "auto":
        raise ConfigError(f"unknown kernel {kernel!r}; use auto, fem or corotated-p1")
    if elastic.space.element == "P1" and isinstance(elastic.material, Corotated):
        return CorotatedP1Kernel(elastic, tangent, backend)
    return FemKernel(elastic)


@dataclass(frozen=True)
class Ground:
    r"""Penalty ground plane :math:`z = z_0` [m] with stiffness :math:`k` [N/m per node]:
    :math:`f_z = k \max(z_0 - z, 0)`."""

    z0: float = 0.0
    stiffness: float = 1e5

    def __post_init__(self):
        if not (self.stiffness > 0 and np.isfinite(self.stiffness)):
            raise ConfigError(f"ground stiffness must be positive, got {self.stiffness}")


class SolidModel(DynamicsModel):
    r"""An elastic body (physar.fem) as a dynamics model (seed Eq. 2.1).

    .. math::

        f(q, v) = -f_\text{int}(q) - D(q)\, v + M g + f_\text{ext} + f_\text{ground}(q), \qquad
        D = \alpha M + \beta K_D(q),

    with :math:`K_D` the tangent :math:`K(q)` (physar.fem kernel) or the warped stiffness :math:`R K^0 R^\top`
    (co-rotated P1 kernel, SPD); the Newton matrix uses the stiffness tangent in place of :math:`K_D` and
    neglects :math:`(\mathrm{d}K_D / \mathrm{d}q)\, v`.
    Parameters: `fixed` pinned dofs held at `q_fixed` (default 0), `mass` 'lumped' | 'consistent',
    `rayleigh` = (:math:`\alpha` [1/s], :math:`\beta` [s]), `gravity` (3,) [m/s²], `f_ext` (n,) [N] constant,
    `ground` a :class:`Ground` or None, `kernel`, `tangent` and `backend` see :func:`make_kernel`.
    """

    def __init__(self, elastic: ElasticModel, fixed=(), q_fixed=None, mass: str = "lumped",
                 rayleigh=(0.0, 0.0), gravity=None, f_ext=None, ground: Ground | None = None,
                 kernel: str = "auto", tangent: str = "exact", backend: str = "numpy"):
        if mass not in ("lumped", "consistent"):
            raise ConfigError(f"mass must be 'lumped' or 'consistent', got {mass!r}")
        alpha, beta = (float(x) for x in rayleigh)
        if alpha < 0 or beta < 0 or not np.isfinite(alpha + beta):
            raise ConfigError(f"Rayleigh coefficients must be >= 0, got alpha={alpha}, beta={beta}")
        self.elastic = elastic
        self.space = elastic.space
        self.n_dofs = n = elastic.n_dofs
        self.kernel = make_kernel(elastic, kernel, tangent, backend)
        self.linear = bool(elastic.linear) and ground is None
        self.mass = elastic.mass_matrix(lumped=(mass == "lumped"))
        self.mass_kind = mass
        self.alpha, self.beta = alpha, beta
        fixed = dof_indices(fixed, n)
        self.fixed = fixed
        self.free = np.setdiff1d(np.arange(n), fixed)
        self.q_fixed = np.zeros(n) if q_fixed is None else np.asarray(q_fixed, dtype=float).copy()
        self.f_ext = np.zeros(n) if f_ext is None else np.asarray(f_ext, dtype=float)
        if self.f_ext.shape != (n,) or self.q_fixed.shape != (n,):
            raise ConfigError(f"f_ext and q_fixed must have shape ({n},)")
        self.gravity = None if gravity is None else np.asarray(gravity, dtype=float)
        if self.gravity is not None and (self.gravity.shape != (3,) or not np.all(np.isfinite(self.gravity))):
            raise ConfigError(f"gravity must be a finite vector (gx, gy, gz) [m/s²], got {gravity!r}")
        if self.gravity is not None:
            self.f_ext = self.f_ext + self.mass @ np.tile(self.gravity, n // 3)
        self.ground = ground
        self._K_lin = None
        self._floor = None
        self._fp = None
        self._mass_data = None

    def __repr__(self):
        """One line: the elastic model, fixed dofs, mass, Rayleigh damping, gravity [m/s^2], ground (no arrays)."""
        g = "none" if self.gravity is None else "[" + ", ".join(f"{v + 0.0:.4g}" for v in self.gravity.tolist()) + "]"
        ground = "none" if self.ground is None else f"z0={self.ground.z0:g} m"
        return (f"SolidModel({self.elastic!r}, {len(self.fixed)} fixed dofs, {self.mass_kind} mass, "
                f"rayleigh ({self.alpha:g}, {self.beta:g}), gravity {g} m/s^2, ground {ground})")

    # -- pieces ------------------------------------------------------------------------------------
    def _ground(self, q):
        """Contact force (n,), active dofs and penetration, from the node heights :math:`z = Z + q_z`."""
        g = self.ground
        z = self.space.nodes[:, 2] + q[2::3]
        pen = g.z0 - z
        active = np.flatnonzero(pen > 0)
        f = np.zeros(self.n_dofs)
        f[3 * active + 2] = g.stiffness * pen[active]
        return f, 3 * active + 2, pen[active]

    def force(self, q, v):
        f = self.f_ext - self.kernel.force(q)
        if self.alpha:
            f -= self.alpha * (self.mass @ v)
        if self.beta:
            f -= self.beta * self.kernel.tangent_matvec(q, v)
        if self.ground is not None:
            f += self._ground(q)[0]
        return f

    def _pattern_for(self, K) -> FreePattern:
        """The free-dof restriction map of the kernel's (fixed) tangent pattern, built on first use."""
        fp = self._fp
        if fp is None or not fp.matches(K):
            fp = FreePattern(K, self.free)
            self._mass_data = fp.align(self.mass_ff)
            self._fp = fp
        return fp

    def _tangent(self, q):
        """f_int(q) and the elastic tangent's data on the free-dof pattern (cached for linear models)."""
        if self.linear and self._K_lin is not None:
            return self.kernel.force(q), self._K_lin
        direct = getattr(self.kernel, "force_tangent_free", None)
        if direct is not None and self._fp is not None:
            out = direct(q, self._fp)
            if out is not None:
                return out[0], (self._fp, out[1])
        f_int, K = self.kernel.force_tangent(q)
        fp = self._pattern_for(sp.csr_matrix(K))
        out = (fp, fp.restrict_data(K))
        if self.linear:
            self._K_lin = out
        return f_int, out

    def linearize(self, q, v):
        f_int, (fp, Kd) = self._tangent(q)
        f = self.f_ext - f_int
        if self.alpha:
            f -= self.alpha * (self.mass @ v)
        if self.beta:
            f -= self.beta * self.kernel.tangent_matvec(q, v)
        Kt = Kd
        scale = max(np.linalg.norm(f_int), np.linalg.norm(self.f_ext))
        if self.ground is not None:
            fg, dofs, _ = self._ground(q)
            f += fg
            scale = max(scale, np.linalg.norm(fg))
            if len(dofs):
                pos = np.searchsorted(self.free, dofs)
                ok = (pos < len(self.free)) & (self.free[np.minimum(pos, len(self.free) - 1)] == dofs)
                Kt = Kd.copy()
                Kt[fp.diag[pos[ok]]] += self.ground.stiffness
        if self._floor is None:
            # f_int(q) is computed from F = I + grad u: its round-off is ~ eps |K| x (body size)
            ext = float(np.ptp(self.space.nodes, axis=0).max())
            self._floor = float(np.finfo(float).eps * np.linalg.norm(Kd[fp.diag]) * ext)
        lin = Linearization(f, fp.csr(Kt), None, float(scale), self._floor)
        lin.K_el = fp.csr(Kd) if self.beta else None  # elastic part, for Rayleigh damping
        lin.data = (fp, Kt, Kd)
        lin.q = q
        return lin

    def system_matrix(self, lin, cm, cd, ck):
        r""":math:`\mathtt{cm}\, M + \mathtt{cd}\, (\alpha M + \beta K_\text{el}) + \mathtt{ck}\, K` on the
        free dofs, summed on the fixed pattern's data (every call returns the same indptr/indices, so
        CHOLMOD's symbolic analysis is reused)."""
        fp, Kt, Kd = lin.data
        data = (cm + cd * self.alpha) * self._mass_data
        if ck:
            data = data + ck * Kt
        if cd and self.beta:
            data = data + (cd * self.beta) * Kd
        return fp.csr(data)

    def frame(self, q):
        """Per-node rotations of the co-rotated kernel at q as a BlockRotation on the free dofs (the
        frame of the rotated PCG preconditioner), or None for other kernels."""
        if not isinstance(self.kernel, CorotatedP1Kernel):
            return None
        return BlockRotation(self.kernel.node_rotations(q), self.free, self.n_dofs)

    def energy(self, q, v):
        r"""Kinetic :math:`\tfrac12 v^\top M v`, elastic :math:`W(q)`, potential :math:`-f_\text{ext}^\top q`
        (gravity, loads) + :math:`\tfrac12 k\, \mathrm{pen}^2` (ground) [J]."""
        kin = self.kinetic(v)
        el = self.kernel.energy(q)
        pot = -float(self.f_ext @ q)
        if self.ground is not None:
            _, _, pen = self._ground(q)
            pot += 0.5 * self.ground.stiffness * float(pen @ pen)
        return {"kinetic": kin, "elastic": el, "potential": pot, "total": kin + el + pot}
