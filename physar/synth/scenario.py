"""The scenario file (TOML) of a synthetic clip of an AR project: only what is synthetic.

The object, its model, markers, dots and camera intrinsics come from the project file; a scenario holds the
video settings, the parameter schedule, the camera trajectory, the lighting, the sensor, the surface texture,
occlusions, the truth refinement and the seed. Every key has a default that gives a sensible clip for any
project: the camera looks at the centre of the model mesh's bounding box from the side the dots and markers
face, at the distance where the object and its markers fill the field of view.

```toml
seed = 0
[video]        # width, height (default: the camera's; another size of the same aspect scales the camera),
               # fps = 30, duration = 8 (s), crf = 18
[schedule]     # rest_until [s]: before it the object is at rest (u = 0, no load body) whatever the schedule
               # (truth.csv at_rest = 1, not scored); markers_until [s]: the markers are drawn only before it
               # (e.g. markers on the wall that register the first frame, then removed); default: always
[schedule.s]   # one table per model parameter (default: a sweep of load_position over 90 % .. 10 % of its
keyframes = [[0, 0.45], [1.5, 0.45], [2, 0.3]]   # range with dwells, other parameters at mid-range)
interp = "smooth"   # "smooth" (smooth-step between keyframes; equal values = a dwell) | "linear"
[camera]       # target [m] (bbox centre), distance [m], azimuth/elevation [deg] of the camera seen from the
               # target (from the mean normal of the dots, markers, plane, bars and features face),
               # orbit = [d_azimuth, d_elevation] deg, period [s], shake_mm, shake_deg, up = [0, 0, 1]
[[camera.pan]] # the camera looks away and back: start [s], duration [s], yaw [deg], ramp [s]; it turns
               # about the vertical (up) through its own centre: R = R_base R_up(a), t = -R c
[lighting]     # ambient, direction (towards the light), brightness (0.4: dimmed), flicker, vignetting
[sensor]       # read_noise [DN], shot_noise, psf [px], motion_blur (fraction of the frame interval)
[texture]      # base = RGB, contrast, feature [m] (finest noise feature; default 3 px at the target), octaves,
               # pores (area fraction of dark pores, foam-like), pore_size [m] (default 4 feature)
[background]   # base = RGB, contrast, distance [m] behind the target; with a project [registration.plane]
               # without image the wall IS that plane (the pipeline learns its texture)
[bar]          # look of the project's [[bar]] levers: colour = RGB (white), thickness (fraction of width)
[plane]        # look of a [registration.plane] with an image: border [m] (dark rim), border_colour
[load_body]    # a body drawn at the load point while loaded (a lead disk): diameter, thickness [m], colour
[[occlusion]]  # start [s], frames, center = [u, v] (image fractions) or point = [x, y, z] (m), radius
               # (fraction of the image height), colour = RGB
[truth]        # refine = 2 (times finer than the model mesh); mesh_size = 0.0035 (m: remesh a surface first)
```

A model with ``[model] visible = false`` (a virtual object) is not drawn and has no finer truth: the truth of its
parameters is the schedule.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import ConfigDict, Field, Strict, model_validator

from physar.errors import ConfigError
from physar.fem.config import _Strict as _StrictBase  # extra keys forbidden, no bool/str -> number coercion

Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
Vec3 = tuple[float, float, float]
RGB = tuple[Int, Int, Int]


class _Strict(_StrictBase):
    """Every scenario table: unknown keys refused, no coercion, and no inf or nan anywhere (``distance = inf``
    or ``fps = nan`` would otherwise pass the range checks and hang the renderer or write a NaN clip)."""

    model_config = ConfigDict(allow_inf_nan=False)


def _nonzero(v, what: str):
    if v is not None and not math.hypot(*v) > 0:
        raise ValueError(f"{what} must be a non-zero vector, got {list(v)}")
    return v


def _rgb_ok(v):
    if v is not None and not all(0 <= c <= 255 for c in v):
        raise ValueError(f"colour must be RGB values in 0..255, got {list(v)}")
    return v


class VideoSection(_Strict):
    width: Int | None = Field(None, ge=16, le=7680, description="frame width [px] (default: the camera's)")
    height: Int | None = Field(None, ge=16, le=4320, description="frame height [px] (default: the camera's)")
    fps: float = Field(30.0, gt=0, le=240, description="frame rate [fps]")
    duration: float = Field(8.0, gt=0, le=600, description="length of the clip [s]")
    crf: Int = Field(18, ge=0, le=51, description="H.264 constant rate factor")


class Schedule(_Strict):
    """``[schedule.NAME]``: the value of the model parameter NAME over time (default: a sweep of the load
    position over 90 % .. 10 % of its range with dwells, the other parameters at mid-range)."""

    keyframes: list[tuple[float, float]] = Field(..., min_length=1, description="[[t, value], ...]: time in s "
                                                 "(increasing), value in the parameter's unit; constant before the "
                                                 "first and after the last")
    interp: Literal["smooth", "linear"] = Field("smooth", description="between keyframes: smooth (smooth-step; "
                                                                     "equal values make a dwell) or linear")

    @model_validator(mode="after")
    def _times(self):
        t = [k[0] for k in self.keyframes]
        if any(b <= a for a, b in itertools.pairwise(t)):
            raise ValueError(f"keyframe times must increase, got {t}")
        return self

    def value(self, t: np.ndarray | float) -> np.ndarray:
        """Value at time(s) t: constant before the first / after the last keyframe."""
        k = np.asarray(self.keyframes, float)
        ta = np.asarray(t, float)
        if len(k) == 1:
            return np.full_like(ta, k[0, 1])
        i = np.clip(np.searchsorted(k[:, 0], ta, side="right") - 1, 0, len(k) - 2)
        a = np.clip((ta - k[i, 0]) / (k[i + 1, 0] - k[i, 0]), 0.0, 1.0)
        if self.interp == "smooth":
            a = a * a * (3 - 2 * a)
        return k[i, 1] + a * (k[i + 1, 1] - k[i, 1])


class ScheduleSection(_Strict):
    """``[schedule]``: events of the clip, and one ``[schedule.NAME]`` table per model parameter."""

    model_config = ConfigDict(extra="allow")
    rest_until: float = Field(0.0, ge=0, description="the object is at rest (u = 0, no load body; not scored) "
                                                     "before this time [s]")
    markers_until: float | None = Field(None, ge=0, description="the markers are drawn only before this time [s] "
                                                                "(default: always)")
    __pydantic_extra__: dict[str, Schedule] = Field(init=False)

    @property
    def parameters(self) -> dict[str, Schedule]:
        """{parameter name: Schedule} of the [schedule.NAME] tables."""
        return dict(self.__pydantic_extra__ or {})


class Pan(_Strict):
    """The camera turns away by ``yaw`` about the vertical through its centre, holds, and turns back."""

    start: float = Field(..., ge=0, description="time the camera starts turning away [s]")
    duration: float = Field(..., gt=0, description="length of the pan: turn away, hold, turn back [s]")
    yaw: float = Field(45.0, ge=-180, le=180, description="deg, right hand about up")
    ramp: float = Field(0.5, gt=0, description="s to turn away (and back), cosine profile")

    def angle(self, t: float) -> float:
        r"""Yaw [deg] at time :math:`t`: 0 outside
        :math:`[\mathrm{start}, \mathrm{start} + \mathrm{duration}]`,
        :math:`\mathrm{yaw}\, (1 - \cos(\pi r)) / 2` inside, with
        :math:`r = \min(\tau / \mathrm{ramp},\ (\mathrm{duration} - \tau) / \mathrm{ramp},\ 1)` and
        :math:`\tau = t - \mathrm{start}`."""
        tau = t - self.start
        if not 0 <= tau <= self.duration:
            return 0.0
        r = min(tau / self.ramp, (self.duration - tau) / self.ramp, 1.0)
        return self.yaw * 0.5 * (1 - math.cos(math.pi * r))


class CameraSection(_Strict):
    target: Vec3 | None = Field(None, description="point looked at [m] (default: model bbox centre)")
    distance: float | None = Field(None, gt=0, description="distance of the camera from the target [m] (default: "
                                                          "object and markers fill the view)")
    azimuth: float | None = Field(None, description="deg, direction target -> camera in the xy plane from +x")
    elevation: float | None = Field(None, ge=-89, le=89, description="deg above the xy plane")
    orbit: tuple[float, float] = Field((8.0, 4.0), description="amplitudes of azimuth, elevation [deg]")
    period: float = Field(12.0, gt=0, description="orbit period [s]")
    shake_mm: float = Field(1.0, ge=0, description="amplitude of the handheld shake of the camera's position "
                                                   "[mm]")
    shake_deg: float = Field(0.2, ge=0, description="amplitude of the handheld shake of azimuth, elevation and "
                                                    "roll [deg]")
    up: Vec3 = Field((0.0, 0.0, 1.0), description="the vertical: azimuth and elevation are measured about it and "
                                                  "the camera pans about it [-]")
    pan: list[Pan] = Field(default_factory=list, description="events where the camera looks away and back")

    @model_validator(mode="after")
    def _up(self):
        _nonzero(self.up, "up")
        return self


class LightingSection(_Strict):
    ambient: float = Field(0.35, ge=0, le=1, description="ambient share a of the Lambert shading a + (1 - a) "
                                                         "max(0, n·l) [-]")
    direction: Vec3 | None = Field(None, description="towards the light (default: from the camera side, above) [-]")
    brightness: float = Field(1.0, gt=0, le=4, description="global factor (0.4: dimmed light) [-]")
    flicker: float = Field(0.02, ge=0, le=0.5, description="relative amplitude of a sinusoidal brightness "
                                                           "flicker [-]")
    vignetting: float = Field(0.2, ge=0, le=1, description="brightness lost at the image corners: gain 1 - "
                                                           "vignetting r², r relative to the half diagonal [-]")

    @model_validator(mode="after")
    def _direction(self):
        _nonzero(self.direction, "direction")
        return self


class SensorSection(_Strict):
    read_noise: float = Field(1.5, ge=0, description="std of the read noise [DN]")
    shot_noise: float = Field(0.25, ge=0, description="std = shot_noise * sqrt(intensity in DN) [sqrt(DN)]")
    psf: float = Field(0.6, ge=0, le=5, description="Gaussian blur sigma [px]")
    motion_blur: float = Field(0.0, ge=0, le=1, description="shutter time as a fraction of the frame interval "
                                                             "(blur along the target's image motion) [-]")


class TextureSection(_Strict):
    base: RGB = Field((178, 172, 160), description="mean albedo of the object's surface, RGB 0-255")
    contrast: float = Field(0.12, ge=0, le=1, description="relative std of the procedural noise [-]")
    feature: float | None = Field(None, gt=0, description="finest noise feature [m] (default 3 px at the target)")
    octaves: Int = Field(4, ge=1, le=8, description="octaves of the band-limited noise, from `feature` up, "
                                                    "each twice as coarse and twice as strong")
    pores: float = Field(0.0, ge=0, le=0.6, description="area fraction of dark pores (foam-like texture) [-]")
    pore_size: float | None = Field(None, gt=0, description="pore diameter [m] (default 4 feature)")

    @model_validator(mode="after")
    def _rgb(self):
        _rgb_ok(self.base)
        return self


class BackgroundSection(_Strict):
    base: RGB = Field((120, 128, 138), description="mean colour of the wall behind the object, RGB 0-255")
    contrast: float = Field(0.2, ge=0, le=1, description="relative std of the wall's procedural noise [-]")
    distance: float | None = Field(None, gt=0, description="wall behind the target [m] (default 2x object size)")

    @model_validator(mode="after")
    def _rgb(self):
        _rgb_ok(self.base)
        return self


class BarLook(_Strict):
    colour: RGB = Field((236, 238, 240), description="colour of the bars, RGB 0-255")
    thickness: float = Field(0.3, gt=0, le=5, description="depth of the box behind the bar's visible face, as a "
                                                          "fraction of the bar's width [-]")

    @model_validator(mode="after")
    def _rgb(self):
        _rgb_ok(self.colour)
        return self


class PlaneLook(_Strict):
    border: float = Field(0.0, ge=0, description="dark rim around the plane's image [m] (a plate's edge)")
    border_colour: RGB = Field((45, 40, 40), description="colour of the rim, RGB 0-255")

    @model_validator(mode="after")
    def _rgb(self):
        _rgb_ok(self.border_colour)
        return self


class LoadBody(_Strict):
    """A cylinder standing on the loaded surface at the load point (the path point of the load_position
    parameter, plus its offset), axis along -load, drawn while the object is loaded (not at rest)."""

    diameter: float = Field(..., gt=0, description="diameter of the cylinder [m]")
    thickness: float = Field(..., gt=0, description="height of the cylinder along its axis [m]")
    colour: RGB = Field((96, 90, 88), description="colour of the body, RGB 0-255")

    @model_validator(mode="after")
    def _rgb(self):
        _rgb_ok(self.colour)
        return self


class Occlusion(_Strict):
    start: float = Field(..., ge=0, description="time the occluder appears [s]")
    frames: Int = Field(..., gt=0, description="number of frames the occluder stays")
    center: tuple[float, float] | None = Field(None, description="centre of the blob in image fractions (u, v) [-]")
    point: Vec3 | None = Field(None, description="object point [m] the blob covers")
    radius: float = Field(0.15, gt=0, le=2, description="radius of the blob as a fraction of the image height [-]")
    colour: RGB = Field((40, 38, 36), description="colour of the blob, RGB 0-255")

    @model_validator(mode="after")
    def _one(self):
        if (self.center is None) == (self.point is None):
            raise ValueError("give exactly one of center = [u, v] (image fractions) or point = [x, y, z]")
        _rgb_ok(self.colour)
        return self


class TruthSection(_Strict):
    refine: Int = Field(2, ge=2, le=8, description="times finer than the model mesh")
    mesh_size: Float | None = Field(None, gt=0, description="for a model meshed from a surface file: mesh the "
                                                            "surface again at this element size [m] before "
                                                            "refining (a truth mesh independent of the model's); "
                                                            "default: refine the model's own mesh")


class Scenario(_Strict):
    """Top level of a scenario file."""

    seed: Int = Field(0, description="seed of the clip's random draws (textures, camera shake, flicker, sensor "
                                     "noise)")
    video: VideoSection = Field(VideoSection(), description="frame size, rate, duration and encoding")
    schedule: ScheduleSection = Field(ScheduleSection(), description="the parameters over time and the clip's "
                                                                     "events")
    camera: CameraSection = Field(CameraSection(), description="the camera's trajectory")
    lighting: LightingSection = Field(LightingSection(), description="light direction, brightness, flicker, "
                                                                     "vignetting")
    sensor: SensorSection = Field(SensorSection(), description="sensor noise and blur")
    texture: TextureSection = Field(TextureSection(), description="procedural texture of the object's surface")
    background: BackgroundSection = Field(BackgroundSection(), description="the wall behind the object")
    bar: BarLook = Field(BarLook(), description="look of the project's [[bar]] levers")
    plane: PlaneLook = Field(PlaneLook(), description="look of the project's [registration.plane] with an image")
    load_body: LoadBody | None = Field(None, description="a body drawn at the load point while loaded (default "
                                                         "none)")
    occlusion: list[Occlusion] = Field(default_factory=list, description="blobs hiding part of the image for a "
                                                                        "few frames")
    truth: TruthSection = Field(TruthSection(), description="refinement of the truth's finer mesh")

    @property
    def n_frames(self) -> int:
        return max(1, round(self.video.duration * self.video.fps))


def parse_scenario(data: dict, source: str = "scenario") -> Scenario:
    from physar.fem.config import parse_config

    return parse_config(data, source, Scenario)


def load_scenario(path, project=None) -> Scenario:
    """Read and validate a scenario TOML (one-line ConfigError naming the file, table and key); with a
    project, also check it against the model (:func:`check_scenario`)."""
    from physar.fem.config import read_toml

    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path}: scenario file is a folder; give the TOML file")
    try:
        data = read_toml(path)
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not a scenario file: byte {e.object[e.start]:#04x} at offset {e.start} is not "
                          "UTF-8 text (a binary file?)") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the scenario file ({e.strerror})") from None
    sc = parse_scenario(data, str(path))
    if project is not None:
        check_scenario(sc, project, str(path))
    return sc


def resolve(sc: Scenario, project, quick: bool = False, source: str = "scenario") -> Resolved:
    """:class:`Resolved` with its ConfigErrors (a frame size of another aspect than the camera's, an odd one)
    naming ``source`` (the scenario file, or the project whose defaults were used), and the camera's path
    checked: an elevation plus its orbit and shake amplitudes reaching the vertical (the view parallel to
    ``up``: no camera orientation) is refused before any frame is drawn."""
    try:
        res = Resolved(sc, project, quick=quick)
    except ConfigError as e:
        raise ConfigError(f"{source}: {e}") from None
    c = sc.camera
    reach = abs(res.elevation) + abs(c.orbit[1]) + c.shake_deg
    if not reach < 89.0:
        raise ConfigError(f"{source}: [camera] elevation {res.elevation:g} deg with orbit = {list(c.orbit)} and "
                          f"shake_deg = {c.shake_deg:g} reaches {reach:g} deg, the vertical (up): keep |elevation| + "
                          "|orbit[1]| + shake_deg below 89")
    return res


def check_scenario(sc: Scenario, project, source: str) -> None:
    """Schedules must name parameters of the model and stay within their ranges."""
    rom = project.rom
    if sc.load_body is not None and not any(p.get("kind") == "load_position" for p in project.parameters()):
        raise ConfigError(f"{source}: [load_body]: the model has no load_position parameter (the body is drawn "
                          "at the load point)")
    for name, s in sc.schedule.parameters.items():
        if name not in rom.names:
            raise ConfigError(f"{source}: [schedule.{name}]: {name!r} is not a parameter of the model "
                              f"(parameters: {', '.join(rom.names)})")
        lo, hi = (float(v) for v in rom.ranges[rom.names.index(name)])
        eps = 1e-9 * max(abs(lo), abs(hi), 1e-12)
        for t, v in s.keyframes:
            if not lo - eps <= v <= hi + eps:
                raise ConfigError(f"{source}: [schedule.{name}] keyframes: value {v} at t = {t} s is outside the "
                                  f"model's range [{lo:.6g}, {hi:.6g}]")


def default_schedule(project, duration: float) -> dict[str, Schedule]:
    """A sweep of the load position from 90 % to 10 % of its range in 5 dwells with smooth moves; the other
    parameters held at mid-range."""
    rom = project.rom
    out = {}
    for j, name in enumerate(rom.names):
        lo, hi = (float(v) for v in rom.ranges[j])
        if j == 0:
            vals = lo + (hi - lo) * np.linspace(0.9, 0.1, 5)
            seg = duration / len(vals)
            kf = []
            for k, v in enumerate(vals):
                kf += [[k * seg, float(v)], [k * seg + 0.7 * seg, float(v)]]
            out[name] = Schedule(keyframes=[tuple(k) for k in kf])
        else:
            out[name] = Schedule(keyframes=[(0.0, 0.5 * (lo + hi))])
    return out


@dataclass(frozen=True)
class BarGeometry:
    r"""A project's [[bar]] resolved against its rotation parameter: the visible face's pivot (the axis point
    moved by ``face`` along the unit ``axis``), the unit direction ``zero`` at parameter 0, length and width
    [m]; ``facing``: the unit normal of the visible face
    (:math:`\operatorname{sign}(\mathrm{face})\, \mathrm{axis}`; :math:`+\mathrm{axis}` for
    :math:`\mathrm{face} = 0`)."""

    name: str
    axis: np.ndarray
    pivot: np.ndarray
    zero: np.ndarray
    length: float
    width: float
    degrees: bool
    facing: np.ndarray

    def direction(self, value: float) -> np.ndarray:
        r"""Unit direction (3,) of the bar at the parameter value: ``zero`` turned by it about ``axis`` (right
        hand; Rodrigues, zero perpendicular to axis:
        :math:`\cos(a)\, \mathrm{zero} + \sin(a)\, \mathrm{axis} \times \mathrm{zero}`, :math:`a` the value
        as an angle)."""
        a = math.radians(value) if self.degrees else float(value)
        return math.cos(a) * self.zero + math.sin(a) * np.cross(self.axis, self.zero)

    def tip(self, value: float) -> np.ndarray:
        """Centre of the bar's tip on its visible face (3,) [m]."""
        return self.pivot + self.length * self.direction(value)


def bar_geometries(project) -> list[BarGeometry]:
    params = {p["name"]: p for p in project.parameters()}
    out = []
    for b in project.config.bar:
        p = params[b.parameter]
        axis = _unit(p["axis"])
        zero = _unit(np.asarray(b.zero, float) - (np.asarray(b.zero, float) @ axis) * axis)
        facing = axis * (1.0 if b.face >= 0 else -1.0)
        out.append(BarGeometry(b.parameter, axis, np.asarray(p["point"], float) + b.face * axis, zero,
                               float(b.length), float(b.width), p.get("unit", "deg") != "rad", facing))
    return out


@dataclass(frozen=True)
class PlaneGeometry:
    r"""The project's [registration.plane]: ``origin`` (the image's top-left corner), unit ``u`` (image rows,
    rightwards) and ``v`` (columns, downwards), ``normal`` = :math:`-(u \times v)` (the side the image is seen
    from); with an image: ``image`` (BGR uint8), ``px_per_m`` and ``size`` = (width, height) [m]."""

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    image: np.ndarray | None = None
    px_per_m: float | None = None

    @property
    def size(self) -> tuple[float, float] | None:
        if self.image is None:
            return None
        h, w = self.image.shape[:2]
        return w / self.px_per_m, h / self.px_per_m

    def corners(self) -> np.ndarray:
        """(4, 3) corners of the image's rectangle: top-left, top-right, bottom-right, bottom-left [m]."""
        w, h = self.size
        o, u, v = self.origin, self.u, self.v
        return np.array([o, o + w * u, o + w * u + h * v, o + h * v])


def plane_geometry(project) -> PlaneGeometry | None:
    pl = project.config.registration.plane
    if pl is None:
        return None
    u, v = _unit(pl.u), _unit(pl.v)
    v = _unit(v - (v @ u) * u)
    return PlaneGeometry(np.asarray(pl.origin, float), u, v, -np.cross(u, v), project.plane_image,
                         None if pl.px_per_m is None else float(pl.px_per_m))


def _rotation(axis: np.ndarray, deg: float) -> np.ndarray:
    """Rotation matrix (3, 3) by deg about the unit axis (right hand)."""
    a = math.radians(deg)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k


class Resolved:
    """A scenario resolved against a project: camera, schedule, trajectory and lighting with every default
    filled in (``as_dict()`` is what ``scenario.json`` holds)."""

    def __init__(self, sc: Scenario, project, quick: bool = False):
        from physar.vision.camera import Camera

        self.sc = sc
        self.project = project
        cam = project.camera
        v = sc.video
        w, h = v.width or cam.width, v.height or cam.height
        duration = v.duration
        if quick:
            w, h = max(16, (w // 4) * 2), max(16, (h // 4) * 2)  # half size, even
            duration = min(duration, 2.0)
        if (w, h) != cam.size:
            f = w / cam.width
            if abs(h - cam.height * f) > 1.0:
                raise ConfigError(f"[video] {w}x{h} does not have the aspect of the camera "
                                  f"({cam.width}x{cam.height})")
            cam = Camera(cam.scaled(f).K, cam.dist, w, h)
        if w % 2 or h % 2:
            raise ConfigError(f"[video] H.264 needs an even frame size, got {w}x{h}")
        self.camera = cam
        self.fps = v.fps
        self.duration = duration
        self.n_frames = max(1, round(duration * v.fps))
        self.schedule = default_schedule(project, duration)
        self.schedule.update(sc.schedule.parameters)
        self.visible = bool(project.config.model.visible)
        self.bars = bar_geometries(project)
        self.plane = plane_geometry(project)
        # geometry of the object, its markers, plane image and bars
        mesh = project.space().mesh
        lo, hi = mesh.bounds
        c = sc.camera
        self.target = np.asarray(c.target if c.target is not None else 0.5 * (lo + hi), float)
        box = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1)
                        for k in (0, 1)])
        pts = [box, _marker_corners(project).reshape(-1, 3)]
        if self.plane is not None and self.plane.image is not None:
            pts.append(self.plane.corners())
        for b in self.bars:
            r = project.rom.ranges[project.rom.names.index(b.name)]
            pts.append(np.array([b.tip(float(x)) for x in (r[0], 0.5 * (r[0] + r[1]), r[1])]))
        pts = np.vstack(pts)
        radius = float(np.linalg.norm(pts - self.target, axis=1).max())
        self.size = float(np.linalg.norm(hi - lo))
        half = math.atan(min(cam.width / (2 * cam.fx), cam.height / (2 * cam.fy)))
        self.distance = float(c.distance if c.distance is not None else 1.1 * radius / math.sin(half))
        view = self._facing().mean(0) if len(self._facing()) else np.zeros(3)
        if np.linalg.norm(view) < 1e-6:
            view = np.array([0.0, -1.0, 0.0])
        view = view / np.linalg.norm(view)
        up = np.asarray(c.up, float) / np.linalg.norm(c.up)
        e1, e2 = _plane_axes(up)
        az = c.azimuth if c.azimuth is not None else math.degrees(math.atan2(view @ e2, view @ e1))
        el = c.elevation if c.elevation is not None else float(np.clip(math.degrees(math.asin(
            np.clip(view @ up, -1, 1))), -60, 60))
        if c.elevation is None and abs(el) < 10:
            el = 15.0  # a little from above: the top face shows, and the light is not grazing
        self.azimuth, self.elevation, self.up, self.axes = float(az), float(el), up, (e1, e2)
        L = sc.lighting
        if L.direction is not None:
            self.light = np.asarray(L.direction, float)
        else:
            self.light = self._eye_dir(self.azimuth - 25, self.elevation + 30)
        self.light = self.light / np.linalg.norm(self.light)
        self._wall_plane(sc)
        tex = sc.texture
        self.feature = tex.feature or 3 * self.distance / cam.fx
        rng = np.random.default_rng(sc.seed + 12345)
        self._shake = (rng.uniform(0.7, 2.5, (6, 3)), rng.uniform(0, 2 * np.pi, (6, 3)), rng.uniform(0.5, 1, (6, 3)))

    def _facing(self) -> np.ndarray:
        """Unit normals (k, 3) of what the camera must see: dots, markers, the plane, the bars' faces, the
        [features] face (outward)."""
        p = self.project
        out = [np.asarray(p.dot_normals, float).reshape(-1, 3), _marker_normals(p)]
        if self.plane is not None:
            out.append(self.plane.normal[None])
        out += [b.facing[None] for b, cfg in zip(self.bars, p.config.bar) if cfg.face != 0]
        f = p.config.features
        if f is not None:
            n = _unit(np.cross(_unit(f.u), _unit(f.v)))
            lo, hi = p.space().mesh.bounds
            centre = np.asarray(f.origin) + 0.5 * (f.size[0] * _unit(f.u) + f.size[1] * _unit(f.v))
            out.append((n if n @ (centre - 0.5 * (lo + hi)) >= 0 else -n)[None])
        return np.vstack(out)

    def _wall_plane(self, sc):
        """The wall behind the scene: the project's [registration.plane] when it has no image (the pipeline
        learns its texture), else a plane perpendicular to the mean line of sight ``distance`` behind the
        target. ``wall_centre`` (the point of the plane nearest the target), ``wall_axes`` (texture right,
        down), ``wall_normal`` (towards the camera side), ``wall_distance`` [m]."""
        pl = self.plane
        if pl is not None and pl.image is None:
            n = pl.normal
            self.wall_centre = self.target - ((self.target - pl.origin) @ n) * n
            self.wall_axes, self.wall_normal = (pl.u, pl.v), n
            self.wall_distance = float(abs((self.target - pl.origin) @ n))
            return
        view = self._eye_dir(self.azimuth, self.elevation)  # target -> camera
        self.wall_distance = sc.background.distance or max(2.0 * self.size, 0.2 * self.distance)
        self.wall_centre = self.target - self.wall_distance * view
        e1 = np.cross(self.up, view)
        if np.linalg.norm(e1) < 1e-6:
            e1 = self.axes[0]
        e1 = e1 / np.linalg.norm(e1)
        down = -np.cross(view, e1)
        self.wall_axes, self.wall_normal = (e1, down), view

    def _eye_dir(self, az, el) -> np.ndarray:
        e1, e2 = self.axes
        a, b = math.radians(az), math.radians(el)
        return math.cos(b) * (math.cos(a) * e1 + math.sin(a) * e2) + math.sin(b) * self.up

    def params(self, t: float) -> dict:
        """{parameter name: value} at time t [s] (the schedule's, also while at rest)."""
        return {n: float(self.schedule[n].value(t)) for n in self.project.rom.names}

    def at_rest(self, t: float) -> bool:
        """The object is undeformed (:math:`u = 0`, unloaded) before [schedule] rest_until."""
        return t < self.sc.schedule.rest_until

    def markers_on(self, t: float) -> bool:
        """The markers are drawn before [schedule] markers_until (always without it)."""
        m = self.sc.schedule.markers_until
        return m is None or t < m

    def pan(self, t: float) -> float:
        """Yaw [deg] of the [[camera.pan]] events at time t (summed)."""
        return float(sum(p.angle(t) for p in self.sc.camera.pan))

    def pose(self, t: float):
        r"""World -> camera Pose at time t: orbit around the target plus a handheld shake (a seeded sum of
        sinusoids of amplitude shake_mm / shake_deg), turned by the pan yaw :math:`a` about the vertical (up)
        through the camera centre :math:`c`: :math:`R = R_\text{base} R_\text{up}(a)`, :math:`t = -R c`."""
        from physar.vision.camera import Pose

        c = self.sc.camera
        f, ph, amp = self._shake
        shake = (amp * np.sin(2 * np.pi * f * t + ph)).sum(0) / amp.sum(0)
        w = 2 * np.pi / c.period
        az = self.azimuth + c.orbit[0] * math.sin(w * t) + c.shake_deg * shake[0]
        el = self.elevation + c.orbit[1] * math.sin(0.73 * w * t + 1.0) + c.shake_deg * shake[1]
        eye = self.target + self.distance * self._eye_dir(az, el) + 1e-3 * c.shake_mm * shake[[2, 0, 1]]
        pose = Pose.look_at(eye, self.target, tuple(self.up))
        roll = math.radians(c.shake_deg * shake[2])
        Rz = np.array([[math.cos(roll), -math.sin(roll), 0], [math.sin(roll), math.cos(roll), 0], [0, 0, 1]])
        R = Rz @ pose.R
        yaw = self.pan(t)
        if yaw:
            centre = -R.T @ (Rz @ pose.t)
            R = R @ _rotation(self.up, yaw)
            return Pose(R, -R @ centre)
        return Pose(R, Rz @ pose.t)

    def occlusions(self, frame: int) -> list:
        return [o for o in self.sc.occlusion if 0 <= frame - round(o.start * self.fps) < o.frames]

    def as_dict(self) -> dict:
        d = self.sc.model_dump(mode="json")
        d["video"].update(width=self.camera.width, height=self.camera.height, duration=self.duration,
                          frames=self.n_frames)
        d["schedule"] = {"rest_until": self.sc.schedule.rest_until, "markers_until": self.sc.schedule.markers_until,
                         **{n: s.model_dump(mode="json") for n, s in self.schedule.items()}}
        d["camera"].update(target=self.target.tolist(), distance=self.distance, azimuth=self.azimuth,
                           elevation=self.elevation)
        d["lighting"]["direction"] = self.light.tolist()
        d["background"]["distance"] = self.wall_distance
        d["background"]["on_plane"] = self.plane is not None and self.plane.image is None
        d["texture"]["feature"] = self.feature
        d["project"] = self.project.source
        return d


def _unit(v) -> np.ndarray:
    a = np.asarray(v, float)
    return a / np.linalg.norm(a)


def _marker_corners(project) -> np.ndarray:
    return np.zeros((0, 4, 3)) if project.board is None else np.asarray(project.board.corners, float)


def _marker_normals(project) -> np.ndarray:
    c = _marker_corners(project)
    # corners TL, TR, BR, BL seen from outside: (TR - TL) x (BL - TL) = 4 h^2 right x (-up) = -normal
    n = -np.cross(c[:, 1] - c[:, 0], c[:, 3] - c[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _plane_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit axes spanning the plane perpendicular to up (x-like first)."""
    ref = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = ref - (ref @ up) * up
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


__all__ = [
    "BarGeometry",
    "PlaneGeometry",
    "Resolved",
    "Scenario",
    "Schedule",
    "bar_geometries",
    "check_scenario",
    "default_schedule",
    "load_scenario",
    "parse_scenario",
    "plane_geometry",
    "resolve",
]
