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
[schedule.s]   # one table per model parameter (default: a sweep of load_position over 90 % .. 10 % of its
keyframes = [[0, 0.45], [1.5, 0.45], [2, 0.3]]   # range with dwells, other parameters at mid-range)
interp = "smooth"   # "smooth" (smooth-step between keyframes; equal values = a dwell) | "linear"
[camera]       # target [m] (bbox centre), distance [m], azimuth/elevation [deg] of the camera seen from the
               # target (from the mean normal of the dots and markers), orbit = [d_azimuth, d_elevation] deg,
               # period [s], shake_mm, shake_deg, up = [0, 0, 1]
[lighting]     # ambient, direction (towards the light), brightness (0.4: dimmed), flicker, vignetting
[sensor]       # read_noise [DN], shot_noise, psf [px]
[texture]      # base = RGB, contrast, feature [m] (finest noise feature; default 3 px at the target), octaves
[background]   # base = RGB, contrast, distance [m] behind the target
[[occlusion]]  # start [s], frames, center = [u, v] (image fractions) or point = [x, y, z] (m), radius
               # (fraction of the image height), colour = RGB
[truth]        # refine = 2 (times finer than the model mesh)
```
"""
from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, Strict, model_validator

from physar.errors import ConfigError
from physar.fem.config import _Strict  # extra keys forbidden, no bool/str -> number coercion

Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
Vec3 = tuple[float, float, float]
RGB = tuple[Int, Int, Int]




def _rgb_ok(v):
    if v is not None and not all(0 <= c <= 255 for c in v):
        raise ValueError(f"colour must be RGB values in 0..255, got {list(v)}")
    return v


class VideoSection(_Strict):
    width: Int | None = Field(None, ge=16, le=7680, description="px (default: the camera's)")
    height: Int | None = Field(None, ge=16, le=4320, description="px (default: the camera's)")
    fps: float = Field(30.0, gt=0, le=240)
    duration: float = Field(8.0, gt=0, le=600, description="s")
    crf: Int = Field(18, ge=0, le=51, description="H.264 constant rate factor")


class Schedule(_Strict):
    keyframes: list[tuple[float, float]] = Field(..., min_length=1, description="[[t (s), value], ...]")
    interp: Literal["smooth", "linear"] = "smooth"

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


class CameraSection(_Strict):
    target: Vec3 | None = Field(None, description="point looked at [m] (default: model bbox centre)")
    distance: float | None = Field(None, gt=0, description="m (default: object and markers fill the view)")
    azimuth: float | None = Field(None, description="deg, direction target -> camera in the xy plane from +x")
    elevation: float | None = Field(None, ge=-89, le=89, description="deg above the xy plane")
    orbit: tuple[float, float] = Field((8.0, 4.0), description="amplitudes of azimuth, elevation [deg]")
    period: float = Field(12.0, gt=0, description="orbit period [s]")
    shake_mm: float = Field(1.0, ge=0)
    shake_deg: float = Field(0.2, ge=0)
    up: Vec3 = (0.0, 0.0, 1.0)


class LightingSection(_Strict):
    ambient: float = Field(0.35, ge=0, le=1)
    direction: Vec3 | None = Field(None, description="towards the light (default: from the camera side, above)")
    brightness: float = Field(1.0, gt=0, le=4, description="global factor (0.4: dimmed light)")
    flicker: float = Field(0.02, ge=0, le=0.5, description="relative amplitude")
    vignetting: float = Field(0.2, ge=0, le=1)


class SensorSection(_Strict):
    read_noise: float = Field(1.5, ge=0, description="std [DN]")
    shot_noise: float = Field(0.25, ge=0, description="std = shot_noise * sqrt(intensity [DN])")
    psf: float = Field(0.6, ge=0, le=5, description="Gaussian blur sigma [px]")


class TextureSection(_Strict):
    base: RGB = (178, 172, 160)
    contrast: float = Field(0.12, ge=0, le=1, description="relative std of the procedural noise")
    feature: float | None = Field(None, gt=0, description="finest noise feature [m] (default 3 px at the target)")
    octaves: Int = Field(4, ge=1, le=8)

    @model_validator(mode="after")
    def _rgb(self):
        _rgb_ok(self.base)
        return self


class BackgroundSection(_Strict):
    base: RGB = (120, 128, 138)
    contrast: float = Field(0.2, ge=0, le=1)
    distance: float | None = Field(None, gt=0, description="wall behind the target [m] (default 2x object size)")

    @model_validator(mode="after")
    def _rgb(self):
        _rgb_ok(self.base)
        return self


class Occlusion(_Strict):
    start: float = Field(..., ge=0, description="s")
    frames: Int = Field(..., gt=0)
    center: tuple[float, float] | None = Field(None, description="image fractions (u, v)")
    point: Vec3 | None = Field(None, description="object point [m] the blob covers")
    radius: float = Field(0.15, gt=0, le=2, description="fraction of the image height")
    colour: RGB = (40, 38, 36)

    @model_validator(mode="after")
    def _one(self):
        if (self.center is None) == (self.point is None):
            raise ValueError("give exactly one of center = [u, v] (image fractions) or point = [x, y, z]")
        _rgb_ok(self.colour)
        return self


class TruthSection(_Strict):
    refine: Int = Field(2, ge=2, le=8, description="times finer than the model mesh")


class Scenario(_Strict):
    """Top level of a scenario file."""

    seed: Int = 0
    video: VideoSection = VideoSection()
    schedule: dict[str, Schedule] = Field(default_factory=dict)
    camera: CameraSection = CameraSection()
    lighting: LightingSection = LightingSection()
    sensor: SensorSection = SensorSection()
    texture: TextureSection = TextureSection()
    background: BackgroundSection = BackgroundSection()
    occlusion: list[Occlusion] = Field(default_factory=list)
    truth: TruthSection = TruthSection()

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
    sc = parse_scenario(read_toml(path), str(path))
    if project is not None:
        check_scenario(sc, project, str(path))
    return sc


def check_scenario(sc: Scenario, project, source: str) -> None:
    """Schedules must name parameters of the model and stay within their ranges."""
    rom = project.rom
    for name, s in sc.schedule.items():
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
        self.schedule.update(sc.schedule)
        # geometry of the object and its markers
        mesh = project.space().mesh
        lo, hi = mesh.bounds
        c = sc.camera
        self.target = np.asarray(c.target if c.target is not None else 0.5 * (lo + hi), float)
        corners = project.board.corners.reshape(-1, 3)
        pts = np.vstack([lo, hi, [lo[0], lo[1], hi[2]], [hi[0], hi[1], lo[2]], corners])
        radius = float(np.linalg.norm(pts - self.target, axis=1).max())
        self.size = float(np.linalg.norm(hi - lo))
        half = math.atan(min(cam.width / (2 * cam.fx), cam.height / (2 * cam.fy)))
        self.distance = float(c.distance if c.distance is not None else 1.1 * radius / math.sin(half))
        normals = np.vstack([project.dot_normals, _marker_normals(project)])
        view = normals.mean(0)
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
        self.wall_distance = sc.background.distance or max(2.0 * self.size, 0.2 * self.distance)
        tex = sc.texture
        self.feature = tex.feature or 3 * self.distance / cam.fx
        rng = np.random.default_rng(sc.seed + 12345)
        self._shake = (rng.uniform(0.7, 2.5, (6, 3)), rng.uniform(0, 2 * np.pi, (6, 3)), rng.uniform(0.5, 1, (6, 3)))

    def _eye_dir(self, az, el) -> np.ndarray:
        e1, e2 = self.axes
        a, b = math.radians(az), math.radians(el)
        return math.cos(b) * (math.cos(a) * e1 + math.sin(a) * e2) + math.sin(b) * self.up

    def params(self, t: float) -> dict:
        """{parameter name: value} at time t [s]."""
        return {n: float(self.schedule[n].value(t)) for n in self.project.rom.names}

    def pose(self, t: float):
        """World -> camera Pose at time t: orbit around the target plus a handheld shake (a seeded sum of
        sinusoids of amplitude shake_mm / shake_deg)."""
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
        return Pose(Rz @ pose.R, Rz @ pose.t)

    def occlusions(self, frame: int) -> list:
        return [o for o in self.sc.occlusion if 0 <= frame - round(o.start * self.fps) < o.frames]

    def as_dict(self) -> dict:
        d = self.sc.model_dump(mode="json")
        d["video"].update(width=self.camera.width, height=self.camera.height, duration=self.duration,
                          frames=self.n_frames)
        d["schedule"] = {n: s.model_dump(mode="json") for n, s in self.schedule.items()}
        d["camera"].update(target=self.target.tolist(), distance=self.distance, azimuth=self.azimuth,
                           elevation=self.elevation)
        d["lighting"]["direction"] = self.light.tolist()
        d["background"]["distance"] = self.wall_distance
        d["texture"]["feature"] = self.feature
        d["project"] = self.project.source
        return d


def _marker_normals(project) -> np.ndarray:
    c = project.board.corners
    # corners TL, TR, BR, BL seen from outside: (TR - TL) x (BL - TL) = 4 h^2 right x (-up) = -normal
    n = -np.cross(c[:, 1] - c[:, 0], c[:, 3] - c[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _plane_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit axes spanning the plane perpendicular to up (x-like first)."""
    ref = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = ref - (ref @ up) * up
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


__all__ = ["Resolved", "Scenario", "Schedule", "check_scenario", "default_schedule", "load_scenario",
           "parse_scenario"]
