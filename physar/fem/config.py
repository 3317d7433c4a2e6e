"""The FEM problem file (TOML), validated with pydantic, and the problem it builds.

See README.md ("The FEM problem file") for the format. Every error names the file, the table and the
key, in one line.
"""

from __future__ import annotations

import tomllib
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)

from physar.errors import (
    ConfigError,
    MeshError,
    PhysarError,
    PhysarWarning,
    format_validation_error,
    refuse_coercion,
)
from physar.fem.assembly import ElasticModel
from physar.fem.elements import FESpace
from physar.fem.loads import (
    default_tol,
    gravity_load,
    plane_miss_hint,
    point_load,
    points_miss_hint,
    select_faces,
    select_nodes_mask,
    surface_distance,
    traction_load,
)
from physar.fem.materials import MATERIALS, make_material
from physar.fem.post import nodal_von_mises, probe, von_mises
from physar.fem.solvers import StaticResult, solve_static
from physar.geometry import TetMesh, TriMesh, box_mesh, read_mesh, tetrahedralize
from physar.geometry.units import bounds_text, check_length_units

Vec3 = tuple[float, float, float]
Box = tuple[Vec3, Vec3]


class _Strict(BaseModel):
    # inf/nan refused in every number (a load total = [0, 0, nan] reached the solver: "singular system?")
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_coercion(cls, value, info):  # E = true, E = "69e9" and cells = ["40", 2, 2] are errors, not numbers
        return refuse_coercion(value, cls.model_fields[info.field_name].annotation)


class MeshSection(_Strict):
    file: str | None = Field(None, description="mesh file, relative to the problem file: a volume mesh (VTU, "
                                               "XDMF, Gmsh .msh, Medit .mesh; its tags are the regions) or a "
                                               "closed surface (STL, OBJ, PLY, OFF, or a surface .msh/VTU) "
                                               "tetrahedralised at `size`; a surface's tags (physical groups, "
                                               "OBJ groups) become regions of its boundary")
    box: Vec3 | None = Field(None, description="instead of a file: the box [0, L] x [0, W] x [0, H] given as "
                                               "[L, W, H] [m]")
    cells: tuple[int, int, int] | None = Field(None, description="hexahedra [nx, ny, nz] along the sides of "
                                                                 "`box`, 6 tetrahedra each")
    size: float | None = Field(None, gt=0, description="element size [m] when tetrahedralising a surface file")
    max_elements: int | None = Field(None, gt=0, description="refuse a surface file whose tetrahedralisation at "
                                                             "`size` is estimated above this many elements "
                                                             "(default 2 million, about 10 min of gmsh)")

    @model_validator(mode="after")
    def _one_source(self):
        if (self.file is None) == (self.box is None):
            raise ValueError("give either file = \"...\" or box = [L, W, H] with cells = [nx, ny, nz]")
        if self.box is not None and self.cells is None:
            raise ValueError("box needs cells = [nx, ny, nz]")
        if self.max_elements is not None and self.file is None:
            raise ValueError("max_elements applies to a surface file (file = \"part.stl\"), not to box")
        if self.size is not None and self.file is None:
            raise ValueError("size applies to a surface file (file = \"part.stl\"), not to box")
        return self


class PlaneSelector(_Strict):
    """The nodes (for a traction: the boundary faces with all three vertices) within ``tol`` of a plane."""

    point: Vec3 = Field(..., description="a point of the plane [m]")
    normal: Vec3 = Field(..., description="normal of the plane, any non-zero length [-]")
    tol: float | None = Field(None, ge=0, description="distance from the plane within which nodes are selected [m]; "
                                                     "default 4 float32 ulps of the coordinates + 1e-6 of the mesh "
                                                     "extent (physar.fem.loads.default_tol)")

    @model_validator(mode="after")
    def _normal(self):
        if not np.linalg.norm(self.normal) > 0:
            raise ValueError("plane normal must be non-zero")
        return self


class _Selector(_Strict):
    """Exactly one of box, region, points, plane selects the nodes/faces of a table."""

    box: Box | None = Field(None, description="nodes inside the closed box [[x0, y0, z0], [x1, y1, z1]] (for a "
                                              "traction: boundary faces whose centroid is inside) [m]")
    region: str | int | None = Field(None, description="mesh tag (physical group) name or id")
    points: list[Vec3] | None = Field(None, min_length=1, description="nodes within tol of these points [m]")
    tol: float | None = Field(None, ge=0, description="distance from `points` within which nodes are selected [m]; "
                                                     "default 4 float32 ulps of the coordinates + 1e-6 of the mesh "
                                                     "extent (physar.fem.loads.default_tol)")
    plane: PlaneSelector | None = Field(None, description="nodes within tol of a plane {point, normal, tol}")

    def _check_selector(self, required: bool = True):
        given = [k for k in ("box", "region", "points", "plane") if getattr(self, k) is not None]
        if not given and required:
            raise ValueError(f"{self._what()} needs one of box, region, points, plane")
        if len(given) > 1:
            raise ValueError(f"give exactly one of box, region, points, plane (got {', '.join(given) or 'none'})")
        if self.tol is not None and self.points is None:
            raise ValueError("tol applies to points (a plane takes its own tol)")

    def _what(self) -> str:
        return f"a {self.type} load" if hasattr(self, "type") else "a fix"

    def selector(self) -> dict:
        plane = None if self.plane is None else (self.plane.point, self.plane.normal)
        tol = self.plane.tol if self.plane is not None else self.tol
        return {"box": self.box, "region": self.region, "points": self.points, "plane": plane, "tol": tol}

    def describe(self) -> str:
        if self.box is not None:
            return f"box {list(map(list, self.box))}"
        if self.region is not None:
            return f"region {self.region!r}"
        if self.points is not None:
            return f"points {list(map(list, self.points))} (tol {self.tol})"
        return f"plane {{point={list(self.plane.point)}, normal={list(self.plane.normal)}, tol={self.plane.tol}}}"


class MaterialSection(_Strict):
    model: Literal["linear", "stvk", "neohookean", "neohookean_incompressible", "corotated"] = Field(
        ..., description="constitutive law: linear (small strain), stvk (St Venant-Kirchhoff), neohookean, "
                         "neohookean_incompressible (C1 and kappa, or E and nu; seed 000 §5.3), corotated")
    E: float | None = Field(None, description="Young's modulus [Pa]")
    nu: float | None = Field(None, description="Poisson ratio [-]")
    C1: float | None = Field(None, description="neo-Hookean constant C1 of W = C1 (Ī1 - 3) + ... (small strain: mu = 2 C1) [Pa]")
    kappa: float | None = Field(None, description="bulk penalty of neohookean_incompressible [Pa]")
    density: float = Field(0.0, ge=0, description="mass density [kg/m^3]; needed by a gravity load and by dynamics")


class FixSection(_Selector):
    components: list[Literal["x", "y", "z"]] = Field(
        ["x", "y", "z"], description="displacement components held (the others stay free: symmetry planes, "
                                     "plane strain)")
    value: Vec3 | None = Field(None, description="prescribed displacement [m] (x, y, z); default 0")

    @model_validator(mode="after")
    def _one(self):
        self._check_selector()
        return self


class LoadSection(_Selector):
    type: Literal["point", "traction", "gravity"] = Field(
        ..., description="traction: `total` spread uniformly over the selected boundary faces; point: `total` "
                         "spread over the boundary within `radius` of `point` by a smooth bump kernel (a "
                         "regularised Dirac, seed 000 §5.1); gravity: [material] density times `g`")
    total: Vec3 | None = Field(None, description="total force (x, y, z) of a traction or point load [N]")
    point: Vec3 | None = Field(None, description="centre of a point load [m]")
    radius: float | None = Field(None, gt=0, description="radius of the bump kernel of a point load [m]")
    g: Vec3 = Field((0.0, 0.0, -9.81), description="gravitational acceleration of a gravity load [m/s^2]")

    @model_validator(mode="after")
    def _needed(self):
        need = {"traction": ("total",), "point": ("point", "total", "radius"), "gravity": ()}[self.type]
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"a {self.type} load needs {', '.join(missing)}")
        if self.type == "traction":
            self._check_selector()
        elif any(getattr(self, k) is not None for k in ("box", "region", "points", "plane")):
            raise ValueError(f"a {self.type} load takes no box/region/points/plane (only traction does)")
        return self


class ProbeSection(_Strict):
    point: Vec3 = Field(..., description="point where the displacement is interpolated and reported [m]")


class FemSection(_Strict):
    element: Literal["P1", "P2"] = Field("P2", description="Lagrange tetrahedra: P1 (linear; locks in "
                                                           "bending) or P2 (quadratic; use it for beams)")


class SolverSection(_Strict):
    steps: int = Field(1, ge=1, description="least number of load steps (more are taken where Newton needs them)")
    tol: float = Field(1e-10, gt=0, description="Newton stops at |residual| <= tol max(|load|, |internal "
                                                "forces|) [-]")
    max_iter: int = Field(50, ge=1, description="Newton iterations per load step before it is cut back")
    linear: Literal["auto", "direct", "amg"] = Field(
        "auto", description="linear solver: direct (Cholesky), amg (CG + smoothed aggregation), auto (by size)")


class FemConfig(_Strict):
    """Top level of a `physar fem solve` file."""

    mesh: MeshSection = Field(..., description="the body: a box or a mesh file")
    material: MaterialSection = Field(..., description="the material law and its constants")
    fix: list[FixSection] = Field([], description="supports: nodes held at zero or at a prescribed "
                                                  "displacement (a later table overrides an earlier one)")
    load: list[LoadSection] = Field([], description="loads, summed: traction, point or gravity")
    probe: list[ProbeSection] = Field([], description="points where the displacement is reported")
    fem: FemSection = Field(FemSection(), description="the finite element")
    solver: SolverSection = Field(SolverSection(), description="load stepping, Newton and the linear solver")
    _base_dir: Path | None = PrivateAttr(default=None)  # folder of the file, for relative paths


def read_toml(path: str | Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"config file not found: {path}")
    if path.is_dir():
        raise ConfigError(f"{path}: is a folder; give the TOML file")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not a TOML file (byte {e.start} is not UTF-8 text)") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror})") from None


def parse_config(data: dict, source: str = "config", model: type[BaseModel] = FemConfig):
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source, model, data=data)) from None


def load_config(path: str | Path, model: type[BaseModel] = FemConfig):
    """Read and validate a TOML problem file (any `model` deriving from FemConfig)."""
    cfg = parse_config(read_toml(path), str(path), model)
    if isinstance(cfg, FemConfig):
        cfg._base_dir = Path(path).resolve().parent
    return cfg


@dataclass(repr=False)
class Problem:
    """A static problem built from a FemConfig."""

    space: FESpace
    model: ElasticModel
    f_ext: np.ndarray
    fixed: np.ndarray
    probes: np.ndarray  # (p, 3)
    config: FemConfig
    prescribed: np.ndarray | None = None  # Dirichlet values on `fixed` (n_dofs,), None = all zero

    def __repr__(self) -> str:
        """One line: the model, fixed dofs, total external force [N], probes (no arrays)."""
        total = np.asarray(self.f_ext, dtype=float).reshape(-1, 3).sum(axis=0)
        force = ", ".join(f"{v:.4g}" for v in total.tolist())
        return (f"Problem({self.model!r}, {len(self.fixed)} fixed dofs, total load [{force}] N, "
                f"{len(self.probes)} probe{'' if len(self.probes) == 1 else 's'})")


def check_mesh_size(size: float | None, points, name: str, what: str = "[mesh] size") -> None:
    """Refuse an element size larger than the object's largest bounding-box extent (a length in mm
    given as m: ``size = 3`` on a 0.16 m part): one ConfigError line with the value and the extent.

    The rule cannot refuse a legitimate coarse mesh: no element can be longer than the object, so any
    size above the largest extent gives the mesh of size = extent (one element across); the finest mm
    slip it misses (a size in mm below the extent in m) is a part over 1 m meshed at under 1 mm."""
    if size is None:
        return
    extent = float(np.ptp(np.asarray(points, float), axis=0).max())
    if size > extent + default_tol(points):  # the slack: a size = extent written from float32 STL coordinates
        raise ConfigError(f"{what} = {size:g} m is larger than the object's largest extent {extent:.4g} m "
                          f"({name}): lengths are in metres ({size:g} mm is {size / 1000:g})")


_SCALE_HINT = " (physar has no unit option: export the mesh in metres)"


def build_mesh(section: MeshSection, base_dir: Path | None = None) -> TetMesh:
    """The [mesh] of a problem file: a box, a volume mesh file (with its tags), or a closed surface file
    (STL, OBJ, PLY, OFF, or any file with triangles only) tetrahedralised by
    :func:`physar.geometry.tetrahedralize` at `size` (default: half the smallest bounding-box extent); the
    surface's region tags and names (physical groups of a .msh, cell tags of a VTU, OBJ groups) tag the
    tetrahedral mesh's boundary triangles, so ``region = "name"`` selects them in [[fix]] and [[load]].

    Coordinates are metres: a mesh whose largest extent is above 20 m or below 1 mm
    (:func:`physar.geometry.units.check_length_units`) gets one PhysarWarning naming the file and its extent
    (a part in millimetres read as metres deflects 10^3 times too little, silently)."""
    if section.file is not None:
        p = Path(section.file)
        if not p.is_absolute() and base_dir is not None:
            p = base_dir / p
        mesh = read_mesh(p, kind="auto")
        check_length_units(mesh.points, f"[mesh] file {p}", _SCALE_HINT)
        if isinstance(mesh, TriMesh):
            check_mesh_size(section.size, mesh.points, p.name)
            try:
                tet = tetrahedralize(mesh, size=section.size, source=f"[mesh] file {p.name}",
                                     max_elements=section.max_elements)
            except MeshError as exc:
                tet = _mesh_oriented(mesh, section, p, exc)
            _warn_coarse(tet, mesh, section, p)
            return tet
        if section.size is not None:
            raise ConfigError(f"[mesh] size = {section.size}: {p.name} is already a volume mesh (size applies "
                              "to a surface file that is tetrahedralised)")
        return mesh
    mesh = box_mesh(section.box, section.cells)
    check_length_units(mesh.points, f"[mesh] box = {list(section.box)}")
    return mesh


def _mesh_oriented(mesh: TriMesh, section: MeshSection, path: Path, exc: MeshError) -> TetMesh:
    """gmsh could not mesh the surface as given (``exc``): when its faces are wound against their neighbours, mesh
    it again with them turned to agree (:func:`physar.geometry.quality.oriented`, one warning); else, or if that
    fails too, the first error as one ConfigError line. gmsh meshes most surfaces of mixed winding as they are
    (the file is then used unchanged, so its tetrahedra do not depend on this repair)."""
    from physar.geometry.quality import orient_faces, oriented

    try:
        turned = orient_faces(mesh)[1]
    except MeshError:
        turned = 0
    if not turned:
        raise ConfigError(str(exc)) from None
    try:
        return tetrahedralize(oriented(mesh, f"[mesh] file {path}"), size=section.size,
                              source=f"[mesh] file {path.name}", max_elements=section.max_elements)
    except MeshError:
        raise ConfigError(str(exc)) from None


def _warn_coarse(tet: TetMesh, surface: TriMesh, section: MeshSection, path: Path) -> None:
    """One PhysarWarning when a surface file tetrahedralised at the default size kept under half of its
    vertices on the boundary: [[fix]] and [[load]] then select among far fewer nodes than the file shows (a
    plane that held 32 of the file's vertices may hold 2), which a user cannot see from the file."""
    if section.size is not None:
        return
    nb = len(tet.boundary().node_map)
    if nb >= 0.5 * surface.n_points:
        return
    from physar.geometry.quality import mean_edge_length
    from physar.geometry.tetra import default_size

    edge = mean_edge_length(surface)
    warnings.warn(PhysarWarning(
        f"[mesh] file {path}: tetrahedralised at the default size {default_size(surface):.3g} m (half its smallest "
        f"extent): the volume mesh has {nb} boundary nodes for the file's {surface.n_points} vertices, and "
        f"[[fix]] / [[load]] select among those; set [mesh] size (the file's mean edge is {edge:.3g} m) to keep "
        "its detail"), stacklevel=3)


def _miss_hint(space, sel: dict) -> str:
    """Why a plane / points selector picked nothing: the nearest node's distance and the tol to give."""
    if sel.get("plane") is not None:
        return plane_miss_hint(space, *sel["plane"], sel.get("tol"))
    if sel.get("points") is not None:
        return points_miss_hint(space, sel["points"], sel.get("tol"))
    return "check the selector (metres, in the mesh's frame)"


def _load_misses(space, ld: LoadSection) -> bool:
    """Whether a traction's box / points / plane selects no boundary face, or a point load lies farther from
    the surface than its radius (the errors after which the mesh's bounding box is worth stating)."""
    if ld.type == "traction" and ld.region is None:
        sel = ld.selector()
        return not len(select_faces(space, **{k: v for k, v in sel.items() if k != "region"}))
    if ld.type == "point":
        return bool(surface_distance(space, ld.point)[0] >= ld.radius)
    return False


def build_problem(cfg: FemConfig, base_dir: Path | None = None, mesh=None) -> Problem:
    """The FE problem of a configuration: mesh (``[mesh]``, or the given ``mesh``: e.g. a refined copy for a
    check solve or a finer truth), material, supports with their values (a later [[fix]] overrides an
    earlier one), loads, probes."""
    base_dir = base_dir or cfg._base_dir
    if mesh is None:
        mesh = build_mesh(cfg.mesh, base_dir)
    space = FESpace(mesh, cfg.fem.element)
    mat = cfg.material
    params = {k: v for k, v in mat.model_dump().items() if k not in ("model", "density") and v is not None}
    try:
        material = make_material(mat.model, **params)
    except ConfigError as exc:
        raise ConfigError(f"[material] {exc}") from None
    model = ElasticModel(space, material, density=mat.density)
    fix_dofs = []
    for i, f in enumerate(cfg.fix):
        mask = select_nodes_mask(space, **f.selector(), what=f"[[fix]] #{i + 1}")
        if not mask.any():
            if f.box is not None:
                raise ConfigError(f"[[fix]] #{i + 1}: no node lies in box {list(map(list, f.box))}; the mesh "
                                  f"spans {bounds_text(space.mesh.points)}")
            raise ConfigError(f"[[fix]] #{i + 1}: no node matches {f.describe()}; {_miss_hint(space, f.selector())}"
                              + ("" if f.region is not None else f"; the mesh spans {bounds_text(space.mesh.points)}"))
        nodes = np.flatnonzero(mask)
        fix_dofs.append({c: 3 * nodes + "xyz".index(c) for c in f.components})
    fixed = np.unique(np.concatenate([d for fd in fix_dofs for d in fd.values()] or [np.zeros(0, np.int64)]))
    fixed = fixed.astype(np.int64)
    prescribed = None
    if any(f.value is not None for f in cfg.fix):
        prescribed = np.zeros(space.n_dofs)
        for f, fd in zip(cfg.fix, fix_dofs):  # in file order: a later [[fix]] overrides an earlier one
            for c, dofs in fd.items():
                prescribed[dofs] = 0.0 if f.value is None else f.value["xyz".index(c)]
    f_ext = np.zeros(space.n_dofs)
    for i, ld in enumerate(cfg.load):
        try:
            if ld.type == "traction":
                sel = ld.selector()
                f_ext += traction_load(space, sel.pop("box"), ld.total, **sel)
            elif ld.type == "point":
                f_ext += point_load(space, ld.point, ld.total, ld.radius)
            else:
                if mat.density <= 0:
                    raise ConfigError("a gravity load needs [material] density > 0")
                f_ext += gravity_load(space, mat.density, ld.g)
        except ConfigError as exc:
            if _load_misses(space, ld):  # a box / point in other units than the mesh: show where the mesh is
                raise ConfigError(f"[[load]] #{i + 1}: {exc}; the mesh spans {bounds_text(space.mesh.points)}") \
                    from None
            raise ConfigError(f"[[load]] #{i + 1}: {exc}") from None
    probes = np.array([p.point for p in cfg.probe], dtype=float).reshape(-1, 3)
    return Problem(space, model, f_ext, fixed, probes, cfg, prescribed)


@dataclass(repr=False)
class FemResult:
    """A solved static problem. Two von Mises fields [Pa]:

    * ``von_mises`` (m,): per element, of the element-averaged stress (the VTU's cell field ``von_mises``);
      it reads low where the stress varies across an element (on the example cantilever, two elements deep,
      the peak is 28 % below beam theory's clamp stress, its nodal average 41-46 % low along the top fibre);
    * ``nodal_von_mises`` (n_points,): at the mesh vertices, of the stress recovered by
      :func:`physar.fem.post.nodal_stress` (each element's stress at its own vertices, volume-averaged at
      shared vertices; exact for the linear stress of P2 in bending). It is the VTU's point field
      ``von_mises`` and its peak is the summary's ``max_von_mises``.
    """

    problem: Problem
    static: StaticResult
    von_mises: np.ndarray  # per element, of the element-averaged stress [Pa]
    nodal_von_mises: np.ndarray | None = None  # at the mesh vertices, recovered [Pa]; None: computed on use

    def _nodal(self) -> np.ndarray:
        if self.nodal_von_mises is None:
            self.nodal_von_mises = nodal_von_mises(self.problem.model, self.static.u)
        return self.nodal_von_mises

    def __repr__(self) -> str:
        """One line: element, elements, dofs, largest displacement [m] and von Mises stress [Pa] (no arrays):
        the peak at the vertices when it has been computed (:func:`solve_problem` does), else that of the
        element means, labelled so (a repr computes no stress)."""
        sp_ = self.problem.space
        u = np.asarray(self.static.u, dtype=float).reshape(-1, 3)
        vm = np.asarray(self.von_mises, dtype=float)
        elem = float(vm.max()) if vm.size else float("nan")
        if self.nodal_von_mises is not None and np.size(self.nodal_von_mises):
            stress = (f"max von Mises {float(np.max(self.nodal_von_mises)):.4g} Pa at the vertices "
                      f"(element means {elem:.4g} Pa)")
        else:
            stress = f"max von Mises {elem:.4g} Pa (element means)"
        return (f"FemResult({sp_.element} on {sp_.mesh.name!r}, {sp_.mesh.n_cells} tetrahedra, {sp_.n_dofs} dofs, "
                f"max |u| {float(np.sqrt((u ** 2).sum(axis=1)).max()):.4g} m, {stress})")

    def summary(self) -> dict:
        """The `--json` summary: ``max_von_mises`` is the peak of the recovered vertex field
        (``nodal_von_mises``) and ``max_von_mises_point`` the vertex where it lies (near a clamp's edge or a
        point load the peak is singular and grows with refinement); ``max_von_mises_element_mean`` is the peak
        of the per-element field."""
        u = self.static.u.reshape(-1, 3)
        probes = [
            {"point": p.tolist(), "u": probe(self.problem.space, self.static.u, p).tolist()}
            for p in self.problem.probes
        ]
        vm = self._nodal()
        k = int(np.argmax(vm))
        return {
            "max_displacement": float(np.linalg.norm(u, axis=1).max()),
            "probes": probes,
            "newton_iterations": list(self.static.newton_iterations),
            "max_von_mises": float(vm[k]),
            "max_von_mises_point": self.problem.space.mesh.points[k].tolist(),
            "max_von_mises_element_mean": float(self.von_mises.max()),
            "dofs": int(self.problem.space.n_dofs),
            "elements": int(self.problem.space.mesh.n_cells),
            "element": self.problem.space.element,
            "material": self.problem.model.material.name,
        }

    def point_data(self) -> dict:
        """The VTU's point fields: ``displacement``, ``displacement_magnitude`` [m] and ``von_mises`` [Pa] (the
        recovered vertex field, ``nodal_von_mises``)."""
        sp_ = self.problem.space
        u = sp_.vertex_values(self.static.u)
        return {
            "displacement": u,
            "displacement_magnitude": np.linalg.norm(u, axis=1),
            "von_mises": self._nodal(),
        }


def solve_problem(problem: Problem, progress: Callable[[int, int], None] | None = None) -> FemResult:
    s = problem.config.solver
    for p in problem.probes:  # fail before the solve if a probe is outside the mesh
        probe(problem.space, np.zeros(problem.space.n_dofs), p)
    with np.errstate(over="ignore", invalid="ignore"):  # judged below, in one line, not as numpy warnings
        res = solve_static(problem.model, problem.f_ext, problem.fixed, steps=s.steps, tol=s.tol,
                           max_iter=s.max_iter, progress=progress, prescribed=problem.prescribed, linear=s.linear)
        u = np.linalg.norm(np.asarray(res.u).reshape(-1, 3), axis=1)  # inf where it overflows
    X = problem.space.mesh.points
    size = float(np.linalg.norm(X.max(0) - X.min(0)))
    if not np.all(np.isfinite(u)):
        raise PhysarError("the displacement is not finite: the stiffness is too small for the loads (check the "
                          "material's E, in Pa, and the loads, in N)")
    if u.max() > size:
        warnings.warn(f"the largest displacement, {u.max():.3g} m, exceeds the body's size ({size:.3g} m, its "
                      "bounding-box diagonal): check the material's E (Pa, not GPa or MPa) and the loads (N)",
                      PhysarWarning, stacklevel=2)
    return FemResult(problem, res, von_mises(problem.model, res.u), nodal_von_mises(problem.model, res.u))


def run_config(path: str | Path, progress=None) -> FemResult:
    """Load a problem file, build and solve it (the Python equivalent of `physar fem solve`)."""
    cfg = load_config(path)
    try:
        return solve_problem(build_problem(cfg), progress)
    except PhysarError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise type(exc)(f"{path}: {exc}") from None


__all__ = [
    "MATERIALS",
    "FemConfig",
    "FemResult",
    "Problem",
    "build_mesh",
    "build_problem",
    "check_mesh_size",
    "format_validation_error",
    "load_config",
    "parse_config",
    "read_toml",
    "run_config",
    "solve_problem",
]
