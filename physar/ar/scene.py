"""Synthetic AR scenes: scene (a) of seed 000 §5.1 rendered as a realistic video with its ground truth.

An aluminium cantilever (E = 69 GPa, nu = 0.334) clamped at x = 0, with small blue dots on its front face
(y = 0) and four ArUco markers on a board behind it (plane y = board_offset), is loaded by a point force P
moving along its top face (position s(t) from the load schedule). The deformation comes from a P2 finite-
element solve on a mesh finer than the reduced model's (no inverse crime). A handheld camera (smooth
orbit + shake) films it under directional light with flicker and vignetting; the image gets motion blur,
the lens PSF, shot + read noise, occluders and H.264 compression.

World frame: x along the beam, y away from the camera (into the scene), z up. Lengths in m, forces in N.
"""
from __future__ import annotations

import csv
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from physar.errors import ConfigError, PhysarError, format_validation_error
from physar.vision.camera import Camera, Pose
from physar.vision.markers import MarkerBoard


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class VideoSection(_Strict):
    width: int = Field(1280, ge=64, le=7680)
    height: int = Field(720, ge=64, le=4320)
    fps: float = Field(30.0, gt=0, le=240)
    duration: float = Field(15.0, gt=0, le=600, description="s")
    crf: int = Field(18, ge=0, le=51, description="H.264 constant rate factor (0 lossless, 23 default)")
    hfov: float = Field(65.0, gt=5, lt=150, description="horizontal field of view [deg]")


class BeamSection(_Strict):
    length: float = Field(0.5, gt=0)
    width: float = Field(0.02, gt=0, description="depth along y [m]")
    height: float = Field(0.015, gt=0, description="along z [m]")
    E: float = Field(69e9, gt=0)
    nu: float = Field(0.334, gt=-1, lt=0.5)
    load: float = Field(200.0, gt=0, description="point load magnitude [N], towards -z (200 N: 21 mm tip "
                                                     "deflection, 134 MPa bending stress, elastic for 6061-T6)")
    load_radius: float = Field(0.01, gt=0, description="regularisation radius of the point load [m]")
    truth_cells: tuple[int, int, int] = (80, 4, 3)
    model_cells: tuple[int, int, int] = (40, 2, 2)
    dots: int = Field(24, ge=3, le=200)
    dot_diameter: float = Field(0.005, gt=0)
    dot_margin: float = Field(0.02, ge=0, description="first dot distance from the clamp [m]")


class MarkerSection(_Strict):
    dictionary: str = "DICT_4X4_50"
    size: float = Field(0.05, gt=0)
    board_offset: float = Field(0.03, description="board plane y [m] (behind the beam's front face y = 0)")
    ids: list[int] = [0, 1, 2, 3]
    centres: list[tuple[float, float]] = [(0.03, 0.105), (0.47, 0.105), (0.03, -0.09), (0.47, -0.09)]

    @model_validator(mode="after")
    def _same(self):
        if len(self.ids) != len(self.centres):
            raise ValueError(f"ids ({len(self.ids)}) and centres ({len(self.centres)}) differ in length")
        return self


class CameraSection(_Strict):
    distance: float = Field(0.55, gt=0, description="m from the target")
    target: tuple[float, float, float] = (0.25, 0.0, 0.005)
    elevation: float = Field(8.0, description="deg above the beam's plane")
    orbit_deg: tuple[float, float] = (7.0, 3.0)
    orbit_period: float = Field(14.0, gt=0, description="s")
    shake_mm: float = Field(1.5, ge=0)
    shake_deg: float = Field(0.25, ge=0)
    file: str | None = Field(None, description="camera TOML (intrinsics); default: pinhole with hfov")


class LightingSection(_Strict):
    ambient: float = Field(0.45, ge=0, le=1)
    direction: tuple[float, float, float] = Field((-0.3, -1.0, 0.8), description="towards the light")
    flicker: float = Field(0.03, ge=0, le=0.5, description="relative amplitude of 100 Hz-aliased flicker")
    vignetting: float = Field(0.25, ge=0, le=1)


class SensorSection(_Strict):
    read_noise: float = Field(1.5, ge=0, description="std [DN]")
    shot_noise: float = Field(0.25, ge=0, description="std = shot_noise * sqrt(intensity [DN])")
    motion_blur: float = Field(0.5, ge=0, le=1, description="exposure as a fraction of the frame interval")
    psf: float = Field(0.6, ge=0, le=5, description="Gaussian lens blur sigma [px]")


class LoadSchedule(_Strict):
    positions: list[float] = Field(default_factory=lambda: [0.46, 0.42, 0.38, 0.34, 0.30, 0.26, 0.22, 0.18,
                                                            0.14, 0.10, 0.06],
                                   description="dwell positions s [m] from the clamp, in order")
    dwell: float = Field(1.0, gt=0, description="s at each position")
    move: float = Field(0.3, ge=0, description="s to move between positions (smooth)")


class Occlusion(_Strict):
    start: float = Field(ge=0, description="s")
    frames: int = Field(gt=0)
    kind: Literal["full", "markers", "beam"] = "full"


class SceneSpec(_Strict):
    name: str = "cantilever"
    seed: int = 0
    video: VideoSection = VideoSection()
    beam: BeamSection = BeamSection()
    markers: MarkerSection = MarkerSection()
    camera: CameraSection = CameraSection()
    lighting: LightingSection = LightingSection()
    sensor: SensorSection = SensorSection()
    load: LoadSchedule = LoadSchedule()
    occlusion: list[Occlusion] = []

    @model_validator(mode="after")
    def _check(self):
        L = self.beam.length
        bad = [s for s in self.load.positions if not 0 <= s <= L]
        if bad:
            raise ValueError(f"load positions {bad} lie outside the beam [0, {L}] m")
        return self

    # -- derived --------------------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return max(1, round(self.video.duration * self.video.fps))

    def dot_positions(self) -> np.ndarray:
        """Reference dot centres (n, 3) on the front face y = 0, at mid-height [m]."""
        b = self.beam
        x = np.linspace(b.dot_margin, b.length - b.dot_diameter, b.dots)
        return np.column_stack([x, np.zeros_like(x), np.full_like(x, b.height / 2)])

    def board(self) -> MarkerBoard:
        m = self.markers
        # board plane y = board_offset, seen from -y: image right = +x, image down = -z
        return MarkerBoard.on_plane(m.ids, [(c[0], -c[1]) for c in m.centres], m.size,
                                    [0, m.board_offset, 0], [1, 0, 0], [0, 0, -1], m.dictionary)

    def load_path(self) -> list[list[float]]:
        b = self.beam
        return [[0.0, b.width / 2, b.height], [b.length, b.width / 2, b.height]]

    def camera_model(self, base: Path | None = None) -> Camera:
        if self.camera.file:
            p = Path(self.camera.file)
            if base is not None and not p.is_absolute():
                p = base / p
            cam = Camera.load(p)
            if cam.size != (self.video.width, self.video.height):
                raise ConfigError(f"{p}: camera is {cam.width}x{cam.height}, scene video is "
                                  f"{self.video.width}x{self.video.height}")
            if np.any(cam.dist):
                raise ConfigError(f"{p}: the scene renderer needs a distortion-free camera (distortion = [])")
            return cam
        return Camera.from_fov(self.video.width, self.video.height, self.video.hfov)

    def load_position(self, t: float) -> float:
        """s(t): dwell at each position, smooth (cosine) moves between them."""
        pos, dw, mv = self.load.positions, self.load.dwell, self.load.move
        period = dw + mv
        k = int(t // period)
        if k >= len(pos) - 1:
            return float(pos[-1])
        tau = t - k * period
        if tau <= dw:
            return float(pos[k])
        a = (tau - dw) / mv
        return float(pos[k] + (pos[k + 1] - pos[k]) * 0.5 * (1 - math.cos(math.pi * a)))

    def camera_pose(self, t: float) -> Pose:
        """Handheld camera: smooth orbit around the target plus a shake (sum of sinusoids, seeded)."""
        c = self.camera
        rng = np.random.default_rng(self.seed + 12345)
        f = rng.uniform(0.7, 2.5, (6, 3))
        ph = rng.uniform(0, 2 * np.pi, (6, 3))
        amp = rng.uniform(0.5, 1.0, (6, 3))
        shake = (amp * np.sin(2 * np.pi * f * t + ph)).sum(0) / amp.sum(0)
        w = 2 * np.pi / c.orbit_period
        yaw = math.radians(c.orbit_deg[0] * math.sin(w * t) + c.shake_deg * shake[0])
        pitch = math.radians(c.elevation + c.orbit_deg[1] * math.sin(0.73 * w * t + 1.0) + c.shake_deg * shake[1])
        d = c.distance * (1 + 0.02 * math.sin(0.5 * w * t))
        target = np.asarray(c.target, float)
        eye = target + d * np.array([math.sin(yaw) * math.cos(pitch), -math.cos(yaw) * math.cos(pitch),
                                     math.sin(pitch)])
        eye = eye + 1e-3 * c.shake_mm * np.array([shake[2], shake[0], shake[1]])
        pose = Pose.look_at(eye, target)
        roll = math.radians(c.shake_deg * shake[2])
        Rz = np.array([[math.cos(roll), -math.sin(roll), 0], [math.sin(roll), math.cos(roll), 0], [0, 0, 1]])
        return Pose(Rz @ pose.R, Rz @ pose.t)

    def occluded(self, frame: int) -> list[str]:
        fps = self.video.fps
        return [o.kind for o in self.occlusion if 0 <= frame - round(o.start * fps) < o.frames]


def read_scene_toml(path) -> dict:
    """The raw table of a scene TOML; a missing or malformed file is a one-line ConfigError."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except (FileNotFoundError, IsADirectoryError):
        raise ConfigError(f"{path}: scene file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML ({e})") from None


def validate_scene(path, model):
    """Read a scene TOML and validate it with the pydantic ``model``; errors name the file and the key."""
    data = read_scene_toml(path)
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise ConfigError(format_validation_error(e, str(path), model)) from None


def load_scene(path) -> SceneSpec:
    """Read and validate a scene TOML; errors name the file and the key."""
    path = Path(path)
    spec = validate_scene(path, SceneSpec)
    spec.__dict__["_base"] = path.parent
    return spec


# ------------------------------------------------------------------------------------------------------
# ground truth
# ------------------------------------------------------------------------------------------------------
class BeamTruth:
    """Fine-mesh P2 solutions u(s) of the scene's cantilever, cached per load position."""

    def __init__(self, spec: SceneSpec, cells=None):
        from physar.fem import ElasticModel, FESpace, LinearElastic, LinearSolver, fixed_dofs
        from physar.geometry import box_mesh

        b = spec.beam
        self.spec = spec
        self.space = FESpace(box_mesh((b.length, b.width, b.height), tuple(cells or b.truth_cells)), "P2")
        self.model = ElasticModel(self.space, LinearElastic(b.E, b.nu))
        fixed = fixed_dofs(self.space, box=[[0, 0, 0], [0, b.width, b.height]])
        self.solver = LinearSolver(self.model, fixed)
        nodes = self.space.nodes
        front = np.flatnonzero(np.abs(nodes[:, 1]) < 1e-12)
        xs, zs = np.unique(nodes[front, 0].round(12)), np.unique(nodes[front, 2].round(12))
        order = np.lexsort((nodes[front, 0], nodes[front, 2]))  # z-major, then x
        if len(front) != xs.size * zs.size:
            raise PhysarError("truth mesh front face is not a structured grid")
        self.grid_x, self.grid_z = xs, zs
        self.front = front[order].reshape(zs.size, xs.size)
        from physar.vision.observation import surface_observation_matrix

        self.C_dots = surface_observation_matrix(self.space, spec.dot_positions())
        self._cache: dict[float, np.ndarray] = {}

    def solve(self, s: float) -> np.ndarray:
        from physar.fem import point_load

        key = round(float(s), 9)
        if key not in self._cache:
            b = self.spec.beam
            path = np.asarray(self.spec.load_path())
            p = path[0] + key / b.length * (path[1] - path[0])
            self._cache[key] = self.solver.solve(point_load(self.space, p, [0, 0, -b.load], b.load_radius))
            if len(self._cache) > 256:
                self._cache.pop(next(iter(self._cache)))
        return self._cache[key]

    def front_grid(self, u: np.ndarray) -> np.ndarray:
        """Displacement on the front-face node grid, (nz, nx, 3) [m]."""
        return u.reshape(-1, 3)[self.front]

    def dots(self, u: np.ndarray) -> np.ndarray:
        """Displaced dot centres (n, 3) [m] (exact P2 interpolation)."""
        return self.spec.dot_positions() + (self.C_dots @ u).reshape(-1, 3)


# ------------------------------------------------------------------------------------------------------
# rendering
# ------------------------------------------------------------------------------------------------------
def _aruco_image(dictionary: str, marker_id: int, px: int) -> np.ndarray:
    from physar.vision.calibration import aruco_dictionary

    return cv2.aruco.generateImageMarker(aruco_dictionary(dictionary), marker_id, px, borderBits=1)


@dataclass
class _Textures:
    board: np.ndarray
    board_px_per_m: float
    board_origin: tuple[float, float]   # (x, z) of texture pixel (0, 0) corner (top-left, z max)
    front: np.ndarray
    front_px_per_m: float


class SceneRenderer:
    """Renders frames of a :class:`SceneSpec` (uint8 BGR) and their truth."""

    def __init__(self, spec: SceneSpec, truth: BeamTruth | None = None, camera: Camera | None = None):
        self.spec = spec
        self.camera = camera or spec.camera_model(spec.__dict__.get("_base"))
        self.truth = truth or BeamTruth(spec)
        self.board = spec.board()
        self.rng = np.random.default_rng(spec.seed)
        self.tex = self._make_textures()
        w, h = self.camera.size
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        self.vignette3 = cv2.merge([(1 - spec.lighting.vignetting * r2).astype(np.float32)] * 3)
        self._prev_center = None

    # -- textures --------------------------------------------------------------------------------------
    def _make_textures(self) -> _Textures:
        spec, rng = self.spec, np.random.default_rng(self.spec.seed + 1)
        b, m = spec.beam, spec.markers
        f_nominal = self.camera.fx / spec.camera.distance  # image px per m at the target
        # board: white-ish matte board with the markers (and quiet zones) around the beam
        s = 1.5 * f_nominal
        cz = np.array([c[1] for c in m.centres])
        cx = np.array([c[0] for c in m.centres])
        x0, x1 = min(-0.15, cx.min() - 0.2), max(b.length + 0.15, cx.max() + 0.2)
        z0, z1 = min(-0.2, cz.min() - 0.2), max(0.2, cz.max() + 0.2)
        W, H = int((x1 - x0) * s), int((z1 - z0) * s)
        board = np.full((H, W, 3), (196, 203, 206), np.float32)
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        board *= (1 + 0.04 * np.sin(xx / W * 3.1 + 0.5) * np.cos(yy / H * 2.3))[..., None]
        board += cv2.GaussianBlur(rng.normal(0, 6, (H, W)).astype(np.float32), (0, 0), 2)[..., None]
        for mid, (mx, mz) in zip(m.ids, m.centres):
            # exact sub-pixel placement: the marker image is mapped affinely into the texture
            pxf = m.size * s
            hr = 6 * 48
            img = _aruco_image(m.dictionary, mid, hr).astype(np.float32)
            k = pxf / hr
            img = cv2.GaussianBlur(img, (0, 0), 0.5 / k) * (225 / 255.0) + 20
            u0, v0 = (mx - x0) * s - pxf / 2, (z1 - mz) * s - pxf / 2
            q = 0.25 * pxf
            board[int(v0 - q):int(v0 + pxf + q), int(u0 - q):int(u0 + pxf + q)] = (245, 245, 245)
            M = np.array([[k, 0, u0 + 0.5 * k - 0.5], [0, k, v0 + 0.5 * k - 0.5]])
            mk = cv2.warpAffine(cv2.merge([img] * 3), M, (W, H), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=(-1, -1, -1))
            cov = cv2.warpAffine(np.ones((hr, hr), np.float32), M, (W, H), flags=cv2.INTER_LINEAR)[..., None]
            board = board * (1 - cov) + np.maximum(mk, 0) * cov
        # front face: brushed aluminium with blue dots
        sf = 2.0 * f_nominal
        Wf, Hf = int(b.length * sf) + 1, int(b.height * sf) + 1
        streak = cv2.GaussianBlur(rng.normal(0, 1, (Hf, Wf)).astype(np.float32), (0, 0), sigmaX=25, sigmaY=0.7)
        front = np.empty((Hf, Wf, 3), np.float32)
        front[...] = (178, 176, 170)
        front += 18 * streak[..., None] / max(streak.std(), 1e-6)
        dot = np.zeros((Hf * 4, Wf * 4), np.uint8)
        for p in spec.dot_positions():
            c = (int(round((4 * p[0] * sf - 0.5) * 16)), int(round((4 * (b.height - p[2]) * sf - 0.5) * 16)))  # noqa: RUF046 - numpy 1.x round
            cv2.circle(dot, c, int(round(b.dot_diameter / 2 * sf * 4 * 16)), 255, -1, cv2.LINE_AA, shift=4)  # noqa: RUF046 - numpy 1.x round
        a = cv2.resize(dot, (Wf, Hf), interpolation=cv2.INTER_AREA).astype(np.float32)[..., None] / 255
        front = front * (1 - a) + np.array((170, 70, 25), np.float32) * a
        return _Textures(np.clip(board, 0, 255), s, (x0, z1), np.clip(front, 0, 255), sf)

    # -- pieces ----------------------------------------------------------------------------------------
    def _shade(self, normal, pose_center=None) -> float:
        li = np.asarray(self.spec.lighting.direction, float)
        li = li / np.linalg.norm(li)  # direction towards the light
        amb = self.spec.lighting.ambient
        return amb + (1 - amb) * max(0.0, float(np.dot(normal, li))) / max(1e-9, float(np.dot([0, -1, 0], li)))

    def _draw_board(self, pose: Pose) -> np.ndarray:
        t = self.tex
        s = t.board_px_per_m
        x0, z1 = t.board_origin
        yb = self.spec.markers.board_offset
        # texture pixel (c, r) -> world (x0 + (c + .5)/s, yb, z1 - (r + .5)/s)
        A = np.array([[1 / s, 0, x0 + 0.5 / s], [0, 0, yb], [0, -1 / s, z1 - 0.5 / s]])
        M = self.camera.K @ (pose.R @ A + np.column_stack([np.zeros((3, 2)), pose.t]))
        img = cv2.warpPerspective(t.board, M, self.camera.size, flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=(70, 72, 75))
        return img * self._shade(np.array([0, -1.0, 0]))

    def _poly(self, img, pts3, colour, pose):
        p = self.camera.project(pts3, pose)
        cv2.fillPoly(img, [np.round(p * 16).astype(np.int32)], colour, cv2.LINE_AA, shift=4)

    def _draw_beam(self, img, pose: Pose, grid: np.ndarray, s_load: float):
        b, t = self.spec.beam, self.tex
        gx, gz = self.truth.grid_x, self.truth.grid_z
        cam_c = pose.center
        # clamp block (dark steel) and its front face
        cl = [[-0.05, -0.012, -0.035], [0.0, -0.012, -0.035], [0.0, -0.012, b.height + 0.035],
              [-0.05, -0.012, b.height + 0.035]]
        self._poly(img, cl, tuple(float(v) * self._shade(np.array([0, -1.0, 0])) for v in (60, 62, 66)), pose)
        top_u = grid[-1]  # (nx, 3) top row of the front face
        bot_u = grid[0]
        xs = gx
        if cam_c[2] > b.height:  # top face visible
            f_edge = np.column_stack([xs, np.zeros_like(xs), np.full_like(xs, b.height)]) + top_u
            b_edge = f_edge + [0, b.width, 0]
            sh = self._shade(np.array([0, 0, 1.0]))
            self._poly(img, np.vstack([f_edge, b_edge[::-1]]), tuple(v * sh for v in (190, 190, 186)), pose)
        elif cam_c[2] < 0:
            f_edge = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)]) + bot_u
            self._poly(img, np.vstack([f_edge, (f_edge + [0, b.width, 0])[::-1]]),
                       tuple(v * self._shade(np.array([0, 0, -1.0])) for v in (150, 150, 146)), pose)
        if cam_c[0] > b.length:  # free end face
            e = np.array([[b.length, 0, 0], [b.length, 0, b.height], [b.length, b.width, b.height],
                          [b.length, b.width, 0]]) + np.array([bot_u[-1], top_u[-1], top_u[-1], bot_u[-1]])
            self._poly(img, e, tuple(v * self._shade(np.array([1.0, 0, 0])) for v in (160, 160, 156)), pose)
        # load: a steel block resting on the top face at s
        ux = np.interp(s_load, xs, top_u[:, 2])
        blk = 0.012
        c0 = np.array([s_load, 0.0, b.height + ux])
        for face, nrm, col in (([[-blk, 0, 0], [blk, 0, 0], [blk, 0, 2 * blk], [-blk, 0, 2 * blk]], [0, -1, 0],
                                (55, 55, 58)),
                               ([[-blk, 0, 2 * blk], [blk, 0, 2 * blk], [blk, b.width, 2 * blk],
                                 [-blk, b.width, 2 * blk]], [0, 0, 1], (85, 85, 90))):
            if cam_c[2] > b.height + 2 * blk or nrm[2] == 0:
                self._poly(img, c0 + np.array(face, float), tuple(v * self._shade(np.array(nrm, float))
                                                                  for v in col), pose)
        # front face: texture mapped through the (inverse) deformation, anti-aliased silhouette
        corners = np.array([[0, 0, 0], [b.length, 0, 0], [b.length, 0, b.height], [0, 0, b.height]], float)
        umax = np.abs(grid).max()
        pc = self.camera.project(np.vstack([corners + [0, 0, -umax - 0.002], corners + [0, 0, umax + 0.002]]),
                                 pose)
        w, h = self.camera.size
        c0_, r0_ = np.floor(pc.min(0)).astype(int) - 2
        c1_, r1_ = np.ceil(pc.max(0)).astype(int) + 2
        c0_, r0_, c1_, r1_ = max(c0_, 0), max(r0_, 0), min(c1_, w), min(r1_, h)
        if c1_ <= c0_ or r1_ <= r0_:
            return
        jj, ii = np.meshgrid(np.arange(c0_, c1_, dtype=float), np.arange(r0_, r1_, dtype=float))
        X = self.camera.backproject_to_plane(np.column_stack([jj.ravel(), ii.ravel()]), pose, [0, 0, 0],
                                             [0, 1.0, 0])
        xd, zd = X[:, 0], X[:, 2]
        dx, dz = gx[1] - gx[0], gz[1] - gz[0]
        g32 = np.ascontiguousarray(grid, dtype=np.float32)
        Xr, Zr = xd.astype(np.float32), zd.astype(np.float32)
        for _ in range(4):  # reference point: X = x - u(X) (fixed point, |grad u| << 1), bilinear u via remap
            u = cv2.remap(g32, (Xr / dx).astype(np.float32).reshape(jj.shape),
                          (Zr / dz).astype(np.float32).reshape(jj.shape), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
            Xr, Zr = xd - u[:, 0], zd - u[:, 2]
        sf = t.front_px_per_m
        mx = (Xr * sf - 0.5).reshape(jj.shape).astype(np.float32)
        my = ((b.height - Zr) * sf - 0.5).reshape(jj.shape).astype(np.float32)
        tex = cv2.remap(t.front, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        depth = (pose.apply(X)[:, 2]).reshape(jj.shape)
        ppm = self.camera.fx / depth  # image px per m
        edge = np.minimum.reduce([Xr.reshape(jj.shape), b.length - Xr.reshape(jj.shape),
                                  Zr.reshape(jj.shape), b.height - Zr.reshape(jj.shape)])
        alpha = np.clip(edge * ppm + 0.5, 0, 1)[..., None].astype(np.float32)
        sh = self._shade(np.array([0, -1.0, 0]))
        roi = img[r0_:r1_, c0_:c1_]
        roi[...] = roi * (1 - alpha) + tex * sh * alpha

    def _occlude(self, img, kinds, frame):
        w, h = self.camera.size
        rng = np.random.default_rng(self.spec.seed * 1000 + frame)
        for kind in kinds:
            mask = np.zeros((h, w), np.uint8)
            if kind == "full":  # something (a person) passes right in front of the lens
                cv2.rectangle(mask, (0, 0), (w, h), 255, -1)
            elif kind == "markers":  # a hand over the two left markers
                cv2.ellipse(mask, (int(0.08 * w), int(0.5 * h)), (int(0.16 * w), int(0.45 * h)), 0, 0, 360, 255, -1)
            else:  # a hand over the middle of the beam
                cv2.ellipse(mask, (int(0.5 * w), int(0.55 * h)), (int(0.1 * w), int(0.3 * h)), 10, 0, 360, 255, -1)
            a = cv2.GaussianBlur(mask, (0, 0), 6).astype(np.float32)[..., None] / 255
            base = np.array((95, 120, 165), np.float32) if kind != "full" else np.array((40, 45, 55), np.float32)
            shade = base * (0.85 + 0.15 * rng.random())
            img[...] = img * (1 - a) + shade * a

    # -- frame -----------------------------------------------------------------------------------------
    def render(self, frame: int) -> tuple[np.ndarray, dict]:
        """BGR uint8 frame `frame` and its truth row (dict)."""
        spec = self.spec
        fps = spec.video.fps
        t = frame / fps
        pose = spec.camera_pose(t)
        s = spec.load_position(t)
        u = self.truth.solve(s)
        grid = self.truth.front_grid(u)
        kinds = spec.occluded(frame)
        if "full" in kinds:  # nothing of the scene is visible: skip drawing it
            img = np.zeros((self.camera.height, self.camera.width, 3), np.float32)
        else:
            img = self._draw_board(pose)
            self._draw_beam(img, pose, grid, s)
        if kinds:
            self._occlude(img, kinds, frame)
        L = spec.lighting
        gain = 1 + L.flicker * math.sin(2 * math.pi * 2.3 * t) * math.sin(2 * math.pi * 0.37 * t + 1)
        img = cv2.multiply(img, self.vignette3, scale=gain)
        # motion blur along the image motion of the target during the exposure
        sen = spec.sensor
        c_now = self.camera.project([spec.camera.target], pose)[0]
        c_prev = self.camera.project([spec.camera.target], spec.camera_pose(t - 1 / fps))[0]
        blur = (c_now - c_prev) * sen.motion_blur
        n = float(np.linalg.norm(blur))
        if n > 0.5:
            k = math.ceil(n) | 1
            ker = np.zeros((k + 2, k + 2), np.float32)
            ctr = (k + 1) / 2
            d = blur / n
            cv2.line(ker, (int(round((ctr - d[0] * n / 2) * 16)), int(round((ctr - d[1] * n / 2) * 16))),  # noqa: RUF046 - numpy 1.x round
                     (int(round((ctr + d[0] * n / 2) * 16)), int(round((ctr + d[1] * n / 2) * 16))), 1.0, 1,  # noqa: RUF046 - numpy 1.x round
                     cv2.LINE_AA, shift=4)
            img = cv2.filter2D(img, -1, ker / ker.sum())
        if sen.psf > 0:
            img = cv2.GaussianBlur(img, (0, 0), sen.psf)
        if sen.read_noise > 0 or sen.shot_noise > 0:
            noise = np.empty(img.shape, np.float32)
            cv2.setRNGSeed((self.spec.seed * 1_000_003 + frame) % (2**31 - 1))  # per-thread global RNG: reproducible
            cv2.randn(noise, 0.0, 1.0)
            std = cv2.sqrt(cv2.max(img, 0.0) * np.float32(sen.shot_noise ** 2) + np.float32(sen.read_noise ** 2))
            img = cv2.add(img, cv2.multiply(noise, std))
        out = cv2.convertScaleAbs(img)  # saturating round to uint8
        dots = self.truth.dots(u)
        row = {"frame": frame, "time_s": t, "s_true_m": s, "load_n": spec.beam.load,
               "occluded": "+".join(kinds), "cam_rvec": pose.rvec, "cam_t": pose.t, "dots": dots,
               "tip_deflection_m": float(-np.interp(spec.beam.length, self.truth.grid_x, grid[len(grid) // 2, :, 2]))}
        return out, row


def truth_header(n_dots: int) -> list[str]:
    h = ["frame", "time_s", "s_true_m", "load_n", "tip_deflection_m", "occluded", "cam_rx", "cam_ry", "cam_rz",
         "cam_tx", "cam_ty", "cam_tz"]
    for k in range(n_dots):
        h += [f"dot{k}_x", f"dot{k}_y", f"dot{k}_z"]
    return h


def camera_values(row: dict) -> list[str]:
    """The camera pose columns (cam_rx .. cam_tz) of a truth.csv row."""
    return [f"{x:.9f}" for x in row["cam_rvec"]] + [f"{x:.9f}" for x in row["cam_t"]]


def truth_values(row: dict) -> list:
    v = [row["frame"], f"{row['time_s']:.6f}", f"{row['s_true_m']:.6f}", row["load_n"],
         f"{row['tip_deflection_m']:.9e}", row["occluded"]]
    v += camera_values(row)
    v += [f"{x:.9e}" for x in np.asarray(row["dots"]).ravel()]
    return v


def render_scene(spec: SceneSpec, out_dir, progress: Callable[[int, int], None] | None = None,
                 video_name: str = "scene.mp4", threads: int = 0) -> dict:
    """Render the scene into out_dir: `video_name` (H.264 yuv420p), truth.csv, camera.toml, object.json.

    Files are written to temporaries and renamed at the end (no partial outputs on failure).
    """
    from physar.ar.video import write_clip

    cam = spec.camera_model(spec.__dict__.get("_base"))
    rend = SceneRenderer(spec, camera=cam)

    def frame(k):
        img, row = rend.render(k)
        return img, truth_values(row)

    return write_clip(out_dir, video_name, cam, spec.video.fps, spec.video.crf, truth_header(spec.beam.dots),
                      spec.n_frames, frame, progress, threads=threads)


def read_csv_columns(path, what: str = "file") -> dict:
    """Columns of a CSV file with a header row as numpy arrays: float where every value parses, else str."""
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise PhysarError(f"{path}: empty {what}")
    head, body = rows[0], rows[1:]
    cols = {}
    for j, h in enumerate(head):
        vals = [r[j] for r in body]
        try:
            cols[h] = np.array(vals, float)
        except ValueError:
            cols[h] = np.array(vals)
    return cols


def read_truth(path) -> dict:
    """Columns of a truth.csv as numpy arrays (frame, time_s, s_true_m, ..., occluded as str)."""
    cols = read_csv_columns(path, "truth file")
    if "occluded" in cols:
        cols["occluded"] = cols["occluded"].astype(str)
    return cols
