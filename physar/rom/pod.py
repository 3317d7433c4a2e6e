r"""POD baseline (for comparison with PGD, seed 000 §3): snapshots + SVD + interpolated coefficients.

Snapshots :math:`u(\mu_q)` on a tensor grid of the parameters are stacked as columns of :math:`S`
(n_dof x N); the thin SVD :math:`S = \Phi \Sigma V^\top` gives the spatial basis :math:`\Phi_1, \dots, \Phi_n`
(:math:`n` chosen by max_modes and the relative energy criterion
:math:`\sqrt{\sum_{i>n} \sigma_i^2 / \sum_i \sigma_i^2} \le \mathrm{tol}`) and the coefficients
:math:`a_i(\mu_q) = \sigma_i V_{qi}`. The coefficients are interpolated between grid points by cubic splines:

.. math::

    u(\mu) \approx \sum_i \Phi_i\, a_i(\mu).

With one parameter this is a SeparatedModel as it stands (:math:`F_i = \Phi_i`, :math:`G_i = a_i`). With two,
each coefficient table :math:`a_i(\mu_1, \mu_2)` is written as :math:`\sum_r s_{ir} U_{ir}(\mu_1) V_{ir}(\mu_2)`
by its own SVD (exact up to ``coef_tol``), so the result is again a SeparatedModel (:math:`\Phi_i` repeated once
per term),
and the fast assimilation path applies unchanged.
"""
from __future__ import annotations

import numpy as np

from physar.errors import ConfigError
from physar.rom._threads import blas_single_threaded
from physar.rom.separated import SeparatedModel


def pod_from_snapshots(snapshots, grids, names, units=None, max_modes=20, tol=1e-8, coef_tol=1e-12,
                       metadata=None):
    """POD model from snapshots of shape (n_dof, n_1[, n_2]) on the parameter grids.

    Returns (model, info) with info["singular_values"], info["n_modes"] (spatial POD modes) and
    info["energy_error"] (relative discarded singular-value energy).
    """
    S = np.asarray(snapshots, float)
    grids = [np.asarray(g, float) for g in grids]
    p = len(grids)
    if p not in (1, 2):
        raise ConfigError(f"POD baseline supports 1 or 2 parameters, got {p}")
    if S.shape[1:] != tuple(g.size for g in grids):
        raise ConfigError(f"snapshots have shape {S.shape}, expected (n_dof, {', '.join(str(g.size) for g in grids)})")
    n_dof = S.shape[0]
    Phi, sig, Vt = np.linalg.svd(S.reshape(n_dof, -1), full_matrices=False)
    energy = np.cumsum(sig[::-1] ** 2)[::-1]  # energy[i] = sum_{k>=i} sigma_k^2
    rel = np.sqrt(np.append(energy[1:], 0.0) / max(energy[0], 1e-300))  # discarded after i+1 modes
    n = int(min(max_modes, np.searchsorted(-rel, -tol) + 1, sig.size))
    A = sig[:n, None] * Vt[:n]  # (n, N) coefficients on the grid
    if p == 1:
        model = SeparatedModel(Phi[:, :n].T, grids, [A], names, units, metadata)
    else:
        F, G1, G2 = [], [], []
        for i in range(n):
            U, s, Wt = np.linalg.svd(A[i].reshape(grids[0].size, grids[1].size), full_matrices=False)
            r = max(1, int(np.sum(s > coef_tol * s[0])))
            for k in range(r):
                F.append(Phi[:, i])
                G1.append(U[:, k] * s[k])
                G2.append(Wt[k])
        model = SeparatedModel(np.array(F), grids, [np.array(G1), np.array(G2)], names, units, metadata)
    model.metadata.setdefault("method", "pod")
    return model, {"singular_values": sig, "n_modes": n, "energy_error": float(rel[n - 1])}


@blas_single_threaded
def build_moving_load_pod(model, fixed, path, points=60, load=(0, 0, -1.0), radius=0.04, max_modes=20,
                          tol=1e-8, progress=None):
    """POD model u(x, s) of the moving-load problem of :func:`physar.rom.elastic.build_moving_load_pgd`
    (same load, same grid of `points` positions uniform in arc length along the polyline `path`), from
    full linear solves at the grid points. Runs with one BLAS thread, as the PGD builders (2 shared cores
    at load 1-4: the block solve and the SVD of 101 snapshots of 19,683 dofs took 0.17 s on one thread,
    0.27-3.3 s with the default threads; :mod:`physar.rom._threads`)."""
    from physar.fem import LinearSolver
    from physar.rom.elastic import load_path_matrix

    if not model.linear:
        raise ConfigError("build_moving_load_pod needs a linear material; use method='pgd_nonintrusive'")
    s, B = load_path_matrix(model.space, path, points, load, radius)
    solver = LinearSolver(model, fixed)
    U = solver.solve(B)
    if progress:
        progress(points, points)
    meta = {"kind": "load_position", "path": np.asarray(path, float).tolist(),
            "load": list(map(float, load)), "radius": float(radius),
            "material": type(model.material).__name__, "method": "pod"}
    return pod_from_snapshots(U, [s], ["s"], ["m"], max_modes=max_modes, tol=tol, metadata=meta)


__all__ = ["build_moving_load_pod", "pod_from_snapshots"]
