r"""The parametric problem behind `physar rom build`: what each parameter does to the FE problem.

Parameters :math:`\mu = (\mu_1, \dots, \mu_p)`, :math:`1 \le p \le 3`, each of one kind (seed 000 §5.1-5.3):

* ``load_position`` :math:`s` [m]: a point load (regularised Dirac, :func:`physar.fem.point_load`) at
  :math:`\mathrm{path}(s)` on a polyline; ``load_magnitude`` :math:`P` [N] scales it to :math:`|\mathrm{load}| = P`;
  ``load_offset`` :math:`t` [m] moves it to :math:`\mathrm{path}(s) + t e`.
* ``displacement`` :math:`d` [m]: the nodes of a region are prescribed :math:`u = d e` (a translation along the
  unit :math:`e`).
* ``rotation`` :math:`\theta` [deg]: the nodes of a region follow the rigid rotation :math:`R(\theta)` about the
  unit axis :math:`a` through the point :math:`c`, the finite rotation :math:`u = R(\theta)(X - c) + c - X`; by
  Rodrigues' formula, with :math:`v = X - c`,

  .. math::

      u = (\cos\theta - 1)\,(v - a\, (a \cdot v)) + \sin\theta\, (a \times v),

  a sum of two separated terms in :math:`\theta`.
* ``youngs_modulus`` :math:`E` [Pa]: the cells of a region have Young's modulus :math:`E` (the rest
  :math:`E_{\mathrm{ref}}` of [material]). Every material here has :math:`W` proportional to :math:`E` at fixed
  :math:`\nu`, so :math:`K(E) = K_{\mathrm{rest}} + (E / E_{\mathrm{ref}})\, K_{\mathrm{region}}`.

The other supports ([[fix]], :math:`u = u_{\mathrm{fix}}` there) and loads ([[load]], :math:`f_{\mathrm{fix}}`) of
the file apply at every :math:`\mu`.
A node in a prescribed region is driven by the region, not by a [[fix]] it also lies in; a node in two
regions moves by the sum. :class:`ParametricProblem` is the full model as a black box ``u = problem(mu)``
(non-intrusive PGD, check solves) and, for a linear material, gives the separated operator, loads and
prescribed displacements of the intrusive PGD (:func:`physar.rom.elastic.build_parametric_pgd`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physar.errors import SolverError
from physar.fem import ElasticModel, point_load, solve_static
from physar.geometry.path import as_path, path_length, path_point

LOAD_KINDS = ("load_position", "load_magnitude", "load_offset")


class CellScaledModel(ElasticModel):
    """An :class:`ElasticModel` whose energy density is multiplied by ``cell_scale`` (n_cells,) cell by cell
    (the Young's modulus of cell e is cell_scale[e] E_ref: W is proportional to E at fixed nu).

    Shares the shape-function gradients of ``base`` (its quadrature weights w det J are scaled); mass and
    body-force integrals are not scaled.
    """

    def __init__(self, base: ElasticModel, cell_scale):
        super().__init__(base.space, base.material, base.density)
        scale = np.asarray(cell_scale, float)
        if scale.shape != (base.space.mesh.n_cells,) or np.any(scale < 0):
            raise SolverError(f"cell scale must be >= 0 with shape ({base.space.mesh.n_cells},), got {scale.shape}")
        self.cell_scale = scale
        G, wdet = base._quad
        self.__dict__["_quad"] = (G, wdet * scale[:, None])  # the cached property of ElasticModel


def _vec(v) -> str:
    """``[1, 0, -0.5]``: a short vector for a summary (4 significant digits)."""
    return "[" + ", ".join(f"{x + 0.0:.4g}" for x in np.asarray(v, float).ravel().tolist()) + "]"


@dataclass(frozen=True, repr=False)
class MovingLoad:
    """A point load ``load`` (3,) [N] of radius ``radius`` [m] at path(s) (+ t ``offset_dir``)."""

    path: np.ndarray
    load: np.ndarray
    radius: float
    offset_dir: np.ndarray | None = None

    @property
    def length(self) -> float:
        return path_length(self.path)

    def __repr__(self) -> str:
        """One line: path points and length [m], load [N], radius [m] (and the offset direction)."""
        off = "" if self.offset_dir is None else f", offset along {_vec(self.offset_dir)}"
        return (f"MovingLoad(path of {len(self.path)} points, {self.length:.4g} m long, load {_vec(self.load)} N, "
                f"radius {self.radius:.4g} m{off})")

    def point(self, s, t=0.0) -> np.ndarray:
        x = path_point(self.path, s)
        return x if self.offset_dir is None else x + t * self.offset_dir

    def force(self, space, s, t=0.0, magnitude=None) -> np.ndarray:
        """Nodal forces (n_dofs,) [N]; ``magnitude`` P rescales the load to |load| = P."""
        load = self.load if magnitude is None else self.load * (magnitude / np.linalg.norm(self.load))
        return point_load(space, self.point(s, t), load, self.radius)


@dataclass(frozen=True, repr=False)
class Translation:
    """u = d e on the nodes ``nodes`` (indices into space.nodes), e = ``direction`` (unit), d in m."""

    nodes: np.ndarray
    direction: np.ndarray

    def shapes(self, X) -> np.ndarray:
        """(1, n_dofs): the prescribed field per unit d."""
        out = np.zeros((len(X), 3))
        out[self.nodes] = self.direction
        return out.reshape(1, -1)

    def factors(self, d) -> np.ndarray:
        return np.atleast_1d(np.asarray(d, float))[None, :]

    def __repr__(self) -> str:
        return f"Translation({len(self.nodes)} nodes, direction {_vec(self.direction)})"


@dataclass(frozen=True, repr=False)
class Rotation:
    r""":math:`u = R(\theta)(X - c) + c - X` on ``nodes``, about the unit ``axis`` :math:`a` through ``point``
    :math:`c` (right hand); :math:`\theta` in degrees (``degrees=False``: radians)."""

    nodes: np.ndarray
    axis: np.ndarray
    point: np.ndarray
    degrees: bool = True

    def shapes(self, X) -> np.ndarray:
        r"""(2, n_dofs): :math:`w_1 = v - a\, (a \cdot v)` and :math:`w_2 = a \times v` (:math:`v = X - c`) on the
        nodes, 0 elsewhere."""
        a = self.axis
        v = X[self.nodes] - self.point
        out = np.zeros((2, len(X), 3))
        out[0, self.nodes] = v - np.outer(v @ a, a)
        out[1, self.nodes] = np.cross(a, v)
        return out.reshape(2, -1)

    def factors(self, theta) -> np.ndarray:
        r"""(2, len(theta)): :math:`\cos\theta - 1` and :math:`\sin\theta`."""
        th = np.atleast_1d(np.asarray(theta, float)) * (np.pi / 180.0 if self.degrees else 1.0)
        return np.stack([np.cos(th) - 1.0, np.sin(th)])

    def __repr__(self) -> str:
        return (f"Rotation({len(self.nodes)} nodes, axis {_vec(self.axis)} through {_vec(self.point)} m, "
                f"angle in {'deg' if self.degrees else 'rad'})")


@dataclass(frozen=True, repr=False)
class Modulus:
    """Young's modulus E [Pa] on the cells ``cells`` (bool mask); ``E_ref`` [Pa] of the material."""

    cells: np.ndarray
    E_ref: float

    def __repr__(self) -> str:
        """One line: the cells it acts on (of all, for a mask) and E_ref [Pa]."""
        cells = np.asarray(self.cells)
        mask = cells.dtype == bool
        n, of = (int(np.count_nonzero(cells)), f" of {cells.size}") if mask else (cells.size, "")
        return f"Modulus({n}{of} cells, E_ref {self.E_ref:.4g} Pa)"


@dataclass(frozen=True, repr=False)
class ParametricProblem:
    """The full FE model of a parametric problem; ``problem(mu)`` solves it (a picklable black box).

    ``kinds`` (p,) and ``parts`` (p,): per parameter its kind and data (:class:`MovingLoad` for
    load_position, :class:`Translation`, :class:`Rotation`, :class:`Modulus`; None for load_magnitude and
    load_offset, which act on the load_position part). ``fixed``: every Dirichlet dof ([[fix]] and the
    prescribed regions, all three components); ``u_fix`` (n_dofs,): the [[fix]] values (0 on the regions);
    ``f_fix`` (n_dofs,): the constant loads [N]. Nonlinear materials: ``steps`` increments of the loads and
    of the prescribed displacements along their parameter (a rotation turns by theta / steps per step).
    """

    model: ElasticModel
    fixed: np.ndarray
    kinds: tuple
    parts: tuple
    u_fix: np.ndarray
    f_fix: np.ndarray
    steps: int = 1
    tol: float = 1e-10
    max_iter: int = 30

    def index(self, kind):
        return self.kinds.index(kind) if kind in self.kinds else None

    def __repr__(self) -> str:
        """One line: the model, fixed dofs, parameter kinds, load steps (no arrays)."""
        steps = f"{self.steps} load step{'' if self.steps == 1 else 's'}"
        return (f"ParametricProblem({self.model!r}, {len(self.fixed)} fixed dofs, parameters "
                f"{', '.join(map(str, self.kinds)) or 'none'}, {steps})")

    @property
    def free(self) -> np.ndarray:
        mask = np.ones(self.model.n_dofs, bool)
        mask[self.fixed] = False
        return np.flatnonzero(mask)

    @property
    def moving_load(self) -> MovingLoad | None:
        j = self.index("load_position")
        return None if j is None else self.parts[j]

    def force(self, mu, lam=1.0) -> np.ndarray:
        """External forces (n_dofs,) [N] at mu (times the load factor lam)."""
        mu = np.asarray(mu, float)
        f = self.f_fix.copy()
        ml = self.moving_load
        if ml is not None:
            jp, jt = self.index("load_magnitude"), self.index("load_offset")
            f += ml.force(self.model.space, mu[self.index("load_position")], 0.0 if jt is None else mu[jt],
                          None if jp is None else mu[jp])
        return lam * f

    def prescribed(self, mu, lam=1.0) -> np.ndarray:
        """Dirichlet values (n_dofs,) [m] at mu; lam scales u_fix and the prescribed parameters' values."""
        mu = np.asarray(mu, float)
        u = lam * self.u_fix
        X = self.model.space.nodes
        for j, part in enumerate(self.parts):
            if isinstance(part, (Translation, Rotation)):
                u = u + part.factors(lam * mu[j])[:, 0] @ part.shapes(X)
        return u

    def cell_scale(self, mu) -> np.ndarray | None:
        """E / E_ref per cell at mu, None without a youngs_modulus parameter."""
        mods = [(j, p) for j, p in enumerate(self.parts) if isinstance(p, Modulus)]
        if not mods:
            return None
        scale = np.ones(self.model.space.mesh.n_cells)
        for j, p in mods:
            scale[p.cells] = float(mu[j]) / p.E_ref
        return scale

    def model_at(self, mu) -> ElasticModel:
        scale = self.cell_scale(mu)
        return self.model if scale is None else CellScaledModel(self.model, scale)

    def __call__(self, mu) -> np.ndarray:
        """u(mu) (n_dofs,) [m] by :func:`physar.fem.solve_static`."""
        mu = np.atleast_1d(np.asarray(mu, float))
        model = self.model_at(mu)
        if len(self.free) == 0:
            return self.prescribed(mu)
        steps = 1 if model.linear else self.steps
        u = np.zeros(model.space.n_dofs)
        try:
            for k in range(1, steps + 1):
                lam = k / steps
                f, u_d = self.force(mu, lam), self.prescribed(mu, lam)
                if not model.linear:
                    u = self._predict(model, u, f, u_d)
                u = solve_static(model, f, self.fixed, steps=1, u0=u, tol=self.tol,
                                 max_iter=self.max_iter, prescribed=u_d).u
        except SolverError as exc:
            raise SolverError(f"full solve at parameters {np.round(mu, 6).tolist()}: {exc}") from None
        return u

    def _predict(self, model, u, f, u_d) -> np.ndarray:
        r"""Predictor of a load/Dirichlet increment: the tangent at the last equilibrium :math:`u`,
        :math:`K_{ff}(u)\, \delta u_f = (f - f_{\mathrm{int}}(u) - K(u)\, \delta u_d)_f` with :math:`\delta u_d`
        the increment of the prescribed values (Newton
        from the raw jump of the prescribed nodes alone starts from badly distorted elements next to them)."""
        from physar.fem.solvers import factorize, has_cholmod

        free = self.free
        du = np.zeros_like(u)
        du[self.fixed] = u_d[self.fixed] - u[self.fixed]
        K = model.tangent_stiffness(u)
        r = f - model.internal_force(u) - K @ du
        try:   # Cholesky only: an indefinite tangent (past a limit point) gives no predictor
            du[free] = factorize(K[free][:, free], method="cholmod" if has_cholmod() else "auto").solve(r[free])
        except (SolverError, ArithmeticError, ValueError, RuntimeError):
            return u
        # keep the predictor only where it starts Newton closer to equilibrium than the raw jump of the
        # prescribed nodes does (an LU of an indefinite tangent, or a step that inverts elements, does not)
        jump = u.copy()
        jump[self.fixed] = u_d[self.fixed]
        try:
            with np.errstate(all="ignore"):
                r_pred = np.linalg.norm((f - model.internal_force(u + du))[free])
                r_jump = np.linalg.norm((f - model.internal_force(jump))[free])
        except (SolverError, ArithmeticError, ValueError, RuntimeError):
            return u
        if not np.isfinite(r_pred) or (np.isfinite(r_jump) and r_pred > r_jump):
            return u
        return u + du

    # -- the separated form of a linear problem (intrusive PGD) ------------------------------------------
    def stiffness_terms(self, grids):
        r"""[(:math:`K_m` (n_dofs, n_dofs), {j: :math:`\alpha_m(\mu_j)` on grids[j]})]:
        :math:`K(\mu) = \sum_m K_m \prod_j \alpha_m(\mu_j)`; :math:`K_{\mathrm{rest}}` (cells in no
        youngs_modulus region, omitted when empty) and one :math:`K_{\mathrm{region}}` per youngs_modulus."""
        mods = [(j, p) for j, p in enumerate(self.parts) if isinstance(p, Modulus)]
        if not mods:
            return [(self.model.tangent_stiffness(), {})]
        rest = np.ones(self.model.space.mesh.n_cells, bool)
        out = []
        for j, p in mods:
            rest &= ~p.cells
            out.append((CellScaledModel(self.model, p.cells.astype(float)).tangent_stiffness(),
                        {j: np.asarray(grids[j], float) / p.E_ref}))
        if rest.any():
            out.insert(0, (CellScaledModel(self.model, rest.astype(float)).tangent_stiffness(), {}))
        return out

    def prescribed_terms(self, grids):
        r"""[(w (n_dofs,), {j: :math:`h(\mu_j)` on grids[j]})]: :math:`u_D(\mu) = \sum w \prod_j h(\mu_j)`
        (u_fix, then per region)."""
        X = self.model.space.nodes
        out = [(self.u_fix, {})] if np.any(self.u_fix) else []
        for j, part in enumerate(self.parts):
            if isinstance(part, (Translation, Rotation)):
                for w, h in zip(part.shapes(X), part.factors(grids[j])):
                    out.append((w, {j: h}))
        return out

    def load_terms(self, grids):
        r"""[(B (n_dofs, N) sparse/dense, axes, {j: :math:`h(\mu_j)`})]:
        :math:`f(\mu) = \sum B[:, \text{grid node of axes}] \prod_j h(\mu_j)`."""
        import scipy.sparse as sp

        out = [(self.f_fix[:, None], (), {})] if np.any(self.f_fix) else []
        ml = self.moving_load
        if ml is not None:
            js, jt, jp = self.index("load_position"), self.index("load_offset"), self.index("load_magnitude")
            space = self.model.space
            ts = [0.0] if jt is None else grids[jt]
            cols = [sp.csc_matrix(point_load(space, ml.point(s, t), ml.load, ml.radius)[:, None])
                    for s in grids[js] for t in ts]
            axes = (js,) if jt is None else (js, jt)
            B = sp.hstack(cols).tocsr()
            if jt is not None and jt < js:  # columns in C order of the axes as numbered
                B = B[:, np.arange(B.shape[1]).reshape(len(grids[js]), len(ts)).T.ravel()]
                axes = (jt, js)
            out.append((B, axes, {} if jp is None else {jp: np.asarray(grids[jp], float) / np.linalg.norm(ml.load)}))
        return out


def moving_load(path, load, radius, offset_dir=None) -> MovingLoad:
    e = None if offset_dir is None else np.asarray(offset_dir, float) / np.linalg.norm(offset_dir)
    return MovingLoad(as_path(path, "load path"), np.asarray(load, float), float(radius), e)


__all__ = ["LOAD_KINDS", "CellScaledModel", "Modulus", "MovingLoad", "ParametricProblem", "Rotation",
           "Translation", "moving_load"]
