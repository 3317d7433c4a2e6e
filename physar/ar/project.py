"""The AR project file (TOML): what a user describes of their own object, camera and markers (seed 000 §2.1).

Nothing in it belongs to a synthetic renderer. A project holds

- ``[model]``: the reduced model, a ``physar rom build`` configuration (``config = "rom.toml"``, built on
  first use and cached in ``file``) or a built model file (``file = "model.npz"``). The model file carries
  the mesh, the material and the parameters (names, units, ranges, the load path), so the object's
  geometry comes from the model;
- ``[camera]``: the camera file written by ``physar calibrate``;
- ``[[marker]]``: ArUco markers fixed in the object's frame (on the object's clamp, a support or a board
  beside it), each with dictionary, id, side length and pose (centre, outward normal of its face, the
  direction of the marker image's top edge), on any face and in any number;
- ``[dots]``: printed dots at object coordinates on the surface, their colour and diameter;
- ``[overlay]``: the field drawn (|u|, a component, von Mises stress), its colour range, the
  exaggeration of the drawn displacement and which parameters are written with their std;
- ``[tracking]``: optional settings of the frame loop (defaults need no tuning).

Every error is one line naming the file, the table and the field (:func:`load_project`).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, PrivateAttr, Strict, field_validator, model_validator

from physar.errors import ConfigError
from physar.fem.config import _Strict  # extra keys forbidden, no bool/str -> number coercion

# strict scalars: no bool -> number or str -> number coercion (TOML arrays still become tuples)
Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
Str = Annotated[str, Strict()]
Bool = Annotated[bool, Strict()]
Vec3 = tuple[Float, Float, Float]




class ModelSection(_Strict):
    config: Str | None = Field(None, description="a `physar rom build` configuration (TOML), relative to the "
                                                 "project file; built on first use")
    file: Str | None = Field(None, description="the reduced model file (.npz): read if it exists (and was built "
                                               "from `config` when that is given), else written there")
    visible: Bool = Field(True, description="the modelled object is in the video (false: a virtual object driven "
                                            "by what is observed, like the seed's boot seal on a real lever)")

    @model_validator(mode="after")
    def _one(self):
        if self.config is None and self.file is None:
            raise ValueError("give config = \"rom.toml\" (a `physar rom build` file) and/or file = \"model.npz\"")
        return self


class CameraSection(_Strict):
    file: Str = Field(..., description="camera file written by `physar calibrate` (TOML)")
    scale: Float = Field(1.0, gt=0, le=16, description="image scale of the videos against the calibration [-]: a "
                         "video recorded in the calibrated mode and resized by this factor (0.5: 1280x720 -> "
                         "640x360, same field of view) is read with the camera scaled alike "
                         "(fx, fy times scale; cx, cy as (c + 0.5) scale - 0.5)")


class MarkerSection(_Strict):
    id: Int = Field(..., ge=0, description="ArUco id within the dictionary")
    size: Float = Field(..., gt=0, description="side length of the black square [m]")
    center: Vec3 = Field(..., description="centre of the marker in the object's frame [m]")
    normal: Vec3 = Field(..., description="outward normal of the face the marker is stuck on [-]")
    up: Vec3 = Field(..., description="direction of the marker image's top edge (from its centre to the top) [-]")
    dictionary: Str = Field("DICT_4X4_50", description="ArUco dictionary (one per project)")

    @model_validator(mode="after")
    def _frame(self):
        n, u = np.asarray(self.normal, float), np.asarray(self.up, float)
        if not np.linalg.norm(n) > 0 or not np.linalg.norm(u) > 0:
            raise ValueError("normal and up must be non-zero")
        c = abs(n @ u) / (np.linalg.norm(n) * np.linalg.norm(u))
        if c > 1e-3:
            raise ValueError(f"up {list(self.up)} must be perpendicular to normal {list(self.normal)} "
                             f"(cos = {c:.3g})")
        return self

    def corners(self) -> np.ndarray:
        r"""(4, 3) corners in ArUco order (top-left, top-right, bottom-right, bottom-left) seen from outside:
        :math:`\mathrm{right} = \mathrm{up} \times \mathrm{normal}`."""
        n = np.asarray(self.normal, float)
        n /= np.linalg.norm(n)
        u = np.asarray(self.up, float)
        u /= np.linalg.norm(u)
        r = np.cross(u, n)
        h = self.size / 2
        c = np.asarray(self.center, float)
        return np.array([c - r * h + u * h, c + r * h + u * h, c + r * h - u * h, c - r * h - u * h])


class DotsSection(_Strict):
    points: list[Vec3] = Field(..., min_length=1, description="dot centres on the object's surface [m]")
    colour: tuple[Int, Int, Int] = Field((30, 70, 200), description="printed colour, RGB 0-255")
    diameter: Float = Field(..., gt=0, description="dot diameter [m]")
    tol: Float | None = Field(None, gt=0, description="largest distance of a dot from the model's surface [m] "
                                                      "(default: a quarter of the diameter)")

    @field_validator("colour")
    @classmethod
    def _rgb(cls, v):
        if not all(0 <= c <= 255 for c in v):
            raise ValueError(f"colour must be RGB values in 0..255, got {list(v)}")
        return v


def _unit(v, what):
    a = np.asarray(v, float)
    n = float(np.linalg.norm(a))
    if not n > 0:
        raise ValueError(f"{what} must be a non-zero vector")
    return a / n


class PlaneSection(_Strict):
    """A planar textured surface fixed in the object's frame that gives the camera pose without markers in
    view: a support plate, a printed poster, the wall behind the object (seed 000 §5.2, §5.3.2)."""

    origin: Vec3 = Field(..., description="object coordinates of the top-left corner of the plane's image [m]")
    u: Vec3 = Field((1.0, 0.0, 0.0), description="direction of the image's rows (rightwards) in the object frame "
                                                 "[-]")
    v: Vec3 = Field((0.0, 0.0, -1.0), description="direction of the image's columns (downwards) [-]")
    image: Str | None = Field(None, description="reference image of the plane (its design file or a scan), "
                                                "relative to the project; none: learned from the first frame "
                                                "whose pose the markers give")
    px_per_m: Float | None = Field(None, gt=0, description="resolution of `image` [px/m]")
    distance: Float | None = Field(None, gt=0, description="typical distance of the camera from the plane [m] "
                                                           "(default: the plane fills 3/4 of the image width)")

    @model_validator(mode="after")
    def _check(self):
        u, v = _unit(self.u, "u"), _unit(self.v, "v")
        if abs(u @ v) > 1e-3:
            raise ValueError(f"u {list(self.u)} and v {list(self.v)} must be perpendicular")
        if self.image is not None and self.px_per_m is None:
            raise ValueError("image needs px_per_m (its resolution in pixels per metre)")
        return self


class RegistrationSection(_Strict):
    method: Literal["markers", "plane"] = Field("markers", description="camera pose from the [[marker]] tables "
                                                "in every frame, or from a textured plane ([registration.plane])")
    plane: PlaneSection | None = Field(None, description="the textured plane (needed by method = \"plane\")")

    @model_validator(mode="after")
    def _check(self):
        if self.method == "plane" and self.plane is None:
            raise ValueError("method = \"plane\" needs a [registration.plane] table")
        return self


class BarSection(_Strict):
    """A rigid bar (a lever) turned by a rotation parameter of the model about that parameter's axis, seen by
    its colour in the plane it turns in (seed 000 §5.3.2): the parameter is measured directly."""

    parameter: Str = Field(..., description="name of a rotation parameter of the model")
    zero: Vec3 = Field(..., description="direction from the pivot along the bar at parameter 0 (perpendicular "
                                        "to the rotation axis) [-]")
    length: Float = Field(..., gt=0, description="from the pivot to the bar's tip [m]")
    width: Float = Field(..., gt=0, description="width of the bar's visible face [m]")
    face: Float = Field(0.0, description="position of the bar's visible face along the rotation axis, from the "
                                         "axis point [m]")
    saturation_max: Int = Field(45, ge=0, le=255, description="the bar's colour: HSV saturation at most this")
    value_min: Int = Field(150, ge=0, le=255, description="the bar's colour: HSV value at least this")
    sigma: Float = Field(0.2, gt=0, description="std of one measurement, in the parameter's unit")


class FeaturesSection(_Strict):
    """The object's own texture on one planar face (seed 000 §5.2). Alone (``mode = "plane"``): features chosen
    in the first frames (the object at rest, :math:`u = 0`), tracked by Lucas-Kanade in the face's rectified
    view; their in-plane displacements are the observations. With ``[dots]`` (``mode = "points"``): features
    chosen on the face in the first tracked frame, placed on the model's deformed surface there, tracked in the
    image and used beside the dots as rows of the same (pose, parameters) solve, each group weighted by its own
    residual."""

    origin: Vec3 = Field(..., description="a corner of the face [m]")
    u: Vec3 = Field(..., description="direction of the face's first side [-]")
    v: Vec3 = Field(..., description="direction of its second side (perpendicular to u) [-]")
    size: tuple[Float, Float] = Field(..., description="lengths of the two sides [m]")
    margin: Float | None = Field(None, ge=0, description="rectified band around the face [m] (default: a "
                                                         "quarter of the shorter side)")
    reference_frames: Int = Field(8, ge=1, description="first frames showing the object at rest")
    mode: Literal["auto", "plane", "points"] = Field(
        "auto", description="how the features observe the parameters: \"plane\" (in-plane displacements in "
                            "the face's rectified view), \"points\" (image points in the joint solve with the "
                            "dots); auto: points with [dots], else plane")
    points: Int | None = Field(None, ge=3, le=20000, description="features tracked (default: 600 in plane mode, "
                                                                 "80 in points mode)")
    window_px: Int = Field(15, ge=5, le=61, description="Lucas-Kanade window")
    nuisance: Literal["none", "rigid", "similarity", "affine"] = Field(
        "similarity", description="apparent in-plane motion of the whole face removed from the observations "
                                  "(pose error between the registration plane and the face)")
    free_scale: Bool = Field(True, description="fit the displacement's amplitude as a nuisance (a stiffness "
                                               "error of the model does not bias the parameters)")
    rest_mm: Float = Field(1.0, ge=0, description="rms displacement below which the object is taken as at rest")
    ends: Bool = Field(False, description="correct the features' coordinates along u by the face's two ends seen "
                                          "against their surroundings (when the registration frame's pose is poor)")

    @model_validator(mode="after")
    def _check(self):
        u, v = _unit(self.u, "u"), _unit(self.v, "v")
        if abs(u @ v) > 1e-3:
            raise ValueError(f"u {list(self.u)} and v {list(self.v)} must be perpendicular")
        if not min(self.size) > 0:
            raise ValueError(f"size must be positive, got {list(self.size)}")
        return self


FIELDS = ("von_mises", "u", "ux", "uy", "uz")


class OverlaySection(_Strict):
    field: Literal["von_mises", "u", "ux", "uy", "uz"] = Field("von_mises", description="field drawn on the "
                                                                "deformed surface: von Mises stress [Pa], |u| or "
                                                                "a displacement component [m]")
    range: tuple[Float, Float] | None = Field(None, description="colour range in the field's unit (Pa for "
                                                                "von_mises, m for the displacements); default: 0 "
                                                                "to the largest 98th percentile of the field over "
                                                                "a grid of the parameter box")
    exaggeration: Float = Field(1.0, gt=0, description="scale of the drawn displacement [-]")
    alpha: Float = Field(0.65, ge=0, le=1, description="opacity of the drawn surface [-]")
    show: list[Str] | None = Field(None, description="parameters written as estimate ± std (default all)")
    faces: Int = Field(3000, ge=0, description="most triangles drawn [-]: a finer model surface is drawn as an "
                                               "even coarser triangulation carrying the model's field "
                                               "(drawing costs about 2 µs per triangle); 0: the model's own")

    @field_validator("range")
    @classmethod
    def _increasing(cls, v):
        if v is not None and not v[1] > v[0]:
            raise ValueError(f"range must be increasing, got {list(v)}")
        return v


class TrackingSection(_Strict):
    dot_sigma_px: Float = Field(0.3, gt=0, description="dot centroid noise [px]")
    corner_sigma_px: Float = Field(0.15, gt=0, description="marker corner noise [px]")
    min_dots: Int = Field(3, ge=1, description="fewest dots seen to assimilate a frame (else the estimate is held)")
    search_px: Float = Field(0.0, ge=0, description="extra search radius around each predicted dot [px] "
                                                    "(0: from the dot's size in the image)")
    joint_pose: Bool = Field(True, description="refine the camera pose together with the parameters (false: the pose held at the markers'; its uncertainty still enters the parameters' std)")
    filter: Literal["imm", "none"] = Field("imm", description="temporal filter of the estimates")


class ProjectConfig(_Strict):
    """Top level of an AR project file."""

    model: ModelSection = Field(..., description="the reduced model of the object")
    camera: CameraSection = Field(..., description="the calibrated camera")
    marker: list[MarkerSection] = Field(default_factory=list, description="ArUco markers fixed in the object's "
                                                                          "frame (one dictionary, distinct ids)")
    registration: RegistrationSection = Field(RegistrationSection(), description="how the camera pose is found "
                                                                                 "in each frame")
    dots: DotsSection | None = Field(None, description="printed dots on the surface, observing the parameters "
                                                       "(or [features] or [[bar]])")
    features: FeaturesSection | None = Field(None, description="the object's own texture on a planar face, "
                                                               "observing the parameters (alone, or beside [dots])")
    bar: list[BarSection] = Field(default_factory=list, description="rigid bars turned by rotation parameters, "
                                                                    "each measuring its parameter")
    overlay: OverlaySection = Field(OverlaySection(), description="what is drawn over the video")
    tracking: TrackingSection = Field(TrackingSection(), description="settings of the frame loop (the defaults "
                                                                     "need no tuning)")
    name: Str | None = Field(None, description="title of the project in plots (default: its folder's name)")
    _base_dir: Path = PrivateAttr(default=Path("."))

    @model_validator(mode="after")
    def _markers(self):
        reg = self.registration
        if reg.method == "markers" and not self.marker:
            raise ValueError("the camera pose needs [[marker]] tables, or [registration] method = \"plane\"")
        if reg.method == "plane" and reg.plane.image is None and not self.marker:
            raise ValueError("[registration.plane] without an image is learned from a frame registered by "
                             "markers: give [[marker]] tables or the plane's image")
        if self.dots is None and self.features is None and not self.bar:
            raise ValueError("nothing observes the parameters: give [dots], [features] or [[bar]]")
        if self.features is not None and self.features.mode == "points" and self.dots is None:
            raise ValueError("[features] mode = \"points\" needs [dots] (the first tracked frame places the "
                             "features on the object); without dots use mode = \"plane\"")
        if self.features is not None and self.features.mode == "plane" and self.dots is not None:
            raise ValueError("[features] mode = \"plane\" cannot be used with [dots]: give mode = \"points\" "
                             "(or leave it out)")
        ids = [m.id for m in self.marker]
        if len(set(ids)) != len(ids):
            twice = next(i for i in ids if ids.count(i) > 1)
            raise ValueError(f"[[marker]] id {twice} is given twice (ids must be distinct, got {ids})")
        first = self.marker[0] if self.marker else None
        other = next((m for m in self.marker if m.dictionary != first.dictionary), None)
        if other is not None:
            raise ValueError(f"[[marker]] id {other.id}: dictionary {other.dictionary!r} differs from "
                             f"{first.dictionary!r} of [[marker]] id {first.id} (one dictionary per project)")
        return self


@dataclass
class ARProject:
    """A validated project with its files resolved: the reduced model (``rom``, a SeparatedModel with its
    mesh), the camera, the marker board, the dots and the overlay/tracking settings. ``source`` is the
    project file (for messages)."""

    config: ProjectConfig
    source: str
    rom: object
    camera: object
    board: object            # MarkerBoard, or None without markers
    dots: np.ndarray         # (n, 3), empty without [dots]
    dot_normals: np.ndarray
    plane_image: np.ndarray | None = None   # [registration.plane] image (BGR)

    @property
    def overlay(self) -> OverlaySection:
        return self.config.overlay

    @property
    def tracking(self) -> TrackingSection:
        return self.config.tracking

    def space(self):
        return self.rom.space()

    def parameters(self) -> list[dict]:
        """The model's parameters as built: name, unit, range and (from the build configuration) kind,
        path/load for a load position."""
        return _parameters(self.rom)


def read_project_toml(path) -> dict:
    from physar.fem.config import read_toml

    return read_toml(path)


def marker_name(tables, k: int) -> str:
    """How every message names the k-th ``[[marker]]`` table: ``[[marker]] id N`` (its id), or
    ``[[marker]] table K`` (1-based) when it has no integer id."""
    t = tables[k] if isinstance(tables, list) and 0 <= k < len(tables) else None
    i = t.get("id") if isinstance(t, dict) else getattr(t, "id", None)
    return f"[[marker]] id {i}" if isinstance(i, int) and not isinstance(i, bool) else f"[[marker]] table {k + 1}"


def parse_project(data: dict, source: str) -> ProjectConfig:
    """Validate a project's TOML data; ConfigError (one line) naming the file, the table and the key. A
    ``[[marker]]`` table is named by its id (:func:`marker_name`), as in every other message about markers."""
    from pydantic import ValidationError

    from physar.errors import format_validation_error

    try:
        cfg = ProjectConfig.model_validate(data)
    except ValidationError as exc:
        msg = format_validation_error(exc, source, ProjectConfig, data=data)
        loc = exc.errors()[0]["loc"]
        if len(loc) >= 2 and loc[0] == "marker" and isinstance(loc[1], int):
            msg = _name_marker(msg, loc, marker_name(data.get("marker"), loc[1]))
        msg = msg.replace(": [top level] [[marker]]", ": [[marker]]", 1)   # a check across the tables
        raise ConfigError(msg) from None
    if cfg.marker:      # every id within the dictionary (here, so that `ar print-markers` says it too)
        from physar.vision.calibration import aruco_dictionary

        dictionary = cfg.marker[0].dictionary
        try:
            dic = aruco_dictionary(dictionary)
        except ConfigError as e:
            raise ConfigError(f"{source}: [[marker]] id {cfg.marker[0].id}: dictionary: {e}") from None
        n_ids = dic.bytesList.shape[0]
        for m in cfg.marker:
            if m.id >= n_ids:
                raise ConfigError(f"{source}: [[marker]] id {m.id} is outside {dictionary} (ids 0-{n_ids - 1})")
    return cfg


def _name_marker(msg: str, loc: tuple, name: str) -> str:
    """``msg`` of an error at ``loc`` = ("marker", k, key...) with the table's pydantic location (``[marker.k.key]``,
    ``[marker.k]``, ``marker.k.key``, ``in [marker]``) replaced by ``name`` (``[[marker]] id N``)."""
    import re

    k = loc[1]
    for pat, fmt in ((rf"\[marker\.{k}\.([^\]]+)\] ", "{name}: {key}: "), (rf"\[marker\.{k}\] ", "{name}: "),
                     (rf"(?<![\w\[.])marker\.{k}\.([\w.]+)", "{name}: {key}"), (r"in \[marker\]", "in {name}")):
        out, n = re.subn(pat, lambda m, fmt=fmt: fmt.format(name=name, key=m.group(1) if m.groups() else ""), msg,
                         count=1)
        if n:
            return out
    return msg


def _file(base: Path, name: str) -> Path:
    p = Path(name)
    return p if p.is_absolute() else base / p


def _config_inputs(path: Path) -> list[Path]:
    """The files a rom.toml reads besides itself: its ``[mesh] file`` (the only file input of a
    `physar rom build` file), resolved against the file's folder; none if it does not parse (the build
    then reports the error)."""
    import tomllib

    try:
        mesh = tomllib.loads(path.read_text()).get("mesh", {})
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return []
    f = mesh.get("file") if isinstance(mesh, dict) else None
    return [_file(path.parent, f)] if isinstance(f, str) else []


def _config_hash(path: Path) -> str:
    """SHA-256 of a rom.toml and of the content of its file inputs (:func:`_config_inputs`: the mesh or
    surface file), so that editing either rebuilds the model. A missing input hashes as missing (the
    build then names it)."""
    h = hashlib.sha256(path.read_bytes())
    for f in _config_inputs(path):
        h.update(b"\0input\0" + str(f.name).encode())
        h.update(hashlib.sha256(f.read_bytes()).digest() if f.is_file() else b"missing")
    return h.hexdigest()


def load_model(cfg: ProjectConfig, source: str, progress=None, build: bool = True):
    """The project's reduced model: ``[model] file`` if it exists (and, when ``config`` is given too, was
    built from that configuration as it is now: the SHA-256 of the rom.toml and of its mesh file is stored
    in the model, :func:`_config_hash`), else built from
    ``[model] config`` (``physar rom build``) and, if ``file`` is given, written there atomically."""
    from physar.rom import SeparatedModel
    from physar.rom.config import build_rom, load_rom_config

    base = cfg._base_dir
    m = cfg.model
    file = _file(base, m.file) if m.file else None
    conf = _file(base, m.config) if m.config else None
    if conf is not None and not conf.is_file():
        raise ConfigError(f"{source}: [model] config = {m.config!r}: file not found")
    digest = _config_hash(conf) if conf is not None else None
    if file is not None and file.is_file():
        rom = SeparatedModel.load(file)
        if digest is None or rom.metadata.get("config_sha256") == digest:
            return rom
        if not build:
            also = "".join(f" and {f.name}" for f in _config_inputs(conf))
            raise ConfigError(f"{source}: [model] file = {m.file!r} was not built from {m.config!r}{also} as they "
                              "are now; rebuild it by running `physar synth render` or `physar ar run` on this project (or "
                              "delete the file)")
    elif file is not None and conf is None:
        raise ConfigError(f"{source}: [model] file = {m.file!r}: file not found (give config = \"rom.toml\" to "
                          "build it)")
    rcfg = load_rom_config(conf)
    rom, space, _ = build_rom(rcfg, progress=progress, source=str(conf))
    rom.metadata.update(config_sha256=digest, element=space.element, mesh_checksum=space.mesh.checksum())
    rom._mesh_arrays = (space.mesh.points, space.mesh.cells)
    rom.__dict__["_space_cache"] = [space]
    if file is not None:
        rom.save(file, space=space)
    return rom


def _camera(cfg, source: str):
    from physar.vision.camera import Camera

    cam_path = _file(cfg._base_dir, cfg.camera.file)
    try:
        camera = Camera.load(cam_path)
    except ConfigError as e:
        raise ConfigError(f"{source}: [camera] file: {e}") from None
    return camera.scaled(cfg.camera.scale) if cfg.camera.scale != 1.0 else camera


def project_camera(path) -> tuple:
    """(camera, scale) of the AR project file ``path``: its ``[camera]`` file scaled by ``[camera] scale``, read
    without the model, so that a video's size can be checked against it before a model is built."""
    path = Path(path)
    cfg = parse_project(read_project_toml(path), str(path))
    cfg._base_dir = path.resolve().parent
    return _camera(cfg, str(path)), cfg.camera.scale


def load_project(path, progress=None, build: bool = True) -> ARProject:
    """Read, validate and resolve an AR project file (model built if needed, see :func:`load_model`).

    Checks beyond the schema, each one clear line: the camera file, every marker id within its dictionary,
    every dot on the model's surface (within ``[dots] tol``), ``[overlay] show`` naming the model's
    parameters. The camera's resolution is checked against the video when a source is opened."""
    from physar.vision.markers import MarkerBoard

    path = Path(path)
    source = str(path)
    cfg = parse_project(read_project_toml(path), source)
    cfg._base_dir = path.resolve().parent
    camera = _camera(cfg, source)
    board = None
    if cfg.marker:      # (ids and dictionary checked by parse_project)
        board = MarkerBoard([m.id for m in cfg.marker], np.stack([m.corners() for m in cfg.marker]),
                            cfg.marker[0].dictionary)
    plane_image = None
    pl = cfg.registration.plane
    if pl is not None and pl.image is not None:
        plane_image = _read_image(_file(cfg._base_dir, pl.image), f"{source}: [registration.plane] image")
    rom = load_model(cfg, source, progress=progress, build=build)
    space = rom.space()
    dots, normals = np.zeros((0, 3)), np.zeros((0, 3))
    if cfg.dots is not None:
        dots = np.asarray(cfg.dots.points, float)
        normals = _dot_normals(space, dots, cfg.dots.tol or cfg.dots.diameter / 4, source)
    params = {p["name"]: p for p in _parameters(rom)}
    for k, b in enumerate(cfg.bar):
        p = params.get(b.parameter)
        if p is None:
            raise ConfigError(f"{source}: [[bar]] {k + 1}: parameter = {b.parameter!r} is not a parameter of the "
                              f"model (parameters: {', '.join(rom.names)})")
        if p.get("kind") != "rotation":
            raise ConfigError(f"{source}: [[bar]] {k + 1}: parameter {b.parameter!r} is a {p.get('kind')} "
                              "parameter; a bar measures a rotation")
        axis = _unit(p["axis"], "axis")
        if abs(_unit(b.zero, "zero") @ axis) > 1e-3:
            raise ConfigError(f"{source}: [[bar]] {k + 1}: zero = {list(b.zero)} must be perpendicular to the "
                              f"rotation axis {list(p['axis'])}")
    if len({b.parameter for b in cfg.bar}) < len(cfg.bar):
        raise ConfigError(f"{source}: [[bar]]: two bars measure the same parameter")
    if cfg.dots is None and cfg.features is None:
        unobserved = [n for n in rom.names if n not in {b.parameter for b in cfg.bar}]
        if unobserved:
            raise ConfigError(f"{source}: parameters {unobserved} are observed by nothing (give [dots] or "
                              "[features], or a [[bar]] for each)")
    if cfg.overlay.show is not None:
        bad = [s for s in cfg.overlay.show if s not in rom.names]
        if bad:
            raise ConfigError(f"{source}: [overlay] show = {bad} is not a parameter of the model "
                              f"(parameters: {', '.join(rom.names)})")
    return ARProject(cfg, source, rom, camera, board, dots, normals, plane_image)


def _read_image(path: Path, what: str) -> np.ndarray:
    import cv2

    if not path.is_file():
        raise ConfigError(f"{what} = {str(path)!r}: file not found")
    try:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    except cv2.error:  # OpenCV refuses a header announcing more than 2**30 pixels
        img = None
    if img is None or min(img.shape[:2]) < 16:
        raise ConfigError(f"{what} = {str(path)!r}: not an image OpenCV reads (PNG, JPEG, ...) of at least 16 px")
    return img


def _parameters(rom) -> list[dict]:
    meta = rom.metadata.get("parameters") or []
    out = []
    for j, (n, u, r) in enumerate(zip(rom.names, rom.units, rom.ranges)):
        d = dict(meta[j]) if j < len(meta) else {}
        d.update(name=n, unit=u, range=[float(r[0]), float(r[1])])
        out.append(d)
    return out


def _dot_normals(space, dots, tol, source) -> np.ndarray:
    """Outward unit normals (n, 3) of the surface at the dots; a dot farther than ``tol`` from the surface
    is an error naming it."""
    from physar.vision.observation import closest_on_triangles

    surf = space.mesh.boundary().mesh
    tri = surf.points[surf.faces]
    f, _, dist = closest_on_triangles(dots, tri)
    far = np.flatnonzero(dist > tol)
    if far.size:
        k = int(far[np.argmax(dist[far])])
        raise ConfigError(f"{source}: [dots] points[{k}] = {dots[k].tolist()} is {dist[k] * 1e3:.3g} mm from the "
                          f"model's surface (tol {tol * 1e3:.3g} mm)")
    n = np.cross(tri[f, 1] - tri[f, 0], tri[f, 2] - tri[f, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    # orient outward: away from the centroid of the tets touching the face is not at hand here, so use the
    # surface's own orientation (boundary faces are outward-oriented, checked in geometry)
    return n


TEMPLATE = '''# physar AR project: your object, your camera, your markers.  `physar ar run project.toml VIDEO|CAMERA|URL`
# Every length is in metres, in the object's frame (the frame of the model's mesh).
name = "my-object"

[model]
config = "rom.toml"        # a `physar rom build` file: mesh (box, or a VTU/XDMF/MSH file, or a closed STL/OBJ/PLY
                           # surface), material, supports, [[parameter]] tables (load position along a path,
                           # magnitude, ...)
file = "model.npz"         # the built reduced model (written on first use, rebuilt when rom.toml changes)

[camera]
file = "camera.toml"       # `physar calibrate board_*.png -o camera.toml` (print the board with --print-board)
# scale = 0.5              # videos resized from the calibrated mode (1280x720 -> 640x360): camera scaled alike

[[marker]]                 # one table per ArUco marker (any number, on any face); print them with
id = 0                     # `physar ar print-markers project.toml -o markers.pdf`
size = 0.04                # side of the black square [m]
center = [0.02, -0.001, 0.05]
normal = [0, -1, 0]        # outward normal of the face it is stuck on
up = [0, 0, 1]             # direction of the marker's top edge
dictionary = "DICT_4X4_50"

[dots]                     # printed dots on the surface, tracked in every frame
points = [[0.1, 0.0, 0.0075], [0.2, 0.0, 0.0075], [0.3, 0.0, 0.0075]]
diameter = 0.005           # [m]
colour = [30, 70, 200]     # RGB of the printed dots

# Nothing stuck on the object? (README "Markerless AR"; examples/ar/foam, examples/ar/seal)
# [registration] method = "plane" + [registration.plane] origin, u, v and image + px_per_m: the pose from a
#                textured plate (its design image), or no image: learned from the first frame the markers give
# [features]     origin, u, v, size of a textured face of the object, tracked from the first frames (at rest);
#                beside [dots]: its texture's corners become more observed points of the same solve
# [[bar]]        parameter, zero, length, width, face: a lever turned by a rotation parameter, seen by colour

[overlay]
field = "von_mises"        # von_mises | u | ux | uy | uz
# range = [0, 100e6]       # colour range (Pa or m); default 0 .. the field's maximum
exaggeration = 1.0
# show = ["s"]             # parameters written as estimate ± std (default all)
# faces = 3000             # most triangles drawn (a finer model surface is drawn coarser); 0: all

[tracking]                 # optional; the defaults need no tuning
# dot_sigma_px = 0.3
# min_dots = 3
'''


__all__ = ["ARProject", "ProjectConfig", "load_model", "load_project", "project_camera"]  # TEMPLATE: `physar ar init`
