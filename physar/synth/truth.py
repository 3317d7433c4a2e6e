r"""Ground truth of a synthetic clip from a FINER finite-element model than the project's reduced model.

The FE problem is rebuilt from the project's ``physar rom build`` configuration (``[model] config``): the
same material, supports, constant loads and ``[[parameter]]`` definitions, on a mesh ``refine`` times finer
(``[mesh] box``: cells multiplied by ``refine``; a mesh file or a tetrahedralised surface: every
tetrahedron split into 8, ``log2(refine)`` times, with its region tags carried over). A surface file can
first be tetrahedralised again at another size (``mesh_size``), so that the truth's mesh is not a
subdivision of the model's. The parameters act exactly as in the reduced model's build
(:class:`physar.rom.problem.ParametricProblem`, from :func:`physar.rom.config.build_parametric_problem`): a
load at :math:`\mathrm{path}(s) + t\, \mathrm{direction}` (``path_point(path, s)``) with the total
:math:`\mathrm{load}\; P / |\mathrm{load}|`, a prescribed translation :math:`d\, e` of a region, the finite
rigid rotation :math:`u = R(\theta)(X - c) + c - X` of a region, a Young's modulus of a region; so truth and
model differ only by the discretisation (no inverse crime).

Linear material: :math:`K` (on the free dofs) is factored once (per Young's modulus value when a
youngs_modulus parameter changes it) and :math:`u = u_D + K_{ff}^{-1} (f - K u_D)` with :math:`u_D` the
prescribed values. Nonlinear material
(St.VK, neo-Hookean, ...): Newton (:func:`physar.fem.solve_static`) by continuation in the parameters from the
previous solution (the frames' order: a loading path), its step halved until Newton converges; the first
solve from the unloaded state in the configuration's ``[solver] steps``. Each distinct parameter vector is
solved once (dwell frames reuse it).
"""
from __future__ import annotations

import math
from collections import OrderedDict
from pathlib import Path

import numpy as np

from physar.errors import ConfigError, SolverError


def refine_tets(mesh, times: int = 1):
    """Uniform refinement of a tet mesh: every tetrahedron split into 8 (4 corner tets and the inner
    octahedron cut along one diagonal) by its edge midpoints, ``times`` times. Region tags are carried over
    (a tagged tetrahedron's children keep its tag, a tagged triangle is split into 4). Returns a TetMesh
    whose points are the parent's P2 nodes (vertices first, then edge midpoints)."""
    from physar.fem.elements import p2_nodes
    from physar.geometry import MeshTags, TetMesh
    from physar.geometry.mesh import row_keys

    for _ in range(int(times)):
        nodes, c = p2_nodes(mesh)
        v0, v1, v2, v3, e01, e12, e02, e03, e13, e23 = c.T
        kids = np.stack([
            [v0, e01, e02, e03], [e01, v1, e12, e13], [e02, e12, v2, e23], [e03, e13, e23, v3],
            [e02, e13, e01, e12], [e02, e13, e12, e23], [e02, e13, e23, e03], [e02, e13, e03, e01],
        ], axis=0)  # (8, 4, m)
        cells = kids.transpose(2, 0, 1).reshape(-1, 4)
        tags = mesh.tags
        if tags is not None:
            ct = None if tags.cell_tags is None else np.repeat(tags.cell_tags, 8)
            fn = np.asarray(tags.face_nodes, np.int64).reshape(-1, 3)
            if len(fn):
                # midpoint node of each triangle edge: look the sorted edge up among the P2 edges
                edges = np.sort(mesh.cells[:, [0, 1, 1, 2, 0, 2, 0, 3, 1, 3, 2, 3]].reshape(-1, 2), axis=1)
                keys = row_keys(edges, mesh.n_points)
                order = np.argsort(keys)
                mids = c[:, 4:].reshape(-1)
                # P2_EDGES order is 01, 12, 02, 03, 13, 23: matches the pairs above
                def mid(a, b, mesh=mesh, keys=keys, order=order, mids=mids):
                    k = row_keys(np.sort(np.column_stack([a, b]), axis=1), mesh.n_points)
                    i = np.searchsorted(keys, k, sorter=order)
                    return mids[order[np.minimum(i, len(order) - 1)]]
                a, b, cc = fn.T
                mab, mbc, mca = mid(a, b), mid(b, cc), mid(cc, a)
                fn = np.concatenate([np.column_stack(t) for t in ((a, mab, mca), (mab, b, mbc), (mca, mbc, cc),
                                                                   (mab, mbc, mca))])
                ft = np.tile(np.asarray(tags.face_tags), 4)
            else:
                ft = np.asarray(tags.face_tags)
            tags = MeshTags(ct, fn, ft, dict(tags.names))
        mesh = TetMesh.reoriented(nodes, cells, name=mesh.name, tags=tags)
    return mesh


# memory of the truth per entry of its element stiffness matrices ((3 n)^2 for n nodes per tetrahedron): the
# COO triplets (value and two indices, 24 B) and their CSR copies; measured peak 38.5 kB per P2 tetrahedron
# (900 entries) building the stiffness of the cantilever and foam examples refined 4x
_TRUTH_BYTES_PER_ENTRY = 43


def _check_truth_memory(n_tets: int, element: str, source, refine: int) -> None:
    r"""Refuse (ConfigError, one line) a truth of ``n_tets`` tetrahedra whose stiffness assembly would need more
    memory than is available: about ``_TRUTH_BYTES_PER_ENTRY`` :math:`\cdot\, (3 n)^2` bytes per tetrahedron,
    :math:`n` = 4 (P1) or 10 (P2) nodes; checked before the refined mesh is made."""
    from physar.output import check_memory

    nodes = 10 if element == "P2" else 4
    check_memory(_TRUTH_BYTES_PER_ENTRY * (3 * nodes) ** 2 * n_tets,
                 f"{source}: the truth mesh at [truth] refine = {refine} ({n_tets:,} {element} tetrahedra)")


def _problem_on(mesh, cfg, source: str):
    """The FE problem of a rom configuration on another (refined) ``mesh``
    (:func:`physar.fem.config.build_problem` with that mesh)."""
    from physar.fem.config import build_problem

    try:
        return build_problem(cfg, mesh=mesh)
    except ConfigError as e:
        raise ConfigError(f"{source}: on the refined truth mesh: {e}") from None


class FineTruth:
    """The finer FE model of a project: ``space`` (the config's element on the refined mesh), ``problem``
    (its :class:`physar.rom.problem.ParametricProblem`), ``solve(params)`` -> u (n_dofs,) [m] for a dict
    {parameter name: value}, cached per distinct parameter vector; ``solves`` counts the distinct solves."""

    def __init__(self, project, refine: int = 2, cache: int = 64, mesh_size: float | None = None,
                 coarsest: bool = False):
        """``project``: an ARProject (its ``[model] config``) or the path of a ``physar rom build`` file.
        ``mesh_size`` [m]: for a model meshed from a surface file, tetrahedralise that surface again at this
        size before refining (a truth mesh independent of the model's, not a subdivision of it). ``coarsest``
        (quick clips, smoke checks): raise ``mesh_size`` to ``refine`` times the model's [mesh] size, the
        coarsest truth still no coarser than the model and still on an independent mesh; ``mesh_size_used``
        says what was meshed."""
        from physar.fem.config import build_mesh, build_problem
        from physar.rom.config import build_parametric_problem, load_rom_config

        if isinstance(project, (str, Path)):
            path = Path(project)
        else:
            cfg_p = project.config
            if cfg_p.model.config is None:
                raise ConfigError(f"{project.source}: [model] config: the truth renderer rebuilds the FE problem "
                                  "from the `physar rom build` file; give config = \"rom.toml\"")
            path = Path(cfg_p.model.config)
            if not path.is_absolute():
                path = cfg_p._base_dir / path
        cfg = load_rom_config(path)
        self.source = str(path)
        self.mesh_size_used = None
        refine = int(refine)
        if refine < 1:
            raise ConfigError(f"{path}: truth refinement must be >= 1, got {refine}")
        base = path.resolve().parent
        if mesh_size is not None:
            if not (np.isfinite(mesh_size) and mesh_size > 0):
                raise ConfigError(f"{path}: truth mesh_size must be a positive length in m, got {mesh_size}")
            if cfg.mesh.file is None or Path(cfg.mesh.file).suffix.lower() not in (".stl", ".obj", ".ply", ".off"):
                raise ConfigError(f"{path}: [mesh]: a truth mesh_size needs a model meshed from a surface file "
                                  "(STL, OBJ, PLY, OFF); a box or volume mesh is refined as it is")
            model_size = cfg.mesh.size
            if model_size is None:  # the model's default: tetrahedralize's, from its surface
                from physar.geometry import read_mesh
                from physar.geometry.tetra import default_size

                f = Path(cfg.mesh.file)
                model_size = default_size(read_mesh(f if f.is_absolute() else base / f, kind="auto"))
            if coarsest:
                mesh_size = max(float(mesh_size), refine * model_size)
            if mesh_size / refine > model_size * (1 + 1e-9):
                raise ConfigError(f"{path}: [truth] mesh_size = {mesh_size:g} m refined {refine}x gives elements of "
                                  f"{mesh_size / refine:.4g} m, larger than the model's [mesh] size "
                                  f"{model_size:.4g} m: the truth would be coarser than the model; give "
                                  f"mesh_size <= {refine * model_size:.4g} (refine x the model's size)")
            cfg = cfg.model_copy(deep=True)
            cfg.mesh.size = float(mesh_size)
            self.mesh_size_used = float(mesh_size)
        try:
            if cfg.mesh.box is not None:
                fine = cfg.model_copy(deep=True)
                fine.mesh.cells = tuple(int(c) * refine for c in cfg.mesh.cells)
                _check_truth_memory(6 * math.prod(fine.mesh.cells), cfg.fem.element, path, refine)
                problem = build_problem(fine, base)
            else:
                times = round(np.log2(refine))
                if 2 ** times != refine:
                    raise ConfigError(f"[mesh] file: the truth refinement of a mesh file splits each tet into 8 "
                                      f"(refine = 2, 4, 8, ...), got {refine}")
                coarse = build_mesh(cfg.mesh, base)
                _check_truth_memory(coarse.n_cells * 8 ** times, cfg.fem.element, path, refine)
                problem = _problem_on(refine_tets(coarse, times), cfg, str(path))
            self.problem = build_parametric_problem(cfg, problem, str(path))
        except ConfigError as exc:
            msg = str(exc)
            raise ConfigError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
        self.space, self.model, self.fixed = problem.space, self.problem.model, self.problem.fixed
        self.linear = bool(self.model.linear)
        self.names = [p.name for p in cfg.parameter]
        self.params = [p.model_dump() for p in cfg.parameter]
        self._modulus = "youngs_modulus" in self.problem.kinds
        self._solver = None
        self._cache: OrderedDict = OrderedDict()
        self._max = cache
        self._last = None  # (mu, u) of the latest nonlinear solve: the continuation's start
        # largest continuation step per parameter: a rotation turns by at most 5 deg per Newton solve (a larger
        # jump of a region can land on a spurious, inverted equilibrium); the others are not limited
        self._max_step = np.array([(5.0 if p.unit != "rad" else math.radians(5.0)) if p.kind == "rotation"
                                   else np.inf for p in cfg.parameter])
        self.solves = 0

    def mu(self, values: dict) -> np.ndarray:
        return np.array([float(values[n]) for n in self.names])

    def load(self, values: dict) -> np.ndarray:
        """The nodal force vector (n_dofs,) [N] at the parameter values (with the constant [[load]] tables)."""
        return self.problem.force(self.mu(values))

    def prescribed(self, values: dict) -> np.ndarray:
        """The Dirichlet values (n_dofs,) [m] at the parameter values (zero off the fixed dofs)."""
        return self.problem.prescribed(self.mu(values))

    def solve(self, values: dict) -> np.ndarray:
        mu = self.mu(values)
        key = tuple(np.round(mu, 12).tolist())
        u = self._cache.get(key)
        if u is None:
            u = self._linear(mu) if self.linear else self._newton(mu)
            self.solves += 1
            self._cache[key] = u
            if len(self._cache) > self._max:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        return u

    def _linear(self, mu) -> np.ndarray:
        from physar.fem import LinearSolver
        from physar.fem.solvers import available_memory, direct_memory_estimate

        pb = self.problem
        if self._solver is None or self._modulus:
            model = pb.model_at(mu)
            self._K = model.tangent_stiffness()
            # K factored once (per E value); CG with AMG instead when the factor would not fit in half the
            # memory available (a fine [truth] refine of a large mesh: the factorisation would be killed)
            free = self._K.shape[0] - len(np.unique(pb.fixed))
            fits = direct_memory_estimate(free, self._K.nnz) <= 0.5 * available_memory()
            self._solver = LinearSolver(model, pb.fixed, linear="direct" if fits else "amg")
        u_d = pb.prescribed(mu)
        f = pb.force(mu)
        if np.any(u_d):
            f = f - self._K @ u_d
        return u_d + self._solver.solve(f)

    def _newton(self, mu, max_halvings: int = 6) -> np.ndarray:
        r"""Continuation from the previous solution :math:`(\mu_0, u_0)` to :math:`\mu` (from rest,
        :math:`\mu_0 = \mu` at load factor 0, for the first solve, in [solver] steps): :math:`n` equal steps
        in the parameters (and the load factor), a rotation by at most 5 deg per step, :math:`n` doubled while
        Newton fails."""
        pb = self.problem
        if self._last is None:
            mu0, u0, lam0 = mu, np.zeros(self.space.n_dofs), 0.0
            n0 = max(1, pb.steps)
        else:
            (mu0, u0), lam0 = self._last, 1.0
            n0 = max(1, int(np.ceil(np.max(np.abs(mu - mu0) / self._max_step))))
        for k in range(max_halvings + 1):
            n = n0 * 2 ** k
            u = u0
            try:
                for i in range(1, n + 1):
                    a = i / n
                    u = self._equilibrium(mu0 + (mu - mu0) * a, lam0 + (1.0 - lam0) * a, u)
                break
            except SolverError:
                if k == max_halvings:
                    raise SolverError(f"{self.source}: truth Newton continuation from parameters "
                                      f"{np.round(mu0, 6).tolist()} to {np.round(mu, 6).tolist()} did not converge "
                                      f"in {n} steps") from None
        self._last = (mu, u)
        return u

    def _equilibrium(self, mu, lam: float, u0: np.ndarray) -> np.ndarray:
        r"""Newton with backtracking from :math:`u_0` for :math:`f_\text{int}(u) = \lambda f(\mu)` on the free
        dofs, :math:`u = \lambda u_D(\mu)` on the fixed ones, from the tangent predictor at :math:`u_0`; a
        state with an inverted element (:math:`J \le 0` at a quadrature point) is refused. Converged when
        :math:`|R_\text{free}| \le \mathrm{tol}\, \max(|f|, |f_\text{int}|, |R_0|)`, :math:`R_0` the
        predictor's right-hand side (the out-of-balance force of the increment): it keeps the criterion
        meaningful where the reactions vanish (a free part turned rigidly)."""
        from physar.fem import factorize

        pb = self.problem
        model = pb.model_at(mu)
        free, fixed = pb.free, pb.fixed
        f = pb.force(mu, lam)
        u = np.array(u0, float)
        # tangent predictor at u0: the increment of the Dirichlet values enters linearly (K_fd du_D), not as a
        # jump of the boundary nodes alone that can invert the elements next to them
        du_d = pb.prescribed(mu, lam)[fixed] - u[fixed]
        K = model.tangent_stiffness(u)
        rhs = (f - model.internal_force(u))[free] - K[free][:, fixed] @ du_d
        scale = float(np.linalg.norm(rhs))
        try:
            u[free] += factorize(K[free][:, free]).solve(rhs)
        except SolverError:
            pass
        u[fixed] += du_d
        f_int = model.internal_force(u)
        r = f_int - f
        rn = float(np.linalg.norm(r[free]))
        scale = max(float(np.linalg.norm(f[free])), scale)
        for _ in range(pb.max_iter):
            if rn <= pb.tol * max(scale, float(np.linalg.norm(f_int)), 1e-300):
                if np.linalg.det(model.deformation_gradient(u)).min() <= 0:
                    raise SolverError("an inverted element (J <= 0) in the converged state")
                return u
            K = model.tangent_stiffness(u)
            du = np.zeros_like(u)
            du[free] = -factorize(K[free][:, free]).solve(r[free])
            pi0, alpha = model.energy(u) - f @ u, 1.0
            for _ in range(16):  # backtracking: lower the residual or the potential energy
                trial = u + alpha * du
                f_t = model.internal_force(trial)
                rn_t = float(np.linalg.norm((f_t - f)[free]))
                if np.isfinite(rn_t) and (rn_t < rn or model.energy(trial) - f @ trial < pi0):
                    break
                alpha *= 0.5
            else:
                raise SolverError(f"line search failed (residual {rn:.3e})")
            u, f_int, r, rn = trial, f_t, f_t - f, rn_t
        raise SolverError(f"Newton did not converge in {pb.max_iter} iterations (residual {rn:.3e})")


__all__ = ["FineTruth", "refine_tets"]
