"""The reduced-model problem file (TOML): a FEM problem file plus ``[[parameter]]`` tables and ``[rom]``.

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
    [[parameter]]                             # optional: the load magnitude |load| in N
    name = "P"
    kind = "load_magnitude"
    range = [0.5, 2.0]
    [rom]
    method = "pgd"                            # "pgd" | "pgd_nonintrusive" | "pod"
    max_modes = 20
    tol = 1e-4

The load point is ``physar.geometry.path_point(path, s)``; a point off the surface loads the body where
the bump kernel of radius ``radius`` meets it (as a fem ``point`` load does). The load of ``rom eval``
at s is exactly the load of a ``[[load]] type = "point"`` at path(s) with the
same total and radius, so the two commands solve the same problem.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from physar.errors import ConfigError
from physar.fem.config import FemConfig, Vec3, _Strict, build_problem, load_config


class ParameterSection(_Strict):
    name: str = Field(..., min_length=1)
    kind: Literal["load_position", "load_magnitude", "load_offset"]
    path: list[Vec3] | None = Field(None, min_length=2, description="polyline [[x0,y0,z0],[x1,y1,z1],...] (m)")
    points: int = Field(60, ge=3, description="grid points of the parameter")
    load: Vec3 | None = Field(None, description="total force (N)")
    radius: float | None = Field(None, gt=0, description="m")
    range: tuple[float, float] | None = None
    direction: Vec3 | None = Field(None, description="offset direction (load_offset)")
    unit: str | None = None

    @model_validator(mode="after")
    def _needed(self):
        need = {"load_position": ("path", "load", "radius"), "load_magnitude": ("range",),
                "load_offset": ("range", "direction")}[self.kind]
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"a {self.kind} parameter needs {', '.join(missing)}")
        if self.range is not None and not self.range[1] > self.range[0]:
            raise ValueError(f"range must be increasing, got {list(self.range)}")
        if self.kind == "load_position":
            seg = np.linalg.norm(np.diff(np.asarray(self.path, float), axis=0), axis=1)
            if (seg <= 0).any():
                i = int(np.flatnonzero(seg <= 0)[0])
                raise ValueError(f"path segment {i} (points {i} and {i + 1}) has zero length")
        if self.kind == "load_position" and np.linalg.norm(self.load) <= 0:
            raise ValueError("load must be non-zero")
        if self.direction is not None and np.linalg.norm(self.direction) <= 0:
            raise ValueError("direction must be non-zero")
        return self


class RomSection(_Strict):
    method: Literal["pgd", "pgd_nonintrusive", "pod"] = "pgd"
    max_modes: int = Field(20, ge=1)
    tol: float = Field(1e-4, gt=0, description="PGD: relative mode amplitude; POD: energy; "
                                                "non-intrusive: relative error at new samples")
    check_points: int = Field(5, ge=0, description="random full solves for the error estimate (pgd)")
    check_tol: float | None = Field(None, gt=0, description="pgd: also stop once the error estimate at the "
                                                             "check points is <= check_tol")
    max_points: int = Field(65, ge=3, description="non-intrusive: max samples per parameter")
    workers: int | None = Field(None, ge=1, description="non-intrusive: Dask LocalCluster workers")
    scheduler: str | None = Field(None, description="non-intrusive: address of a Dask scheduler")

    @model_validator(mode="after")
    def _check_tol_needs_points(self):
        if self.check_tol is not None and self.check_points == 0:
            raise ValueError("check_tol needs check_points > 0 (the error estimate it applies to)")
        return self


class RomConfig(FemConfig):
    """Top level of a `physar rom build` file: a FemConfig plus [[parameter]] and [rom]."""

    parameter: list[ParameterSection]
    rom: RomSection = RomSection()

    @model_validator(mode="after")
    def _parameters(self):
        kinds = [p.kind for p in self.parameter]
        if kinds.count("load_position") != 1 or kinds[0] != "load_position":
            raise ValueError("the first [[parameter]] must be the one kind = \"load_position\" parameter")
        if kinds.count("load_magnitude") > 1 or kinds.count("load_offset") > 1:
            raise ValueError("at most one load_magnitude and one load_offset [[parameter]]")
        if len(self.parameter) > 3:
            raise ValueError("at most 3 [[parameter]] tables")
        names = [p.name for p in self.parameter]
        if len(set(names)) != len(names):
            raise ValueError(f"parameter names must be distinct, got {names}")
        if self.load:
            raise ValueError("[[load]] is not used by `rom build`: the load is the [[parameter]] load_position")
        order = {"load_position": 0, "load_magnitude": 1, "load_offset": 2}
        self.parameter.sort(key=lambda p: order[p.kind])
        return self


def load_rom_config(path) -> RomConfig:
    return load_config(path, RomConfig)


def build_rom(cfg: RomConfig, progress: Callable[[int, int], None] | None = None, source: str = "config",
              workers: int | None = None, scheduler: str | None = None):
    """Build the reduced model a RomConfig describes. Returns (SeparatedModel, space, info)."""
    problem = build_problem(cfg)
    space, model, fixed = problem.space, problem.model, problem.fixed
    if problem.prescribed is not None and np.any(problem.prescribed[fixed] != 0):
        raise ConfigError(f"{source}: [[fix]] value (prescribed displacement) is not supported by `rom build`")
    pos = cfg.parameter[0]
    mag = next((p for p in cfg.parameter if p.kind == "load_magnitude"), None)
    off = next((p for p in cfg.parameter if p.kind == "load_offset"), None)
    r = cfg.rom
    method = r.method
    workers = workers if workers is not None else r.workers
    scheduler = scheduler if scheduler is not None else r.scheduler
    t0 = time.perf_counter()
    if method in ("pgd", "pod"):
        if not model.linear:
            raise ConfigError(f"{source}: [rom] method = {method!r} needs [material] model = \"linear\"; "
                              "use method = \"pgd_nonintrusive\" for a nonlinear material")
        if off is not None and method == "pod":
            raise ConfigError(f"{source}: a load_offset parameter needs [rom] method = \"pgd\" or "
                              "\"pgd_nonintrusive\"")
        if method == "pgd":
            from physar.rom.elastic import build_moving_load_pgd

            extra = {} if off is None else {"offset_range": off.range, "offset_dir": off.direction,
                                            "offset_points": off.points}
            rom, info = build_moving_load_pgd(model, fixed, pos.path, points=pos.points, load=pos.load,
                                              radius=pos.radius, max_modes=r.max_modes, tol=r.tol,
                                              n_check=r.check_points, check_tol=r.check_tol,
                                              progress=progress, **extra)
        else:
            from physar.rom.pod import build_moving_load_pod

            rom, info = build_moving_load_pod(model, fixed, pos.path, points=pos.points, load=pos.load,
                                              radius=pos.radius, max_modes=r.max_modes, tol=r.tol,
                                              progress=progress)
        if mag is not None:  # linear elasticity: u(s, P) = u(s) P / |load| exactly
            rom = _with_magnitude(rom, mag.range, float(np.linalg.norm(pos.load)))
            if off is not None:  # built as (s, t, P); the [[parameter]] order is (s, P, t)
                from physar.rom.separated import SeparatedModel

                rom = SeparatedModel(rom.F, [rom.grids[i] for i in (0, 2, 1)], [rom.G[i] for i in (0, 2, 1)],
                                     [rom.names[i] for i in (0, 2, 1)], [rom.units[i] for i in (0, 2, 1)],
                                     rom.metadata)
    else:
        from physar.rom.nonintrusive import build_moving_load_nonintrusive

        rom, info = build_moving_load_nonintrusive(
            model, fixed, pos.path, load=pos.load, radius=pos.radius,
            magnitude_range=None if mag is None else mag.range,
            offset_range=None if off is None else off.range, offset_dir=None if off is None else off.direction,
            steps=cfg.solver.steps, tol=r.tol, max_modes=r.max_modes, max_points=r.max_points,
            initial_points=min(pos.points, 9), workers=workers, scheduler=scheduler, progress=progress)
    names = [p.name for p in cfg.parameter]
    units = [p.unit or {"load_position": "m", "load_magnitude": "N", "load_offset": "m"}[p.kind]
             for p in cfg.parameter]
    rom.names, rom.units = names, units
    rom.metadata.update({"method": method, "material": cfg.material.model,
                         "material_params": cfg.material.model_dump(exclude_none=True),
                         "parameters": [p.model_dump(exclude_none=True) for p in cfg.parameter],
                         "fixed_dofs": len(fixed), "build_time_s": time.perf_counter() - t0})
    if "check_errors" in info:
        rom.metadata["check_errors"] = [float(v) for v in info["check_errors"]]
    for k in ("check_error", "error_estimate", "n_solves", "svd_rank"):
        if k in info:
            v = info[k]
            rom.metadata[k] = float(v) if k != "n_solves" and k != "svd_rank" else int(v)
    if "amplitudes" in info:
        rom.metadata["mode_amplitudes"] = [float(a) for a in info["amplitudes"]]
    return rom, space, info


def _with_magnitude(rom, magnitude_range, load_norm):
    from physar.rom.separated import SeparatedModel

    gp = np.linspace(*map(float, magnitude_range), 3)
    return SeparatedModel(rom.F, list(rom.grids) + [gp], list(rom.G) + [np.tile(gp / load_norm, (rom.n_modes, 1))],
                          list(rom.names) + ["P"], list(rom.units) + ["N"], rom.metadata)


__all__ = ["ParameterSection", "RomConfig", "RomSection", "build_rom", "load_rom_config"]
