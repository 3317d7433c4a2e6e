"""Scene (b) of seed 000 §5.2: the foam beam without fiducials.

A 797.5 x 200 x 105 mm foam beam (Kirchhoff–Saint Venant, E = 0.11 N/mm², nu = 0.2; the FE model of
:mod:`physar.fem.seed_examples`), pinned on its leftmost 40 mm and sliding on its rightmost 40 mm, carries a
15 N lead disk of 80 mm diameter placed centred on its top face at x = s (the parameter). A handheld camera
films its textured front face (y = 0) against a cluttered wall; ArUco markers on the wall are visible in
frame 0 only (they register the reference configuration, Fig. 8), then removed.

Truth: the nonlinear (St.VK) equilibrium on a P2 mesh finer than the reduced model's (no inverse crime).
Reduced model: non-intrusive PGD u(x, s) ~ Σ F_i(x) G_i(s) of the nonlinear problem over s in
[100 mm, L - 100 mm] (the seed's range, §5.2), snapshots by Newton continuation in s.
Vision: pose from ORB features of the wall (map built in the registered frame 0), deformation from the
beam's own texture (ORB keypoints tracked by Lucas-Kanade in the rectified front face), assimilation
s* = argmin ||u* - C u(s)||² (seed 000 Eq. (2)) on the reduced model, overlay of |u|.

World frame: x along the beam, y into the scene (away from the camera), z up; m, N, Pa.
"""
from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from pydantic import Field, model_validator

from physar.ar.runner import pipeline_stats, run_scene_demo, run_video, write_report
from physar.ar.scene import (
    CameraSection,
    LightingSection,
    MarkerSection,
    SensorSection,
    VideoSection,
    _Strict,
    camera_values,
    read_csv_columns,
)
from physar.errors import ConfigError, PhysarError
from physar.vision.camera import Camera, Pose
from physar.vision.markers import MarkerBoard


# ------------------------------------------------------------------------------------------------------
# scene description
# ------------------------------------------------------------------------------------------------------
class FoamSection(_Strict):
    length: float = Field(0.7975, gt=0)
    width: float = Field(0.200, gt=0, description="depth along y [m]")
    height: float = Field(0.105, gt=0, description="along z [m]")
    E: float = Field(0.11e6, gt=0, description="Pa (0.11 N/mm²)")
    nu: float = Field(0.2, gt=-1, lt=0.5)
    load: float = Field(15.0, gt=0, description="weight of the lead disk [N]")
    disk_diameter: float = Field(0.080, gt=0)
    disk_thickness: float = Field(0.027, gt=0, description="15 N of lead, 80 mm diameter: 27 mm")
    support: float = Field(0.040, gt=0, description="pinned length on the left, sliding on the right [m]")
    margin: float = Field(0.100, ge=0, description="ends outside the load range (seed: 100 mm) [m]")
    truth_cells: tuple[int, int, int] = (32, 4, 4)
    model_cells: tuple[int, int, int] = (24, 4, 3)
    element: str = "P2"
    texture_scale: float = Field(0.004, gt=0, description="typical pore/feature size of the foam [m]")


class FoamLoad(_Strict):
    reference: float = Field(0.5, gt=0, description="s of unloaded beam at the start (reference frames)")
    positions: list[float] = Field(default_factory=lambda: [0.22, 0.55, 0.32, 0.64, 0.42, 0.15, 0.50, 0.27,
                                                            0.60, 0.37], description="disk positions s [m]")
    dwell: float = Field(1.0, gt=0, description="s at each position (the disk is lifted and placed)")


def _foam_markers() -> MarkerSection:
    return MarkerSection(size=0.08, board_offset=0.35, centres=[(-0.10, 0.30), (0.90, 0.30), (-0.20, -0.22),
                                                                 (1.00, -0.22)])


class FoamSceneSpec(_Strict):
    name: str = "foam"
    seed: int = 0
    video: VideoSection = VideoSection(duration=10.5)
    foam: FoamSection = FoamSection()
    markers: MarkerSection = Field(default_factory=_foam_markers)
    camera: CameraSection = CameraSection(distance=1.0, target=(0.40, 0.0, 0.03), elevation=10.0,
                                          orbit_deg=(6.0, 3.0), orbit_period=12.0, shake_mm=2.0, shake_deg=0.2)
    lighting: LightingSection = LightingSection()
    sensor: SensorSection = SensorSection()
    load: FoamLoad = FoamLoad()

    @model_validator(mode="after")
    def _check(self):
        f = self.foam
        lo, hi = f.margin, f.length - f.margin
        bad = [s for s in self.load.positions if not lo - 1e-12 <= s <= hi + 1e-12]
        if bad:
            raise ValueError(f"load positions {bad} lie outside the load range [{lo}, {hi}] m")
        if f.element not in ("P1", "P2"):
            raise ValueError(f"element must be P1 or P2, got {f.element!r}")
        return self

    @property
    def n_frames(self) -> int:
        return max(1, round(self.video.duration * self.video.fps))

    @property
    def s_range(self) -> tuple[float, float]:
        return (self.foam.margin, self.foam.length - self.foam.margin)

    def load_position(self, t: float) -> float:
        """s(t) [m], NaN while the beam is unloaded (the first `reference` seconds)."""
        ld = self.load
        if t < ld.reference:
            return float("nan")
        k = min(int((t - ld.reference) // ld.dwell), len(ld.positions) - 1)
        return float(ld.positions[k])

    def board(self) -> MarkerBoard:
        m = self.markers
        return MarkerBoard.on_plane(m.ids, [(c[0], -c[1]) for c in m.centres], m.size,
                                    [0, m.board_offset, 0], [1, 0, 0], [0, 0, -1], m.dictionary)

    def camera_model(self) -> Camera:
        return Camera.from_fov(self.video.width, self.video.height, self.video.hfov)

    def camera_pose(self, t: float) -> Pose:
        from physar.ar.scene import SceneSpec

        # the handheld camera of scene (a) (orbit + shake about the target), with this scene's settings
        return SceneSpec(seed=self.seed, camera=self.camera).camera_pose(t)


def load_foam_scene(path) -> FoamSceneSpec:
    """Read and validate a scene (foam) TOML; errors name the file and the key."""
    from physar.ar.scene import validate_scene

    return validate_scene(path, FoamSceneSpec)


# ------------------------------------------------------------------------------------------------------
# object description and FE models
# ------------------------------------------------------------------------------------------------------
@dataclass
class FoamObject:
    """What the pipeline knows about the foam beam (stored as JSON in the reduced model's metadata)."""

    length: float
    width: float
    height: float
    cells: tuple
    element: str
    E: float
    nu: float
    load: float
    disk_radius: float
    support: float
    marker_ids: list
    marker_corners: list
    dictionary: str
    wall_y: float

    @classmethod
    def from_scene(cls, spec: FoamSceneSpec) -> FoamObject:
        f, b = spec.foam, spec.board()
        return cls(f.length, f.width, f.height, tuple(f.model_cells), f.element, f.E, f.nu, f.load,
                   f.disk_diameter / 2, f.support, b.ids.tolist(), b.corners.tolist(), b.dictionary,
                   spec.markers.board_offset)

    def board(self) -> MarkerBoard:
        return MarkerBoard(self.marker_ids, self.marker_corners, self.dictionary)

    def beam(self):
        from physar.fem.seed_examples import foam_beam

        return foam_beam(tuple(self.cells), self.element, E=self.E, nu=self.nu, load=self.load,
                         radius=self.disk_radius, size=(self.length, self.width, self.height), support=self.support)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> FoamObject:
        try:
            return cls(**json.loads(text))
        except (json.JSONDecodeError, TypeError) as e:
            raise ConfigError(f"reduced model: invalid foam_object metadata ({e})") from None


class ContinuationSolver:
    """u(s): St.VK equilibrium under the disk at s, by Newton continuation from the cached solution at the
    nearest solved s (one load step), falling back to load stepping from rest if that fails."""

    def __init__(self, beam, cache_size: int = 512):
        self.beam, self.cache, self.cache_size = beam, {}, cache_size
        self.solves = 0

    def __call__(self, mu) -> np.ndarray:
        from physar.errors import SolverError

        s = round(float(np.atleast_1d(mu)[0]), 9)
        if s in self.cache:
            return self.cache[s]
        u0 = None
        if self.cache:
            near = min(self.cache, key=lambda k: abs(k - s))
            u0 = self.cache[near]
        try:
            u = self.beam.solve(s, steps=1, u0=u0).u if u0 is not None else self.beam.solve(s).u
        except SolverError:
            u = self.beam.solve(s, steps=2 * self.beam.steps).u
        self.solves += 1
        self.cache[s] = u
        if len(self.cache) > self.cache_size:
            self.cache.pop(next(iter(self.cache)))
        return u


def build_foam_model(spec: FoamSceneSpec, progress: Callable[[int, int], None] | None = None, tol: float = 2e-3,
                     max_points: int = 65, max_modes: int = 30, initial_points: int = 9):
    """Reduced model u(x; s) of the foam beam by non-intrusive PGD (physar.rom.nonintrusive) of the
    nonlinear St.VK problem on the model mesh. Returns (SeparatedModel, FoamObject, FESpace, info)."""
    from physar.rom.nonintrusive import nonintrusive_pgd

    obj = FoamObject.from_scene(spec)
    beam = obj.beam()
    solver = ContinuationSolver(beam)
    rom, info = nonintrusive_pgd(solver, [spec.s_range], ["s"], ["m"], initial_points=initial_points, tol=tol,
                                 max_points=max_points, max_modes=max_modes, progress=progress,
                                 metadata={"kind": "foam_beam", "material": "StVK", "method": "pgd_nonintrusive"})
    rom.metadata["foam_object"] = obj.to_json()
    return rom, obj, beam.space, info


# ------------------------------------------------------------------------------------------------------
# ground truth and rendering
# ------------------------------------------------------------------------------------------------------
class FoamTruth:
    """Fine-mesh St.VK solutions of the scene's beam and their front-face displacement grids."""

    def __init__(self, spec: FoamSceneSpec):
        from physar.fem.seed_examples import foam_beam

        f = spec.foam
        self.spec = spec
        self.beam = foam_beam(tuple(f.truth_cells), f.element, E=f.E, nu=f.nu, load=f.load,
                              radius=f.disk_diameter / 2, size=(f.length, f.width, f.height), support=f.support)
        self.solver = ContinuationSolver(self.beam)
        nodes = self.beam.space.nodes
        front = np.flatnonzero(np.abs(nodes[:, 1]) < 1e-12)
        xs, zs = np.unique(nodes[front, 0].round(12)), np.unique(nodes[front, 2].round(12))
        if len(front) != xs.size * zs.size:
            raise PhysarError("foam truth: front face is not a structured grid")
        order = np.lexsort((nodes[front, 0], nodes[front, 2]))
        self.front = front[order].reshape(zs.size, xs.size)
        self.xs, self.zs = xs, zs
        self.xu = np.linspace(0, f.length, 4 * (xs.size - 1) + 1)  # uniform resampling for rendering

    def solve(self, s: float) -> np.ndarray:
        if not np.isfinite(s):
            return np.zeros(self.beam.space.n_dofs)
        return self.solver(s)

    def front_grid(self, u: np.ndarray) -> np.ndarray:
        """Displacement (nz, nxu, 3) on the front face, resampled to the uniform x grid `xu` [m]."""
        g = u.reshape(-1, 3)[self.front]
        return np.stack([np.stack([np.interp(self.xu, self.xs, g[k, :, c]) for c in range(3)], -1)
                         for k in range(len(self.zs))])

    def midspan_deflection(self, u: np.ndarray) -> float:
        return self.beam.deflection(u, self.spec.foam.length / 2)


def _noise_texture(rng, h, w, scales, weights) -> np.ndarray:
    out = np.zeros((h, w), np.float32)
    for s, a in zip(scales, weights):
        n = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), s)
        out += a * n / max(float(n.std()), 1e-6)
    return out


def sensor_effects(img: np.ndarray, sensor, lighting, vignette3, t: float, blur_px: np.ndarray,
                   noise_seed: int | None = None) -> np.ndarray:
    """Flicker, vignetting, motion blur along `blur_px`, lens PSF, shot + read noise, uint8 rounding."""
    gain = 1 + lighting.flicker * math.sin(2 * math.pi * 2.3 * t) * math.sin(2 * math.pi * 0.37 * t + 1)
    img = cv2.multiply(img, vignette3, scale=gain)
    n = float(np.linalg.norm(blur_px))
    if n > 0.5:
        k = math.ceil(n) | 1
        ker = np.zeros((k + 2, k + 2), np.float32)
        c = (k + 1) / 2
        d = blur_px / n
        cv2.line(ker, (int(round((c - d[0] * n / 2) * 16)), int(round((c - d[1] * n / 2) * 16))),  # noqa: RUF046 - numpy 1.x round
                 (int(round((c + d[0] * n / 2) * 16)), int(round((c + d[1] * n / 2) * 16))), 1.0, 1, cv2.LINE_AA,  # noqa: RUF046 - numpy 1.x round
                 shift=4)
        img = cv2.filter2D(img, -1, ker / ker.sum())
    if sensor.psf > 0:
        img = cv2.GaussianBlur(img, (0, 0), sensor.psf)
    if sensor.read_noise > 0 or sensor.shot_noise > 0:
        noise = np.empty(img.shape, np.float32)
        if noise_seed is not None:  # OpenCV's RNG is global per thread: seed it so a frame is reproducible
            cv2.setRNGSeed(int(noise_seed) % (2**31 - 1))
        cv2.randn(noise, 0.0, 1.0)
        std = cv2.sqrt(cv2.max(img, 0.0) * np.float32(sensor.shot_noise ** 2) + np.float32(sensor.read_noise ** 2))
        img = cv2.add(img, cv2.multiply(noise, std))
    return cv2.convertScaleAbs(img)


def vignette(camera: Camera, amount: float) -> np.ndarray:
    w, h = camera.size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    return cv2.merge([(1 - amount * r2).astype(np.float32)] * 3)


def shade(lighting, normal) -> float:
    li = np.asarray(lighting.direction, float)
    li = li / np.linalg.norm(li)
    amb = lighting.ambient
    return amb + (1 - amb) * max(0.0, float(np.dot(normal, li))) / max(1e-9, float(np.dot([0, -1, 0], li)))


def poly(img, camera, pose, pts3, colour):
    p = camera.project(np.asarray(pts3, float), pose)
    cv2.fillPoly(img, [np.round(p * 16).astype(np.int32)], tuple(float(c) for c in colour), cv2.LINE_AA, shift=4)


class FoamRenderer:
    """Renders frames of a :class:`FoamSceneSpec` (BGR uint8) and their truth rows."""

    def __init__(self, spec: FoamSceneSpec, truth: FoamTruth | None = None, camera: Camera | None = None):
        self.spec = spec
        self.camera = camera or spec.camera_model()
        self.truth = truth or FoamTruth(spec)
        self.vig = vignette(self.camera, spec.lighting.vignetting)
        self._textures()

    def _textures(self):
        spec, f, m = self.spec, self.spec.foam, self.spec.markers
        rng = np.random.default_rng(spec.seed + 7)
        ppm = self.camera.fx / spec.camera.distance
        # wall: a cluttered pinboard (rectangles, discs, print-like strokes), rigid environment for ORB
        s = 1.3 * ppm
        x0, x1, z0, z1 = -0.9, 1.7, -0.8, 0.9
        W, H = int((x1 - x0) * s), int((z1 - z0) * s)
        wall = np.full((H, W, 3), (150, 160, 168), np.float32)
        wall += 10 * _noise_texture(rng, H, W, (2.0, 12.0), (0.5, 1.0))[..., None]
        for _ in range(int(0.08 * W * H / (0.02 * s) ** 2)):
            col = rng.uniform(40, 230, 3)
            c = (int(rng.uniform(0, W)), int(rng.uniform(0, H)))
            r = int(rng.uniform(0.004, 0.03) * s)
            if rng.random() < 0.5:
                cv2.circle(wall, c, r, col.tolist(), -1, cv2.LINE_AA)
            else:
                cv2.rectangle(wall, c, (c[0] + int(rng.uniform(0.5, 2.5) * r), c[1] + r), col.tolist(), -1)
        self.wall_markers = wall.copy()
        for mid, (mx, mz) in zip(m.ids, m.centres):
            from physar.ar.scene import _aruco_image

            pxf = m.size * s
            hr = 6 * 48
            img = _aruco_image(m.dictionary, mid, hr).astype(np.float32) * (225 / 255.0) + 20
            k = pxf / hr
            u0, v0 = (mx - x0) * s - pxf / 2, (z1 - mz) * s - pxf / 2
            q = 0.25 * pxf
            self.wall_markers[int(v0 - q):int(v0 + pxf + q), int(u0 - q):int(u0 + pxf + q)] = (245, 245, 245)
            M = np.array([[k, 0, u0 + 0.5 * k - 0.5], [0, k, v0 + 0.5 * k - 0.5]])
            mk = cv2.warpAffine(cv2.merge([img] * 3), M, (W, H), flags=cv2.INTER_LINEAR)
            cov = cv2.warpAffine(np.ones((hr, hr), np.float32), M, (W, H), flags=cv2.INTER_LINEAR)[..., None]
            self.wall_markers = self.wall_markers * (1 - cov) + mk * cov
        self.wall = np.clip(wall, 0, 255)
        self.wall_markers = np.clip(self.wall_markers, 0, 255)
        self.wall_s, self.wall_origin = s, (x0, z1)
        # foam front face: yellowish polyurethane with pores (dark blobs) at several scales
        sf = 2.0 * ppm
        Wf, Hf = int(f.length * sf) + 2, int(f.height * sf) + 2
        base = np.array((95, 185, 215), np.float32)  # BGR
        n = _noise_texture(rng, Hf, Wf, (0.6, 1.5, 4.0), (0.6, 1.0, 0.7))
        front = base * (1 + 0.12 * n[..., None])
        pores = np.zeros((Hf, Wf), np.float32)
        npores = int(Wf * Hf / (f.texture_scale * sf) ** 2 * 0.35)
        pc = rng.uniform(0, 1, (npores, 2)) * (Wf, Hf)
        pr = rng.uniform(0.25, 0.6, npores) * f.texture_scale * sf
        for (cx, cy), r in zip(pc, pr):
            cv2.circle(pores, (int(cx * 16), int(cy * 16)), max(int(r * 16), 8), 1.0, -1, cv2.LINE_AA, shift=4)
        pores = cv2.GaussianBlur(pores, (0, 0), 0.7)
        self.front = np.clip(front * (1 - 0.55 * pores[..., None]), 0, 255)
        self.front_s = sf

    def _draw_wall(self, pose: Pose, markers: bool) -> np.ndarray:
        s = self.wall_s
        x0, z1 = self.wall_origin
        yb = self.spec.markers.board_offset
        A = np.array([[1 / s, 0, x0 + 0.5 / s], [0, 0, yb], [0, -1 / s, z1 - 0.5 / s]])
        M = self.camera.K @ (pose.R @ A + np.column_stack([np.zeros((3, 2)), pose.t]))
        tex = self.wall_markers if markers else self.wall
        img = cv2.warpPerspective(tex, M, self.camera.size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                  borderValue=(70, 72, 75))
        return img * shade(self.spec.lighting, np.array([0, -1.0, 0]))

    def _draw_beam(self, img, pose: Pose, grid: np.ndarray, s: float):
        f, L = self.spec.foam, self.spec.lighting
        cam, xu = self.camera, self.truth.xu
        c = pose.center
        sh_front = shade(L, np.array([0, -1.0, 0]))
        # supports: wooden blocks under both ends
        for xa, xb in ((-0.03, f.support), (f.length - f.support, f.length + 0.03)):
            poly(img, cam, pose, [[xa, -0.01, -0.12], [xb, -0.01, -0.12], [xb, -0.01, 0], [xa, -0.01, 0]],
                 np.array((60, 105, 140)) * sh_front)
            if c[2] > 0:
                poly(img, cam, pose, [[xa, -0.01, 0], [xb, -0.01, 0], [xb, f.width + 0.01, 0], [xa, f.width + 0.01, 0]],
                     np.array((75, 125, 160)) * shade(L, np.array([0, 0, 1.0])))
        top = grid[-1]
        if c[2] > f.height:  # top face
            fe = np.column_stack([xu, np.zeros_like(xu), np.full_like(xu, f.height)]) + top
            poly(img, cam, pose, np.vstack([fe, (fe + [0, f.width, 0])[::-1]]),
                 np.array((90, 175, 205)) * shade(L, np.array([0, 0, 1.0])))
        if np.isfinite(s):  # the lead disk, resting on the top face
            r, th = f.disk_diameter / 2, f.disk_thickness
            uz = float(np.interp(s, xu, top[:, 2]))
            ux = float(np.interp(s, xu, top[:, 0]))
            a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
            ring = np.column_stack([s + ux + r * np.cos(a), f.width / 2 + r * np.sin(a), np.zeros_like(a)])
            bot = ring + [0, 0, f.height + uz]
            topr = ring + [0, 0, f.height + uz + th]
            p = cam.project(np.vstack([bot, topr]), pose)
            hull = cv2.convexHull(np.round(p * 16).astype(np.int32))
            cv2.fillPoly(img, [hull], tuple(float(v) * sh_front for v in (88, 90, 96)), cv2.LINE_AA, shift=4)
            if c[2] > f.height + uz + th:
                poly(img, cam, pose, topr, np.array((120, 122, 128)) * shade(L, np.array([0, 0, 1.0])))
        # front face: texture through the inverse deformation X = x - u(X) (fixed point), anti-aliased edges
        corners = np.array([[0, 0, 0], [f.length, 0, 0], [f.length, 0, f.height], [0, 0, f.height]], float)
        umax = float(np.abs(grid).max())
        pc = cam.project(np.vstack([corners + [0, 0, -umax - 0.004], corners + [0, 0, umax + 0.004]]), pose)
        w, h = cam.size
        c0, r0 = np.floor(pc.min(0)).astype(int) - 2
        c1, r1 = np.ceil(pc.max(0)).astype(int) + 2
        c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, w), min(r1, h)
        if c1 <= c0 or r1 <= r0:
            return
        jj, ii = np.meshgrid(np.arange(c0, c1, dtype=float), np.arange(r0, r1, dtype=float))
        X = cam.backproject_to_plane(np.column_stack([jj.ravel(), ii.ravel()]), pose, [0, 0, 0], [0, 1.0, 0])
        xd, zd = X[:, 0], X[:, 2]
        zs = self.truth.zs
        dx = xu[1] - xu[0]
        g32 = np.ascontiguousarray(grid, dtype=np.float32)
        zi = np.interp(zd, zs, np.arange(zs.size)).astype(np.float32)
        Xr, Zr = xd.astype(np.float32), zd.astype(np.float32)
        for _ in range(5):
            u = cv2.remap(g32, (Xr / dx).astype(np.float32).reshape(jj.shape), zi.reshape(jj.shape), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
            Xr, Zr = xd - u[:, 0], zd - u[:, 2]
            zi = np.interp(Zr, zs, np.arange(zs.size)).astype(np.float32)
        sf = self.front_s
        mx = (Xr * sf - 0.5).reshape(jj.shape).astype(np.float32)
        my = ((f.height - Zr) * sf - 0.5).reshape(jj.shape).astype(np.float32)
        tex = cv2.remap(self.front, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        ppm = cam.fx / pose.apply(X)[:, 2].reshape(jj.shape)
        edge = np.minimum.reduce([Xr.reshape(jj.shape), f.length - Xr.reshape(jj.shape), Zr.reshape(jj.shape),
                                  f.height - Zr.reshape(jj.shape)])
        alpha = np.clip(edge * ppm + 0.5, 0, 1)[..., None].astype(np.float32)
        roi = img[r0:r1, c0:c1]
        roi[...] = roi * (1 - alpha) + tex * sh_front * alpha

    def render(self, frame: int) -> tuple[np.ndarray, dict]:
        spec = self.spec
        fps = spec.video.fps
        t = frame / fps
        pose = spec.camera_pose(t)
        s = spec.load_position(t)
        u = self.truth.solve(s)
        grid = self.truth.front_grid(u)
        img = self._draw_wall(pose, markers=frame == 0)
        self._draw_beam(img, pose, grid, s)
        tgt = [spec.camera.target]
        blur = (self.camera.project(tgt, pose)[0] - self.camera.project(tgt, spec.camera_pose(t - 1 / fps))[0])
        out = sensor_effects(img, spec.sensor, spec.lighting, self.vig, t, blur * spec.sensor.motion_blur,
                             noise_seed=spec.seed * 1_000_003 + frame)
        row = {"frame": frame, "time_s": t, "s_true_m": s, "markers_visible": int(frame == 0),
               "midspan_deflection_m": self.truth.midspan_deflection(u), "cam_rvec": pose.rvec, "cam_t": pose.t}
        return out, row


FOAM_TRUTH_HEADER = ["frame", "time_s", "s_true_m", "markers_visible", "midspan_deflection_m", "cam_rx", "cam_ry",
                     "cam_rz", "cam_tx", "cam_ty", "cam_tz"]


def render_foam_scene(spec: FoamSceneSpec, out_dir, progress: Callable[[int, int], None] | None = None,
                      video_name: str = "scene.mp4") -> dict:
    """Render scene (b) into out_dir: `video_name` (H.264), truth.csv, camera.toml (atomic writes)."""
    from physar.ar.video import write_clip

    cam = spec.camera_model()
    rend = FoamRenderer(spec, camera=cam)

    def frame(k):
        img, row = rend.render(k)
        values = [k, f"{row['time_s']:.6f}", f"{row['s_true_m']:.6f}", row["markers_visible"],
                  f"{row['midspan_deflection_m']:.9e}"]
        return img, values + camera_values(row)

    out = write_clip(out_dir, video_name, cam, spec.video.fps, spec.video.crf, FOAM_TRUTH_HEADER, spec.n_frames,
                     frame, progress)
    return {**out, "truth_solves": rend.truth.solver.solves}


# ------------------------------------------------------------------------------------------------------
# the markerless AR pipeline
# ------------------------------------------------------------------------------------------------------
def object_from_foam_model(rom) -> FoamObject:
    text = rom.metadata.get("foam_object")
    if not text:
        raise ConfigError("reduced model has no foam beam description (metadata 'foam_object'); build it with "
                          "physar.ar.foam.build_foam_model")
    return FoamObject.from_json(text)


@dataclass
class FoamFrame:
    frame: int
    status: str           # reference | tracking | unloaded | hold | lost
    mu: np.ndarray
    std: np.ndarray
    residual_mm: float
    n_env: int            # ORB inliers on the wall (pose)
    n_surface: int        # tracked texture features of the beam (deformation)
    latency_ms: float
    stages_ms: dict


# estimates.csv: frame, time_s, status, then these columns
FOAM_ESTIMATES_HEADER = ["s_est", "s_std", "residual_mm", "env_features", "surface_features", "latency_ms"]


def _foam_row(r: FoamFrame) -> list:
    return [f"{r.mu[0]:.6f}", f"{r.std[0]:.6f}", f"{r.residual_mm:.5f}", r.n_env, r.n_surface, f"{r.latency_ms:.3f}"]


class FoamPipeline:
    """Markerless frame loop of scene (b) (see the module docstring).

    Frame 0 (or the first frame where the markers are found) registers the camera by the fiducial markers
    and builds the ORB map of the wall from it; afterwards the markers are never looked for again. The
    first ``reference_frames`` frames show the unloaded beam: their rectified front faces are averaged into
    the reference view and its ORB keypoints become the tracked material points. Each later frame:
    pose (ORB map) -> texture displacements u* (u_x, u_z) -> s* = argmin ||u* - a C u(s)||² by a global
    search over a fine s grid (a quadratic form in the mode coefficients; ``free_scale``: the amplitude a is
    a nuisance absorbing the model's stiffness error, else a = 1) -> temporal filter -> overlay.
    """

    def __init__(self, rom, camera: Camera, obj: FoamObject | None = None, reference_frames: int = 8,
                 px_per_m: float | None = None, n_points: int = 600, win: int = 15, field: str = "u",
                 overlay: bool = True,
                 smoothing: float = 0.5, jump_sigma: float = 4.0,
                 min_points: float = 0.3, unloaded_mm: float = 1.0, search_points: int = 601,
                 free_scale: bool = True, outlier_mm: float = 0.5, nuisance: str = "similarity"):
        from physar.fem import FESpace
        from physar.vision.markers import MarkerTracker

        self.rom, self.camera = rom, camera
        self.obj = obj or object_from_foam_model(rom)
        o = self.obj
        self.beam = o.beam()
        self.space: FESpace = self.beam.space
        if rom.F.shape[1] != self.space.n_dofs:
            raise ConfigError(f"reduced model has {rom.F.shape[1]} dofs, its foam mesh {self.space.n_dofs}")
        self.markers = MarkerTracker(camera, o.board())
        self.reference_frames, self.px_per_m, self.n_points = int(reference_frames), px_per_m, n_points
        self.win = int(win)
        self.smoothing, self.jump_sigma = smoothing, jump_sigma
        self.min_points, self.unloaded = min_points, unloaded_mm * 1e-3
        self.free_scale, self.scale, self.outlier_mm = free_scale, float('nan'), outlier_mm
        if nuisance not in ("none", "rigid", "similarity", "affine"):
            raise ConfigError(f"nuisance must be none, rigid, similarity or affine, got {nuisance!r}")
        self.nuisance = nuisance
        self.map = None
        self.tracker = None
        self._refs, self._refs_col = [], []
        self.points = None
        self.registration = {}
        lo, hi = rom.ranges[0]
        self.s_grid = np.linspace(lo, hi, search_points)
        self.c_grid = np.array([rom.coefficients([s])[0] for s in self.s_grid])  # (n_s, n_modes)
        self.mu = np.array([(lo + hi) / 2])
        self.std = np.array([np.nan])
        self._fresh = True
        self.overlay = None
        if overlay:
            self.overlay = FoamOverlay(self.space, rom, o, field=field)
        self.top_margin, self.bottom_margin, self.side_margin = 0.015, 0.09, 0.02

    # -- registration -------------------------------------------------------------------------------------
    def _register(self, gray, pose):
        from physar.vision.markerless import PlanarMap, PlaneTextureTracker

        o, cam = self.obj, self.camera
        h, w = gray.shape
        mask = np.full((h, w), 255, np.uint8)
        # the wall, without the markers (they are removed after frame 0) nor the beam, its supports and disk
        for c in o.board().corners:
            q = c.mean(0) + 1.6 * (c - c.mean(0))
            cv2.fillPoly(mask, [np.round(cam.project(q, pose)).astype(np.int32)], 0)
        box = np.array([[-0.06, -0.02, -0.14], [o.length + 0.06, o.width + 0.02, o.height + 0.06]])
        corners = np.array([[box[i, 0], box[j, 1], box[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        hull = cv2.convexHull(np.round(cam.project(corners, pose)).astype(np.int32))
        cv2.fillPoly(mask, [hull], 0)
        self.map = PlanarMap.from_frame(cam, gray, pose, [0, o.wall_y, 0], [1, 0, 0], [0, 0, -1], mask=mask)
        # direct refinement on the rectified wall (the part seen in this frame), at ~0.75 of the image scale
        wc = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float)
        Xw = cam.backproject_to_plane(wc, pose, [0, o.wall_y, 0], [0, 1.0, 0])
        u0, u1 = Xw[:, 0].min(), Xw[:, 0].max()
        v0, v1 = -Xw[:, 2].max(), -Xw[:, 2].min()
        depth = float(np.median(pose.apply(Xw)[:, 2]))
        sw = 0.6 * cam.fx / depth
        rect = PlaneTextureTracker(cam, [u0, o.wall_y, -v0], [1, 0, 0], [0, 0, -1], (u1 - u0, v1 - v0), sw, n_points=1)
        ref = np.clip(rect.rectify(gray, pose), 0, 255).astype(np.uint8)
        rmask = rect.rectify(mask, pose) >= 254
        rmask = cv2.erode(rmask.astype(np.uint8) * 255, np.ones((15, 15), np.uint8))
        self.map.enable_refinement(ref, sw, (u0, v0), rmask, n_points=250)
        self._pose = pose
        dist = float(pose.apply([[o.length / 2, 0, o.height / 2]])[0, 2])
        ppm = self.px_per_m or cam.fx / dist
        sm = self.side_margin
        self.tracker = PlaneTextureTracker(cam, [-sm, 0, o.height + self.top_margin], [1, 0, 0], [0, 0, -1],
                                           (o.length + 2 * sm, o.height + self.top_margin + self.bottom_margin), ppm,
                                           n_points=self.n_points, win=self.win)

    @staticmethod
    def _edge(profile, c_expected, half):
        """Sub-pixel position of the strongest intensity step of `profile` within c_expected +- half."""
        g = np.abs(np.gradient(profile))
        lo, hi = max(int(c_expected - half), 1), min(int(c_expected + half), len(g) - 2)
        if hi <= lo:
            return None
        k = lo + int(np.argmax(g[lo:hi]))
        a, b, c = g[k - 1], g[k], g[k + 1]
        if b < 4 * np.median(g) or (a - 2 * b + c) >= 0:
            return None
        return k + 0.5 * (a - c) / (a - 2 * b + c)

    def _register_faces(self, ref):
        """Reference-configuration registration on the beam's own silhouette: the front face's left and
        right edges in the averaged rectified (colour) reference view, where they should be at x = 0 and L.
        Returns the affine maps (gain, offset) of the rectified coordinates to the material ones along x and
        below the top (identity where the edges are not found): the markers' pose error at frame 0 would
        otherwise shift every tracked point's material coordinate (and the load position) by millimetres."""
        o, tr = self.obj, self.tracker
        s, sm, tm = tr.s, self.side_margin, self.top_margin
        img = ref.astype(np.float32)
        # the face against its surroundings: the colour contrast (foam yellow: R - B large), rows averaged
        band = img[int((tm + 0.25 * o.height) * s):int((tm + 0.75 * o.height) * s)]
        prof = cv2.GaussianBlur((band[..., 2] - band[..., 0]).mean(0).reshape(1, -1), (0, 0), 1.0).ravel()
        half = 0.015 * s
        xl = self._edge(prof, sm * s - 0.5, half)
        xr = self._edge(prof, (sm + o.length) * s - 0.5, half)
        maps = [(1.0, -sm), (1.0, -tm)]
        if xl is not None and xr is not None and abs((xr - xl) / s / o.length - 1) < 0.02:
            a0, a1 = (xl + 0.5) / s, (xr + 0.5) / s
            maps[0] = (o.length / (a1 - a0), -a0 * o.length / (a1 - a0))
        self.registration = {"edges_px": [None if xl is None else float(xl), None if xr is None else float(xr)],
                             "x_map": [float(v) for v in maps[0]]}
        return maps

    def _set_reference(self):
        o, tr = self.obj, self.tracker
        w, h = tr.size
        mask = np.zeros((h, w), np.uint8)
        m = (tr.win[0] // 2 + 2) / tr.s + 0.003
        r0, r1 = int((self.top_margin + m) * tr.s), int((self.top_margin + o.height - m) * tr.s)
        c0, c1 = int((self.side_margin + m) * tr.s), int((self.side_margin + o.length - m) * tr.s)
        mask[r0:r1, c0:c1] = 255
        ab = tr.set_reference(self._refs, mask)
        self._refs = []
        (gx, ox), (gz, oz) = self._register_faces(np.mean(self._refs_col, axis=0))
        self._refs_col = []
        x = gx * ab[:, 0] + ox
        depth = gz * ab[:, 1] + oz  # distance below the top face
        self.points = np.column_stack([np.clip(x, 0, o.length), np.zeros(len(ab)), np.clip(o.height - depth, 0,
                                                                                           o.height)])
        from physar.vision.observation import surface_observation_matrix

        self.C = surface_observation_matrix(self.space, self.points, components=(0, 2)).tocsr()
        self.CF = np.asarray(self.C @ self.rom.F.T)  # (2 n, n_modes)

    # -- estimation ---------------------------------------------------------------------------------------
    def _estimate(self, y, valid):
        """s* = argmin_s min_a ||y - a C u(s)||² (a = 1 unless ``free_scale``): the cost is a quadratic form in
        the mode coefficients c(s), evaluated on the fine s grid (global, no local minima), refined by the
        parabola through the best grid point and its neighbours. sd(s*)² = 2 sigma² / cost''(s*), with
        sigma² = cost(s*) / (m - p) (Gauss-Newton covariance of seed 000 §4)."""
        rows = np.flatnonzero(np.repeat(valid, 2))
        A = self.CF[rows]
        yv = y[rows]
        k_nuis = 0
        if self.nuisance != "none":
            # apparent in-plane rigid motion of the face (pose error between the wall's plane and the beam's):
            # nuisance (t_x, t_z, omega) projected out of the data and the model (variable projection)
            Q, _ = np.linalg.qr(self._nuisance_basis(valid)[rows])
            yv = yv - Q @ (Q.T @ yv)
            A = A - Q @ (Q.T @ A)
            k_nuis = Q.shape[1]
        Aty, AtA, yy = A.T @ yv, A.T @ A, float(yv @ yv)
        num = self.c_grid @ Aty
        den = np.einsum("si,ij,sj->s", self.c_grid, AtA, self.c_grid)
        if self.free_scale:
            cost = yy - np.where(num > 0, num ** 2 / np.maximum(den, 1e-300), 0.0)
        else:
            cost = yy - 2 * num + den
        k = int(np.clip(np.argmin(cost), 1, len(cost) - 2))
        h = self.s_grid[1] - self.s_grid[0]
        c0, c1, c2 = cost[k - 1], cost[k], cost[k + 1]
        curv = (c0 - 2 * c1 + c2) / h ** 2
        d = 0.5 * (c0 - c2) / (c0 - 2 * c1 + c2) if curv > 0 else 0.0
        d = float(np.clip(d, -1.0, 1.0))
        s = float(np.clip(self.s_grid[k] + d * h, self.s_grid[0], self.s_grid[-1]))
        cmin = max(c1 - 0.25 * (c0 - c2) * d, 0.0)
        dof = max(len(yv) - 1 - int(self.free_scale) - k_nuis, 1)
        std = np.sqrt(2 * cmin / dof / curv) if curv > 0 else np.nan
        scale = num[k] / den[k] if den[k] > 0 else np.nan
        return np.array([s]), np.array([std]), float(np.sqrt(cmin)), float(scale)

    def _nuisance_basis(self, valid) -> np.ndarray:
        """(2 n, k): apparent in-plane motions of all points (centred on the valid ones): "rigid" (t_x, t_z,
        omega), "similarity" (+ scale), "affine" (t_x, t_z and the 4 linear terms)."""
        p = self.points
        xc, zc = p[:, 0] - p[valid, 0].mean(), p[:, 2] - p[valid, 2].mean()
        kind = self.nuisance
        N = np.zeros((2 * len(p), {"rigid": 3, "similarity": 4, "affine": 6}[kind]))
        N[0::2, 0], N[1::2, 1] = 1.0, 1.0
        if kind == "affine":
            N[0::2, 2], N[0::2, 3], N[1::2, 4], N[1::2, 5] = xc, zc, xc, zc
        else:
            N[0::2, 2], N[1::2, 2] = -zc, xc
            if kind == "similarity":
                N[0::2, 3], N[1::2, 3] = xc, zc
        return N

    def _predict(self, mu, y, valid) -> np.ndarray:
        """Model observations (u_x, u_z) of all tracked points at s = mu (times the fitted scale), plus the
        apparent rigid motion fitted to the valid observations."""
        c = self.rom.coefficients(mu)[0]
        a = self.scale if self.free_scale and np.isfinite(self.scale) else 1.0
        pred = a * (self.CF @ c)
        if self.nuisance != "none":
            N = self._nuisance_basis(valid)
            rows = np.flatnonzero(np.repeat(valid, 2))
            th = np.linalg.lstsq(N[rows], (y - pred)[rows], rcond=None)[0]
            pred = pred + N @ th
        return pred

    def _filter(self, mu, std):
        lo, hi = self.rom.ranges[0]
        if self._fresh or self.smoothing >= 1:
            self.mu, self.std, self._fresh = mu.copy(), std.copy(), False
            return
        scale = np.maximum(np.nan_to_num(std, nan=0.0), 2e-3 * (hi - lo))
        jump = np.abs(mu - self.mu) > self.jump_sigma * scale
        a = np.where(jump, 1.0, self.smoothing)
        self.mu = self.mu + a * (mu - self.mu)
        self.std = np.sqrt(np.where(jump, 1.0, a / (2 - a))) * std

    def process(self, frame: np.ndarray, index: int, draw: bool = True) -> tuple[np.ndarray, FoamFrame]:
        t0 = time.perf_counter()
        st = {}
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        pose, n_env, n_surf, resid, status = None, 0, 0, float("nan"), "lost"
        if self.map is None:
            pe = self.markers.update(gray)
            if pe.status == "measured":
                pose = pe.pose
                self._register(gray, pose)
                n_env = pe.n_markers
        else:
            loc = self.map.track(gray, self._pose)
            pose, n_env = loc.pose, loc.inliers
            self._pose = pose
        t1 = time.perf_counter()
        st["pose"] = (t1 - t0) * 1e3
        if pose is not None:
            if self.points is None:
                self._refs.append(self.tracker.rectify(gray, pose))
                self._refs_col.append(self.tracker.rectify(frame, pose))
                status = "reference"
                if len(self._refs) >= self.reference_frames:
                    self._set_reference()
                t2 = t3 = time.perf_counter()
            else:
                d, ok, _ = self.tracker.update(gray, pose)
                n_surf = int(ok.sum())
                t2 = time.perf_counter()
                y = np.column_stack([d[:, 0], -d[:, 1]]).ravel()  # (u_x, u_z) per point
                if n_surf < max(3, self.min_points * len(ok)):
                    status = "hold"
                elif np.sqrt(np.mean(y.reshape(-1, 2)[ok] ** 2) * 2) < self.unloaded:
                    status, self._fresh = "unloaded", True
                else:
                    mu, std, res, self.scale = self._estimate(y, ok)
                    # robust step: features locked onto a wrong pore (consistent forward and backward, but
                    # far from the fitted field) are dropped and re-seeded from the model's prediction
                    pred = self._predict(mu, y, ok)
                    r = np.linalg.norm((y - pred).reshape(-1, 2), axis=1)
                    sig = 1.4826 * np.median(r[ok])
                    bad = ok & (r > max(4 * sig, self.outlier_mm * 1e-3))
                    if bad.any() and (ok & ~bad).sum() >= max(3, self.min_points * len(ok)):
                        ok = ok & ~bad
                        mu, std, res, self.scale = self._estimate(y, ok)
                        pred = self._predict(mu, y, ok)
                    reseed = ~ok
                    self.tracker.flow[reseed, 0, 0] = pred.reshape(-1, 2)[reseed, 0] * self.tracker.s
                    self.tracker.flow[reseed, 0, 1] = -pred.reshape(-1, 2)[reseed, 1] * self.tracker.s
                    n_surf = int(ok.sum())
                    self._filter(mu, std)
                    resid = res / np.sqrt(max(n_surf, 1)) * 1e3
                    status = "tracking"
                t3 = time.perf_counter()
            st["surface"], st["assimilate"] = (t2 - t1) * 1e3, (t3 - t2) * 1e3
        else:
            if self.tracker is not None:
                self.tracker.reset()
            self._fresh = True
            t3 = time.perf_counter()
            st["surface"] = st["assimilate"] = 0.0
        out = frame
        if draw and self.overlay is not None:
            c = self.rom.coefficients(self.mu)[0] if status in ("tracking", "hold") else np.zeros(self.rom.n_modes)
            info = {"env": n_env, "surface": n_surf, "surface_total": 0 if self.points is None else len(self.points),
                    "frame": index, "latency_ms": (t3 - t0) * 1e3, "field_max": float(self.overlay.values(c).max())}
            out = self.overlay.draw(frame, self.camera, pose, c, self.mu, self.std,
                                    status if pose is not None else "lost", info)
        t4 = time.perf_counter()
        st["overlay"] = (t4 - t3) * 1e3
        return out, FoamFrame(index, status, self.mu.copy(), self.std.copy(), resid, n_env, n_surf, (t4 - t0) * 1e3,
                              st)

    def run(self, source, out_video=None, out_csv=None, fps: float | None = None, crf: int = 20,
            progress: Callable[[int, int], None] | None = None, snapshots: dict | None = None,
            max_frames: int | None = None) -> dict:
        """Process a video (path or iterable of frames); atomic outputs; returns fps and latency statistics
        (:func:`physar.ar.runner.run_video`)."""
        return run_video(lambda k, frame, draw: self.process(frame, k, draw=draw), self.camera, source, out_video,
                         out_csv, fps, crf, FOAM_ESTIMATES_HEADER, _foam_row, progress, snapshots, max_frames)


from physar.ar.overlay import BeamOverlay


class FoamOverlay(BeamOverlay):
    """The reduced model's front face coloured by |u| (seed 000 Fig. 11) with the disk arrow; markerless HUD."""

    def _hud(self, img, mu, std, status, info):
        h, w = img.shape[:2]
        sc = h / 720
        lines = []
        if status == "lost":
            lines.append(("no pose: the wall's features are not found", (80, 80, 255)))
        elif status in ("reference", "unloaded"):
            lines.append((f"{status}: unloaded beam", (200, 255, 200)))
        else:
            lines.append((f"disk position s = {mu[0] * 1e3:6.1f} +/- {2 * std[0] * 1e3:.1f} mm (2 sd)",
                          (255, 255, 255) if status == "tracking" else (150, 200, 255)))
            lines.append((f"max |u| {info.get('field_max', float('nan')):.1f} mm", (230, 230, 230)))
        lines.append(((f"{status}: {info.get('env', 0)} wall features, {info.get('surface', 0)}/"
                       f"{info.get('surface_total', 0)} foam features | frame {info.get('frame', 0)} "
                       f"{info.get('latency_ms', 0):.1f} ms | no markers"), (200, 200, 200)))
        fs, lh = 0.62 * sc, int(28 * sc)
        pw, ph = int(700 * sc), lh * len(lines) + int(14 * sc)
        x0, y0 = int(14 * sc), int(14 * sc)
        roi = img[y0:y0 + ph, x0:x0 + pw]
        cv2.addWeighted(roi, 0.35, np.zeros_like(roi), 0.65, 0, dst=roi)
        for k, (txt, col) in enumerate(lines):
            cv2.putText(img, txt, (x0 + int(10 * sc), y0 + int((k + 1) * lh)), cv2.FONT_HERSHEY_SIMPLEX, fs, col, 1,
                        cv2.LINE_AA)
        bar = self._colour_bar(h)
        bh, bw = bar.shape[:2]
        bx, by = w - bw - int(100 * sc), int(0.27 * h)
        panel = img[by - int(46 * sc):by + bh + int(16 * sc), bx - int(10 * sc):w - int(8 * sc)]
        cv2.addWeighted(panel, 0.35, np.zeros_like(panel), 0.65, 0, dst=panel)
        img[by:by + bh, bx:bx + bw] = bar
        cv2.putText(img, f"{self.label} [{self.unit}]", (bx - int(6 * sc), by - int(12 * sc)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45 * sc, (255, 255, 255), 1, cv2.LINE_AA)
        for k in range(5):
            yy = by + bh - 1 - int(k / 4 * (bh - 1))
            cv2.putText(img, f"{self.vmax * k / 4:.1f}", (bx + bw + int(8 * sc), yy + 5), cv2.FONT_HERSHEY_SIMPLEX,
                        0.45 * sc, (255, 255, 255), 1, cv2.LINE_AA)


# ------------------------------------------------------------------------------------------------------
# demo: scene (b) end to end
# ------------------------------------------------------------------------------------------------------
def foam_demo_scene(quick: bool = False) -> FoamSceneSpec:
    """Scene (b) at 1280x720, 30 fps, 10.5 s (0.5 s unloaded, 10 disk positions of 1 s); ``quick``: 640x360,
    3.5 s, 3 positions, coarser meshes (a fast check)."""
    if quick:
        return FoamSceneSpec(video=VideoSection(width=640, height=360, duration=3.5),
                             foam=FoamSection(truth_cells=(24, 3, 3), model_cells=(16, 2, 2)),
                             load=FoamLoad(positions=[0.25, 0.55, 0.40], dwell=1.0))
    return FoamSceneSpec()


def evaluate_foam(truth: dict, est: dict, settle_frames: int = 2) -> dict:
    """Load-position errors [mm] on the loaded frames (the `settle_frames` frames after each placement of
    the disk are reported apart), per-position table like the seed's Table 1."""
    n = min(len(truth["s_true_m"]), len(est["s_est"]))
    s_t, s_e, status = truth["s_true_m"][:n], est["s_est"][:n], est["status"][:n]
    loaded = np.isfinite(s_t)
    placed = np.zeros(n, bool)
    starts = np.flatnonzero(loaded & ~np.r_[False, loaded[:-1]] | (loaded & np.r_[False, s_t[1:] != s_t[:-1]]))
    for k in starts:
        placed[k:k + settle_frames] = True
    tracking = status == "tracking"
    judged = loaded & tracking & ~placed
    err = np.abs(s_e - s_t) * 1e3
    table = []
    for s in np.unique(s_t[loaded]):
        sel = judged & (s_t == s)
        if sel.any():
            m = float(np.mean(s_e[sel]))
            table.append({"actual_mm": round(s * 1e3, 2), "mean_estimate_mm": round(m * 1e3, 2),
                          "abs_difference_mm": round(abs(m - s) * 1e3, 2), "frames": int(sel.sum())})
    nan = float("nan")
    return {"mean_abs_error_mm": float(np.mean(err[judged])) if judged.any() else nan,
            "median_abs_error_mm": float(np.median(err[judged])) if judged.any() else nan,
            "max_abs_error_mm": float(np.max(err[judged])) if judged.any() else nan,
            "mean_abs_error_incl_placement_mm": float(np.mean(err[loaded & tracking])) if (loaded & tracking).any()
            else nan,
            "judged_frames": int(judged.sum()), "loaded_frames": int(loaded.sum()),
            "tracking_fraction_loaded": float(np.mean(tracking[loaded])) if loaded.any() else nan,
            "table": table}


def plot_foam(truth: dict, est: dict, path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = min(len(truth["time_s"]), len(est["time_s"]))
    t, s_t, s_e = truth["time_s"][:n], truth["s_true_m"][:n] * 1e3, est["s_est"][:n] * 1e3
    sd = np.nan_to_num(est["s_std"][:n] * 1e3, nan=0.0)
    tracking = est["status"][:n] == "tracking"
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    a1.plot(t, s_t, "k-", lw=2, label="true disk position")
    a1.plot(t, np.where(tracking, s_e, np.nan), "-", color="tab:blue", lw=1.2, label="AR estimate (markerless)")
    a1.fill_between(t, s_e - 2 * sd, s_e + 2 * sd, where=tracking, color="tab:blue", alpha=0.25, lw=0,
                    label="estimate ± 2 sd")
    a1.set_ylabel("load position s [mm]")
    a1.set_title(title)
    a1.legend(loc="upper right", fontsize=8)
    error_panel(a2, t, np.where(tracking, s_e - s_t, np.nan), 1.5, 8, "mm")
    save_figure(fig, path)


def error_panel(ax, t, err, band: float, ylim: float, unit: str) -> None:
    """Lower panel of the estimate-vs-truth plots: the error over time with dashed +-``band`` lines."""
    ax.plot(t, err, color="tab:red", lw=1)
    for v in (-band, band):
        ax.axhline(v, color="0.3", ls="--", lw=1)
    ax.set_ylim(-ylim, ylim)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"error [{unit}]")


def save_figure(fig, path) -> None:
    """tight_layout, write the PNG to a temporary and rename it (no partial file), close the figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    tmp = Path(path).with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


def mode_study(rom, beam, s_values, counts=(5, 11, 19)) -> list[dict]:
    """Relative error max_s ||u_n(s) - u_FE(s)|| / ||u_FE(s)|| of the first n PGD modes against direct
    Newton solves at `s_values` (not sampling points of the PGD), for each n in `counts`."""
    solver = ContinuationSolver(beam)
    ref = {float(s): solver(s) for s in s_values}
    rows = []
    for n in counts:
        if n > rom.n_modes:
            continue
        r = rom.truncated(n)
        e = [np.linalg.norm(r.evaluate([s]) - u) / np.linalg.norm(u) for s, u in ref.items()]
        rows.append({"modes": int(n), "max_rel_error": float(max(e)), "mean_rel_error": float(np.mean(e))})
    return rows


def run_foam_demo(out, quick: bool = False, progress: Callable[[str, int, int], None] | None = None,
                  spec: FoamSceneSpec | None = None, mode_counts=(5, 8, 11, 14)) -> dict:
    """Render scene (b), build its reduced model (non-intrusive PGD of the St.VK problem), run the markerless
    pipeline with the full model and with truncations to `mode_counts` modes; write the outputs into `out`."""
    out, spec = Path(out), spec or foam_demo_scene(quick)

    def build(p):
        rom, obj, space, info = build_foam_model(spec, progress=p)
        rom.save(out / "model.npz", mesh=space.mesh)
        return rom, obj, info

    run = run_scene_demo(out, spec, progress, render_foam_scene, "reduced model (non-intrusive PGD)", build,
                         lambda model, cam: FoamPipeline(model[0], cam, model[1]), 0.55)
    (rom, obj, info), cam = run.model, run.camera
    truth, est = read_csv_columns(out / "truth.csv"), read_csv_columns(out / "estimates.csv")
    ev = evaluate_foam(truth, est)
    plot_foam(truth, est, out / "estimate_vs_truth.png",
              f"Scene (b): foam beam, {spec.foam.load:.0f} N lead disk, no fiducials after frame 0 - estimate vs truth")
    # accuracy against the mode count: the same video through truncated models (no video output)
    modes = []
    for n in mode_counts:
        if n < rom.n_modes:
            p = FoamPipeline(rom.truncated(n), cam, obj, overlay=False)
            tmpcsv = out / f".estimates_{n}.csv"
            p.run(out / "scene.mp4", None, tmpcsv, fps=spec.video.fps)
            e = evaluate_foam(truth, read_csv_columns(tmpcsv))
            tmpcsv.unlink()
            modes.append({"modes": n, "mean_abs_error_mm": e["mean_abs_error_mm"],
                          "max_abs_error_mm": e["max_abs_error_mm"]})
    modes.append({"modes": rom.n_modes, "mean_abs_error_mm": ev["mean_abs_error_mm"],
                  "max_abs_error_mm": ev["max_abs_error_mm"]})
    markers_after_0 = int(np.sum(truth["markers_visible"][1:]))
    f = spec.foam
    report = {
        "example": "ar_foam_beam",
        "scene": {"width": spec.video.width, "height": spec.video.height, "fps": spec.video.fps,
                  "duration_s": spec.video.duration, "beam_mm": [f.length * 1e3, f.width * 1e3, f.height * 1e3],
                  "material": "St.VK", "E_pa": f.E, "nu": f.nu, "load_n": f.load,
                  "disk_diameter_mm": f.disk_diameter * 1e3, "truth_mesh": [f.element, *f.truth_cells],
                  "model_mesh": [f.element, *f.model_cells], "frames_with_markers": 1 + markers_after_0},
        **pipeline_stats(run.summary),
        "modes": rom.n_modes,
        "pgd": {"snapshots": info["n_solves"], "error_estimate": info["error_estimate"],
                "s_range_mm": [v * 1e3 for v in spec.s_range]},
        "accuracy_vs_modes": modes,
        **ev,
        "timings_s": run.timings_s,
        "files": ["scene.mp4", "truth.csv", "camera.toml", "model.npz", "augmented.mp4", "estimates.csv",
                  "estimate_vs_truth.png", "augmented_frame.png", "report.json"],
    }
    write_report(out, report)
    return report
