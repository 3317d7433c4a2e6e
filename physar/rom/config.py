r"""The reduced-model problem file (TOML): a FEM problem file plus ``[[parameter]]`` tables and ``[rom]``.

Example (see README, "Reduced models")::

    [mesh] / [material] / [[fix]] / [fem]     # exactly as for `physar fem solve`
    [[parameter]]
    name = "s"
    kind = "load_position"                    # arc length s (m) from path[0] along the path
    path = [[0.0, 0.05, 0.1], [1.0, 0.05, 0.1]]   # a polyline of >= 2 points; s uniform in arc length
    points = 60                               # grid of s values (PGD/POD); initial samples (non-intrusive)
    load = [0, 0, -1.0]                       # N, spread like a fem `point` load of this radius
    radius = 0.04
    [[parameter]]                             # optional: a lateral offset t (m) of the load point,
    name = "t"                                # path(s) + t direction (a position on a surface patch)
    kind = "load_offset"
    range = [-0.1, 0.1]
    direction = [0, 1, 0]
    points = 11
    [[parameter]]                             # optional: the load magnitude P = |load| in N (see below)
    name = "P"
    kind = "load_magnitude"
    range = [0.5, 2.0]
    [rom]
    method = "pgd"                            # "pgd" | "pgd_nonintrusive" | "pod"; default: "pgd" for a
    max_modes = 20                            # linear material, else "pgd_nonintrusive"
    tol = 1e-4

Other kinds (1 to 3 parameters in all, in any combination; load_magnitude and load_offset act on the one
load_position parameter), see :mod:`physar.rom.problem` for what each does::

    [[parameter]]                             # a prescribed translation u = d direction of a region
    name = "d"
    kind = "displacement"                     # unit "m"
    range = [-0.01, 0.01]
    direction = [0, 0, 1]
    box = [[0.9, 0, 0], [1, 0.1, 0.1]]        # region: box | region (mesh tag) | at (points) + tol | plane
    [[parameter]]                             # a rigid rotation of a region: the finite rotation
    name = "theta"                            # u = R(theta)(X - point) + point - X
    kind = "rotation"                         # unit "deg" (default) or "rad"; right hand about axis
    range = [-20, 20]
    axis = [0, 1, 0]
    point = [1.0, 0.05, 0.2]
    plane = {point = [1, 0, 0], normal = [1, 0, 0]}
    [[parameter]]                             # Young's modulus of the cells of a region (box: centroid in
    name = "E"                                # it, or region = a tag of tetrahedra; default every cell;
    kind = "youngs_modulus"                   # the rest keeps [material] E); unit "Pa"; grid geometric
    range = [1e6, 1e7]
    box = [[0, 0, 0], [0.5, 0.1, 0.1]]

The load magnitude :math:`P` [N] is the size of the load_position parameter's force: the force at :math:`P` is
:math:`P\, \mathtt{load} / |\mathtt{load}|`, its direction and sign those of ``load`` (``load = [0, 0, -1000]``
and :math:`P = 1200` push 1200 N downwards), so the reduced model at :math:`P = |\mathtt{load}|` is the full
solve with the configured ``load``. ``range`` is therefore in N and >= 0 (a negative :math:`P` would reverse
the configured direction: refused; reverse ``load`` instead), and either ``load`` is a unit vector (a
direction only, any range) or the range contains :math:`|\mathtt{load}|` (``load = [0, 0, -1000]`` with
``range = [0.5, 2]`` reads :math:`P` as a factor of the load, which it is not: refused). A ``[[load]]`` table
is a constant load on top of it at every :math:`P` (a warning says so: the fem file's own load kept next to
the load_position parameter counts twice).

`points` is the grid of each parameter (intrusive PGD, POD; its initial samples non-intrusively), an integer
3..2001, so the point-set selector of a region is ``at`` here. Nodes of a prescribed region are driven by it
(all three components), not by a [[fix]] they also lie in; [[fix]] values and [[load]] tables apply at every
parameter value. The method: intrusive PGD (:func:`physar.rom.elastic.build_parametric_pgd`) for a linear
material, where the operator is affine in E and the loads and prescribed displacements are separated in the
parameters (a rotation too: :math:`\cos\theta - 1` and :math:`\sin\theta`); non-intrusive PGD (full Newton
solves as a black box) for any other material.

The load point is ``physar.geometry.path_point(path, s)``, spread over the surface by the bump kernel of
radius ``radius`` (as a fem ``point`` load). The path must lie on the object's surface: a path point farther
than ``tol`` (default :math:`\mathtt{radius} / 4`) from it, or a stretch of the path that leaves it (over a
hole, past an edge), or a load_offset range that takes the load off it, is refused before the build
(:func:`check_load_path`). The load of ``rom eval`` at :math:`s` is exactly the load of a
``[[load]] type = "point"`` at :math:`\mathrm{path}(s)` with the same total and radius, so the two commands
solve the same problem.
"""
from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from physar.errors import ConfigError, PhysarWarning, SolverError
from physar.fem.config import Box, FemConfig, PlaneSelector, Vec3, _Strict, build_problem, load_config
from physar.fem.loads import select_cells_mask, select_nodes_mask
from physar.fem.solvers import check_constraints
from physar.rom.problem import LOAD_KINDS, Modulus, ParametricProblem, Rotation, Translation, moving_load
from physar.rom.separated import KIND_UNITS, SeparatedModel

Kind = Literal["load_position", "load_magnitude", "load_offset", "displacement", "rotation", "youngs_modulus"]
MAX_POINTS = 2001
_NEEDS = {"load_position": ("path", "load", "radius"), "load_magnitude": ("range",),
          "load_offset": ("range", "direction"), "displacement": ("range", "direction"),
          "rotation": ("range", "axis", "point"), "youngs_modulus": ("range",)}
_SELECTORS = ("box", "region", "at", "plane")
_NODE_KINDS = ("displacement", "rotation")
_UNITS = {"displacement": ("m",), "rotation": ("deg", "rad"), "youngs_modulus": ("Pa",)}


class ParameterSection(_Strict):
    """One parameter of the reduced model (1 to 3 in all); its kind says which of the other keys it takes."""

    name: str = Field(..., min_length=1, description="name of the parameter (distinct): `rom eval` takes NAME=VALUE, "
                                                     "the AR overlay and a scenario's [schedule.NAME] use it")
    kind: Kind = Field(..., description="load_position (arc length s along `path` of a point load), "
                                        "load_magnitude (|load| of that load), load_offset (offset of its point "
                                        "along `direction`), displacement (translation of a region along "
                                        "`direction`), rotation (rigid turn of a region about `axis`), "
                                        "youngs_modulus (E of a region's cells); see `unit` for the units")
    path: list[Vec3] | None = Field(None, min_length=2, description="load_position: the load's path, a "
                                                                     "polyline [[x0,y0,z0],[x1,y1,z1],...] (m)")
    points: int = Field(60, description=f"grid points of the parameter, an integer 3..{MAX_POINTS}")
    load: Vec3 | None = Field(None, description="load_position: total force (N) of the point load; with a "
                                                "load_magnitude parameter P its direction and sign, the force "
                                                "being P load / |load|")
    radius: float | None = Field(None, gt=0, description="radius of the point load's bump kernel (as a fem "
                                                         "point load), m")
    range: tuple[float, float] | None = Field(
        None, description="[low, high] in the parameter's unit: N for load_magnitude (>= 0, containing |load| "
                          "unless load is a unit direction), m for load_offset and "
                          "displacement, deg or rad for rotation, Pa for youngs_modulus (load_position spans "
                          "its path)")
    direction: Vec3 | None = Field(None, description="offset direction (load_offset), translation (displacement); "
                                                     "normalised [-]")
    unit: str | None = Field(None, description="unit of the parameter (default by kind: m, N, m, m, deg, Pa); a "
                                               "rotation is in \"deg\" or \"rad\", a displacement in \"m\", "
                                               "a Young's modulus in \"Pa\"")
    axis: Vec3 | None = Field(None, description="rotation axis (right hand), normalised [-]")
    point: Vec3 | None = Field(None, description="a point of the rotation axis (m)")
    box: Box | None = Field(None, description="displacement, rotation: nodes inside the box [[x0, y0, z0], "
                                              "[x1, y1, z1]]; youngs_modulus: cells whose centroid is inside [m]")
    region: str | int | None = Field(None, description="mesh tag (physical group) name or id")
    at: list[Vec3] | None = Field(None, min_length=1, description="nodes within tol of these points (m)")
    tol: float | None = Field(None, ge=0, description="at: distance from `at` within which nodes are selected [m] "
                                                     "(default physar.fem.loads.default_tol); load_position: the "
                                                     "farthest the path (its points and the line between them) "
                                                     "may be from the object's surface [m] (default radius / 4)")
    plane: PlaneSelector | None = Field(None, description="displacement, rotation: nodes within tol of a "
                                                          "plane {point, normal, tol}")

    @field_validator("points", mode="before")
    @classmethod
    def _grid_size(cls, v, info):
        if isinstance(v, bool) or not isinstance(v, int) or not 3 <= v <= MAX_POINTS:
            name = info.data.get("name")
            raise ValueError(f"points = {v!r} is not an integer from 3 to {MAX_POINTS} (the grid of parameter "
                             f"{name!r})")
        return v

    @model_validator(mode="after")
    def _needed(self):
        what = f"a {self.kind} parameter"
        missing = [k for k in _NEEDS[self.kind] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"{what} needs {', '.join(missing)}")
        new = ("axis", "point", *_SELECTORS, "tol")
        allowed = {"displacement": ("direction", *_SELECTORS, "tol"), "rotation": ("axis", "point", *_SELECTORS, "tol"),
                   "youngs_modulus": ("box", "region"), "load_position": ("tol",)}.get(self.kind, ())
        extra = [k for k in new if getattr(self, k) is not None and k not in allowed]
        if self.kind in ("youngs_modulus", "rotation") and self.direction is not None:
            extra.insert(0, "direction")
        if self.kind in _UNITS:
            extra += [k for k in ("path", "load", "radius") if getattr(self, k) is not None]
        if extra:
            raise ValueError(f"{', '.join(extra)} does not apply to {what}")
        if self.range is not None and not self.range[1] > self.range[0]:
            raise ValueError(f"range must be increasing, got {list(self.range)}")
        if self.kind == "load_position":
            seg = np.linalg.norm(np.diff(np.asarray(self.path, float), axis=0), axis=1)
            if (seg <= 0).any():
                i = int(np.flatnonzero(seg <= 0)[0])
                raise ValueError(f"path segment {i} (points {i} and {i + 1}) has zero length")
        if self.kind == "load_position" and np.linalg.norm(self.load) <= 0:
            raise ValueError(f"load = {[float(v) for v in self.load]} N has zero magnitude: it is the load's "
                             "direction and size (a load_magnitude parameter P rescales it to |load| = P)")
        for k in ("direction", "axis"):
            if getattr(self, k) is not None and np.linalg.norm(getattr(self, k)) <= 0:
                raise ValueError(f"{k} must be non-zero")
        return self._kind_rules()

    def _kind_rules(self):
        if self.kind in _UNITS and self.unit is not None and self.unit not in _UNITS[self.kind]:
            raise ValueError(f"unit = {self.unit!r}: a {self.kind} parameter is in "
                             f"{' or '.join(repr(u) for u in _UNITS[self.kind])}")
        given = [k for k in _SELECTORS if getattr(self, k) is not None]
        if self.kind in _NODE_KINDS and len(given) != 1:
            raise ValueError(f"a {self.kind} parameter needs exactly one of box, region, at, plane (the nodes "
                             f"it moves; got {', '.join(given) or 'none'})")
        if self.kind == "youngs_modulus" and len(given) > 1:
            raise ValueError(f"give at most one of box, region (the cells of E; got {', '.join(given)})")
        if self.tol is not None and self.at is None and self.kind != "load_position":
            raise ValueError("tol applies to at (a plane takes its own tol)")
        if self.kind == "load_magnitude" and self.range[0] < 0:
            raise ValueError(f"range = {list(self.range)} N: a load_magnitude is |load| >= 0 (the load's direction "
                             "and sign are those of the load_position parameter's load: reverse that vector to "
                             "reverse the load)")
        if self.kind == "youngs_modulus" and self.range[0] <= 0:
            raise ValueError(f"range of Young's modulus must be > 0 Pa, got {list(self.range)}")
        if self.kind == "rotation":
            limit = 360.0 if self.unit != "rad" else 2 * np.pi
            if max(abs(self.range[0]), abs(self.range[1])) > limit:
                raise ValueError(f"range {list(self.range)} of a rotation exceeds one turn "
                                 f"({'2 pi rad' if self.unit == 'rad' else '360 deg'})")
        return self

    def selector(self) -> dict:
        """Keywords of :func:`physar.fem.loads.select_nodes_mask` (``at`` is its ``points``)."""
        plane = None if self.plane is None else (self.plane.point, self.plane.normal)
        tol = self.plane.tol if self.plane is not None else self.tol
        return {"box": self.box, "region": self.region, "points": self.at, "plane": plane, "tol": tol}

    def describe(self) -> str:
        if self.box is not None:
            return f"box {list(map(list, self.box))}"
        if self.region is not None:
            return f"region {self.region!r}"
        if self.at is not None:
            return f"at {list(map(list, self.at))} (tol {self.tol})"
        if self.plane is not None:
            return f"plane {{point={list(self.plane.point)}, normal={list(self.plane.normal)}, tol={self.plane.tol}}}"
        return "every cell"


class RomSection(_Strict):
    method: Literal["pgd", "pgd_nonintrusive", "pod"] | None = Field(
        None, description="default: pgd for a linear material, else pgd_nonintrusive")
    max_modes: int = Field(20, ge=1, description="most modes of the separated representation")
    tol: float = Field(1e-4, gt=0, description="PGD: relative L2 error on the grid (residual estimate) and "
                                                "the last mode's relative change; POD: discarded energy (the "
                                                "same measure); non-intrusive: relative error at new samples [-]")
    check_points: int = Field(5, ge=0, description="random full solves for the error estimate (pgd)")
    check_tol: float | None = Field(None, gt=0, description="pgd: also stop once the relative error estimate at "
                                                             "the check points is <= check_tol [-]")
    update: bool = Field(True, description="pgd: after each new mode re-solve the parameter functions of all "
                                           "modes on the spatial modes found so far (the update step)")
    residual_tol: float | None = Field(None, gt=0, description="pgd: also stop once the relative residual of the "
                                                               "parametric problem, estimated on the grid as the "
                                                               "relative L2 displacement error it causes, is <= "
                                                               "residual_tol; default tol [-]")
    group_parameters: bool = Field(False, description="pgd, a moving load with a load_offset: separate space from "
                                                      "(s, t) taken together, u = sum F_i(x) A_i(s, t) with A_i on "
                                                      "the grid (stored as its SVD terms; max_modes counts the "
                                                      "F_i), instead of one function per parameter")
    max_points: int = Field(65, ge=3, le=MAX_POINTS, strict=True, description="non-intrusive: max samples per "
                                                                                "parameter")
    workers: int | None = Field(None, ge=1, description="non-intrusive: Dask LocalCluster workers")
    scheduler: str | None = Field(None, description="non-intrusive: address of a Dask scheduler")

    @model_validator(mode="after")
    def _check_tol_needs_points(self):
        if self.check_tol is not None and self.check_points == 0:
            raise ValueError("check_tol needs check_points > 0 (the error estimate it applies to)")
        if self.method is not None:  # else checked once RomConfig has chosen the method
            self._check_dask_keys()
        return self

    def _check_dask_keys(self, where="", why="method"):
        """workers / scheduler would be silently ignored by any method but the non-intrusive one: refused."""
        given = [k for k in ("workers", "scheduler") if getattr(self, k) is not None]
        if given and self.method != "pgd_nonintrusive":
            raise ValueError(f"{where}{' and '.join(given)}: only for method = \"pgd_nonintrusive\" (its snapshot "
                             f"solves); {why} is {self.method!r}")


class RomConfig(FemConfig):
    """Top level of a `physar rom build` file: a FemConfig plus [[parameter]] and [rom]."""

    parameter: list[ParameterSection] = Field(..., min_length=1, description="the parameters of the reduced "
                                                                             "model (1 to 3)")
    rom: RomSection = Field(RomSection(), description="the reduction method and its stopping rules")

    @model_validator(mode="after")
    def _parameters(self):
        kinds = [p.kind for p in self.parameter]
        if len(kinds) > 3:
            raise ValueError(f"at most 3 [[parameter]] tables (estimated jointly), got {len(kinds)}")
        for k in LOAD_KINDS:
            if kinds.count(k) > 1:
                raise ValueError(f"at most one kind = \"{k}\" [[parameter]] (got {kinds.count(k)})")
        for k in ("load_magnitude", "load_offset"):
            if k in kinds and "load_position" not in kinds:
                name = self.parameter[kinds.index(k)].name
                raise ValueError(f"[[parameter]] {name!r}: a {k} parameter acts on the load of a "
                                 "kind = \"load_position\" [[parameter]]; there is none")
        if "load_magnitude" in kinds:
            _check_magnitude_range(self.parameter[kinds.index("load_position")],
                                   self.parameter[kinds.index("load_magnitude")])
        names = [p.name for p in self.parameter]
        if len(set(names)) != len(names):
            raise ValueError(f"parameter names must be distinct, got {names}")
        if "youngs_modulus" in kinds and self.material.E is None:
            name = self.parameter[kinds.index("youngs_modulus")].name
            raise ValueError(f"[[parameter]] {name!r}: a youngs_modulus parameter needs [material] E (the "
                             "modulus outside its region and the reference of the others)")
        if self.rom.method is None:  # the default: intrusive where the model is linear
            self.rom = self.rom.model_copy(update={"method": "pgd" if self.material.model == "linear"
                                                   else "pgd_nonintrusive"})
            self.rom._check_dask_keys("[rom] ", "the default method for this material")
        order = {"load_position": 0, "load_magnitude": 1, "load_offset": 2}
        self.parameter.sort(key=lambda p: order.get(p.kind, 3))
        return self


def _check_magnitude_range(pos: ParameterSection, mag: ParameterSection) -> None:
    """Refuse a load_magnitude range without the configured |load| unless that load is a unit direction: P is
    |load| in N, not a factor of the load (``load = [0, 0, -1000]``, ``range = [0.5, 2]`` would give 0.5-2 N)."""
    size = float(np.linalg.norm(pos.load))
    lo, hi = map(float, mag.range)
    slack = 1e-9 * max(size, hi)
    if abs(size - 1.0) <= 1e-6 or lo - slack <= size <= hi + slack:
        return
    raise ValueError(f"[[parameter]] {mag.name!r}: range = {[lo, hi]} N does not contain |load| = {size:.6g} N of "
                     f"[[parameter]] {pos.name!r} (load = {[float(v) for v in pos.load]}): a load_magnitude is "
                     f"|load| in N, not a factor; give its range in N (e.g. [{0.5 * size:.6g}, {1.5 * size:.6g}]) "
                     "or load as a unit direction")


def load_rom_config(path) -> RomConfig:
    return load_config(path, RomConfig)


def build_rom(cfg: RomConfig, progress: Callable[[int, int], None] | None = None, source: str = "config",
              workers: int | None = None, scheduler: str | None = None):
    """Build the reduced model a RomConfig describes. Returns (SeparatedModel, space, info).

    A moving load alone (load_position, with load_magnitude / load_offset) on supports at :math:`u = 0` takes
    the moving-load builders (:func:`physar.rom.elastic.build_moving_load_pgd`, POD, non-intrusive); every
    other combination the general :class:`physar.rom.problem.ParametricProblem`.
    """
    try:
        problem = build_problem(cfg)
    except ConfigError as exc:  # name the file: "[[fix]] #1: no node matches ..." alone does not say which
        if source == "config" or str(exc).startswith(source):
            raise
        raise ConfigError(f"{source}: {exc}") from None
    pos = next((p for p in cfg.parameter if p.kind == "load_position"), None)
    if pos is not None:     # before any solve: a path off the object fails late and with the wrong hint
        check_load_path(problem.space, pos, source,
                        next((p for p in cfg.parameter if p.kind == "load_offset"), None))
    _warn_constant_loads(cfg, source)
    r = cfg.rom
    workers = workers if workers is not None else r.workers
    scheduler = scheduler if scheduler is not None else r.scheduler
    kinds = [p.kind for p in cfg.parameter]
    fix_values = problem.prescribed is not None and np.any(problem.prescribed[problem.fixed] != 0)
    t0 = time.perf_counter()
    if r.method in ("pgd", "pod") and not problem.model.linear:
        raise ConfigError(f"{source}: [rom] method = {r.method!r} needs [material] model = \"linear\"; "
                          "use method = \"pgd_nonintrusive\" for a nonlinear material")
    if set(kinds) <= set(LOAD_KINDS) and not cfg.load and not fix_values:
        rom, info = _build_moving_load(cfg, problem, progress, source, workers, scheduler)
    else:
        if r.method == "pod":
            raise ConfigError(f"{source}: [rom] method = \"pod\" builds a moving load alone (load_position, "
                              "load_magnitude) on fixed supports; use \"pgd\" or \"pgd_nonintrusive\"")
        rom, info = _build_parametric(cfg, build_parametric_problem(cfg, problem, source), progress, workers,
                                      scheduler)
    rom.names = [p.name for p in cfg.parameter]
    rom.units = [p.unit or KIND_UNITS[p.kind] for p in cfg.parameter]
    rom.kinds = kinds
    rom.metadata.update({"method": r.method, "material": cfg.material.model,
                         "material_params": cfg.material.model_dump(exclude_none=True),
                         "parameters": [p.model_dump(exclude_none=True) for p in cfg.parameter],
                         "fixed_dofs": len(problem.fixed), "build_time_s": time.perf_counter() - t0})
    if "check_errors" in info:
        rom.metadata["check_errors"] = [float(v) for v in info["check_errors"]]
    for k in ("check_error", "error_estimate", "n_solves", "svd_rank", "n_prescribed_modes"):
        if k in info:
            v = info[k]
            rom.metadata[k] = int(v) if k in ("n_solves", "svd_rank", "n_prescribed_modes") else float(v)
    if "amplitudes" in info:
        rom.metadata["mode_amplitudes"] = [float(a) for a in info["amplitudes"]]
    return rom, problem.space, info


def _warn_constant_loads(cfg: RomConfig, source: str) -> None:
    """One PhysarWarning per [[load]] table (not gravity) of a file with a load_magnitude parameter: it is applied
    at every P on top of the load P scales, so the fem file's own load kept next to the load_position parameter
    counts twice."""
    mag = next((p for p in cfg.parameter if p.kind == "load_magnitude"), None)
    if mag is None:
        return
    pos = next(p for p in cfg.parameter if p.kind == "load_position")
    for i, ld in enumerate(cfg.load):
        if ld.type == "gravity":
            continue
        warnings.warn(PhysarWarning(
            f"{source}: [[load]] #{i + 1} ({ld.type}, total {[float(v) for v in ld.total]} N) is a constant load, "
            f"applied at every {mag.name} on top of the load of [[parameter]] {pos.name!r} that {mag.name} scales "
            f"(load = {[float(v) for v in pos.load]} N); remove it if it is that same load"), stacklevel=3)


def check_load_path(space, pos: ParameterSection, source: str = "config",
                    offset: ParameterSection | None = None) -> None:
    r"""Refuse a load path that is not on the object's surface (ConfigError, one line naming the file, the
    parameter and where). ``tol`` is the parameter's tol, default :math:`\mathtt{radius} / 4`.

    * a path point farther than tol from the boundary surface (a point past the end of the object, a
      coordinate in mm, a point inside the body): its index and distance;
    * the path between its points sampled every :math:`\mathtt{tol} / 2` of arc length: the first stretch
      farther than tol from the surface (a path over a hole or across a gap between two parts): the arc length
      :math:`s` where it leaves the object and where it comes back. Not a matter of the load's radius: the
      path must go round;
    * with a load_offset, the same samples moved by each end of its range along its direction.
    """
    from physar.fem.loads import surface_distance
    from physar.geometry.path import path_point

    path = np.asarray(pos.path, float)
    tol = float(pos.tol) if pos.tol is not None else float(pos.radius) / 4
    what = f"{source}: [[parameter]] {pos.name!r}"
    d = surface_distance(space, path)
    far = np.flatnonzero(d > tol)
    if far.size:
        i = int(far[0])
        more = f" (and {far.size - 1} more of its points)" if far.size > 1 else ""
        raise ConfigError(f"{what}: path point {i} {path[i].tolist()} is {d[i] * 1e3:.3g} mm from the object's "
                          f"surface (tol {tol * 1e3:.3g} mm){more}: a load path lies on the surface; check the point "
                          "(metres, in the mesh's frame)")
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    n = int(min(20001, max(2, np.ceil(cum[-1] / (0.5 * tol)) + 1))) if tol > 0 else 20001
    s = np.union1d(np.linspace(0.0, cum[-1], n), cum)
    X = path_point(path, s)
    shifts = [(None, 0.0)]
    if offset is not None:
        u = np.asarray(offset.direction, float) / np.linalg.norm(offset.direction)
        shifts += [(offset, float(t)) for t in offset.range]
    for off, t in shifts:
        ds = surface_distance(space, X + t * u) if off is not None else surface_distance(space, X)
        out = ds > tol
        if not out.any():
            continue
        j0 = int(np.flatnonzero(out)[0])
        back = np.flatnonzero(~out[j0:])
        j1 = j0 + int(back[0]) if back.size else len(s)
        k = j0 + int(np.argmax(ds[j0:j1]))
        seg = int(np.clip(np.searchsorted(cum, s[j0], side="right") - 1, 0, len(path) - 2))
        leave = s[j0 - 1] if j0 > 0 else s[0]
        until = f"comes back at s = {s[j1] * 1e3:.1f} mm" if j1 < len(s) else "does not come back"
        if off is None:
            raise ConfigError(f"{what}: the path leaves the object at s = {leave * 1e3:.1f} mm (between path points "
                              f"{seg} and {seg + 1}) and {until}; it is {ds[k] * 1e3:.3g} mm from the object's surface "
                              f"at s = {s[k] * 1e3:.1f} mm (tol {tol * 1e3:.3g} mm): a hole or a gap is in the "
                              "way: route the path round it on the surface (a larger radius does not help)")
        raise ConfigError(f"{what}: with [[parameter]] {off.name!r} = {t:g} m the load leaves the object at s = "
                          f"{leave * 1e3:.1f} mm ({ds[k] * 1e3:.3g} mm from its surface at s = {s[k] * 1e3:.1f} "
                          f"mm, tol {tol * 1e3:.3g} mm): narrow the range of {off.name!r} or move the path")


def _build_moving_load(cfg, problem, progress, source, workers, scheduler):
    """A moving load alone: the builders of :mod:`physar.rom.elastic`, :mod:`pod`, :mod:`nonintrusive`."""
    model, fixed, r = problem.model, problem.fixed, cfg.rom
    pos = cfg.parameter[0]
    mag = next((p for p in cfg.parameter if p.kind == "load_magnitude"), None)
    off = next((p for p in cfg.parameter if p.kind == "load_offset"), None)
    if r.method == "pgd_nonintrusive":
        from physar.rom.nonintrusive import build_moving_load_nonintrusive

        return build_moving_load_nonintrusive(
            model, fixed, pos.path, load=pos.load, radius=pos.radius,
            magnitude_range=None if mag is None else mag.range,
            offset_range=None if off is None else off.range, offset_dir=None if off is None else off.direction,
            steps=cfg.solver.steps, tol=r.tol, max_modes=r.max_modes, max_points=r.max_points,
            initial_points=min(pos.points, 9), workers=workers, scheduler=scheduler, progress=progress)
    if off is not None and r.method == "pod":
        raise ConfigError(f"{source}: a load_offset parameter needs [rom] method = \"pgd\" or "
                          "\"pgd_nonintrusive\"")
    if r.method == "pgd":
        from physar.rom.elastic import build_moving_load_pgd

        extra = {} if off is None else {"offset_range": off.range, "offset_dir": off.direction,
                                        "offset_points": off.points}
        rom, info = build_moving_load_pgd(model, fixed, pos.path, points=pos.points, load=pos.load,
                                          radius=pos.radius, max_modes=r.max_modes, tol=r.tol,
                                          n_check=r.check_points, check_tol=r.check_tol,
                                          update=r.update, residual_tol=r.residual_tol,
                                          group_parameters=r.group_parameters, progress=progress, **extra)
    else:
        from physar.rom.pod import build_moving_load_pod

        rom, info = build_moving_load_pod(model, fixed, pos.path, points=pos.points, load=pos.load,
                                          radius=pos.radius, max_modes=r.max_modes, tol=r.tol,
                                          progress=progress)
    if mag is not None:  # linear elasticity: u(s, P) = u(s) P / |load| exactly
        rom = _with_magnitude(rom, mag.range, float(np.linalg.norm(pos.load)))
        if off is not None:  # built as (s, t, P); the [[parameter]] order is (s, P, t)
            rom = SeparatedModel(rom.F, [rom.grids[i] for i in (0, 2, 1)], [rom.G[i] for i in (0, 2, 1)],
                                 [rom.names[i] for i in (0, 2, 1)], [rom.units[i] for i in (0, 2, 1)],
                                 rom.metadata)
    return rom, info


def parameter_grid(p: ParameterSection, problem: ParametricProblem, j: int) -> np.ndarray:
    """The grid of parameter :math:`j` of the intrusive PGD: uniform (:math:`s` uniform in arc length), 3
    points for the load magnitude (:math:`u` is linear in it), geometric for Young's modulus (:math:`u` varies
    like :math:`1/E`)."""
    if p.kind == "load_position":
        return np.linspace(0.0, problem.parts[j].length, p.points)
    if p.kind == "load_magnitude":
        return np.linspace(*p.range, 3)
    if p.kind == "youngs_modulus":
        return np.geomspace(*p.range, p.points)
    return np.linspace(*p.range, p.points)


def _build_parametric(cfg, problem, progress, workers, scheduler):
    r = cfg.rom
    names = [p.name for p in cfg.parameter]
    units = [p.unit or KIND_UNITS[p.kind] for p in cfg.parameter]
    if r.method == "pgd":
        from physar.rom.elastic import build_parametric_pgd

        if r.group_parameters:
            raise ConfigError("[rom] group_parameters applies to a moving load with a load_offset alone (no "
                              "other parameter kind, no [[load]], no [[fix]] value)")

        grids = [parameter_grid(p, problem, j) for j, p in enumerate(cfg.parameter)]
        rom, info = build_parametric_pgd(problem, grids, names, units, max_modes=r.max_modes, tol=r.tol,
                                         n_check=r.check_points, check_tol=r.check_tol, progress=progress,
                                         update=r.update, residual_tol=r.residual_tol)
    else:
        from physar.rom.nonintrusive import nonintrusive_pgd

        ranges = [(0.0, problem.parts[j].length) if p.kind == "load_position" else p.range
                  for j, p in enumerate(cfg.parameter)]
        rom, info = nonintrusive_pgd(problem, ranges, names, units, tol=r.tol, max_modes=r.max_modes,
                                     max_points=r.max_points, initial_points=min(9, *(p.points for p in cfg.parameter)),
                                     workers=workers, scheduler=scheduler, progress=progress,
                                     metadata={"kind": "parametric", "material": type(problem.model.material).__name__})
    ml = problem.moving_load
    if ml is not None:  # as the moving-load builders record it (rom info, the AR overlay)
        rom.metadata.update({"path": ml.path.tolist(), "load": ml.load.tolist(), "radius": ml.radius})
    return rom, info


def build_parametric_problem(cfg: RomConfig, problem, source: str = "config") -> ParametricProblem:
    """The :class:`ParametricProblem` of a RomConfig on its built FE ``problem`` (:func:`build_problem`):
    the regions of the displacement / rotation / youngs_modulus parameters selected on its mesh, each a
    ConfigError naming the file, the [[parameter]] and its selector when it selects nothing."""
    space = problem.space
    fixed = [np.asarray(problem.fixed, np.int64)]
    u_fix = np.zeros(space.n_dofs) if problem.prescribed is None else problem.prescribed.copy()
    off = next((p for p in cfg.parameter if p.kind == "load_offset"), None)
    parts, moved = [], np.zeros(space.n_nodes, bool)
    E_cells = np.zeros(space.mesh.n_cells, int)
    for p in cfg.parameter:
        what = f"{source}: [[parameter]] {p.name!r}"
        if p.kind == "load_position":
            parts.append(moving_load(p.path, p.load, p.radius, None if off is None else off.direction))
        elif p.kind in LOAD_KINDS:
            parts.append(None)
        elif p.kind in ("displacement", "rotation"):
            try:
                mask = select_nodes_mask(space, **p.selector(), what=f"[[parameter]] {p.name!r}")
            except ConfigError as exc:
                raise ConfigError(f"{source}: {exc}") from None
            if not mask.any():
                from physar.fem.config import _miss_hint

                raise ConfigError(f"{what}: no node matches {p.describe()}; "
                                  f"{_miss_hint(space, {**p.selector()})}")
            nodes = np.flatnonzero(mask)
            moved |= mask
            if p.kind == "displacement":
                parts.append(Translation(nodes, np.asarray(p.direction, float) / np.linalg.norm(p.direction)))
            else:
                parts.append(Rotation(nodes, np.asarray(p.axis, float) / np.linalg.norm(p.axis),
                                      np.asarray(p.point, float), degrees=p.unit != "rad"))
        else:
            try:
                cells = select_cells_mask(space, box=p.box, region=p.region, what=f"[[parameter]] {p.name!r}")
            except ConfigError as exc:
                raise ConfigError(f"{source}: {exc}") from None
            if not cells.any():
                raise ConfigError(f"{what}: no cell (tetrahedron) matches {p.describe()}")
            if (E_cells[cells] > 0).any():
                raise ConfigError(f"{what}: its cells overlap those of another youngs_modulus parameter")
            E_cells[cells] += 1
            parts.append(Modulus(cells, float(cfg.material.E)))
    region_dofs = (3 * np.flatnonzero(moved)[:, None] + np.arange(3)).ravel()
    u_fix[region_dofs] = 0.0
    fixed = np.unique(np.concatenate(fixed + [region_dofs])).astype(np.int64)
    if len(fixed) < space.n_dofs:
        try:
            check_constraints(space.nodes, fixed, space.cells)
        except SolverError as exc:
            raise ConfigError(f"{source}: [[fix]] and the prescribed [[parameter]] regions: {exc}") from None
    mask = np.zeros(space.n_dofs, bool)
    mask[fixed] = True
    u_fix[~mask] = 0.0
    s = cfg.solver
    return ParametricProblem(problem.model, fixed, tuple(p.kind for p in cfg.parameter), tuple(parts), u_fix,
                             problem.f_ext, steps=s.steps, tol=s.tol, max_iter=s.max_iter)


def _with_magnitude(rom, magnitude_range, load_norm):
    gp = np.linspace(*map(float, magnitude_range), 3)
    return SeparatedModel(rom.F, list(rom.grids) + [gp], list(rom.G) + [np.tile(gp / load_norm, (rom.n_modes, 1))],
                          list(rom.names) + ["P"], list(rom.units) + ["N"], rom.metadata)


__all__ = ["MAX_POINTS", "ParameterSection", "RomConfig", "RomSection", "build_parametric_problem", "build_rom",
           "check_load_path", "load_rom_config", "parameter_grid"]
