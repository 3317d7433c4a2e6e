"""Ground truth of a synthetic clip from a FINER finite-element model than the project's reduced model.

The FE problem is rebuilt from the project's ``physar rom build`` configuration (``[model] config``): the
same material, supports and ``[[parameter]]`` load definitions, on a mesh ``refine`` times finer
(``[mesh] box``: cells multiplied by ``refine``; a mesh file or a tetrahedralised surface: every
tetrahedron split into 8, ``log2(refine)`` times, with its region tags carried over). The load of a
parameter vector is built exactly as the reduced model's parameters define it
(:func:`physar.fem.point_load` at ``path_point(path, s) + t * direction`` with the total ``load * P / |load|``),
so truth and model differ only by the discretisation (no inverse crime). Linear material only: K is factored
once and each distinct parameter vector is solved once (dwell frames reuse it).
"""
from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import numpy as np

from physar.errors import ConfigError


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


def _fixed_dofs(space, cfg, source: str) -> np.ndarray:
    """The [[fix]] dofs of a rom configuration on ``space`` (the selection rules of ``fem solve``)."""
    from physar.fem.loads import select_nodes_mask

    out = []
    for i, f in enumerate(cfg.fix):
        if f.value is not None and any(f.value):
            raise ConfigError(f"{source}: [[fix]] #{i + 1} value: prescribed displacements are not supported")
        mask = select_nodes_mask(space, **f.selector(), what=f"[[fix]] #{i + 1}")
        if not mask.any():
            raise ConfigError(f"{source}: [[fix]] #{i + 1}: no node of the refined truth mesh matches {f.describe()}")
        nodes = np.flatnonzero(mask)
        out += [3 * nodes + "xyz".index(c) for c in f.components]
    return np.unique(np.concatenate(out or [np.zeros(0, np.int64)])).astype(np.int64)


class FineTruth:
    """The finer FE model of a project: ``space`` (P2 or the config's element), ``solve(params)`` -> u
    (n_dofs,) [m] for a dict {parameter name: value}, cached per distinct parameter vector."""

    def __init__(self, project, refine: int = 2, cache: int = 64):
        from physar.fem import ElasticModel, FESpace, LinearSolver, make_material
        from physar.fem.config import build_mesh, build_problem
        from physar.rom.config import load_rom_config

        cfg_p = project.config
        src = project.source
        if cfg_p.model.config is None:
            raise ConfigError(f"{src}: [model] config: the truth renderer rebuilds the FE problem from the "
                              "`physar rom build` file; give config = \"rom.toml\"")
        path = Path(cfg_p.model.config)
        if not path.is_absolute():
            path = cfg_p._base_dir / path
        cfg = load_rom_config(path)
        self.source = str(path)
        if cfg.material.model != "linear":
            raise ConfigError(f"{path}: [material] model = {cfg.material.model!r}: the synthetic truth supports "
                              "linear elasticity only (model = \"linear\")")
        other = [p.kind for p in cfg.parameter if p.kind not in ("load_position", "load_magnitude", "load_offset")]
        if other:
            raise ConfigError(f"{path}: [[parameter]] kind = {other[0]!r}: the synthetic truth supports load_position, "
                              "load_magnitude and load_offset parameters")
        refine = int(refine)
        if refine < 1:
            raise ConfigError(f"{path}: truth refinement must be >= 1, got {refine}")
        base = path.resolve().parent
        if cfg.mesh.box is not None:
            fine = cfg.model_copy(deep=True)
            fine.mesh.cells = tuple(int(c) * refine for c in cfg.mesh.cells)
            problem = build_problem(fine, base)
            space, model, fixed = problem.space, problem.model, problem.fixed
        else:
            times = round(np.log2(refine))
            if 2 ** times != refine:
                raise ConfigError(f"{path}: [mesh] file: the truth refinement of a mesh file splits each tet into "
                                  f"8 (refine = 2, 4, 8, ...), got {refine}")
            mesh = refine_tets(build_mesh(cfg.mesh, base), times)
            space = FESpace(mesh, cfg.fem.element)
            mat = cfg.material
            model = ElasticModel(space, make_material("linear", E=mat.E, nu=mat.nu), density=mat.density)
            fixed = _fixed_dofs(space, cfg, str(path))
        self.space, self.model, self.fixed = space, model, fixed
        self.params = [p.model_dump() for p in cfg.parameter]
        self.names = [p.name for p in cfg.parameter]
        self.solver = LinearSolver(model, fixed)  # K factored once
        self._cache: OrderedDict = OrderedDict()
        self._max = cache
        self.solves = 0

    def load(self, values: dict) -> np.ndarray:
        """The nodal force vector (n_dofs,) [N] of the parameter values, built as the model's parameters
        define it."""
        from physar.fem import point_load
        from physar.geometry import path_point

        pos = self.params[0]
        point = path_point(pos["path"], float(values[pos["name"]]))
        total = np.asarray(pos["load"], float)
        for p in self.params[1:]:
            v = float(values[p["name"]])
            if p["kind"] == "load_magnitude":
                total = total * (v / np.linalg.norm(pos["load"]))
            elif p["kind"] == "load_offset":
                d = np.asarray(p["direction"], float)
                point = point + v * d / np.linalg.norm(d)
        return point_load(self.space, point, total, pos["radius"])

    def solve(self, values: dict) -> np.ndarray:
        key = tuple(round(float(values[n]), 12) for n in self.names)
        u = self._cache.get(key)
        if u is None:
            u = self.solver.solve(self.load(values))
            self.solves += 1
            self._cache[key] = u
            if len(self._cache) > self._max:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        return u


__all__ = ["FineTruth", "refine_tets"]
