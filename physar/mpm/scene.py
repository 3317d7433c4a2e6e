"""TOML scene files for ``physar mpm run`` (validated with pydantic, unknown keys rejected).

Example (all lengths in m, times in s, stresses in Pa, densities in kg/m^3)::

    device = "cpu"         # optional, top of the file: Warp device of the simulation, cpu | cuda | cuda:N
    [grid]
    size = 1.0
    resolution = 32
    [time]
    frame_dt = 0.0333
    substeps = 50
    frames = 30
    [gravity]
    g = [0, 0, -9.81]
    [boundary]
    ground = "slip"        # sticky | slip | separate | none   (ground = the face z = 0)
    walls = "slip"         # the five other faces
    friction = 0.0         # Coulomb coefficient of the ground
    [[body]]
    shape = "box"          # box | sphere | mesh (file = "...", watertight)
    min = [0.4, 0.4, 0.6]
    max = [0.6, 0.6, 0.8]
    particles_per_cell = 8 # 1, 8, 27 or 64 (a regular lattice of n^3 particles per cell)
    material = "fixed_corotated"
    E = 1e5
    nu = 0.3
    density = 1000
    velocity = [0, 0, 0]
    velocity_gradient = [[0, 0, 0], [0, 0, 0], [0, 0, 0]]   # optional, 1/s
    fiber = [1, 0, 0]      # optional fibre direction a0 (rest frame, normalised); anisotropic fibre term
    fiber_E = 5e4          # fibre modulus E_f, Pa: Psi += (E_f / 8)(|F a0|^2 - 1)^2 (physar.mpm.model.MPMModel)
    [[collider]]           # optional, up to 8 kinematic colliders (physar.mpm.colliders)
    shape = "box"          # box (size = full side lengths) | capsule (radius, length, axis)
    center = [0.5, 0.5, 0.05]
    size = [0.6, 0.6, 0.1]
    velocity = [0.2, 0, 0] # m/s, straight motion; or path = [[t, x, y, z], ...] (piecewise-linear keyframes)
    boundary = "slip"      # sticky | slip | separate
    friction = 0.3
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from physar.errors import ConfigError, format_validation_error, refuse_coercion
from physar.mpm.colliders import MAX_COLLIDERS, Collider
from physar.mpm.constitutive import ELASTIC_CODES, PLASTIC_CODES, drucker_prager_alpha
from physar.mpm.model import MPMModel, device_name

# material name -> (elastic law, plastic return map)
MATERIALS = {
    "fixed_corotated": ("fixed_corotated", "identity"),
    "stvk": ("stvk", "identity"),
    "neohookean": ("neohookean", "identity"),
    "hencky": ("hencky", "identity"),
    "von_mises": ("hencky", "von_mises"),
    "metal": ("hencky", "von_mises"),
    "drucker_prager": ("hencky", "drucker_prager"),
    "sand": ("hencky", "drucker_prager"),
    "snow": ("fixed_corotated", "snow"),
}

Vec3 = tuple[float, float, float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # inf gravity or a NaN velocity: refused on reading

    @field_validator("*", mode="before")
    @classmethod
    def _no_coercion(cls, value, info):  # E = true, E = "69e9" and cells = ["40", 2, 2] are errors, not numbers
        return refuse_coercion(value, cls.model_fields[info.field_name].annotation)


class Grid(_Strict):
    size: float = Field(1.0, gt=0, description="side of the cubic domain [0, size]^3, m")
    resolution: int = Field(32, ge=4, le=512, description="cells per side")


class Time(_Strict):
    frame_dt: float = Field(1.0 / 30.0, gt=0, description="time between written frames [s]")
    substeps: int = Field(50, ge=1, le=100000, description="MPM steps per frame (dt = frame_dt / substeps; raise "
                                                          "it if a run diverges)")
    frames: int = Field(30, ge=1, le=100000, description="number of frames simulated and written")


class Gravity(_Strict):
    g: Vec3 = Field((0.0, 0.0, -9.81), description="gravitational acceleration [m/s^2]")


class Boundary(_Strict):
    """Conditions on the faces of the domain: sticky (v = 0), slip (v.n = 0), separate (v.n >= 0: bodies may lift
    off), none."""

    ground: Literal["sticky", "slip", "separate", "none"] = Field("slip", description="condition on the face z = 0")
    walls: Literal["sticky", "slip", "separate", "none"] = Field("slip", description="condition on the five other "
                                                                                  "faces")
    friction: float = Field(0.0, ge=0, description="Coulomb coefficient of the ground (slip / separate) [-]")


class Body(_Strict):
    """A body of particles: its shape, sampling, material and initial velocity."""

    shape: Literal["box", "sphere", "mesh"] = Field("box", description="box (min, max), sphere (center, radius) or "
                                                                       "mesh (file)")
    min: Vec3 | None = Field(None, description="box: lowest corner [m]")
    max: Vec3 | None = Field(None, description="box: highest corner [m]")
    center: Vec3 | None = Field(None, description="sphere: centre [m]")
    radius: float | None = Field(None, gt=0, description="sphere: radius [m]")
    file: str | None = Field(None, description="mesh: a closed (watertight) surface mesh, relative to the scene "
                                               "file; its inside is sampled")
    particles_per_cell: int = Field(8, description="particles per grid cell, a cube n^3 (1, 8, 27, 64): a regular "
                                                   "lattice of n^3 per cell")
    material: str = Field("fixed_corotated", description="fixed_corotated, stvk, neohookean, hencky (elastic); "
                                                         "von_mises or metal (Hencky + von Mises plasticity), "
                                                         "drucker_prager or sand (Hencky + Drucker-Prager), snow "
                                                         "(fixed_corotated + snow plasticity, Stomakhin et al. 2013)")
    E: float = Field(1.0e5, gt=0, description="Young's modulus, Pa")
    nu: float = Field(0.3, gt=-1, lt=0.5, description="Poisson ratio [-]")
    density: float = Field(1000.0, gt=0, description="mass density [kg/m^3]")
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="initial velocity [m/s]")
    velocity_gradient: tuple[Vec3, Vec3, Vec3] | None = Field(
        None, description="initial v = velocity + G (x - centroid) [1/s] (e.g. to start a vibration)")
    yield_stress: float = Field(1.0e4, gt=0, description="von Mises yield stress, Pa")
    friction_angle: float = Field(30.0, gt=0, lt=90, description="Drucker-Prager friction angle, degrees")
    theta_c: float = Field(2.5e-2, ge=0, lt=1, description="snow: critical compression, singular values of F "
                                                           "clamped at 1 - theta_c [-]")
    theta_s: float = Field(7.5e-3, ge=0, description="snow: critical stretch, singular values of F clamped at 1 + "
                                                     "theta_s [-]")
    hardening: float = Field(10.0, ge=0, description="snow: hardening coefficient xi, Lamé parameters scaled by "
                                                     "exp(xi (1 - J_p)) [-]")
    fiber: Vec3 | None = Field(None, description="fibre direction a0 in the rest configuration (normalised) [-]")
    fiber_E: float = Field(0.0, ge=0, description="fibre modulus E_f (anisotropic I4 term) [Pa]")

    @field_validator("material")
    @classmethod
    def _known_material(cls, v: str) -> str:
        if v not in MATERIALS:
            raise ValueError(f"unknown material '{v}'; choose one of {sorted(MATERIALS)}")
        return v

    @field_validator("particles_per_cell")
    @classmethod
    def _cube(cls, v: int) -> int:
        k = round(v ** (1 / 3))
        if k < 1 or k**3 != v:
            raise ValueError(f"particles_per_cell = {v} must be a cube (1, 8, 27, 64)")
        return v

    @model_validator(mode="after")
    def _shape_fields(self):
        if self.shape == "box" and (self.min is None or self.max is None):
            raise ValueError("a box body needs 'min' and 'max'")
        if self.shape == "box" and any(a >= b for a, b in zip(self.min, self.max)):
            raise ValueError(f"box min {self.min} must be below max {self.max} in every coordinate")
        if self.shape == "sphere" and (self.center is None or self.radius is None):
            raise ValueError("a sphere body needs 'center' and 'radius'")
        if self.shape == "mesh" and not self.file:
            raise ValueError("a mesh body needs 'file'")
        if self.fiber_E > 0 and (self.fiber is None or all(a == 0 for a in self.fiber)):
            raise ValueError(f"fiber_E = {self.fiber_E:g} Pa needs a non-zero 'fiber' direction")
        if self.fiber is not None and not all(np.isfinite(self.fiber)):
            raise ValueError(f"fiber {self.fiber} must be finite")
        return self


class ColliderSpec(_Strict):
    """A kinematic box or capsule (see :mod:`physar.mpm.colliders`)."""

    shape: Literal["box", "capsule"] = Field("box", description="box (size) or capsule (radius, length, axis)")
    center: Vec3 | None = Field(None, description="centre at t = 0 [m] (not with 'path')")
    size: Vec3 | None = Field(None, description="box: full side lengths, m")
    radius: float | None = Field(None, gt=0, description="capsule radius, m")
    length: float = Field(0.0, ge=0, description="capsule: length of the axis segment (0 = sphere), m")
    axis: Vec3 = Field((1.0, 0.0, 0.0), description="capsule: direction of the axis segment [-]")
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="constant velocity [m/s] (not with 'path')")
    path: list[tuple[float, float, float, float]] | None = Field(
        None, min_length=1, description="keyframes [t, x, y, z] of the centre, piecewise linear: t [s], x, y, z [m]")
    boundary: Literal["sticky", "slip", "separate"] = Field(
        "separate", description="condition on the grid nodes inside it, relative to its velocity: sticky (v = 0), "
                                "slip (v.n = 0), separate (as slip where the node approaches it)")
    friction: float = Field(0.0, ge=0, description="Coulomb coefficient (slip / separate) [-]")

    @model_validator(mode="after")
    def _fields(self):
        if self.shape == "box" and self.size is None:
            raise ValueError("a box collider needs 'size' (full side lengths)")
        if self.shape == "box" and any(a <= 0 for a in self.size):
            raise ValueError(f"box collider size {self.size} must be positive")
        if self.shape == "capsule" and self.radius is None:
            raise ValueError("a capsule collider needs 'radius'")
        if self.path is None and self.center is None:
            raise ValueError("a collider needs 'center' (with an optional 'velocity') or a keyframed 'path'")
        if self.path is not None and (self.center is not None or any(self.velocity)):
            raise ValueError("give either 'path' or 'center'/'velocity', not both")
        if self.path is not None and any(b[0] <= a[0] for a, b in zip(self.path, self.path[1:])):
            raise ValueError(f"path times {[k[0] for k in self.path]} must increase strictly")
        if all(a == 0 for a in self.axis):
            raise ValueError("axis must be non-zero")
        return self

    def build(self) -> Collider:
        return Collider(
            shape=self.shape, center=self.center or (0.0, 0.0, 0.0),
            half_extents=tuple(0.5 * s for s in self.size) if self.size else (0.1, 0.1, 0.1),
            radius=self.radius or 0.05, half_length=0.5 * self.length, axis=self.axis, velocity=self.velocity,
            path=None if self.path is None else np.asarray(self.path, dtype=np.float64),
            boundary=self.boundary, friction=self.friction)


class Scene(_Strict):
    """Top level of a `physar mpm run` scene file."""

    device: str = Field("cpu", description="Warp device the simulation runs on: cpu (default), cuda or cuda:N "
                                           "(physar.mpm.model.MPMModel.device; one Warp does not have is an error)")
    grid: Grid = Field(Grid(), description="the cubic domain and its background grid")
    time: Time = Field(Time(), description="frames and MPM steps")
    gravity: Gravity = Field(Gravity(), description="the gravitational acceleration")
    boundary: Boundary = Field(Boundary(), description="conditions on the domain's faces")
    body: list[Body] = Field(min_length=1, description="the bodies (at least one)")
    collider: list[ColliderSpec] = Field(default_factory=list, max_length=int(MAX_COLLIDERS),
                                         description=f"kinematic colliders (at most {MAX_COLLIDERS})")

    @field_validator("device")
    @classmethod
    def _device_name(cls, value):
        return device_name(value)


def _lattice(lo, hi, h):
    """Points of the lattice with spacing h, offset h/2 from the cell corners, inside [lo, hi]."""
    axes = []
    for a, b in zip(lo, hi):
        start = (np.floor(a / h)) * h + h / 2
        pts = np.arange(start, b, h)
        axes.append(pts[(pts >= a) & (pts < b)])
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def sample_body(body: Body, dx: float, base_dir: Path | None = None) -> tuple[np.ndarray, float]:
    r"""Particle positions (N, 3) and the volume of each particle (:math:`\mathrm{m}^3`), :math:`n^3` =
    ``particles_per_cell`` per cell.

    A box is filled with a lattice centred in it (spacing
    :math:`(\max - \min) / \operatorname{round}((\max - \min)\, n / dx)` per axis), so its centroid and second
    moments are exact for every sampling; spheres and meshes use the lattice of spacing :math:`dx / n` aligned
    with the grid, the shape's volume (:math:`4 \pi r^3 / 3`, the closed mesh's) shared among the points
    inside, so that the body's mass is its density times its volume.
    """
    h = dx / round(body.particles_per_cell ** (1 / 3))
    if body.shape == "box":
        lo, hi = np.asarray(body.min, dtype=np.float64), np.asarray(body.max, dtype=np.float64)
        k = np.maximum(1, np.round((hi - lo) / h)).astype(int)
        step = (hi - lo) / k
        axes = [lo[i] + (np.arange(k[i]) + 0.5) * step[i] for i in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3), float(np.prod(step))
    if body.shape == "sphere":
        c, r = np.asarray(body.center), body.radius
        pts = _lattice(c - r, c + r, h)
        pts = pts[np.sum((pts - c) ** 2, axis=1) <= r * r]
        return pts, _share(4.0 / 3.0 * np.pi * r**3, len(pts), h)
    mesh = _load_mesh(body, base_dir)
    pts = _lattice(mesh.bounds[0], mesh.bounds[1], h)
    pts = pts[mesh.contains(pts)]
    return pts, _share(abs(float(mesh.volume)), len(pts), h)


def _share(volume: float, n: int, h: float) -> float:
    """Each of ``n`` particles' volume so that they add up to the shape's ``volume`` (its mass is then density x
    volume, whatever the lattice cuts at the surface: a grid-aligned lattice over a 0.2 x 0.2 x 0.1 m box mesh
    held 18 % too little); :math:`h^3` when there are none (refused by the caller)."""
    return volume / n if n and volume > 0 and np.isfinite(volume) else h**3


def _load_mesh(body: Body, base_dir: Path | None):
    """The closed surface mesh of a mesh body (trimesh); ConfigError naming the file when it cannot be used."""
    import trimesh

    path = Path(body.file)
    if base_dir is not None and not path.is_absolute():
        path = base_dir / path
    if not path.exists():
        raise ConfigError(f"body.file '{path}' does not exist")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # noqa: BLE001 - any reader failure is a user error about this file
        raise ConfigError(f"body.file '{path}' could not be read as a surface mesh: {exc}") from None
    if len(getattr(mesh, "faces", ())) == 0:
        raise ConfigError(f"body.file '{path}' holds no triangles: an empty or corrupt file, or not a surface mesh "
                          "(STL, OBJ, PLY, OFF)")
    if not mesh.is_watertight:
        raise ConfigError(f"body.file '{path}' is not a closed (watertight) surface; cannot sample its inside")
    return mesh


def _axis_count(a: float, b: float, h: float) -> int:
    """Points :func:`_lattice` puts on one axis of [a, b] (spacing h, offset h/2), without making them."""
    start = np.floor(a / h) * h + h / 2
    return max(0, int(np.ceil((b - start) / h)))


def particle_count(body: Body, dx: float, base_dir: Path | None = None) -> tuple[int, int]:
    r"""(particles, lattice points) that :func:`sample_body` makes for ``body``, computed from the shape
    without sampling: a box's count is exact; a sphere's particles are estimated as :math:`\pi / 6` of its
    bounding lattice, a mesh's as its whole bounding lattice (an upper bound); the lattice points are those
    the sampling allocates (the bounding lattice; a box's own)."""
    h = dx / round(body.particles_per_cell ** (1 / 3))
    if body.shape == "box":
        k = np.maximum(1, np.round((np.asarray(body.max, float) - np.asarray(body.min, float)) / h))
        n = int(np.prod([int(v) for v in k], dtype=object))
        return n, n
    if body.shape == "sphere":
        c, r = np.asarray(body.center, float), body.radius
        lat = int(np.prod([_axis_count(a - r, a + r, h) for a in c], dtype=object))
        return int(np.ceil(lat * np.pi / 6)), lat
    lo, hi = _load_mesh(body, base_dir).bounds
    lat = int(np.prod([_axis_count(a, b, h) for a, b in zip(lo, hi)], dtype=object))
    return lat, lat


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene TOML file; errors name the file and the field."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"scene file '{path}' does not exist")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None
    return parse_scene(data, str(path))


def parse_scene(data: dict, name: str = "scene") -> Scene:
    """Validate an MPM scene given as a dict (a parsed TOML); one-line errors naming ``name``."""
    try:
        return Scene.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, name, Scene, data=data)) from None


# Peak host memory per particle of a forward run (measured 1.40 kB per particle, the grid included, for 262,144
# particles on a 64-cell grid): the sampled columns and their concatenation (~350 B), the model's arrays and
# their Warp copies (~300 B), two states of x, v, C, F, Jp (2 x 200 B) with their NumPy sources, the solver's
# tau and trial F (144 B) and a frame copied out for the diagnostics and the PLY (~250 B); rounded up.
MPM_BYTES_PER_PARTICLE = 1500
MPM_BYTES_PER_NODE = 3 * 8 + 8 + 3 * 8  # the solver's grids: momentum, mass, velocity (float64)
MPM_BYTES_PER_LATTICE_POINT = 64  # sampling: the three meshgrid axes and their stacked copy (float64)


def check_scene_memory(scene: Scene, base_dir: Path | None = None, particles_per_cell: int | None = None,
                       bytes_per_particle: float = 0.0, source: str = "scene") -> int:
    """Estimate, before anything is sampled, the particles and the memory of a run of ``scene`` and raise one
    ConfigError line naming ``source`` when the memory exceeds what is available (:func:`physar.output.check_memory`,
    as ``physar mesh box`` does for huge cell counts); returns the estimated particle count.
    ``bytes_per_particle``: what the caller keeps per particle on top (e.g. the preview's positions of every frame).
    """
    from physar.output import check_memory

    dx = scene.grid.size / scene.grid.resolution
    for b_id, body in enumerate(scene.body):  # first: a body in other units is not a memory problem
        if body.shape == "box":
            lo, hi = np.asarray(body.min, float), np.asarray(body.max, float)
        elif body.shape == "sphere":
            lo, hi = np.asarray(body.center, float) - body.radius, np.asarray(body.center, float) + body.radius
        else:
            lo, hi = _load_mesh(body, base_dir).bounds
        if np.any(lo < 0) or np.any(hi > scene.grid.size):
            ext = float(np.max(hi - lo))
            units = (f"; a mesh in millimetres? its extent is {ext:g} m against a {scene.grid.size:g} m domain: "
                     "write it in metres (scale by 0.001)" if body.shape == "mesh" and ext > 20 * scene.grid.size
                     else "")
            raise ConfigError(f"{source}: body[{b_id}] extends outside the domain [0, {scene.grid.size}]^3 "
                              f"(its bounds {np.round(lo, 6).tolist()} - {np.round(hi, 6).tolist()}){units}")
    total, lattice = 0, 0
    for body in scene.body:
        if particles_per_cell is not None:
            body = body.model_copy(update={"particles_per_cell": particles_per_cell})
        n, lat = particle_count(body, dx, base_dir)
        total += n
        lattice = max(lattice, lat)
    nodes = (scene.grid.resolution + 2 * MPMModel.pad + 1) ** 3
    need = (total * (MPM_BYTES_PER_PARTICLE + bytes_per_particle) + MPM_BYTES_PER_LATTICE_POINT * lattice
            + MPM_BYTES_PER_NODE * nodes)
    ppc = sorted({particles_per_cell or b.particles_per_cell for b in scene.body})
    check_memory(need, f"{source}: about {total:.3g} particles ({', '.join(map(str, ppc))} per cell on a "
                       f"{scene.grid.resolution}^3 grid)")
    return total


def build_model(scene: Scene, base_dir: Path | None = None, particles_per_cell: int | None = None,
                substeps: int | None = None, source: str = "scene",
                bytes_per_particle: float = 0.0) -> tuple[MPMModel, np.ndarray, np.ndarray]:
    """MPM model, initial positions (N, 3) and velocities (N, 3) of a scene.

    ``particles_per_cell``/``substeps`` override the scene (used to make identification targets at a finer
    sampling than the model that is fitted to them).  The model runs on ``scene.device``.  ``source`` (the scene
    file) starts every error line.  Before sampling, a scene whose run would need more memory than is
    available is refused (:func:`check_scene_memory`, with the caller's ``bytes_per_particle`` on top); after
    it, a body outside the domain or without particles, and an initial velocity that moves a particle more
    than a grid cell per substep (the CFL condition of MPM's transfers; 1e300 m/s overflowed the energy).
    """
    check_scene_memory(scene, base_dir, particles_per_cell, bytes_per_particle, source)
    dx = scene.grid.size / scene.grid.resolution
    T = substeps or scene.time.substeps
    dt = scene.time.frame_dt / T
    cols = {k: [] for k in ("x", "v", "mass", "vol", "E", "nu", "el", "pl", "pp", "body", "fiber", "fiber_E")}
    for b_id, body in enumerate(scene.body):
        if particles_per_cell is not None:
            body = body.model_copy(update={"particles_per_cell": particles_per_cell})
        x, vol = sample_body(body, dx, base_dir)
        inside = np.all((x > 0) & (x < scene.grid.size), axis=1)
        if not np.all(inside):
            raise ConfigError(f"{source}: body[{b_id}] extends outside the domain [0, {scene.grid.size}]^3")
        n = len(x)
        if n == 0:
            raise ConfigError(f"{source}: body[{b_id}] contains no particles at this resolution; enlarge it or "
                              "refine the grid")
        el, pl = MATERIALS[body.material]
        if pl == "von_mises":
            pp = (body.yield_stress, 0, 0, 0)
        elif pl == "drucker_prager":
            pp = (drucker_prager_alpha(body.friction_angle), 0, 0, 0)
        elif pl == "snow":
            pp = (body.theta_c, body.theta_s, body.hardening, 0)
        else:
            pp = (0, 0, 0, 0)
        cols["x"].append(x)
        v = np.tile(np.asarray(body.velocity, dtype=np.float64), (n, 1))
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below
            if body.velocity_gradient is not None:
                v = v + (x - x.mean(0)) @ np.asarray(body.velocity_gradient, dtype=np.float64).T
            cells = np.abs(v).max() * dt / dx  # the largest per-axis move in one substep, in cells
        if not cells <= 1.0:
            what = "velocity" + (" and velocity_gradient" if body.velocity_gradient is not None else "")
            raise ConfigError(f"{source}: body[{b_id}] starts particles at up to {np.abs(v).max():.3g} m/s ({what}), "
                              f"{cells:.3g} grid cells per substep (dt = {dt:.3g} s, dx = {dx:.3g} m); MPM needs "
                              "at most 1: lower the velocity or raise time.substeps")
        cols["v"].append(v)
        cols["vol"].append(np.full(n, vol))
        cols["mass"].append(np.full(n, vol * body.density))
        cols["E"].append(np.full(n, body.E))
        cols["nu"].append(np.full(n, body.nu))
        cols["el"].append(np.full(n, ELASTIC_CODES[el]))
        cols["pl"].append(np.full(n, PLASTIC_CODES[pl]))
        cols["pp"].append(np.tile(pp, (n, 1)))
        cols["body"].append(np.full(n, b_id))
        cols["fiber"].append(np.tile(np.asarray(body.fiber or (0.0, 0.0, 0.0), dtype=np.float64), (n, 1)))
        cols["fiber_E"].append(np.full(n, body.fiber_E))
    colliders = [spec.build() for spec in scene.collider]
    for b_id in range(len(scene.body)):
        for c_id, col in enumerate(colliders):
            if np.any(col.signed_distance(cols["x"][b_id], 0.0) < 0):
                raise ConfigError(f"{source}: body[{b_id}] overlaps collider[{c_id}] at t = 0; move one of them")
    c = {k: np.concatenate(v) for k, v in cols.items()}
    walls = {w: scene.boundary.walls for w in ("x_min", "x_max", "y_min", "y_max", "z_max")}
    walls["z_min"] = scene.boundary.ground
    friction = {w: 0.0 for w in walls}
    friction["z_min"] = scene.boundary.friction
    model = MPMModel(
        size=scene.grid.size, resolution=scene.grid.resolution, dt=scene.time.frame_dt / T, substeps=T,
        mass=c["mass"], volume=c["vol"], E=c["E"], nu=c["nu"], elastic=c["el"], plastic=c["pl"],
        plastic_params=c["pp"], body=c["body"], gravity=tuple(scene.gravity.g), walls=walls, friction=friction,
        colliders=colliders, fiber=c["fiber"], fiber_E=c["fiber_E"], device=scene.device,
    )
    return model, c["x"], c["v"]
