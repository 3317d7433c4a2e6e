r"""How far a reduced model is from the converged solution: its discretisation error against a finer check solve.

The finite-element problem of a ``physar rom build`` configuration is rebuilt on a finer mesh (``[mesh] box``:
cells x ``refine`` in every direction; a mesh file or a tetrahedralised surface: every tetrahedron split into 8
at its edge midpoints, :math:`\log_2` ``refine`` times, region tags carried over) with the same material,
supports, loads and parameters (:func:`physar.rom.config.build_parametric_problem`: every parameter kind), and
solved in full at a few parameter points :math:`\mu_k`. The reduced model :math:`u_R(\mu)` (its modes live on
the configuration's mesh) is compared with the finer solution :math:`u_f(\mu)` at the reduced model's nodes,
all of which are nodes of the finer mesh. Displacement, over all dofs:

.. math::

    e_{L2} = \frac{\|u_R - u_f\|_2}{\|u_f\|_2}, \qquad
    e_{\max} = \frac{\max_a |u_{R,a} - u_{f,a}|}{\max_a |u_{f,a}|}

(:math:`|\cdot|` the Euclidean norm of a node's displacement); von Mises stress: the same with
:math:`\sigma_{vM} = \sqrt{\tfrac32\, s : s}` (:math:`s` the deviatoric Cauchy stress) at the mesh vertices,
both recovered by :func:`physar.fem.post.nodal_stress` (each mesh with its own elements). The difference holds
the reduced model's truncation error and the discretisation error of the coarser mesh; the latter dominates a
converged PGD. For smooth solutions :math:`e(h) - e(h/2) = (1 - 2^{-p})\, e(h)` with :math:`p` the order of
convergence, so the check is a slight underestimate (P2 displacement :math:`p = 3`: 7/8 of the error; P2 stress
and P1 displacement :math:`p = 2`: 3/4; P1 stress :math:`p = 1`: 1/2).

Where the exact stress is singular (a perfect clamp's edge, a re-entrant corner) or concentrated under a point
load, the stress error does not shrink with refinement. The von Mises errors are therefore also given *away*
from them, over the set :math:`A` of vertices at least :math:`2 l` from every supported or prescribed node and
:math:`2 l` beyond the radius of every point load (:math:`l = (6 V / n_{\mathrm{cells}})^{1/3}` the model's mean
element size, the edge of a cube that 6 such tetrahedra fill), relative to the whole field (the scale an
overlay's colours span; the field in :math:`A` alone may be near zero, beyond a load):

.. math::

    e_{L2,A} = \frac{\operatorname{rms}_A(\sigma_R - \sigma_f)}{\operatorname{rms}(\sigma_f)}, \qquad
    e_{\max,A} = \frac{\max_A |\sigma_R - \sigma_f|}{\max \sigma_f}

A re-entrant corner that is neither support nor load stays in :math:`A`: ``*_max_at`` says where the largest error lies.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from physar.errors import ConfigError
from physar.fem.config import Problem, build_mesh, build_problem
from physar.fem.elements import p2_nodes
from physar.fem.post import nodal_stress
from physar.geometry import MeshTags, TetMesh
from physar.geometry.mesh import row_keys
from physar.rom.config import build_parametric_problem
from physar.rom.separated import ReducedModelError

GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True, repr=False)
class DiscretisationCheck:
    """Errors of a reduced model against the finer check solve at ``params`` (k, p) (order of ``names``).

    Per point (k,), relative, as defined in the module docstring: ``displacement_l2``, ``displacement_max``;
    von Mises ``stress_l2``, ``stress_max`` over all vertices and ``away_l2``, ``away_max`` over the vertices
    at least ``away`` [m] from the supported or prescribed nodes and beyond the radius of every point load,
    relative to the whole field (NaN when there are none);
    ``stress_max_at``/``away_max_at`` (k, 3) [m] where the largest of each lies; ``peak_model``/``peak_fine``
    (k,) [Pa] the largest von Mises stress of each. ``refine``, the dofs of both meshes and the wall time [s]."""

    names: list
    params: np.ndarray
    displacement_l2: np.ndarray
    displacement_max: np.ndarray
    stress_l2: np.ndarray
    stress_max: np.ndarray
    stress_max_at: np.ndarray
    away_l2: np.ndarray
    away_max: np.ndarray
    away_max_at: np.ndarray
    peak_model: np.ndarray
    peak_fine: np.ndarray
    away: float
    refine: int
    dofs: int
    fine_dofs: int
    time_s: float

    def __repr__(self) -> str:
        """One line: refinement, points, dofs of both meshes, the worst relative errors (%), wall time (no arrays)."""
        def worst(a):
            a = np.asarray(a, float)
            return f"{np.nanmax(a) * 100:.3g} %" if np.isfinite(a).any() else "n/a"

        return (f"DiscretisationCheck(refine {self.refine}, {len(self.params)} points, {self.dofs} -> "
                f"{self.fine_dofs} dofs, worst displacement_l2 {worst(self.displacement_l2)}, stress_l2 "
                f"{worst(self.stress_l2)}, away_l2 {worst(self.away_l2)}, {self.time_s:.3g} s)")

    def summary(self) -> dict:
        """JSON-ready: the worst value over the points of each error, and every point."""
        keys = ("displacement_l2", "displacement_max", "stress_l2", "stress_max", "away_l2", "away_max")
        points = []
        for k, mu in enumerate(self.params):
            row = {"params": dict(zip(self.names, map(float, mu)))}
            row.update({key: _num(getattr(self, key)[k]) for key in keys})
            row.update(stress_max_at=self.stress_max_at[k].tolist(), away_max_at=self.away_max_at[k].tolist(),
                       peak_von_mises=float(self.peak_model[k]), peak_von_mises_fine=float(self.peak_fine[k]))
            points.append(row)
        worst = {key: _num(np.nanmax(getattr(self, key)) if np.isfinite(getattr(self, key)).any() else np.nan)
                 for key in keys}
        return {"refine": self.refine, "dofs": self.dofs, "fine_dofs": self.fine_dofs, "away_m": self.away,
                **worst, "time_s": self.time_s, "points": points}


def _num(v) -> float | None:
    """A float for JSON (None for NaN)."""
    return float(v) if np.isfinite(v) else None


def split_tets(mesh: TetMesh, times: int = 1) -> TetMesh:
    """Every tetrahedron split into 8 at its edge midpoints (4 corner tets, the inner octahedron cut along one
    diagonal), ``times`` times. The new points are the P2 nodes of the parent (vertices first, then edge
    midpoints); a tagged tetrahedron's children keep its tag, a tagged triangle becomes 4 tagged triangles."""
    for _ in range(int(times)):
        nodes, conn = p2_nodes(mesh)
        v0, v1, v2, v3, e01, e12, e02, e03, e13, e23 = conn.T
        kids = np.stack([[v0, e01, e02, e03], [e01, v1, e12, e13], [e02, e12, v2, e23], [e03, e13, e23, v3],
                         [e02, e13, e01, e12], [e02, e13, e12, e23], [e02, e13, e23, e03], [e02, e13, e03, e01]])
        cells = kids.transpose(2, 0, 1).reshape(-1, 4)
        tags = mesh.tags
        if tags is not None:
            tags = _split_tags(mesh, conn, tags)
        mesh = TetMesh.reoriented(nodes, cells, name=mesh.name, tags=tags)
    return mesh


def _split_tags(mesh: TetMesh, conn: np.ndarray, tags: MeshTags) -> MeshTags:
    """The tags of :func:`split_tets`' children (``conn``: the parent's P2 connectivity)."""
    cell_tags = None if tags.cell_tags is None else np.repeat(tags.cell_tags, 8)
    tri = np.asarray(tags.face_nodes, np.int64).reshape(-1, 3)
    if not len(tri):
        return MeshTags(cell_tags, tri, np.asarray(tags.face_tags), dict(tags.names))
    n = mesh.n_points
    pairs = np.sort(mesh.cells[:, [0, 1, 1, 2, 0, 2, 0, 3, 1, 3, 2, 3]].reshape(-1, 2), axis=1)  # P2_EDGES order
    keys, mids = row_keys(pairs, n), conn[:, 4:].ravel()
    order = np.argsort(keys)

    def mid(a, b):
        k = row_keys(np.sort(np.column_stack([a, b]), axis=1), n)
        return mids[order[np.searchsorted(keys, k, sorter=order)]]

    a, b, c = tri.T
    ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
    faces = np.concatenate([np.column_stack(t) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return MeshTags(cell_tags, faces, np.tile(np.asarray(tags.face_tags), 4), dict(tags.names))


def check_points(ranges, n: int) -> np.ndarray:
    r"""n parameter points (n, p) in the box ``ranges`` [(lo, hi)], :math:`k = 0, \dots, n-1`: the first
    parameter at :math:`\mathrm{lo} + \frac{k + 1}{n} (\mathrm{hi} - \mathrm{lo})`, reaching the end of its range
    (a load position: the far end); parameter :math:`j \ge 1` at
    :math:`\mathrm{lo}_j + \operatorname{frac}\big(\frac{k + 1}{n} + j g\big) (\mathrm{hi}_j - \mathrm{lo}_j)`,
    :math:`g = (\sqrt 5 - 1) / 2` (a rank-1 lattice: no two parameters move together)."""
    lo, hi = (np.array(v, float) for v in zip(*ranges))
    frac = np.mod((np.arange(n)[:, None] + 1.0) / n + GOLDEN * np.arange(len(lo))[None, :], 1.0)
    frac[:, 0] = (np.arange(n) + 1.0) / n
    return lo + frac * (hi - lo)


def _problems(cfg, refine: int, base: Path | None, source: str) -> tuple[Problem, Problem]:
    """The problem of ``cfg`` as ``rom build`` builds it, and the same on the finer mesh."""
    coarse = build_problem(cfg, base)
    if cfg.mesh.box is not None:
        fine = cfg.model_copy(deep=True)
        fine.mesh.cells = tuple(int(c) * refine for c in cfg.mesh.cells)
        return coarse, build_problem(fine, base)
    times = round(np.log2(refine))
    if 2 ** times != refine:
        raise ConfigError(f"{source}: [mesh] file: the check mesh splits every tetrahedron into 8 "
                          f"(refine = 2, 4, 8, ...), got {refine}")
    return coarse, _problem_on(cfg, split_tets(build_mesh(cfg.mesh, base), times), coarse.model)


def _problem_on(cfg, mesh: TetMesh, coarse_model) -> Problem:
    """:func:`physar.fem.config.build_problem` of ``cfg`` on another ``mesh`` (the check mesh)."""
    try:
        return build_problem(cfg, mesh=mesh)
    except ConfigError as e:
        raise ConfigError(f"on the check mesh: {e}") from None


def _matching(coarse: np.ndarray, fine: np.ndarray, what: str) -> np.ndarray:
    """Index into ``fine`` of every point of ``coarse`` (they coincide)."""
    scale = max(float(np.ptp(fine, axis=0).max()), 1e-300)
    d, idx = cKDTree(fine).query(coarse)
    if d.max() > 1e-9 * scale:
        raise ConfigError(f"the finer check mesh misses {what} of the model's mesh (largest gap {d.max():.3g} m)")
    return idx


def _rel(a: np.ndarray, b: np.ndarray) -> tuple[float, float, int]:
    r"""(:math:`\|a - b\| / \|b\|`, :math:`\max_i |a_i - b_i| / \max_i |b_i|`, argmax) over the rows (norm of
    each row)."""
    diff = np.linalg.norm((a - b).reshape(len(b), -1), axis=1)
    ref = np.linalg.norm(b.reshape(len(b), -1), axis=1)
    l2 = float(np.linalg.norm(diff) / max(np.linalg.norm(ref), 1e-300))
    return l2, float(diff.max() / max(ref.max(), 1e-300)), int(diff.argmax())


def _von_mises(sig: np.ndarray) -> np.ndarray:
    dev = sig - np.trace(sig, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) / 3
    return np.sqrt(1.5 * np.einsum("...ij,...ij->...", dev, dev))


def _element_size(space) -> float:
    r""":math:`l = (6 V / n_{\mathrm{cells}})^{1/3}` [m]: the edge of a cube that 6 tetrahedra of the mean volume
    fill."""
    return float((np.abs(space.jacobians[1]).sum() / space.mesh.n_cells) ** (1.0 / 3.0))


def _away(space, fixed: np.ndarray, loads, distance: float) -> np.ndarray:
    """Mask over the mesh vertices at least ``distance`` from the nodes of the ``fixed`` dofs and ``distance``
    beyond the radius of each point load of ``loads`` [(point (3,), radius)]."""
    X = space.mesh.points
    ok = np.ones(len(X), bool)
    for point, radius in loads:
        ok &= np.linalg.norm(X - point, axis=1) >= radius + distance
    if len(fixed):
        ok &= cKDTree(space.nodes[np.unique(fixed // 3)]).query(X)[0] >= distance
    return ok


def _point_loads(cfg, pp, mu) -> list:
    """(point, radius) of the moving load at mu and of every [[load]] type = "point"."""
    out = [(np.asarray(ld.point, float), float(ld.radius)) for ld in cfg.load if ld.type == "point"]
    ml = pp.moving_load
    if ml is not None:
        jt = pp.index("load_offset")
        out.append((ml.point(mu[pp.index("load_position")], 0.0 if jt is None else mu[jt]), ml.radius))
    return out


def _compare(cfg, pp_c, pp_f, rom, mu, node_of, vert_of, distance) -> tuple:
    """The errors at one parameter point (the fields of a DiscretisationCheck row)."""
    u_f = pp_f(mu)
    u_r = rom.evaluate(mu)
    du = _rel(u_r.reshape(-1, 3), u_f.reshape(-1, 3)[node_of])
    vm_r = _von_mises(nodal_stress(pp_c.model, u_r, cell_scale=pp_c.cell_scale(mu)))
    vm_f = _von_mises(nodal_stress(pp_f.model, u_f, vert_of, cell_scale=pp_f.cell_scale(mu)))
    space = pp_c.model.space
    X = space.mesh.points
    ds = _rel(vm_r, vm_f)
    away = _away(space, pp_c.fixed, _point_loads(cfg, pp_c, mu), distance)
    if away.any():
        e = np.abs(vm_r - vm_f)[away]
        k = int(e.argmax())
        da = (float(np.sqrt(np.mean(e**2) / max(np.mean(vm_f**2), 1e-300))), float(e[k] / max(vm_f.max(), 1e-300)),
              X[away][k])
    else:
        da = (np.nan, np.nan, np.full(3, np.nan))
    return (du[0], du[1], ds[0], ds[1], X[ds[2]], *da, vm_r.max(), vm_f.max())


def discretisation_error(cfg, rom, points: int | np.ndarray = 3, refine: int = 2, source: str = "config",
                         progress=None) -> DiscretisationCheck:
    """The reduced model ``rom`` (built from the RomConfig ``cfg``) against full solves of ``cfg`` on a mesh
    ``refine`` times finer, at ``points`` parameter points (a count: :func:`check_points` over the model's
    ranges; or an array (k, p) in the order of ``rom.names``). See the module docstring for the errors.
    ``progress(done, total)`` after each solve. Raises ConfigError when ``rom`` does not belong to ``cfg``
    (other parameters or another mesh)."""
    t0 = time.perf_counter()
    refine = int(refine)
    if refine < 2:
        raise ConfigError(f"the check mesh must be finer than the model's: refine >= 2, got {refine}")
    names = [p.name for p in cfg.parameter]
    if list(rom.names) != names:
        raise ConfigError(f"{source}: parameters {names}, the reduced model has {list(rom.names)}: "
                          "not the configuration it was built from")
    coarse, fine = _problems(cfg, refine, getattr(cfg, "_base_dir", None), source)
    _check_mesh(rom, coarse.space, source)
    pp_c, pp_f = (build_parametric_problem(cfg, p, source) for p in (coarse, fine))
    mus = check_points(rom.ranges, int(points)) if np.ndim(points) == 0 else np.atleast_2d(np.asarray(points, float))
    node_of = _matching(coarse.space.nodes, fine.space.nodes, "nodes")
    vert_of = _matching(coarse.space.mesh.points, fine.space.mesh.points, "vertices")
    distance = 2 * _element_size(coarse.space)
    rows = []
    for k, mu in enumerate(mus):
        rows.append(_compare(cfg, pp_c, pp_f, rom, mu, node_of, vert_of, distance))
        if progress is not None:
            progress(k + 1, len(mus))
    cols = [np.array(c) for c in zip(*rows)]
    return DiscretisationCheck(names, mus, *cols, away=distance, refine=refine, dofs=coarse.space.n_dofs,
                               fine_dofs=fine.space.n_dofs, time_s=time.perf_counter() - t0)


def _check_mesh(rom, space, source: str) -> None:
    """ConfigError unless the reduced model lives on ``space``'s mesh (same dofs; same mesh when stored)."""
    try:
        stored = rom.mesh()
    except ReducedModelError:  # a model saved without its mesh: the dof count must do
        stored = None
    same = stored is None or (stored.n_points == space.mesh.n_points and np.array_equal(stored.cells, space.mesh.cells)
                               and np.allclose(stored.points, space.mesh.points, rtol=0, atol=1e-9))
    if rom.F.shape[1] != space.n_dofs or not same:
        raise ConfigError(f"{source}: the reduced model's mesh ({rom.F.shape[1]} dofs) is not this configuration's "
                          f"mesh ({space.n_dofs} dofs): not the configuration it was built from")


__all__ = ["DiscretisationCheck", "check_points", "discretisation_error", "split_tets"]
