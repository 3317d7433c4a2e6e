r"""Separated parametric models :math:`u(x, \mu) = \sum_i F_i(x) \prod_j G_i^j(\mu_j)` (seed 000, §2.2 and §4).

Displacements in m, parameters in the units given by ``units``; ``kinds`` says what each parameter is
(:data:`KIND_UNITS`: a load position, a load magnitude, a prescribed displacement, ...).

File format (``.npz``, no pickle): version 2 stores ``kinds``; version 1 files (no ``kinds``) still load,
their kinds taken from the build configuration in the metadata or, failing that, from the units.
"""
from __future__ import annotations

import json
import zipfile
from bisect import bisect_right

import numpy as np
from scipy.interpolate import CubicSpline

from physar.errors import PhysarError

#: Version of the reduced-model file (.npz) that :meth:`SeparatedModel.save` writes.
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)

#: the parameter kinds of ``physar rom build`` and their default units
KIND_UNITS = {"load_position": "m", "load_magnitude": "N", "load_offset": "m", "displacement": "m",
              "rotation": "deg", "youngs_modulus": "Pa"}


class ReducedModelError(PhysarError, ValueError):
    """A reduced-model file is unreadable, of another format version, or built on another mesh."""


class SeparatedModel:
    r"""A separated representation, :math:`u(\mu) = \sum_i F_i \prod_j G_i^j(\mu_j)`, with F (n_modes, n_dof)
    and :math:`G^j` (n_modes, n_grid_j).

    The 1-D parameter modes are interpolated by cubic splines, so :math:`\partial u / \partial \mu_j` (seed
    000 §4, sensitivities for the Gauss-Newton/LM update) is the exact derivative of the interpolant. On
    interval :math:`k` of the grid of parameter :math:`j`,

    .. math:: G_i^j(\mu) = \sum_{d=0}^{3} a_{k,d,i}\, t^{3-d}, \qquad t = \mu - x_k;

    the coefficients a are precomputed once (shape (n_intervals, 4, n_modes)), so an evaluation is a
    bisection and one (2, 4) x (4, n_modes) product (value and derivative) per parameter, in plain numpy.
    Outside the grid the end polynomials extrapolate (as scipy's CubicSpline does).
    """

    def __init__(self, F, grids, G, names, units=None, metadata=None, kinds=None):
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
        self.kinds = list(kinds) if kinds is not None else infer_kinds(self.names, self.units, self.metadata)
        if len(self.kinds) != len(self.names):
            raise PhysarError(f"SeparatedModel: {len(self.kinds)} kinds for {len(self.names)} parameters")
        # piecewise-cubic coefficients per interval, rows for t^3, t^2, t, 1: (n_int, 4, n_modes)
        self._coef = [np.ascontiguousarray(CubicSpline(x, g, axis=1).c.transpose(1, 0, 2))
                      for x, g in zip(self.grids, self.G)]
        self._knots = [x.tolist() for x in self.grids]
        self._obs = None
        self._obs_qr = None

    @property
    def n_modes(self):
        return self.F.shape[0]

    @property
    def n_params(self):
        return len(self.names)

    @property
    def ranges(self):
        return [(float(x[0]), float(x[-1])) for x in self.grids]

    def __repr__(self):
        """One line: modes, dofs, each parameter's name, grid range and unit, and the build method if recorded."""
        params = ", ".join(f"{n} in [{lo:.4g}, {hi:.4g}]" + (f" {u}" if u else "")
                           for n, u, (lo, hi) in zip(self.names, self.units, self.ranges))
        method = self.metadata.get("method")
        return (f"SeparatedModel({self.n_modes} mode{'' if self.n_modes == 1 else 's'}, {self.F.shape[1]} dofs, "
                f"{params}{'' if method is None else f', method {method}'})")

    def _check_mu(self, mu):
        try:
            mu = np.atleast_1d(np.asarray(mu, float))
        except (TypeError, ValueError):
            raise PhysarError(f"expected {self.n_params} numbers for the parameters {self.names}, got {mu!r}") from None
        if mu.shape != (self.n_params,):
            raise PhysarError(f"expected {self.n_params} parameter values {self.names}, got {mu.shape}")
        bad = ~np.isfinite(mu)
        if bad.any():  # NaN gave a NaN field silently (the spline's interval search put it in the first one)
            j = int(np.flatnonzero(bad)[0])
            raise PhysarError(f"parameter {self.names[j]!r} = {mu[j]} must be a finite number "
                              f"(its grid spans {self.ranges[j][0]:g} to {self.ranges[j][1]:g})")
        return mu

    def coefficients(self, mu):
        r"""Mode coefficients :math:`c_i(\mu) = \prod_j G_i^j(\mu_j)` and their derivatives
        :math:`\partial c_i / \partial \mu_j`, shapes (n,), (p, n)."""
        mu = self._check_mu(mu)
        return self._coeffs(mu.tolist())

    def _value_derivative(self, j, m):
        r"""(2, n_modes): :math:`G^j(m)` and :math:`\mathrm{d}G^j/\mathrm{d}\mu_j(m)` from the precomputed cubic
        coefficients."""
        x = self._knots[j]
        k = bisect_right(x, m) - 1
        k = 0 if k < 0 else (min(k, len(x) - 2))
        t = m - x[k]
        t2 = t * t
        return np.dot(((t2 * t, t2, t, 1.0), (3.0 * t2, 2.0 * t, 1.0, 0.0)), self._coef[j][k])

    def _coeffs(self, mu):
        r""":math:`c(\mu)`, :math:`\mathrm{d}c/\mathrm{d}\mu` for a list of floats (no validation; the fast path of
        the LM loop)."""
        if len(mu) == 1:
            vd = self._value_derivative(0, mu[0])
            return vd[0], vd[1:]
        vds = [self._value_derivative(j, m) for j, m in enumerate(mu)]
        if len(mu) == 2:
            (v0, d0), (v1, d1) = vds
            return v0 * v1, np.array([d0 * v1, v0 * d1])
        vals = np.array([vd[0] for vd in vds])
        c = np.prod(vals, axis=0)
        dc = np.empty_like(vals)
        for j, vd in enumerate(vds):
            dc[j] = vd[1] * np.prod(np.delete(vals, j, axis=0), axis=0)
        return c, dc

    def evaluate(self, mu, observed=False):
        r""":math:`u(\mu)` on all DOFs (or the observed DOFs set by :meth:`set_observation`)."""
        c, _ = self.coefficients(mu)
        return c @ (self._F_obs() if observed else self.F)

    def sensitivities(self, mu, observed=False):
        r""":math:`\partial u / \partial \mu_j`, shape (p, n_dof) (seed 000 §4)."""
        _, dc = self.coefficients(mu)
        return dc @ (self._F_obs() if observed else self.F)

    def set_observation(self, dofs=None, matrix=None):
        r"""Precompute :math:`C F^\top` for an observation operator: DOF indices or a (m, n_dof) matrix."""
        if matrix is not None:
            self._obs = np.asarray((matrix @ self.F.T).T)
        else:
            dofs = np.asarray(dofs, int)
            if dofs.size and (dofs.min() < 0 or dofs.max() >= self.F.shape[1]):
                raise PhysarError("observed DOF index out of range")
            self._obs = self.F[:, dofs]
        # thin QR of C F^T = Q R (m x k, k x n): the LM loop then works on k <= n_modes numbers,
        # ||y - C F^T c||^2 = ||Q^T y - R c||^2 + ||(I - Q Q^T) y||^2 (see physar.assimilation)
        Q, R = np.linalg.qr(self._obs.T)
        self._obs_qr = (np.ascontiguousarray(Q.T), np.ascontiguousarray(R))

    @property
    def observation_qr(self):
        r""":math:`(Q^\top, R)` of the thin QR of the observed spatial modes (:math:`C F^\top`), set by
        set_observation."""
        if self._obs_qr is None:
            raise PhysarError("no observation set: call set_observation() first")
        return self._obs_qr

    def _F_obs(self):
        if self._obs is None:
            raise PhysarError("no observation set: call set_observation() first")
        return self._obs

    def truncated(self, n):
        """The model with its first `n` modes only (a PGD truncated after n enrichments)."""
        n = int(n)
        if not 1 <= n <= self.n_modes:
            raise PhysarError(f"cannot keep {n} of {self.n_modes} modes")
        return SeparatedModel(self.F[:n], self.grids, [g[:n] for g in self.G], self.names, self.units,
                              self.metadata, self.kinds)

    def mode_amplitudes(self):
        r""":math:`\lVert F_i \rVert \prod_j \lVert G_i^j \rVert_\infty`, the amplitude of each mode
        (decreasing for a good PGD)."""
        a = np.linalg.norm(self.F, axis=1)
        for g in self.G:
            a = a * np.abs(g).max(axis=1)
        return a

    def save(self, path, mesh=None, space=None):
        """Write a .npz atomically (:func:`physar.output.write_npz`): format version, modes, grids, metadata
        (JSON), and with ``mesh`` its SHA-256 checksum, with ``space`` (an FESpace) also the mesh
        arrays and element so that the file alone can be probed (`physar rom eval`, `assimilate`)."""
        meta = dict(self.metadata)
        if space is not None:
            mesh = space.mesh
            meta["element"] = space.element
        if mesh is not None:
            meta["mesh_checksum"] = mesh.checksum()
        arrays = {"format_version": np.array(FORMAT_VERSION), "F": self.F,
                  "names": np.array(self.names, dtype=str), "units": np.array(self.units, dtype=str),
                  "kinds": np.array(self.kinds, dtype=str),
                  "meta_keys": np.array(list(meta), dtype=str),
                  "meta_values": np.array([str(v) for v in meta.values()], dtype=str),
                  "metadata_json": np.array(json.dumps(meta, default=_jsonable))}
        if space is not None:
            arrays["mesh_points"] = np.asarray(mesh.points, float)
            arrays["mesh_cells"] = np.asarray(mesh.cells)
        for j, (x, g) in enumerate(zip(self.grids, self.G)):
            arrays[f"grid_{j}"] = x
            arrays[f"G_{j}"] = g
        from physar.output import write_npz

        write_npz(path, **arrays)

    @classmethod
    def load(cls, path, mesh=None):
        """Read a model written by :meth:`save` (``allow_pickle=False``).

        Raises :class:`ReducedModelError` for a file that is not a physar reduced model, of another
        format version, or (with ``mesh``) built on another mesh (SHA-256 checksum mismatch); and, naming the
        file and the array, for arrays that do not fit together: a NaN or infinite value, a grid not strictly
        increasing, G_j not (n_modes, grid size), a stored mesh that is invalid or off its checksum, or modes F
        without one column per DOF of the stored mesh.
        """
        try:
            z = np.load(path, allow_pickle=False)
        except FileNotFoundError:
            raise ReducedModelError(f"{path}: cannot read reduced model (file not found)") from None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:  # EOFError: empty file
            why = "not an .npz file" if "pickle" in str(e) else str(e)
            raise ReducedModelError(f"{path}: cannot read reduced model ({why})") from None
        if not hasattr(z, "files"):
            raise ReducedModelError(f"{path}: not a physar reduced model (a single array, not an .npz)")
        with z:
            if "format_version" not in z.files:
                raise ReducedModelError(f"{path}: not a physar reduced model (no format_version)")
            try:
                v = int(z["format_version"])
            except (TypeError, ValueError):
                raise ReducedModelError(f"{path}: unreadable format_version") from None
            if v not in READABLE_VERSIONS:
                raise ReducedModelError(
                    f"{path}: reduced-model format version {v}, this physar reads version {FORMAT_VERSION} "
                    f"(and {', '.join(map(str, READABLE_VERSIONS[:-1]))}); rebuild it with `physar rom build`")
            try:
                names = [str(s) for s in z["names"]]
                if "metadata_json" in z.files:
                    meta = json.loads(str(z["metadata_json"]))
                else:
                    meta = dict(zip([str(k) for k in z["meta_keys"]], [str(s) for s in z["meta_values"]]))
                arrays = {k: z[k] for k in ("F", *(f"{a}_{j}" for j in range(len(names)) for a in ("grid", "G")))}
                units = [str(s) for s in z["units"]]
                kinds = [str(s) for s in z["kinds"]] if v >= 2 else None  # version 1: inferred
                mesh_arrays = (z["mesh_points"], z["mesh_cells"]) if "mesh_points" in z.files else None
            except KeyError as e:
                raise ReducedModelError(f"{path}: reduced model is incomplete (missing {e})") from None
            except (TypeError, ValueError) as e:  # e.g. an object array, which would need pickle
                raise ReducedModelError(f"{path}: cannot read reduced model ({e})") from None
        if not isinstance(meta, dict):
            raise ReducedModelError(f"{path}: metadata_json is not a JSON object")
        _check_arrays(path, names, units, kinds, arrays)
        try:
            model = cls(arrays["F"], [arrays[f"grid_{j}"] for j in range(len(names))],
                        [arrays[f"G_{j}"] for j in range(len(names))], names, units, meta, kinds)
        except PhysarError as e:  # whatever _check_arrays left to the constructor, named with the file
            raise ReducedModelError(f"{path}: {str(e).removeprefix('SeparatedModel: ')}") from None
        if mesh_arrays is not None:
            model._attach_mesh(path, *mesh_arrays)
        if mesh is not None:
            model.check_mesh(mesh, source=str(path))
        return model

    def _attach_mesh(self, path, points, cells):
        """Validate the mesh stored in file ``path`` (finite points, integer cells, valid tetrahedra, its
        checksum) and the modes against it (F has one column per DOF of the stored mesh and element)."""
        from physar.errors import MeshError
        from physar.fem import FESpace
        from physar.geometry import TetMesh

        for key, a, width in (("mesh_points", points, 3), ("mesh_cells", cells, 4)):
            if a.ndim != 2 or a.shape[1] != width or not len(a):
                raise ReducedModelError(f"{path}: {key} has shape {a.shape}, expected (n, {width})")
        if points.dtype.kind not in "fiu" or not np.all(np.isfinite(points)):
            bad = 0 if points.dtype.kind not in "fiu" else int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])
            raise ReducedModelError(f"{path}: mesh_points: point {bad} is not a finite number ({points[bad].tolist()})")
        if cells.dtype.kind not in "iu":
            raise ReducedModelError(f"{path}: mesh_cells must be integer node indices, got dtype {cells.dtype}")
        try:
            mesh = TetMesh(points, cells, name=f"{path}: stored mesh (mesh_points, mesh_cells)")
        except MeshError as e:
            raise ReducedModelError(str(e)) from None
        want = self.metadata.get("mesh_checksum")
        if want is not None and mesh.checksum() != want:
            raise ReducedModelError(f"{path}: stored mesh does not match its checksum (corrupt file)")
        element = self.metadata.get("element", "P2")
        try:
            space = FESpace(mesh, element)
        except PhysarError as e:
            raise ReducedModelError(f"{path}: metadata element: {e}") from None
        if self.F.shape[1] != space.n_dofs:
            raise ReducedModelError(
                f"{path}: F has {self.F.shape[1]} columns, the stored mesh ({mesh.n_points} points, {element}) "
                f"has {space.n_dofs} DOFs (corrupt or edited file)")
        self._mesh_arrays = (mesh.points, mesh.cells)
        self.__dict__["_space_cache"] = [space]

    _mesh_arrays = None

    def check_mesh(self, mesh, source="reduced model"):
        """Raise :class:`ReducedModelError` unless `mesh` is the one the model was built on."""
        want = self.metadata.get("mesh_checksum")
        if want is None:
            raise ReducedModelError(f"{source}: the model records no mesh checksum; cannot check the mesh")
        got = mesh.checksum()
        if got != want:
            raise ReducedModelError(
                f"{source}: reduced model was built on another mesh (checksum {want[:12]}…, the given mesh "
                f"has {got[:12]}…, {mesh.n_points} points, {mesh.n_cells} cells); rebuild the model for this mesh")

    def mesh(self):
        """The TetMesh stored in the file (models saved with ``space=``)."""
        if self._mesh_arrays is None:
            raise ReducedModelError("this reduced model stores no mesh (save it with space=...)")
        from physar.geometry import TetMesh

        return TetMesh(*self._mesh_arrays)

    def space(self):
        """The FESpace (stored mesh and element) the spatial modes F live on."""
        from physar.fem import FESpace

        cache = self.__dict__.setdefault("_space_cache", [])
        if not cache:
            cache.append(FESpace(self.mesh(), self.metadata.get("element", "P2")))
        return cache[0]


def _check_arrays(path, names, units, kinds, arrays) -> None:
    """Refuse, naming file and field, a reduced model whose arrays are not real, finite and of matching
    shapes: F (n_modes, n_dof); per parameter j a strictly increasing grid_j (>= 2 points) and G_j
    (n_modes, grid_j size); one unit (and kind) per name."""
    p = len(names)
    if p == 0:
        raise ReducedModelError(f"{path}: names is empty (a reduced model has at least one parameter)")
    if len(set(names)) != p:
        raise ReducedModelError(f"{path}: names {names} has a name twice")
    for key, vals in (("units", units), ("kinds", kinds)):
        if vals is not None and len(vals) != p:
            raise ReducedModelError(f"{path}: {key} has {len(vals)} entries for {p} parameters {names}")
    for key, a in arrays.items():
        if a.dtype.kind not in "fiu":
            raise ReducedModelError(f"{path}: {key} must be an array of real numbers, got dtype {a.dtype}")
        if not np.all(np.isfinite(a)):
            i = np.unravel_index(int(np.flatnonzero(~np.isfinite(a))[0]), a.shape)
            where = f"[{', '.join(map(str, i))}]" if a.ndim else ""
            raise ReducedModelError(f"{path}: {key}{where} = {a[i]} is not a finite number")
    F = arrays["F"]
    if F.ndim != 2 or 0 in F.shape:
        raise ReducedModelError(f"{path}: F has shape {F.shape}, expected (n_modes, n_dof), both >= 1")
    for j, n in enumerate(names):
        x, g = arrays[f"grid_{j}"], arrays[f"G_{j}"]
        if x.ndim != 1 or x.size < 2:
            raise ReducedModelError(f"{path}: grid_{j} (parameter {n!r}) has shape {x.shape}, expected (n,) "
                                    "with n >= 2")
        if np.any(np.diff(x) <= 0):
            k = int(np.flatnonzero(np.diff(x) <= 0)[0])
            raise ReducedModelError(f"{path}: grid_{j} (parameter {n!r}) must be strictly increasing; "
                                    f"grid_{j}[{k + 1}] = {x[k + 1]} follows grid_{j}[{k}] = {x[k]}")
        if g.shape != (F.shape[0], x.size):
            raise ReducedModelError(f"{path}: G_{j} (parameter {n!r}) has shape {g.shape}, expected "
                                    f"{(F.shape[0], x.size)} (n_modes of F, points of grid_{j})")


def infer_kinds(names, units, metadata) -> list[str]:
    """Kinds of parameters stored without them (format version 1, models built in code): from the build
    configuration in ``metadata["parameters"]`` when it names them, else from the units (version 1 knew
    only load_position "m", load_magnitude "N" and load_offset "m", in that order); "unspecified" else."""
    params = metadata.get("parameters")
    if isinstance(params, list) and len(params) == len(names) and all(
            isinstance(p, dict) and p.get("kind") in KIND_UNITS and p.get("name") == n for p, n in zip(params, names)):
        return [p["kind"] for p in params]
    kinds, seen_length = [], False
    for u in units:
        if u == "m":
            kinds.append("load_offset" if seen_length else "load_position")
            seen_length = True
        else:
            kinds.append({"N": "load_magnitude", "deg": "rotation", "rad": "rotation", "Pa": "youngs_modulus"}
                         .get(u, "unspecified"))
    return kinds


def _jsonable(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return str(v)
