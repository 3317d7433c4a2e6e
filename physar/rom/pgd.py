"""Intrusive PGD for K u = sum_k f_k g_k(mu), one parameter on a 1-D grid (seed 000 §3).

Greedy rank-one enrichment u_n = u_{n-1} + F_n G_n(mu), with F_n, G_n found by the
alternating-direction fixed point:
  F-step: (G.W G) K F = sum_k f_k (g_k.W G) - sum_i K F_i (G_i.W G)
  G-step: G(mu_q) = F.(sum_k f_k g_k(mu_q) - sum_i K F_i G_i(mu_q)) / (F.K F)
with W the trapezoidal quadrature weights of the parameter grid.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from physar.rom._threads import single_blas_thread
from physar.rom.separated import SeparatedModel


def _trapz_weights(x):
    w = np.zeros_like(x)
    d = np.diff(x)
    w[:-1] += d / 2
    w[1:] += d / 2
    return w


def pgd_linear(K, f, g, grid, max_modes=20, tol=1e-4, max_fp=50, fp_tol=1e-6, solve=None,
               name="mu", unit="", progress=None):
    """Build a SeparatedModel for K u = sum_k f[k] g[k](mu) (f: (r, n), g: (r, n_grid) on grid).

    Stops when the relative mode amplitude ||F_n|| ||G_n|| / (||F_1|| ||G_1||) < tol.
    Returns (model, info) with info["amplitudes"]. ``progress(n, max_modes)`` after each mode.
    Runs with one BLAS thread (see :mod:`physar.rom._threads`).
    """
    with single_blas_thread():
        return _pgd_linear(K, f, g, grid, max_modes, tol, max_fp, fp_tol, solve, name, unit, progress)


def _pgd_linear(K, f, g, grid, max_modes, tol, max_fp, fp_tol, solve, name, unit, progress):
    f = np.atleast_2d(np.asarray(f, float))
    g = np.atleast_2d(np.asarray(g, float))
    grid = np.asarray(grid, float)
    w = _trapz_weights(grid)
    if solve is None:
        lu = spla.splu(K.tocsc())
        solve = lu.solve
    Fs, Gs, KFs, amps = [], [], [], []
    for _ in range(max_modes):
        G = np.ones_like(grid)
        F = None
        for _ in range(max_fp):
            gw = g @ (w * G)
            rhs = f.T @ gw
            if Fs:
                rhs -= np.array(KFs).T @ (np.array(Gs) @ (w * G))
            F = solve(rhs / (G @ (w * G)))
            KF = K @ F
            Gnew = (F @ f.T) @ g
            if Fs:
                Gnew -= (np.array(KFs) @ F) @ np.array(Gs)
            Gnew /= F @ KF
            delta = np.linalg.norm(Gnew * np.linalg.norm(F) - G * np.linalg.norm(F)) / max(
                np.linalg.norm(Gnew) * np.linalg.norm(F), 1e-300)
            G = Gnew
            if delta < fp_tol:
                break
        # normalise: F unit norm, amplitude in G
        nF = np.linalg.norm(F)
        F, G = F / nF, G * nF
        Fs.append(F)
        Gs.append(G)
        KFs.append(K @ F)
        amps.append(np.linalg.norm(G * np.sqrt(w)))
        if progress:
            progress(len(Fs), max_modes)
        if amps[-1] < tol * amps[0]:
            break
    model = SeparatedModel(np.array(Fs), [grid], [np.array(Gs)], [name], [unit])
    return model, {"amplitudes": np.array(amps)}
