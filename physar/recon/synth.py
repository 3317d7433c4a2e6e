"""Synthetic benchmark scenes for the reconstruction pipeline (issue 8 part 4, seed 002 §5.1).

The procedural humanoid presses a soft box ("pillow") with its right forearm.  Ground truth:

* material: fixed-corotated elasticity with a heterogeneous Young's modulus (``E_soft`` on the half
  x < centre of the pillow, ``E_stiff`` on the other half), Poisson ratio ``nu``, density ``density``;
* dynamics: MLS-MPM (:class:`physar.mpm.MPMSolver`) on a FINER particle set (``gt_particles_per_cell``,
  default 8 per cell) than the reconstruction uses, with gravity; the forearm is a set of MPM particles
  actuated by the gated PD controller (Eq. 6-7, omega = 1 inside the forearm, 0 on the pillow) towards its
  LBS trajectory; the rest of the body follows LBS kinematically;
* images: the z-buffered sphere renderer of :mod:`physar.recon.pointrender` (not the Gaussian rasteriser),
  one static camera, ``fps`` frames per second, foreground masks.

A ``spin`` clip comes first (seed §5.1, Fig. 4): the humanoid turns about the vertical axis through its root
(yaw sweeping -spin_deg .. +spin_deg) next to the object at rest; pure LBS, no simulation.  It is the clip
from which the canonical Gaussians are learned with fixed skinning (§4.1).

Two clips follow: ``dynamic`` (a flat press to ``press_obs`` during the observation part, then deeper to
``press_pred`` in the prediction part) and ``novel`` (a tilted, wedge-shaped press with another timing:
a novel action for prediction).

DATA_DIR layout (written atomically: to a temporary folder renamed at the end)::

    scene.json                 camera, fps, n_obs, body, object box, MPM settings, PD gains (no truth)
    poses.npz, novel_poses.npz, spin_poses.npz   rotations (F, B, 3, 3), root_translation (F, 3)
    spin/rgb/0000.png, spin/mask/0000.png          spin clip (when spin_frames > 0)
    rgb/0000.png, mask/0000.png         dynamic clip (observation + prediction parts)
    novel/rgb/0000.png, novel/mask/0000.png
    truth.npz                  ground truth for evaluation only (never read by ``fit``): fine rest
                               positions and E, per-frame max object displacement (m) of both clips,
                               fine object positions of the dynamic clip (F, N_fine, 3)
    video.mp4                  preview of the dynamic clip (when an encoder is available)
"""

from __future__ import annotations

import json
import os
import shutil
import tomllib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from physar.errors import ConfigError
from physar.mpm.model import Control, MPMModel, MPMSolver
from physar.recon import scene as S
from physar.recon.pointrender import render_spheres

Vec3 = tuple[float, float, float]


class SynthConfig(BaseModel):
    """Parameters of a synthetic scene (SI units)."""

    model_config = ConfigDict(extra="forbid")
    image_size: int = Field(64, ge=16, le=1024, description="square image side, px")
    fov_deg: float = Field(35.0, gt=5, lt=120)
    camera_distance: float = Field(0.75, gt=0.1, description="m, from the pillow centre")
    camera_elevation_deg: float = Field(25.0, ge=-80, le=80)
    camera_azimuth_deg: float = Field(10.0, ge=-180, le=180)
    fps: float = Field(30.0, gt=0)
    frames: int = Field(20, ge=3, le=2000, description="frames of the dynamic clip")
    n_obs: int = Field(12, ge=2, description="observation frames (the rest is the prediction part)")
    novel_frames: int = Field(16, ge=2, le=2000)
    spin_frames: int = Field(10, ge=0, le=2000, description="frames of the spin clip (0: none)")
    spin_deg: float = Field(20.0, ge=0, le=180, description="yaw amplitude of the spin clip, degrees")
    height: float = Field(1.7, gt=0.5, lt=2.5, description="humanoid height, m")
    pillow_size: Vec3 = (0.24, 0.20, 0.12)
    gap: float = Field(0.005, ge=0, description="initial gap forearm-pillow, m")
    E_soft: float = Field(3.0e3, gt=0, description="Pa")
    E_stiff: float = Field(1.2e4, gt=0, description="Pa")
    nu: float = Field(0.3, gt=-1, lt=0.5)
    density: float = Field(200.0, gt=0, description="kg/m^3")
    human_E: float = Field(1.0e4, gt=0, description="Pa")
    human_density: float = Field(1000.0, gt=0)
    kp: float = Field(3.0e3, ge=0, description="PD gain, 1/s^2 (mass-scaled)")
    kd: float = Field(110.0, ge=0, description="PD gain, 1/s")
    press_obs: float = Field(0.03, description="forearm drop at the end of the observation part, m")
    press_pred: float = Field(0.055, description="forearm drop at the end of the dynamic clip, m")
    press_novel: float = Field(0.05, description="tilted press: drop of the forearm's midpoint, m")
    domain_size: float = Field(0.48, gt=0)
    grid_resolution: int = Field(16, ge=4, le=256)
    substeps: int = Field(32, ge=1)
    gravity: float = Field(-9.81)
    gt_particles_per_cell: int = Field(8, description="1, 8, 27 or 64")
    body_spacing: float = Field(0.012, gt=0, description="spacing of the rendered body samples, m")
    seed: int = 0

    @model_validator(mode="after")
    def _check(self):
        if self.n_obs >= self.frames:
            raise ValueError(f"n_obs ({self.n_obs}) must be < frames ({self.frames})")
        k = round(self.gt_particles_per_cell ** (1 / 3))
        if k**3 != self.gt_particles_per_cell:
            raise ValueError(f"gt_particles_per_cell = {self.gt_particles_per_cell} must be a cube")
        return self


def load_section_config(path: str | Path | None, section: str, model, overrides: dict | None = None):
    """Validate table [section] of a recon TOML (or its top level when it has neither [synth] nor [train]),
    updated by ``overrides``, with ``model``; one-line errors naming the file and the field."""
    data = {}
    if path is not None:
        p = Path(path)
        if not p.exists():
            raise ConfigError(f"config file '{p}' does not exist")
        try:
            raw = tomllib.loads(p.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: invalid TOML: {exc}") from None
        data = dict(raw.get(section, {})) if ("synth" in raw or "train" in raw) else raw
    data.update(overrides or {})
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        e = exc.errors()[0]
        raise ConfigError(f"{path or section + ' config'}: field '{'.'.join(map(str, e['loc']))}': {e['msg']} "
                          f"(got {e.get('input')!r})") from None


def load_synth_config(path: str | Path | None, overrides: dict | None = None) -> SynthConfig:
    """Config from a TOML file (table [synth] or top level) and overrides; one-line errors."""
    return load_section_config(path, "synth", SynthConfig, overrides)


def _checker(X: np.ndarray, cell: float, c0, c1) -> np.ndarray:
    k = np.floor(X / cell).astype(np.int64).sum(1) % 2
    return np.where(k[:, None] == 0, np.asarray(c0), np.asarray(c1)).astype(np.float64)


def dynamic_depths(cfg: SynthConfig) -> np.ndarray:
    f = np.arange(cfg.frames, dtype=np.float64)
    d = cfg.press_obs * S.smoothstep(f / (cfg.n_obs - 1))
    m = f >= cfg.n_obs
    d[m] = cfg.press_obs + (cfg.press_pred - cfg.press_obs) * S.smoothstep(
        (f[m] - cfg.n_obs + 1) / (cfg.frames - cfg.n_obs))
    return d


def novel_depths(cfg: SynthConfig) -> np.ndarray:
    f = np.arange(cfg.novel_frames, dtype=np.float64)
    return cfg.press_novel * S.smoothstep(f / (0.7 * (cfg.novel_frames - 1)))


def spin_poses(body, cfg: SynthConfig) -> dict:
    """Spin clip: root yaw (about +z through the root joint) going smoothly from -spin_deg to +spin_deg."""
    f = np.arange(cfg.spin_frames, dtype=np.float64)
    a = np.radians(cfg.spin_deg) * (2 * S.smoothstep(f / max(cfg.spin_frames - 1, 1)) - 1)
    rots = np.tile(np.eye(3), (cfg.spin_frames, body.skeleton.n_bones, 1, 1))
    c, s = np.cos(a), np.sin(a)
    rz = np.zeros((len(a), 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = c, -s, s, c, 1.0
    rots[:, body.skeleton.index("root")] = rz
    return {"rotations": rots, "root_translation": np.zeros((cfg.spin_frames, 3))}


def _simulate_clip(cfg, meta, body, poses, progress, offset, total):
    """Fine MPM run of one clip: returns object positions (F, No, 3) and human positions (F, Nh, 3) (world)."""
    sim = meta["sim"]
    origin = np.asarray(sim["origin"])
    dx = sim["size"] / sim["resolution"]
    h = dx / round(cfg.gt_particles_per_cell ** (1 / 3))
    lo, hi = S.object_box(meta)
    Xo, vol_o = S.lattice_box(lo, hi, h)
    Xh = S.capsule_points(body, meta["body"]["simulated_bones"], h)
    rot, root = S.check_poses(poses, body.skeleton.n_bones)
    ref, _ = S.skin_sequence(body, Xh, rot, root)
    dt_f = 1.0 / meta["fps"]
    vref = S.central_velocities(ref, dt_f)
    no, nh = len(Xo), len(Xh)
    n = no + nh
    E = np.where(Xo[:, 0] < 0.5 * (lo[0] + hi[0]), cfg.E_soft, cfg.E_stiff)
    model = MPMModel(size=sim["size"], resolution=sim["resolution"], dt=dt_f / sim["substeps"],
                     substeps=sim["substeps"], mass=np.r_[np.full(no, vol_o * cfg.density),
                                                          np.full(nh, h**3 * cfg.human_density)],
                     volume=np.r_[np.full(no, vol_o), np.full(nh, h**3)], E=np.r_[E, np.full(nh, cfg.human_E)],
                     nu=np.full(n, cfg.nu), elastic=np.zeros(n), plastic=np.zeros(n),
                     plastic_params=np.zeros((n, 4)), body=np.r_[np.zeros(no), np.ones(nh)],
                     gravity=(0.0, 0.0, cfg.gravity), walls=sim_walls())
    x0 = np.r_[Xo, ref[0]] - origin
    v0 = np.r_[np.zeros((no, 3)), vref[0]]
    solver = MPMSolver(model)
    st, scratch = model.state(x0, v0), model.state(x0, v0)
    omega = np.r_[np.zeros(no), np.ones(nh)]
    xs = [x0]
    for f in range(len(rot) - 1):
        ctrl = Control(omega, np.r_[np.zeros((no, 3)), ref[f] - origin], np.r_[np.zeros((no, 3)), vref[f]],
                       kp=sim["kp"], kd=sim["kd"])
        st, scratch = solver.simulate_frame(st, scratch, ctrl)
        xs.append(st.x.numpy().copy())
        if progress:
            progress(offset + f + 1, total)
    xs = np.stack(xs) + origin
    return xs[:, :no], xs[:, no:], Xo, Xh, E, h


def sim_walls() -> dict:
    w = {k: "slip" for k in ("x_min", "x_max", "y_min", "y_max", "z_max")}
    w["z_min"] = "sticky"
    return w


def _render_clip(cfg, meta, body, poses, xo, xh, Xo, h, out_dir: Path):
    K, R, t = S.camera_matrices(meta)
    res = cfg.image_size
    col_o = _checker(Xo - Xo.min(0), 0.04, (0.85, 0.35, 0.3), (0.95, 0.85, 0.55))
    sim_bones = meta["body"]["simulated_bones"]
    Xb = S.capsule_points(body, [b for b, r in zip(body.skeleton.names, body.radii.tolist()) if r > 0
                                 and b not in sim_bones], cfg.body_spacing, exclude=sim_bones)
    rot, root = S.check_poses(poses, body.skeleton.n_bones)
    xb, _ = S.skin_sequence(body, Xb, rot, root)
    skin = np.array([0.55, 0.6, 0.85])  # a blue sleeve for the kinematic body
    arm = np.array([0.9, 0.7, 0.55])
    (out_dir / "rgb").mkdir(parents=True, exist_ok=True)
    (out_dir / "mask").mkdir(parents=True, exist_ok=True)
    frames = []
    for f in range(len(xo)):
        pts = np.concatenate([xo[f], xh[f], xb[f]])
        cols = np.concatenate([col_o, np.tile(arm, (len(xh[f]), 1)), np.tile(skin, (len(xb[f]), 1))])
        rad = np.r_[np.full(len(xo[f]) + len(xh[f]), 0.75 * h), np.full(len(xb[f]), 0.75 * cfg.body_spacing)]
        rgb, mask = render_spheres(pts, cols, rad, K, R, t, res, res, background=meta["background"])
        u8 = (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)
        cv2.imwrite(str(out_dir / "rgb" / f"{f:04d}.png"), cv2.cvtColor(u8, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(out_dir / "mask" / f"{f:04d}.png"), mask.astype(np.uint8) * 255)
        frames.append(u8)
    return frames


def generate(out_dir: str | Path, cfg: SynthConfig | None = None,
             progress: Callable[[int, int], None] | None = None) -> Path:
    """Simulate and render a synthetic scene into ``out_dir`` (see the module docstring). Returns the path."""
    from physar.recon.io import write_mp4

    cfg = cfg or SynthConfig()
    out = Path(out_dir)
    body = S.humanoid(cfg.height)
    lay = S.layout(cfg.height, cfg.pillow_size, cfg.gap, cfg.domain_size)
    centre = 0.5 * (lay["object_min"] + lay["object_max"])
    el, az = np.radians(cfg.camera_elevation_deg), np.radians(cfg.camera_azimuth_deg)
    eye = centre + cfg.camera_distance * np.array([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])
    meta = {
        "format_version": S.FORMAT_VERSION,
        "kind": "physar.recon synthetic scene",
        "fps": cfg.fps, "frames": cfg.frames, "n_obs": cfg.n_obs, "novel_frames": cfg.novel_frames,
        "camera": S.look_at(eye, centre, cfg.fov_deg, cfg.image_size, cfg.image_size),
        "background": [0.3, 0.3, 0.35],
        "body": {"kind": "procedural_humanoid", "height": cfg.height, "simulated_bones": ["forearm.R"],
                 "E": cfg.human_E, "density": cfg.human_density},
        "object": {"shape": "box", "min": lay["object_min"].tolist(), "max": lay["object_max"].tolist(),
                   "density": cfg.density, "nu": cfg.nu, "material": "fixed_corotated"},
        "sim": {"size": cfg.domain_size, "resolution": cfg.grid_resolution, "substeps": cfg.substeps,
                "origin": lay["origin"].tolist(), "gravity": [0.0, 0.0, cfg.gravity], "walls": sim_walls(),
                "kp": cfg.kp, "kd": cfg.kd},
        "synth_config": cfg.model_dump(),
    }
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        (tmp / "scene.json").write_text(json.dumps(meta, indent=1))
        clips = {"": S.press_poses(body, dynamic_depths(cfg), "flat"),
                 "novel": S.press_poses(body, novel_depths(cfg), "tilt")}
        total = cfg.frames + cfg.novel_frames - 2
        truth, offset, preview = {}, 0, None
        if cfg.spin_frames >= 2:  # spin clip: LBS only, the object at rest (seed §4.1, §5.1)
            sp = spin_poses(body, cfg)
            np.savez(tmp / "spin_poses.npz", **sp)
            sim = meta["sim"]
            h = sim["size"] / sim["resolution"] / round(cfg.gt_particles_per_cell ** (1 / 3))
            Xo, _ = S.lattice_box(*S.object_box(meta), h)
            Xh = S.capsule_points(body, meta["body"]["simulated_bones"], h)
            xh, _ = S.skin_sequence(body, Xh, sp["rotations"], sp["root_translation"])
            _render_clip(cfg, meta, body, sp, np.broadcast_to(Xo, (cfg.spin_frames, *Xo.shape)), xh, Xo, h,
                         tmp / "spin")
        for name, poses in clips.items():
            np.savez(tmp / (f"{name}_poses.npz" if name else "poses.npz"), **poses)
            xo, xh, Xo, Xh, E, h = _simulate_clip(cfg, meta, body, poses, progress, offset, total)
            offset += len(xo) - 1
            frames = _render_clip(cfg, meta, body, poses, xo, xh, Xo, h, tmp / name if name else tmp)
            key = name or "dynamic"
            truth[f"{key}_max_displacement"] = np.linalg.norm(xo - xo[:1], axis=2).max(1)
            truth[f"{key}_mean_displacement"] = np.linalg.norm(xo - xo[:1], axis=2).mean(1)
            if not name:
                truth["rest_positions"], truth["E"] = Xo, E
                truth["dynamic_object_positions"] = xo.astype(np.float32)
                preview = frames
        np.savez(tmp / "truth.npz", **truth)
        write_mp4(tmp / "video.mp4", preview, cfg.fps)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)
    return out
