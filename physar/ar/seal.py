"""Scene (c) of seed 000 §5.3: the virtual boot seal.

A white lever pivots on a textured support plate (plane y = 0, world x right, z up, the camera at -y); its
angle theta (from +z towards +x) is the parameter. The boot seal does not exist in the video: a nearly
incompressible neo-Hookean bellows (W = C1 (Ī1 - 3) + kappa/2 (J - 1)², C1 = 1166 MPa, the seed's
W = C1 (I1 - 3) for kappa -> inf; :mod:`physar.fem.seed_examples`) whose base cuff is clamped in front of
the plate and whose top cuff follows the lever's rigid rotation about the pivot axis (the world y axis).
Reduced model: non-intrusive PGD u(x, theta) ~ Σ F_i(x) G_i(theta) over theta in [0°, 52°] (seed §5.3.1)
from Newton-continuation snapshots; the von Mises field gets its own separated representation from the
model's displacements (it is not linear in u).

Vision (§5.3.2): ORB features of the plate (a reference image of the plate: its design drawing / scan),
RANSAC homography (plate features are inliers, the rest of the scene outliers), IPPE/LM pose refined by
Lucas-Kanade on the rectified plate, the lever angle by white-colour segmentation in the view rectified on
the lever's plane, and the seal drawn with its von Mises stress. Relocalisation by ORB after the camera has
looked away (§5.3.3).
"""
from __future__ import annotations

import itertools
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

from physar.ar.foam import (
    _noise_texture,
    error_panel,
    read_csv_columns,
    save_figure,
    sensor_effects,
    shade,
    vignette,
)
from physar.ar.runner import pipeline_stats, run_scene_demo, run_video, write_report
from physar.ar.scene import (
    CameraSection,
    LightingSection,
    SensorSection,
    VideoSection,
    _Strict,
    camera_values,
)
from physar.errors import ConfigError
from physar.vision.camera import Camera, Pose


# ------------------------------------------------------------------------------------------------------
# scene description
# ------------------------------------------------------------------------------------------------------
class PlateSection(_Strict):
    x: tuple[float, float] = (-0.25, 0.25)
    z: tuple[float, float] = (-0.14, 0.28)
    px_per_m: float = Field(1500.0, gt=100, description="resolution of the plate's reference image")


class LeverSection(_Strict):
    length: float = Field(0.21, gt=0)
    width: float = Field(0.016, gt=0)
    offset: float = Field(0.006, ge=0, description="lever face in front of the plate [m]")


class SealSection(_Strict):
    n_phi: int = Field(16, ge=6)
    n_profile: int = Field(24, ge=6)
    element: str = "P1"
    C1: float = Field(1166e6, gt=0, description="Pa (seed 000 §5.3)")
    kappa_ratio: float = Field(200.0, gt=0, description="bulk modulus / C1")
    theta_max: float = Field(52.0, gt=0, le=90, description="deg")


class LookAway(_Strict):
    start: float = Field(ge=0, description="s")
    duration: float = Field(gt=0, description="s (pan out, hold, pan back)")
    yaw: float = Field(60.0, description="pan angle [deg]")
    ramp: float = Field(0.4, gt=0, description="s to pan out (and back)")


class SealSceneSpec(_Strict):
    name: str = "seal"
    seed: int = 0
    video: VideoSection = VideoSection(duration=8.0)
    camera: CameraSection = CameraSection(distance=0.7, target=(0.0, 0.0, 0.07), elevation=6.0, orbit_deg=(10.0, 4.0),
                                          orbit_period=8.0, shake_mm=1.5, shake_deg=0.25)
    lighting: LightingSection = LightingSection()
    sensor: SensorSection = SensorSection()
    plate: PlateSection = PlateSection()
    lever: LeverSection = LeverSection()
    seal: SealSection = SealSection()
    keyframes: list[tuple[float, float]] = Field(
        default_factory=lambda: [(0.0, 0.0), (0.3, 0.0), (2.6, 52.0), (3.0, 52.0), (5.2, 18.0), (6.4, 40.0),
                                 (8.0, 10.0)], description="(time s, theta deg), smooth in between")
    look_away: list[LookAway] = Field(default_factory=lambda: [LookAway(start=3.1, duration=2.8, yaw=45.0,
                                                                                  ramp=1.2)])

    @model_validator(mode="after")
    def _check(self):
        th = [k[1] for k in self.keyframes]
        if not self.keyframes or min(th) < 0 or max(th) > self.seal.theta_max:
            raise ValueError(f"keyframe angles {th} must lie in [0, {self.seal.theta_max}] deg")
        if any(b[0] <= a[0] for a, b in zip(self.keyframes, self.keyframes[1:])):
            raise ValueError("keyframe times must increase")
        if self.seal.element not in ("P1", "P2"):
            raise ValueError(f"seal element must be P1 or P2, got {self.seal.element!r}")
        return self

    @property
    def n_frames(self) -> int:
        return max(1, round(self.video.duration * self.video.fps))

    def theta(self, t: float) -> float:
        """Lever angle [deg] at time t: cosine interpolation between keyframes."""
        k = self.keyframes
        if t <= k[0][0]:
            return float(k[0][1])
        for (t0, a0), (t1, a1) in itertools.pairwise(k):
            if t <= t1:
                a = (t - t0) / (t1 - t0)
                return float(a0 + (a1 - a0) * 0.5 * (1 - math.cos(math.pi * a)))
        return float(k[-1][1])

    def yaw(self, t: float) -> float:
        y = 0.0
        for la in self.look_away:
            tau = t - la.start
            if 0 <= tau <= la.duration:
                r = min(tau / la.ramp, (la.duration - tau) / la.ramp, 1.0)
                y += la.yaw * 0.5 * (1 - math.cos(math.pi * r))
        return y

    def camera_model(self) -> Camera:
        return Camera.from_fov(self.video.width, self.video.height, self.video.hfov)

    def camera_pose(self, t: float) -> Pose:
        """The handheld camera of scene (a) about the target, panned by yaw(t) about the vertical through it."""
        from physar.ar.scene import SceneSpec

        base = SceneSpec(seed=self.seed, camera=self.camera).camera_pose(t)
        a = math.radians(self.yaw(t))
        Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])
        R = base.R @ Rz
        return Pose(R, -R @ base.center)

    def lever_points(self, theta_deg: float) -> np.ndarray:
        """Pivot and tip of the lever (2, 3) [m]."""
        a = math.radians(theta_deg)
        y = -self.lever.offset
        return np.array([[0.0, y, 0.0], [self.lever.length * math.sin(a), y, self.lever.length * math.cos(a)]])


def load_seal_scene(path) -> SealSceneSpec:
    """Read and validate a scene (seal) TOML; errors name the file and the key."""
    from physar.ar.scene import validate_scene

    return validate_scene(path, SealSceneSpec)


# ------------------------------------------------------------------------------------------------------
# the plate (reference image) and the rendering
# ------------------------------------------------------------------------------------------------------
def plate_texture(spec: SealSceneSpec) -> np.ndarray:
    """The support plate's appearance (BGR uint8, fronto-parallel, px_per_m): a blue-grey anodised plate with
    printed labels, holes and scratches (saturated or dark: nothing white, the lever's colour)."""
    p = spec.plate
    s = p.px_per_m
    W, H = int((p.x[1] - p.x[0]) * s), int((p.z[1] - p.z[0]) * s)
    rng = np.random.default_rng(spec.seed + 11)
    img = np.empty((H, W, 3), np.float32)
    img[...] = (135, 105, 80)
    img *= (1 + 0.08 * _noise_texture(rng, H, W, (1.0, 6.0, 40.0), (0.3, 0.6, 1.0)))[..., None]
    for _ in range(int(W * H / (0.012 * s) ** 2)):
        c = (int(rng.uniform(0, W)), int(rng.uniform(0, H)))
        r = int(rng.uniform(0.002, 0.009) * s)
        hue = rng.uniform(0, 180)
        hsv = np.uint8([[[hue, rng.uniform(120, 255), rng.uniform(40, 200)]]])
        col = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0].astype(float).tolist()
        k = rng.random()
        if k < 0.4:
            cv2.circle(img, c, r, col, -1, cv2.LINE_AA)
        elif k < 0.8:
            cv2.rectangle(img, c, (c[0] + int(rng.uniform(1, 3) * r), c[1] + r), col, -1)
        else:
            cv2.line(img, c, (c[0] + int(rng.normal(0, 4 * r)), c[1] + int(rng.normal(0, 4 * r))), col,
                     max(1, r // 3), cv2.LINE_AA)
    return np.clip(img, 0, 255).astype(np.uint8)


class SealRenderer:
    """Frames of a :class:`SealSceneSpec`: wall, plate, pivot boss, white lever (no seal: it is virtual)."""

    def __init__(self, spec: SealSceneSpec, camera: Camera | None = None):
        self.spec = spec
        self.camera = camera or spec.camera_model()
        self.vig = vignette(self.camera, spec.lighting.vignetting)
        self.plate = plate_texture(spec).astype(np.float32)
        rng = np.random.default_rng(spec.seed + 3)
        s = 0.5 * self.camera.fx / spec.camera.distance
        self.wall_y, self.wall_s, self.wall_x, self.wall_z = 0.45, s, (-2.5, 2.5), (-1.2, 1.5)
        W, H = int(5.0 * s), int(2.7 * s)
        wall = np.empty((H, W, 3), np.float32)
        wall[...] = (150, 165, 170)
        wall *= (1 + 0.15 * _noise_texture(rng, H, W, (1.5, 8.0), (0.5, 1.0)))[..., None]
        for _ in range(int(W * H / (0.03 * s) ** 2)):
            c = (int(rng.uniform(0, W)), int(rng.uniform(0, H)))
            r = int(rng.uniform(0.005, 0.03) * s)
            cv2.rectangle(wall, c, (c[0] + 2 * r, c[1] + r), rng.uniform(40, 200, 3).tolist(), -1)
        self.wall = np.clip(wall, 0, 255)

    def _warp(self, tex, s, x0, z1, y, pose, dst=None):
        A = np.array([[1 / s, 0, x0 + 0.5 / s], [0, 0, y], [0, -1 / s, z1 - 0.5 / s]])
        M = self.camera.K @ (pose.R @ A + np.column_stack([np.zeros((3, 2)), pose.t]))
        if dst is None:
            return cv2.warpPerspective(tex, M, self.camera.size, flags=cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=(70, 72, 75))
        return cv2.warpPerspective(tex, M, self.camera.size, dst=dst, flags=cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_TRANSPARENT)

    def _poly(self, img, pts, colour, pose):
        p = self.camera.project(np.asarray(pts, float), pose)
        cv2.fillPoly(img, [np.round(p * 16).astype(np.int32)], tuple(float(c) for c in colour), cv2.LINE_AA, shift=4)

    def render(self, frame: int) -> tuple[np.ndarray, dict]:
        spec = self.spec
        fps = spec.video.fps
        t = frame / fps
        pose = spec.camera_pose(t)
        th = spec.theta(t)
        L = spec.lighting
        sh = shade(L, np.array([0, -1.0, 0]))
        img = self._warp(self.wall, self.wall_s, self.wall_x[0], self.wall_z[1], self.wall_y, pose) * sh
        p = spec.plate
        # the plate (a thick panel: its dark edge first, then the face)
        e = 0.012
        self._poly(img, [[p.x[0] - e, 0.001, p.z[0] - e], [p.x[1] + e, 0.001, p.z[0] - e],
                         [p.x[1] + e, 0.001, p.z[1] + e], [p.x[0] - e, 0.001, p.z[1] + e]], (40, 40, 45), pose)
        plate = self._warp(self.plate * sh, p.px_per_m, p.x[0], p.z[1], 0.0, pose, dst=img.copy())
        img = plate
        # pivot boss and the white lever (a flat bar in the plane y = -offset)
        a = np.linspace(0, 2 * np.pi, 40, endpoint=False)
        self._poly(img, np.column_stack([0.02 * np.cos(a), np.full_like(a, -0.002), 0.02 * np.sin(a)]),
                   np.array((45, 45, 50)) * sh, pose)
        piv, tip = spec.lever_points(th)
        d = (tip - piv) / np.linalg.norm(tip - piv)
        n = np.array([d[2], 0.0, -d[0]]) * spec.lever.width / 2
        back = piv - 0.025 * d
        self._poly(img, [back + n, tip + n, tip - n, back - n], np.array((236, 238, 240)) * sh, pose)
        self._poly(img, np.column_stack([0.006 * np.cos(a), np.full_like(a, -spec.lever.offset - 0.001),
                                         0.006 * np.sin(a)]), (90, 90, 95), pose)
        tgt = [spec.camera.target]
        blur = self.camera.project(tgt, pose)[0] - self.camera.project(tgt, spec.camera_pose(t - 1 / fps))[0]
        out = sensor_effects(img, spec.sensor, L, self.vig, t, blur * spec.sensor.motion_blur,
                             noise_seed=spec.seed * 1_000_003 + frame)
        w, h = self.camera.size
        q = self.camera.project(np.vstack([piv, tip]), pose)
        zc = pose.apply(np.vstack([piv, tip]))[:, 2]
        visible = bool(np.all(zc > 0) and np.all((q >= 0) & (q < (w, h))))
        row = {"frame": frame, "time_s": t, "theta_true_deg": th, "lever_visible": int(visible),
               "yaw_deg": spec.yaw(t), "cam_rvec": pose.rvec, "cam_t": pose.t}
        return out, row


SEAL_TRUTH_HEADER = ["frame", "time_s", "theta_true_deg", "lever_visible", "yaw_deg", "cam_rx", "cam_ry", "cam_rz",
                     "cam_tx", "cam_ty", "cam_tz"]


@dataclass
class PlateObject:
    """What the pipeline knows of the real scene: the plate's reference image and geometry, the lever."""

    image: str            # file name of the plate's reference image (next to plate.json)
    px_per_m: float
    x: tuple
    z: tuple
    lever_length: float
    lever_offset: float
    lever_width: float = 0.016

    def save(self, path) -> None:
        tmp = Path(path).with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(self), indent=1))
        os.replace(tmp, path)

    @classmethod
    def load(cls, path) -> PlateObject:
        path = Path(path)
        try:
            return cls(**json.loads(path.read_text()))
        except FileNotFoundError:
            raise ConfigError(f"{path}: plate file not found") from None
        except (json.JSONDecodeError, TypeError) as e:
            raise ConfigError(f"{path}: invalid plate description ({e})") from None


def render_seal_scene(spec: SealSceneSpec, out_dir, progress: Callable[[int, int], None] | None = None,
                      video_name: str = "scene.mp4") -> dict:
    """Render scene (c): `video_name`, truth.csv, camera.toml, plate.png + plate.json (the plate's reference)."""
    from physar.ar.video import atomic_path, write_clip

    cam = spec.camera_model()
    rend = SealRenderer(spec, cam)

    def frame(k):
        img, row = rend.render(k)
        return img, [k, f"{row['time_s']:.6f}", f"{row['theta_true_deg']:.6f}", row["lever_visible"],
                     f"{row['yaw_deg']:.4f}", *camera_values(row)]

    clip = write_clip(out_dir, video_name, cam, spec.video.fps, spec.video.crf, SEAL_TRUTH_HEADER, spec.n_frames,
                      frame, progress)
    out = Path(out_dir)
    with atomic_path(out / "plate.png") as ptmp:
        cv2.imwrite(str(ptmp.with_suffix(".png")), rend.plate.astype(np.uint8))
    p = spec.plate
    PlateObject("plate.png", p.px_per_m, tuple(p.x), tuple(p.z), spec.lever.length, spec.lever.offset,
                spec.lever.width).save(
        out / "plate.json")
    return {**clip, "plate": str(out / "plate.json")}


# ------------------------------------------------------------------------------------------------------
# reduced model of the seal
# ------------------------------------------------------------------------------------------------------
class SealContinuation:
    """u(theta [deg]): the seal's equilibrium by Newton continuation in theta from the nearest smaller solved
    angle (the lever's loading path: the corrugated sleeve may buckle, and approaching an angle from above
    could land on another branch)."""

    def __init__(self, seal, increment_deg: float = 4.0):
        self.seal, self.inc = seal, math.radians(increment_deg)
        self.cache = {0.0: np.zeros(seal.space.n_dofs)}
        self.solves = 0

    def __call__(self, mu) -> np.ndarray:
        th = round(float(np.atleast_1d(mu)[0]), 9)
        if th in self.cache:
            return self.cache[th]
        near = max(k for k in self.cache if k <= th)  # continue upwards: the loading path of the lever
        u, _ = self.seal.solve(math.radians(th), u0=self.cache[near], theta0=math.radians(near), increment=self.inc)
        self.cache[th] = u
        self.solves += 1
        return u


def seal_model(spec: SealSceneSpec):
    from physar.fem.seed_examples import boot_seal

    s = spec.seal
    return boot_seal(n_phi=s.n_phi, n_profile=s.n_profile, element=s.element, C1=s.C1, kappa=s.kappa_ratio * s.C1)


def build_seal_model(spec: SealSceneSpec, progress: Callable[[int, int], None] | None = None, tol: float = 2e-3,
                     max_points: int = 129, initial_points: int = 9):
    """Non-intrusive PGD of the seal over theta [deg] (physar.rom.nonintrusive) and the separated
    representation of its nodal von Mises stress [Pa]. Returns (u_model, vm_model, seal, info)."""
    from physar.fem.post import nodal_average, von_mises
    from physar.rom.nonintrusive import nonintrusive_pgd, separated_fit
    from physar.rom.separated import SeparatedModel

    seal = seal_model(spec)
    bb = SealContinuation(seal)
    rom, info = nonintrusive_pgd(bb, [(0.0, spec.seal.theta_max)], ["theta"], ["deg"], initial_points=initial_points,
                                 tol=tol, max_points=max_points, progress=progress,
                                 metadata={"kind": "boot_seal", "material": "NeoHookeanIncompressible",
                                           "method": "pgd_nonintrusive", "seal": spec.seal.model_dump_json()})
    grid = rom.grids[0]
    T = np.stack([nodal_average(seal.space, von_mises(seal.model, rom.evaluate([th]))) for th in grid], axis=1)
    F, G, _ = separated_fit(T, max_modes=30, fit_tol=1e-3)
    vm = SeparatedModel(F, [grid], G, ["theta"], ["deg"], {"field": "von_mises_nodal", "unit": "Pa"})
    info["snapshots"] = bb.solves
    return rom, vm, seal, info


# ------------------------------------------------------------------------------------------------------
# pipeline
# ------------------------------------------------------------------------------------------------------
@dataclass
class SealFrame:
    frame: int
    status: str        # tracking | hold | lost
    theta: float       # deg (held value when not tracking)
    measured: float    # deg of this frame (NaN if not measured)
    n_plate: int
    n_lever_px: int
    latency_ms: float
    stages_ms: dict


# estimates.csv: frame, time_s, status, then these columns
SEAL_ESTIMATES_HEADER = ["theta_est_deg", "theta_measured_deg", "plate_features", "lever_pixels", "latency_ms"]


def _seal_row(r: SealFrame) -> list:
    return [f"{r.theta:.5f}", f"{r.measured:.5f}", r.n_plate, r.n_lever_px, f"{r.latency_ms:.3f}"]


class SealOverlay:
    """The virtual seal (outer surface, deformed by the reduced model) coloured by von Mises stress."""

    def __init__(self, seal, rom, vm, y_offset: float, levels: int = 48):
        from physar.ar.overlay import turbo_lut

        self.seal, self.rom, self.vm = seal, rom, vm
        surf = seal.space.mesh.boundary()
        self.faces = surf.faces_global if hasattr(surf, "faces_global") else surf.node_map[surf.mesh.faces]
        self.nv = seal.space.mesh.n_points
        self.offset = np.array([0.0, y_offset, 0.0])
        self.X = seal.space.mesh.points
        self.F = rom.F.reshape(rom.n_modes, -1, 3)[:, :self.nv]  # vertex displacements per mode
        self.lut = turbo_lut(levels)
        self.levels = levels
        self.vmax = float(max(np.percentile(vm.evaluate([th]), 99) for th in vm.grids[0])) or 1.0

    def draw(self, img, camera, pose, theta, status, info):
        if pose is not None and np.isfinite(theta):
            c = self.rom.coefficients([theta])[0]
            x = self.X + np.tensordot(c, self.F, 1) + self.offset
            vals = self.vm.evaluate([theta])[:self.nv] if self.vm.F.shape[1] >= self.nv else None
            xc = pose.apply(x)
            if np.all(xc[:, 2] > 1e-3):
                p = camera.project(x, pose)
                tri = p[self.faces]
                # back faces culled (outward normals: counter-clockwise on screen), painter's order
                cross = ((tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1]) -
                         (tri[:, 1, 1] - tri[:, 0, 1]) * (tri[:, 2, 0] - tri[:, 0, 0]))
                depth = xc[self.faces, 2].mean(1)
                order = np.argsort(-depth)
                lev = np.clip((vals[self.faces].mean(1) / self.vmax * (self.levels - 1)).round().astype(int), 0,
                              self.levels - 1)
                layer = img.copy()
                pts = np.round(tri * 16).astype(np.int32)
                for k in order:
                    if cross[k] < 0:
                        continue
                    cv2.fillPoly(layer, [pts[k]], tuple(int(v) for v in self.lut[lev[k]]), cv2.LINE_AA, shift=4)
                cv2.addWeighted(layer, 0.8, img, 0.2, 0, dst=img)
        self._hud(img, theta, status, info)
        return img

    def _hud(self, img, theta, status, info):
        h, w = img.shape[:2]
        sc = h / 720
        if status == "lost":
            lines = [("plate not found (looking away?): holding the last angle", (80, 80, 255))]
        else:
            lines = [(f"lever angle theta = {theta:5.1f} deg", (255, 255, 255) if status == "tracking"
                      else (150, 200, 255)),
                     ((f"virtual boot seal: max von Mises {info.get('vm_max', float('nan')) / 1e6:.0f} MPa "
                       f"(C1 = {self.seal.model.material.C1 / 1e6:.0f} MPa)"), (230, 230, 230))]
        lines.append(((f"{status}: {info.get('plate', 0)} plate features, {info.get('lever_px', 0)} lever px | "
                       f"frame {info.get('frame', 0)} {info.get('latency_ms', 0):.1f} ms"), (200, 200, 200)))
        fs, lh = 0.62 * sc, int(28 * sc)
        x0, y0 = int(14 * sc), int(14 * sc)
        roi = img[y0:y0 + lh * len(lines) + int(14 * sc), x0:x0 + int(720 * sc)]
        cv2.addWeighted(roi, 0.35, np.zeros_like(roi), 0.65, 0, dst=roi)
        for k, (txt, col) in enumerate(lines):
            cv2.putText(img, txt, (x0 + int(10 * sc), y0 + int((k + 1) * lh)), cv2.FONT_HERSHEY_SIMPLEX, fs, col, 1,
                        cv2.LINE_AA)
        bh, bx, by = int(0.4 * h), w - int(90 * sc), int(0.3 * h)
        ramp = np.linspace(255, 0, bh).astype(np.uint8).reshape(-1, 1)
        img[by:by + bh, bx:bx + 18] = cv2.applyColorMap(np.repeat(ramp, 18, 1), cv2.COLORMAP_TURBO)
        cv2.putText(img, "von Mises [MPa]", (bx - int(90 * sc), by - int(10 * sc)), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45 * sc, (255, 255, 255), 1, cv2.LINE_AA)
        for k in range(5):
            yy = by + bh - 1 - int(k / 4 * (bh - 1))
            cv2.putText(img, f"{self.vmax * k / 4 / 1e6:.0f}", (bx + 22, yy + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * sc,
                        (255, 255, 255), 1, cv2.LINE_AA)


class SealPipeline:
    """Frame loop of scene (c): pose from the plate (ORB map of its reference image, RANSAC homography,
    LK refinement), lever angle by colour segmentation on the lever's plane, seal overlay from the reduced
    models. Status: tracking (angle measured), hold (plate found, lever not segmented), lost (no plate)."""

    def __init__(self, rom, vm, camera: Camera, plate: PlateObject, base: Path, seal=None, overlay: bool = True,
                 seal_offset: float | None = None, rect_px_per_m: float = 1000.0):
        from physar.vision.markerless import PlanarMap

        self.rom, self.vm, self.camera, self.plate = rom, vm, camera, plate
        img = cv2.imread(str(Path(base) / plate.image))
        if img is None:
            raise ConfigError(f"{Path(base) / plate.image}: cannot read the plate's reference image")
        origin, eu, ev = [plate.x[0], 0.0, plate.z[1]], [1.0, 0, 0], [0, 0, -1.0]
        # ORB descriptions of the reference at the zooms of the expected views (0.5 to 1.5 x the nominal)
        z0 = camera.fx / 0.7 / plate.px_per_m
        zooms = tuple(min(1.0, z0 * f) for f in (1.4, 0.8, 0.45))
        self.map = PlanarMap.from_image(camera, img, plate.px_per_m, origin, eu, ev, n_features=2500, scales=zooms)
        small = cv2.resize(img, None, fx=0.4, fy=0.4, interpolation=cv2.INTER_AREA)
        self.map.enable_refinement(small, 0.4 * plate.px_per_m, n_points=300)
        self.map.orb = cv2.ORB_create(nfeatures=2000, scaleFactor=1.2, nlevels=8, edgeThreshold=19, patchSize=19,
                                      fastThreshold=10)
        self.map.min_inliers = 10
        # relocalisation at half resolution: the motion blur of a camera swinging back is halved in pixels
        half = camera.scaled(0.5)
        z1 = half.fx / 0.7 / plate.px_per_m
        self.coarse = PlanarMap.from_image(half, img, plate.px_per_m, origin, eu, ev, n_features=2500,
                                           scales=tuple(min(1.0, z1 * f) for f in (1.4, 0.8, 0.45)))
        self.coarse.min_inliers = 10
        # rectified view of the lever's plane around the pivot
        self.rs = rect_px_per_m
        r = plate.lever_length
        self.rect_origin = np.array([-r, -plate.lever_offset, r])
        self.rect_size = (int(2 * r * self.rs), int(1.15 * r * self.rs))
        self.pivot_px = np.array([r * self.rs - 0.5, r * self.rs - 0.5])
        self.theta = float("nan")
        self._pose = None
        self.overlay = None
        if overlay:
            if seal is None:
                raise ConfigError("the seal overlay needs the seal's FE model")
            off = seal_offset if seal_offset is not None else -(seal.geometry.r_bottom + seal.geometry.thickness + 0.01)
            self.overlay = SealOverlay(seal, rom, vm, off)

    def measure_angle(self, frame, pose) -> tuple[float, int]:
        from physar.vision.markerless import lever_angle, plane_homography

        H = plane_homography(self.camera, pose, self.rect_origin, [1.0, 0, 0], [0, 0, -1.0], self.rs)
        rect = cv2.warpPerspective(frame, H, self.rect_size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        r0, r1 = 0.05, 0.95 * self.plate.lever_length
        a, n = lever_angle(rect, self.pivot_px, r0 * self.rs, r1 * self.rs, sat_max=45, val_min=150,
                           min_pixels=int(0.02 * self.rs * 0.05 * self.rs))
        expected = (r1 - r0) * self.plate.lever_width * self.rs ** 2
        lo, hi = self.rom.ranges[0]
        a = math.degrees(a)
        if not (0.4 * expected <= n <= 1.8 * expected) or not (lo - 5 <= a <= hi + 5):
            return float("nan"), n  # not the lever (a wrong pose, or something else white): no measurement
        return a, n

    def process(self, frame, index, draw=True):
        t0 = time.perf_counter()
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        loc = self.map.track(gray, self._pose)
        if loc.pose is None:  # relocalise at half resolution (the pose does not depend on the image scale)
            small = cv2.resize(gray, self.coarse.camera.size, interpolation=cv2.INTER_AREA)
            loc2 = self.coarse.locate(small)
            if loc2.pose is not None and loc2.inliers >= 2 * self.coarse.min_inliers:
                ref, n = self.map.refine(gray, loc2.pose)
                loc = loc2 if ref is None else type(loc2)(ref, n, loc2.matches)
        self._pose = loc.pose
        t1 = time.perf_counter()
        meas, npx, status = float("nan"), 0, "lost"
        if loc.pose is not None:
            meas, npx = self.measure_angle(frame, loc.pose)
            if np.isfinite(meas):
                self.theta = meas
                status = "tracking"
            else:
                status = "hold"
        t2 = time.perf_counter()
        out = frame
        th = float(np.clip(self.theta, *self.rom.ranges[0])) if np.isfinite(self.theta) else float("nan")
        if draw and self.overlay is not None:
            vm_max = float(self.vm.evaluate([th]).max()) if np.isfinite(th) else float("nan")
            out = self.overlay.draw(frame, self.camera, loc.pose, th, status,
                                    {"plate": loc.inliers, "lever_px": npx, "frame": index,
                                     "latency_ms": (t2 - t0) * 1e3, "vm_max": vm_max})
        t3 = time.perf_counter()
        return out, SealFrame(index, status, self.theta, meas, loc.inliers, npx, (t3 - t0) * 1e3,
                              {"pose": (t1 - t0) * 1e3, "lever": (t2 - t1) * 1e3, "overlay": (t3 - t2) * 1e3})

    def run(self, source, out_video=None, out_csv=None, fps=None, crf=20, progress=None, snapshots=None) -> dict:
        """Process a video (path or iterable of frames); atomic outputs; returns fps and latency statistics
        (:func:`physar.ar.runner.run_video`)."""
        return run_video(lambda k, frame, draw: self.process(frame, k, draw=draw), self.camera, source, out_video,
                         out_csv, fps, crf, SEAL_ESTIMATES_HEADER, _seal_row, progress, snapshots,
                         stage_names=("pose", "lever", "overlay"))


def evaluate_seal(truth: dict, est: dict, recovery_tol_deg: float = 1.0) -> dict:
    """Angle errors [deg] on the frames where the lever is in view, and the recovery after each look-away:
    frames from the lever's re-entry into the image until the estimate is within `recovery_tol_deg`."""
    n = min(len(truth["theta_true_deg"]), len(est["theta_est_deg"]))
    th, te, status = truth["theta_true_deg"][:n], est["theta_est_deg"][:n], est["status"][:n]
    vis = truth["lever_visible"][:n] > 0
    err = np.abs(te - th)
    judged = vis & (status == "tracking")
    rec = []
    for k in np.flatnonzero(vis[1:] & ~vis[:-1]) + 1:
        ok = np.flatnonzero((err[k:k + 60] <= recovery_tol_deg) & (status[k:k + 60] == "tracking"))
        rec.append(int(ok[0]) + 1 if ok.size else None)
    nan = float("nan")
    return {"median_abs_error_deg": float(np.median(err[judged])) if judged.any() else nan,
            "mean_abs_error_deg": float(np.mean(err[judged])) if judged.any() else nan,
            "p95_abs_error_deg": float(np.percentile(err[judged], 95)) if judged.any() else nan,
            "max_abs_error_deg": float(np.max(err[judged])) if judged.any() else nan,
            "tracking_fraction_visible": float(np.mean(status[vis] == "tracking")) if vis.any() else nan,
            "frames_lever_out_of_view": int((~vis).sum()),
            "lost_frames": int(np.sum(status == "lost")),
            "recovery_frames_after_look_away": rec}


def plot_seal(truth, est, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = min(len(truth["time_s"]), len(est["time_s"]))
    t, th, te = truth["time_s"][:n], truth["theta_true_deg"][:n], est["theta_est_deg"][:n]
    vis = truth["lever_visible"][:n] > 0
    tracking = est["status"][:n] == "tracking"
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    for ax in (a1, a2):
        ax.fill_between(t, 0, 1, where=~vis, transform=ax.get_xaxis_transform(), color="0.6", alpha=0.3, lw=0,
                        label="lever out of view" if ax is a1 else None)
    a1.plot(t, th, "k-", lw=2, label="true lever angle")
    a1.plot(t, np.where(tracking, te, np.nan), ".", color="tab:blue", ms=3, label="estimate (markerless)")
    a1.set_ylabel("theta [deg]")
    a1.set_title("Scene (c): virtual boot seal - lever angle, estimate vs truth")
    a1.legend(loc="upper right", fontsize=8)
    error_panel(a2, t, np.where(tracking, te - th, np.nan), 1, 3, "deg")
    save_figure(fig, path)


def seal_demo_scene(quick: bool = False) -> SealSceneSpec:
    """Scene (c) at 1280x720, 30 fps, 8 s with one look-away; ``quick``: 640x360 and a coarser seal mesh."""
    if quick:
        return SealSceneSpec(video=VideoSection(width=640, height=360, duration=8.0),
                             seal=SealSection(n_phi=12, n_profile=16))
    return SealSceneSpec()


def run_seal_demo(out, quick: bool = False, progress=None, spec: SealSceneSpec | None = None) -> dict:
    """Render scene (c), build its reduced models (displacement and von Mises), run the markerless pipeline;
    write the outputs into `out`."""
    out, spec = Path(out), spec or seal_demo_scene(quick)

    def build(p):
        rom, vm, seal, info = build_seal_model(spec, progress=p)
        rom.save(out / "model.npz", mesh=seal.space.mesh)
        vm.save(out / "model_von_mises.npz", mesh=seal.space.mesh)
        return rom, vm, seal, info

    def pipeline(model, cam):
        rom, vm, seal, _ = model
        return SealPipeline(rom, vm, cam, PlateObject.load(out / "plate.json"), out, seal=seal)

    run = run_scene_demo(out, spec, progress, render_seal_scene, "reduced model (non-intrusive PGD)", build,
                         pipeline, 0.3)
    rom, vm, _, info = run.model
    truth, est = read_csv_columns(out / "truth.csv"), read_csv_columns(out / "estimates.csv")
    ev = evaluate_seal(truth, est)
    plot_seal(truth, est, out / "estimate_vs_truth.png")
    s = spec.seal
    report = {
        "example": "ar_boot_seal",
        "scene": {"width": spec.video.width, "height": spec.video.height, "fps": spec.video.fps,
                  "duration_s": spec.video.duration, "theta_range_deg": [0.0, s.theta_max],
                  "material": "neo-Hookean, nearly incompressible", "C1_pa": s.C1, "kappa_pa": s.kappa_ratio * s.C1,
                  "mesh": [s.element, s.n_phi, s.n_profile], "look_away": [la.model_dump() for la in spec.look_away]},
        **pipeline_stats(run.summary),
        "modes": rom.n_modes,
        "von_mises_modes": vm.n_modes,
        "pgd": {"parameter_points": int(rom.grids[0].size), "snapshots": info["snapshots"],
                "error_estimate": info["error_estimate"]},
        **ev,
        "timings_s": run.timings_s,
        "files": ["scene.mp4", "truth.csv", "camera.toml", "plate.png", "plate.json", "model.npz",
                  "model_von_mises.npz", "augmented.mp4", "estimates.csv", "estimate_vs_truth.png",
                  "augmented_frame.png", "report.json"],
    }
    write_report(out, report)
    return report
