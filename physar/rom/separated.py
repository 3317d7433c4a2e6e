"""Separated parametric models u(x, mu) = sum_i F_i(x) prod_j G_i^j(mu_j) (seed 000, §2.2 and §4).

Displacements in m, parameters in the units given by ``units``.
"""
from __future__ import annotations

import os
import tempfile

import numpy as np
from scipy.interpolate import CubicSpline

from physar.errors import PhysarError

FORMAT_VERSION = 1


class SeparatedModel:
    """u(mu) = sum_i F_i prod_j G_i^j(mu_j) with F (n_modes, n_dof) and G^j (n_modes, n_grid_j).

    The 1-D parameter modes are interpolated by cubic splines, so du/dmu_j (seed 000 §4,
    sensitivities for the Gauss-Newton/LM update) is the exact derivative of the interpolant.
    """

    def __init__(self, F, grids, G, names, units=None, metadata=None):
        F = np.asarray(F, float)
        if F.ndim != 2:
            raise PhysarError(f"SeparatedModel: F must be 2-D (n_modes, n_dof), got shape {F.shape}")
        if len(grids) != len(G) or len(names) != len(G):
            raise PhysarError("SeparatedModel: grids, G and names must have one entry per parameter")
        self.F = F
        self.grids = [np.asarray(g, float) for g in grids]
        self.G = [np.asarray(g, float) for g in G]
        for j, (x, g) in enumerate(zip(self.grids, self.G)):
            if g.shape != (F.shape[0], x.size):
                raise PhysarError(f"SeparatedModel: G[{j}] has shape {g.shape}, expected {(F.shape[0], x.size)}")
            if x.size < 2 or np.any(np.diff(x) <= 0):
                raise PhysarError(f"SeparatedModel: grid of parameter {names[j]!r} must be strictly increasing")
        self.names = list(names)
        self.units = list(units) if units is not None else [""] * len(names)
        self.metadata = dict(metadata or {})
        self._splines = [CubicSpline(x, g, axis=1) for x, g in zip(self.grids, self.G)]
        self._dsplines = [s.derivative() for s in self._splines]
        self._obs = None

    @property
    def n_modes(self):
        return self.F.shape[0]

    @property
    def n_params(self):
        return len(self.names)

    @property
    def ranges(self):
        return [(float(x[0]), float(x[-1])) for x in self.grids]

    def _check_mu(self, mu):
        mu = np.atleast_1d(np.asarray(mu, float))
        if mu.shape != (self.n_params,):
            raise PhysarError(f"expected {self.n_params} parameter values {self.names}, got {mu.shape}")
        return mu

    def coefficients(self, mu):
        """Mode coefficients c_i(mu) = prod_j G_i^j(mu_j) and dc_i/dmu_j, shapes (n,), (p, n)."""
        mu = self._check_mu(mu)
        vals = np.array([s(m) for s, m in zip(self._splines, mu)])  # (p, n)
        ders = np.array([d(m) for d, m in zip(self._dsplines, mu)])
        c = np.prod(vals, axis=0)
        dc = np.empty_like(vals)
        for j in range(self.n_params):
            dc[j] = ders[j] * np.prod(np.delete(vals, j, axis=0), axis=0)
        return c, dc

    def evaluate(self, mu, observed=False):
        """u(mu) on all DOFs (or the observed DOFs set by :meth:`set_observation`)."""
        c, _ = self.coefficients(mu)
        return c @ (self._F_obs() if observed else self.F)

    def sensitivities(self, mu, observed=False):
        """du/dmu_j, shape (p, n_dof) (seed 000 §4)."""
        _, dc = self.coefficients(mu)
        return dc @ (self._F_obs() if observed else self.F)

    def set_observation(self, dofs=None, matrix=None):
        """Precompute C F^T for an observation operator: DOF indices or a (m, n_dof) matrix."""
        if matrix is not None:
            self._obs = np.asarray((matrix @ self.F.T).T)
        else:
            dofs = np.asarray(dofs, int)
            if dofs.size and (dofs.min() < 0 or dofs.max() >= self.F.shape[1]):
                raise PhysarError("observed DOF index out of range")
            self._obs = self.F[:, dofs]

    def _F_obs(self):
        if self._obs is None:
            raise PhysarError("no observation set: call set_observation() first")
        return self._obs

    def mode_amplitudes(self):
        """||F_i|| prod_j ||G_i^j||_inf, the amplitude of each mode (decreasing for a good PGD)."""
        a = np.linalg.norm(self.F, axis=1)
        for g in self.G:
            a = a * np.abs(g).max(axis=1)
        return a

    def save(self, path, mesh=None):
        """Write a .npz (format version, metadata, optional mesh checksum) atomically."""
        meta = dict(self.metadata)
        if mesh is not None:
            meta["mesh_checksum"] = mesh.checksum()
        arrays = {"format_version": np.array(FORMAT_VERSION), "F": self.F,
                  "names": np.array(self.names, dtype=str), "units": np.array(self.units, dtype=str),
                  "meta_keys": np.array(list(meta), dtype=str),
                  "meta_values": np.array([str(v) for v in meta.values()], dtype=str)}
        for j, (x, g) in enumerate(zip(self.grids, self.G)):
            arrays[f"grid_{j}"] = x
            arrays[f"G_{j}"] = g
        d = os.path.dirname(os.path.abspath(path))
        fd, tmp = tempfile.mkstemp(suffix=".npz", dir=d)
        os.close(fd)
        try:
            np.savez(tmp, **arrays)
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.remove(tmp)
            raise

    @classmethod
    def load(cls, path, mesh=None):
        try:
            z = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise PhysarError(f"{path}: cannot read reduced model ({e})") from None
        with z:
            if "format_version" not in z:
                raise PhysarError(f"{path}: not a physar reduced model (no format_version)")
            v = int(z["format_version"])
            if v != FORMAT_VERSION:
                raise PhysarError(f"{path}: reduced-model format version {v}, this physar reads {FORMAT_VERSION}")
            names = [str(s) for s in z["names"]]
            meta = dict(zip([str(k) for k in z["meta_keys"]], [str(s) for s in z["meta_values"]]))
            model = cls(z["F"], [z[f"grid_{j}"] for j in range(len(names))],
                        [z[f"G_{j}"] for j in range(len(names))], names,
                        [str(s) for s in z["units"]], meta)
        if mesh is not None and "mesh_checksum" in meta and meta["mesh_checksum"] != mesh.checksum():
            raise PhysarError(f"{path}: reduced model was built on another mesh (checksum "
                              f"{meta['mesh_checksum']} != {mesh.checksum()})")
        return model
