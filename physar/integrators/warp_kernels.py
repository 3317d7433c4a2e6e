r"""NVIDIA Warp CPU kernels for co-rotated linear P1 tetrahedra (seed 001 §2, Eq. 2.1; the fast path of
:class:`physar.integrators.model.CorotatedP1Kernel`, backend 'warp').

Per element :math:`e` with shape-function gradients :math:`G_a` (:math:`a = 0, \dots, 3`) and volume :math:`V`
(all float64):

* :math:`F = I + \sum_a u_a \otimes G_a = R S` (polar decomposition by the scaled Newton iteration
  :math:`R \leftarrow \tfrac12 (g R + R^{-\top} / g)`, :math:`g = |\det R|^{-1/3}`, the same iteration and
  tolerance as :func:`physar.integrators.model.fast_polar`; an element with
  :math:`\det F \le 10^{-12} |F|^3` or not converged in 12 iterations is flagged and redone in numpy by the
  SVD polar decomposition);
* :math:`P = 2\mu (F - R) + \lambda \operatorname{tr}(S - I)\, R`, nodal forces :math:`f_a = V P G_a`;
* warped stiffness :math:`K_e = R K^0_e R^\top`, entry by entry with :math:`g_a = R G_a`:
  :math:`K_e[ai, bk] = V (\lambda\, g_{ai} g_{bk} + \mu\, g_{ak} g_{bi} + \mu\, \delta_{ik}\, G_a \cdot G_b)`,
  summed into CSR data slots;
* matrix-free product :math:`K_e x_e`: :math:`H = \sum_a (R^\top x_a) \otimes G_a`,
  :math:`\sigma = \lambda \operatorname{tr}(H)\, I + \mu (H + H^\top)`,
  :math:`y_a \mathrel{+}= V R \sigma G_a`;
* per-node frame: the polar factor of :math:`\sum_{e \ni \mathrm{node}} V_e R_e`.

Every allocation and launch names its device (``device`` of :class:`WarpCorotatedP1`, "cpu" by default;
without it Warp would use its default device, ``cuda:0`` on a machine with a GPU).  Warp runs these kernels as
compiled native loops; numpy needs several passes over (m, 12, 12) arrays
for the same work (see benchmarks/bench_integrators.py, table "SI step variants").
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physar.output import native_stderr_without

wp.config.quiet = True  # warp < 1.10
wp.config.log_level = 30  # warp >= 1.10: no banner on stdout
with native_stderr_without("Could not find or load the NVIDIA CUDA driver"):  # a CPU-only machine: no noise
    wp.init()

_f = wp.float64
DEVICE = "cpu"  # the default device of WarpCorotatedP1


@wp.func
def _polar_newton(F: wp.mat33d, tol: wp.float64):
    """(R, flag): R the polar factor of F by scaled Newton; flag 1 when F is (near) singular or inverted,
    or the iteration did not converge in 12 steps (the caller then uses the SVD polar)."""
    fro = wp.ddot(F, F)
    det = wp.determinant(F)
    R = F
    ok = int(0)  # noqa: UP018, RUF046 - warp: a dynamic (loop-mutable) int
    if det > _f(1e-12) * fro * wp.sqrt(fro):
        for _it in range(12):
            g = wp.pow(wp.abs(det), _f(-1.0) / _f(3.0))
            new = _f(0.5) * (g * R + wp.transpose(wp.inverse(R)) / g)
            d = new - R
            mx = _f(0.0)
            for i in range(3):
                for j in range(3):
                    mx = wp.max(mx, wp.abs(d[i, j]))
            R = new
            if mx <= tol:
                ok = 1
                break
            det = wp.determinant(R)
    return R, 1 - ok


@wp.kernel
def _deformation(u: wp.array(dtype=wp.vec3d), cells: wp.array2d(dtype=wp.int32),
                 G: wp.array2d(dtype=wp.vec3d), F_out: wp.array(dtype=wp.mat33d)):
    e = wp.tid()
    F = wp.identity(n=3, dtype=wp.float64)
    for a in range(4):
        F += wp.outer(u[cells[e, a]], G[e, a])
    F_out[e] = F


@wp.kernel
def _stress_forces(u: wp.array(dtype=wp.vec3d), cells: wp.array2d(dtype=wp.int32),
                   G: wp.array2d(dtype=wp.vec3d), vol: wp.array(dtype=wp.float64), lam: wp.float64,
                   mu: wp.float64, tol: wp.float64, F_out: wp.array(dtype=wp.mat33d),
                   R_out: wp.array(dtype=wp.mat33d), fe: wp.array2d(dtype=wp.vec3d),
                   flag: wp.array(dtype=wp.int32)):
    e = wp.tid()
    F = wp.identity(n=3, dtype=wp.float64)
    for a in range(4):
        F += wp.outer(u[cells[e, a]], G[e, a])
    R, bad = _polar_newton(F, tol)
    F_out[e] = F
    R_out[e] = R
    flag[e] = bad
    S = wp.transpose(R) * F
    trD = S[0, 0] + S[1, 1] + S[2, 2] - _f(3.0)
    P = _f(2.0) * mu * (F - R) + lam * trD * R
    V = vol[e]
    for a in range(4):
        fe[e, a] = V * (P * G[e, a])


@wp.kernel
def _warped_assemble(R_in: wp.array(dtype=wp.mat33d), G: wp.array2d(dtype=wp.vec3d),
                     vol: wp.array(dtype=wp.float64), lam: wp.float64, mu: wp.float64,
                     slots: wp.array2d(dtype=wp.int32), data: wp.array(dtype=wp.float64)):
    e = wp.tid()
    R = R_in[e]
    V = vol[e]
    for a in range(4):
        ga = R * G[e, a]
        for b in range(4):
            gb = R * G[e, b]
            gg = mu * wp.dot(G[e, a], G[e, b])
            for i in range(3):
                for k in range(3):
                    val = lam * ga[i] * gb[k] + mu * ga[k] * gb[i]
                    if i == k:
                        val += gg
                    s = slots[e, (a * 3 + i) * 12 + b * 3 + k]
                    if s >= 0:  # elements share slots: atomic on a GPU (on the CPU, serial: the same sum)
                        wp.atomic_add(data, s, V * val)


@wp.kernel
def _warped_matvec(x: wp.array(dtype=wp.vec3d), cells: wp.array2d(dtype=wp.int32),
                   R_in: wp.array(dtype=wp.mat33d), G: wp.array2d(dtype=wp.vec3d),
                   vol: wp.array(dtype=wp.float64), lam: wp.float64, mu: wp.float64,
                   y: wp.array(dtype=wp.vec3d)):
    e = wp.tid()
    R = R_in[e]
    RT = wp.transpose(R)
    H = wp.mat33d()
    for a in range(4):
        H += wp.outer(RT * x[cells[e, a]], G[e, a])
    tr = H[0, 0] + H[1, 1] + H[2, 2]
    sig = mu * (H + wp.transpose(H)) + lam * tr * wp.identity(n=3, dtype=wp.float64)
    M = vol[e] * (R * sig)
    for a in range(4):
        wp.atomic_add(y, cells[e, a], M * G[e, a])


@wp.kernel
def _node_accumulate(R_in: wp.array(dtype=wp.mat33d), cells: wp.array2d(dtype=wp.int32),
                     vol: wp.array(dtype=wp.float64), acc: wp.array(dtype=wp.mat33d)):
    e = wp.tid()
    M = vol[e] * R_in[e]
    for a in range(4):
        wp.atomic_add(acc, cells[e, a], M)


@wp.kernel
def _node_polar(acc: wp.array(dtype=wp.mat33d), tol: wp.float64, R_out: wp.array(dtype=wp.mat33d),
                flag: wp.array(dtype=wp.int32)):
    i = wp.tid()
    A = acc[i]
    if wp.ddot(A, A) == _f(0.0):  # a node of no element: identity frame
        R_out[i] = wp.identity(n=3, dtype=wp.float64)
        flag[i] = 0
        return
    R, bad = _polar_newton(A, tol)
    R_out[i] = R
    flag[i] = bad


def _wp(a: np.ndarray, dtype, device: str = DEVICE):
    """A warp array of the numpy array `a` on `device`: on the CPU sharing memory with `a` made C-contiguous
    (no copy), elsewhere a copy."""
    on_cpu = wp.get_device(device).is_cpu
    return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device, copy=not on_cpu)


class WarpCorotatedP1:
    """Warp buffers and launches for one mesh: `cells` (m, 4) node ids, `G` (m, 4, 3) gradients [1/m],
    `vol` (m,) [m³], Lamé `lam`, `mu` [Pa], `n_nodes`, on the Warp `device` ("cpu", the default, or
    "cuda:N"). On the CPU all results are numpy views of warp memory, overwritten by the next call of the same
    method (copy to keep); on a GPU they are host copies."""

    def __init__(self, cells, G, vol, lam: float, mu: float, n_nodes: int, tol: float = 1e-13,
                 device: str = DEVICE):
        self.device = device = wp.get_device(device).alias
        self.m = m = len(cells)
        self.n_nodes = n_nodes
        self.lam, self.mu, self.tol = float(lam), float(mu), float(tol)
        self.cells = _wp(np.asarray(cells, dtype=np.int32), wp.int32, device)
        self.G = _wp(np.asarray(G, dtype=np.float64), wp.vec3d, device)
        self.vol = _wp(np.asarray(vol, dtype=np.float64), wp.float64, device)
        self.F = wp.zeros(m, dtype=wp.mat33d, device=device)
        self.R = wp.zeros(m, dtype=wp.mat33d, device=device)
        self.fe = wp.zeros((m, 4), dtype=wp.vec3d, device=device)
        self.flag = wp.zeros(m, dtype=wp.int32, device=device)
        self.y = wp.zeros(n_nodes, dtype=wp.vec3d, device=device)
        self.acc = wp.zeros(n_nodes, dtype=wp.mat33d, device=device)
        self.Rn = wp.zeros(n_nodes, dtype=wp.mat33d, device=device)
        self.nflag = wp.zeros(n_nodes, dtype=wp.int32, device=device)
        self._slots = {}  # name -> (slots (m, 144), data buffer)

    def deformation(self, u: np.ndarray) -> np.ndarray:
        """F (m, 3, 3) at displacement u (n_nodes * 3,)."""
        u = _wp(u.reshape(-1, 3), wp.vec3d, self.device)
        wp.launch(_deformation, dim=self.m, inputs=[u, self.cells, self.G, self.F], device=self.device)
        return self.F.numpy()

    def stress_forces(self, u: np.ndarray):
        """(F, R, fe, flagged): F and its polar factor R (m, 3, 3), element nodal forces fe (m, 4, 3)
        f_a = V P G_a, and the ids of the elements left to the caller (Newton polar not applicable)."""
        wp.launch(_stress_forces, dim=self.m,
                  inputs=[_wp(u.reshape(-1, 3), wp.vec3d, self.device), self.cells, self.G, self.vol, self.lam,
                          self.mu, self.tol, self.F, self.R, self.fe, self.flag], device=self.device)
        return self.F.numpy(), self.R.numpy(), self.fe.numpy(), np.flatnonzero(self.flag.numpy())

    def set_rotations(self, R: np.ndarray) -> None:
        """Overwrite the stored element rotations (after the caller fixed flagged elements)."""
        self.R.assign(np.ascontiguousarray(R, dtype=np.float64))  # on the CPU: a copy into R's memory

    def has_slots(self, name: str) -> bool:
        return name in self._slots

    def set_slots(self, name: str, slots: np.ndarray, nnz: int) -> None:
        """Data slot of every element-matrix entry, (m, 144) in (a i, b k) order (-1 = dropped), for a
        CSR pattern with nnz entries, stored under `name`."""
        slots = np.asarray(slots, dtype=np.int32).reshape(self.m, 144)
        data = wp.zeros(int(nnz), dtype=wp.float64, device=self.device)
        self._slots[name] = (_wp(slots, wp.int32, self.device), data)

    def warped_assemble(self, name: str) -> np.ndarray:
        r"""CSR data (nnz,) of :math:`\sum_e R_e K^0_e R_e^\top` at the stored rotations, on the slots `name`."""
        slots, data = self._slots[name]
        data.zero_()
        wp.launch(_warped_assemble, dim=self.m,
                  inputs=[self.R, self.G, self.vol, self.lam, self.mu, slots, data], device=self.device)
        return data.numpy()

    def warped_matvec(self, x: np.ndarray) -> np.ndarray:
        r""":math:`\sum_e R_e K^0_e R_e^\top x` (n_nodes * 3,) at the stored rotations (a fresh array)."""
        self.y.zero_()
        wp.launch(_warped_matvec, dim=self.m,
                  inputs=[_wp(x.reshape(-1, 3), wp.vec3d, self.device), self.cells, self.R, self.G, self.vol,
                          self.lam, self.mu, self.y], device=self.device)
        return self.y.numpy().reshape(-1).copy()

    def node_frames(self):
        r"""(Rn, acc, flagged): per-node polar factors of :math:`\sum_e V_e R_e` (n_nodes, 3, 3) at the stored
        rotations, the sums themselves, and the nodes left to the caller."""
        self.acc.zero_()
        d = self.device
        wp.launch(_node_accumulate, dim=self.m, inputs=[self.R, self.cells, self.vol, self.acc], device=d)
        wp.launch(_node_polar, dim=self.n_nodes, inputs=[self.acc, self.tol, self.Rn, self.nflag], device=d)
        return self.Rn.numpy(), self.acc.numpy(), np.flatnonzero(self.nflag.numpy())
