r"""Synthetic benchmark scenes for the reconstruction pipeline (issue 8 part 4, seed 002 §5.1).

The procedural humanoid acts on a soft object with its right forearm.  Scenes (``object`` + ``action``):

==========  =================  ============================================================================
object      action             what happens
==========  =================  ============================================================================
pillow      press (default)    a box pillow; the forearm presses its top flat (novel: a tilted press)
c_pillow    squeeze, press     a C lying on its back (spine at +y, prongs pointing at the camera, -y); the
                               forearm lies over the free upper prong and pushes it down so the C closes
                               (novel: a tilted squeeze with another timing); ``press`` = the same, shallower
bag         lift               a sack (stiff shell, soft filling) with a handle: an arch over its top forming
                               a tunnel along x; the forearm starts inside the tunnel, rises, catches the
                               handle bar and carries the bag off the support (novel: a tilted lift, another
                               timing); the support is then a ``separate`` wall (not sticky)
==========  =================  ============================================================================

Ground truth:

* geometry: a union of boxes (``scene.json`` ``object.boxes``), sampled by :func:`physar.recon.scene.
  object_points` both here (fine) and by the reconstruction (coarse);
* material: fixed-corotated elasticity with a heterogeneous Young's modulus (``E_soft``/``E_stiff``: pillow =
  soft half x < centre, stiff half; C = stiff spine, soft prongs; bag = stiff shell (``bag_wall`` thick) and
  handle, soft filling), Poisson ratio ``nu``, density ``density``, plus an anisotropic fibre term
  :math:`\Psi_f = (E_f/8)(|F a_0|^2 - 1)^2` (:class:`physar.mpm.MPMModel` ``fiber``/``fiber_E``; small-strain
  stiffness along :math:`a_0` grows by :math:`E_f` = ``fiber_E``) with directions :math:`a_0`: pillow along x;
  C tangent to its centreline (y in the prongs, z in the spine); bag vertical in the shell and the handle's
  posts, along y in its bar, none in the filling. The reconstruction learns an isotropic E field only (the
  fibres are what it must absorb);
* plasticity (``yield_stress`` > 0): the object's elastic law becomes Hencky with a von Mises return map on
  the Hencky strain (yield stress ``yield_stress``), the fibre term acting on the elastic part; the
  reconstruction's expert law is fixed-corotated and elastic;
* dynamics: MLS-MPM (:class:`physar.mpm.MPMSolver`) on a FINER particle set (``gt_particles_per_cell``,
  default 8 per cell) than the reconstruction uses, with gravity; the forearm is a set of MPM particles
  actuated by the gated PD controller (Eq. 6-7, :math:`\omega = 1` inside the forearm, 0 on the object and,
  with ``soft_layer`` > 0, on a passive layer within that depth of the body's rest surface:
  :func:`soft_tissue_gate`) towards its LBS trajectory; the rest of the body follows LBS kinematically;
* images: the z-buffered sphere renderer of :mod:`physar.recon.pointrender` (not the Gaussian rasteriser),
  one static camera, ``fps`` frames per second, foreground masks.

A ``spin`` clip comes first (seed §5.1, Fig. 4): the humanoid turns about the vertical axis through its root
(yaw sweeping -spin_deg .. +spin_deg) next to the object at rest; pure LBS, no simulation.  It is the clip
from which the canonical Gaussians are learned with fixed skinning (§4.1).

Two clips follow: ``dynamic`` (the forearm, kept horizontal, travels ``press_obs`` during the observation part,
then on to ``press_pred`` in the prediction part; down for press/squeeze, up for lift) and ``novel`` (the
forearm tilted, shoulder rotation only, its midpoint travelling ``press_novel`` with another timing: a novel
action for prediction).

DATA_DIR layout (written atomically: to a temporary folder renamed at the end)::

    scene.json                 camera, fps, n_obs, body, object boxes, MPM settings, PD gains (no truth)
    poses.npz, novel_poses.npz, spin_poses.npz   rotations (F, B, 3, 3), root_translation (F, 3)
    spin/rgb/0000.png, spin/mask/0000.png          spin clip (when spin_frames > 0)
    rgb/0000.png, mask/0000.png         dynamic clip (observation + prediction parts)
    novel/rgb/0000.png, novel/mask/0000.png
    truth.npz                  ground truth for evaluation only (never read by ``fit``): fine rest
                               positions, E, fiber (N, 3), fiber_E (N,), part (N,) (index into
                               scene.json object.parts), per-frame max/mean object displacement (m) of both
                               clips, fine object positions of both clips (F, N_fine, 3)
    video.mp4                  preview of the dynamic clip (when an encoder is available)
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Literal

import cv2
import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from physar.errors import ConfigError, format_validation_error, refuse_coercion
from physar.mpm.constitutive import ELASTIC_HENCKY, PLASTIC_VON_MISES
from physar.mpm.model import Control, MPMModel, MPMSolver, device_name
from physar.output import atomic_folder, check_folder, own_names
from physar.recon import scene as S
from physar.recon.pointrender import render_spheres

Vec3 = tuple[float, float, float]
Size = Annotated[float, Field(gt=0)]
Size3 = tuple[Size, Size, Size]  # a box's extents: positive (a negative one made boxes that scene.json refused)

# Bounds of the recon config tables shared by [synth] (here and synth_anny.py) and [train] (module docstrings):
PARTICLES_PER_CELL = (1, 8, 27, 64)  # k^3 particles per cell, k = 1..4
MAX_SUBSTEPS = 10_000  # MPM substeps per frame (32 by default; 10^4 covers elastic wave speeds of km/s)
# grid cells an elastic wave may cross per MPM substep (estimated from above: check_simulation). Measured on
# recon_tiny with E_stiff = 1e6 Pa: 1.12 diverged, 1.06 ran (examples/recon_anny_bag.toml runs at 1.06)
MAX_CFL = 1.1
CFL_ADVISED = 0.9  # what the "raise substeps to >= N" advice aims at: a margin below the measured limit
MAX_FPS = 1000.0  # frame rate of a (high-speed) camera, fps
MAX_GRAVITY = 100.0  # |gravity| <= ~10 g, m/s^2
MAX_SEED = 2**63 - 1  # the seeds are int64 (torch.manual_seed, numpy)
MAX_BODY_SPACING = 0.1  # m: coarser body samples miss whole limbs (a forearm is ~0.08 m thick)
MAX_BODY_SAMPLES = 2.0e6  # rendered body samples a scene may ask for (body_spacing's lower bound)
BODY_VOLUME = 0.1  # m^3, an upper estimate of a body's volume (the procedural 1.7 m humanoid: 0.070 m^3)
BODY_AREA = 2.5  # m^2, an upper estimate of a body's surface area (adults: 1.6-2.2 m^2)
MIN_OBJECT_PX = 4.0  # the object must span at least this many pixels of the image
RENDER_BYTES_PER_CANDIDATE = 64  # pointrender: i, j (int64), dx, dy, d2 (float64), keep, and temporaries


def check_particles_per_cell(value: int) -> int:
    """``value`` when it is one of :data:`PARTICLES_PER_CELL`, else ValueError (a field validator's message)."""
    if value not in PARTICLES_PER_CELL:
        raise ValueError(f"must be 1, 8, 27 or 64 (k^3 particles per cell, k = 1..4), got {value}")
    return value


def check_sample_count(spacing: float, extent: float, dim: int, what: str) -> float:
    """``spacing`` (m) when the samples it makes of a body of volume (dim 3) or area (dim 2) ``extent`` stay
    within :data:`MAX_BODY_SAMPLES`, else ValueError with the estimate and the smallest spacing allowed."""
    n = extent / spacing**dim
    if not n <= MAX_BODY_SAMPLES:
        raise ValueError(f"{spacing:g} m makes about {n:.3g} {what} (a body of {extent:g} m^{dim}), more than "
                         f"{MAX_BODY_SAMPLES:.3g}: use >= {(extent / MAX_BODY_SAMPLES) ** (1 / dim):.2g} m")
    return spacing


def check_simulation(cfg, feature: tuple[str, float], object_volume: float) -> None:
    """Checks of a synthetic scene's truth run shared by :class:`SynthConfig` and the anny scene's config
    (ValueError naming the fields): the grid cell resolves the object's thinnest part ``feature`` (name, m);
    the explicit MPM step is not clearly unstable for the elastic waves (wave speed c = sqrt(M / rho), M =
    lambda + 2 mu of the stiffest part plus the fibre modulus: an upper bound; c dt <= MAX_CFL dx, dt = 1 / (fps
    substeps; MAX_CFL = 1.1 as measured: 1.12 diverged, 1.06 ran) and the PD gains (sqrt(kp) dt < 2, kd dt < 2); the run's memory,
    estimated from ``object_volume`` (m^3) at gt_particles_per_cell, fits in the machine
    (:func:`physar.output.check_memory`)."""
    from physar.mpm.scene import MPM_BYTES_PER_NODE, MPM_BYTES_PER_PARTICLE
    from physar.output import check_memory

    dx = cfg.domain_size / cfg.grid_resolution
    name, size = feature
    if dx > size * (1 + 1e-9):
        raise ValueError(f"the grid cell domain_size / grid_resolution = {dx:.3g} m is coarser than {name} "
                         f"({size:g} m): the object would not be resolved; lower domain_size or raise "
                         "grid_resolution")
    dt = 1.0 / (cfg.fps * cfg.substeps)
    p_mod = (1 - cfg.nu) / ((1 + cfg.nu) * (1 - 2 * cfg.nu))  # (lambda + 2 mu) / E
    for what, M, rho, E_name, rho_name in (
            ("the object", p_mod * max(cfg.E_soft, cfg.E_stiff) + cfg.fiber_E, cfg.density,
             f"E_soft/E_stiff = {max(cfg.E_soft, cfg.E_stiff):.3g} Pa, fiber_E = {cfg.fiber_E:.3g} Pa", "density"),
            ("the body", p_mod * cfg.human_E, cfg.human_density, f"human_E = {cfg.human_E:.3g} Pa", "human_density")):
        c = math.sqrt(M / rho)
        if c * dt > MAX_CFL * dx:
            need = math.ceil(c / (CFL_ADVISED * cfg.fps * dx))
            fix = f"raise substeps to >= {need} or lower" if need <= MAX_SUBSTEPS else "lower"
            raise ValueError(f"elastic waves in {what} ({E_name}, nu = {cfg.nu:g}, {rho_name} = "
                             f"{rho:.3g} kg/m^3: {c:.3g} m/s) cross {c * dt / dx:.3g} grid cells per MPM substep "
                             f"(> {MAX_CFL:g}: the explicit step diverges; dt = 1 / (fps substeps) = {dt:.3g} s): "
                             f"{fix} the stiffness")
    if math.sqrt(cfg.kp) * dt >= 2 or cfg.kd * dt >= 2:
        raise ValueError(f"PD gains kp = {cfg.kp:g} 1/s^2, kd = {cfg.kd:g} 1/s are unstable at the MPM substep "
                         f"dt = 1 / (fps substeps) = {dt:.3g} s (needs sqrt(kp) dt < 2 and kd dt < 2): lower them "
                         "or raise substeps")
    k = round(cfg.gt_particles_per_cell ** (1 / 3))
    n = object_volume / (dx / k) ** 3
    frames = cfg.frames + cfg.novel_frames
    check_memory(n * (MPM_BYTES_PER_PARTICLE + 36 * frames) + MPM_BYTES_PER_NODE * (cfg.grid_resolution + 7) ** 3,
                 f"the truth run of about {n:.3g} object particles ({cfg.gt_particles_per_cell} per cell of "
                 f"{dx:.3g} m: domain_size / grid_resolution) over {frames} frames")

# supported object -> action -> default forearm travel (m): end of the observation part, end of the dynamic clip,
# novel (tilted) action
ACTIONS = {
    "pillow": {"press": (0.03, 0.055, 0.05)},
    "c_pillow": {"squeeze": (0.05, 0.085, 0.075), "press": (0.025, 0.04, 0.04)},
    "bag": {"lift": (0.06, 0.13, 0.11)},
}


class SynthConfig(BaseModel):
    """Parameters of a synthetic scene (SI units); numbers must be finite (inf is refused as nan is)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    @field_validator("*", mode="before")
    @classmethod
    def _no_coercion(cls, value, info):  # E = true, E = "69e9" and cells = ["40", 2, 2] are errors, not numbers
        return refuse_coercion(value, cls.model_fields[info.field_name].annotation)

    image_size: int = Field(64, ge=16, le=1024, description="square image side, px")
    fov_deg: float = Field(35.0, gt=5, lt=120, description="vertical field of view of the camera [deg]")
    object: Literal["pillow", "c_pillow", "bag"] = Field("pillow", description="pillow | c_pillow | bag")
    action: Literal["press", "squeeze", "lift"] = Field(
        "press", description="press (pillow, c_pillow) | squeeze (c_pillow) | lift (bag)")
    camera_distance: float = Field(0.75, gt=0.1, description="m, from the object centre")
    camera_elevation_deg: float = Field(25.0, ge=-80, le=80, description="camera elevation above the horizontal, "
                                                                        "seen from the object centre [deg]")
    camera_azimuth_deg: float = Field(10.0, ge=-180, le=180, description="camera azimuth about the vertical from "
                                                                        "the -y side, towards +x [deg]")
    fps: float = Field(30.0, gt=0, le=MAX_FPS, description="frame rate of the clips [fps]")
    frames: int = Field(20, ge=3, le=2000, description="frames of the dynamic clip")
    n_obs: int = Field(12, ge=2, description="observation frames (the rest is the prediction part)")
    novel_frames: int = Field(16, ge=2, le=2000, description="frames of the novel-action clip")
    spin_frames: int = Field(10, ge=0, le=2000, description="frames of the spin clip (0: none, else >= 2)")
    spin_deg: float = Field(20.0, ge=0, le=180, description="yaw amplitude of the spin clip, degrees")
    height: float = Field(1.7, gt=0.5, lt=2.5, description="humanoid height, m")
    pillow_size: Size3 = Field((0.24, 0.20, 0.12), description="pillow box (x along the forearm, y, z), m")
    c_pillow_size: Size3 = Field((0.24, 0.15, 0.18), description="C pillow: length along the forearm (x), depth "
                                "(y, spine at the back) and height (z), m")
    c_thickness: float = Field(0.06, gt=0, description="C pillow: thickness of the prongs and the spine [m] "
                               "(the gap between the prongs is height - 2 thickness)")
    bag_size: Size3 = Field((0.21, 0.18, 0.12), description="bag body (x, y, z) below the handle, m")
    bag_wall: float = Field(0.03, gt=0, description="bag: shell and handle thickness, m")
    handle_length: float = Field(0.09, gt=0, description="bag: extent of the handle along the forearm (x), m")
    handle_hole: float = Field(0.12, gt=0, description="bag: clear height of the tunnel under the handle bar, m")
    gap: float = Field(0.005, ge=0, description="initial gap forearm-object top (press, squeeze) [m]; for a "
                       "lift the forearm starts centred in the handle's tunnel")
    E_soft: float = Field(3.0e3, gt=0, description="Young's modulus of the object's soft part [Pa]")
    E_stiff: float = Field(1.2e4, gt=0, description="Young's modulus of the object's stiff part [Pa]")
    fiber_E: float = Field(2.4e4, ge=0, description="fibre modulus E_f of the anisotropic term [Pa] (0: isotropic)")
    yield_stress: float = Field(0.0, ge=0, description="von Mises yield stress of the object [Pa] (Hencky "
                                "elasticity + von Mises plasticity in the truth; 0: elastic, fixed-corotated)")
    nu: float = Field(0.3, gt=-1, lt=0.5, description="Poisson ratio of the object [-]")
    density: float = Field(200.0, gt=0, description="density of the object [kg/m^3]")
    human_E: float = Field(1.0e4, gt=0, description="Young's modulus of the simulated forearm [Pa]")
    human_density: float = Field(1000.0, gt=0, description="density of the simulated forearm [kg/m^3]")
    soft_layer: float = Field(0.0, ge=0, description="passive layer of the simulated body [m]: particles within "
                              "soft_layer of the body's rest surface get no PD force (omega = 0; moved by "
                              "elasticity and contact only, soft_tissue_gate); 0: the whole simulated forearm is "
                              "driven")
    kp: float = Field(3.0e3, ge=0, description="PD gain (mass-scaled) [1/s^2]")
    kd: float = Field(110.0, ge=0, description="PD gain, 1/s")
    press_obs: float | None = Field(None, ge=0, description="forearm travel at the end of the observation part "
                                    "[m] (down for press/squeeze, up for lift); default per scene (ACTIONS)")
    press_pred: float | None = Field(None, ge=0, description="forearm travel at the end of the dynamic clip, m")
    press_novel: float | None = Field(None, ge=0, description="novel (tilted) action: travel of the forearm's "
                                      "midpoint, m")
    domain_size: float = Field(0.48, gt=0, description="side of the cubic MPM domain around the object [m]")
    grid_resolution: int = Field(16, ge=4, le=256, description="MPM grid cells per side of the domain")
    substeps: int = Field(32, ge=1, le=MAX_SUBSTEPS, description="MPM steps per frame")
    gravity: float = Field(-9.81, ge=-MAX_GRAVITY, le=MAX_GRAVITY,
                           description="vertical (z) gravitational acceleration [m/s^2]")
    gt_particles_per_cell: int = Field(8, description="MPM particles per cell of the truth run: 1, 8, 27 or 64")
    body_spacing: float = Field(0.012, gt=0, le=MAX_BODY_SPACING, description="spacing of the rendered body samples (at most 2e6 "
                                "samples of the body's volume: >= 3.7 mm) [m]")
    seed: int = Field(0, ge=0, le=MAX_SEED, description="recorded in scene.json; the synthesis draws no random numbers, so it "
                                     "changes nothing")
    device: str = Field("cpu", description="Warp device of the truth's MPM run: cpu (default), cuda or cuda:N "
                                    "(physar.mpm.model.MPMModel.device); not recorded in scene.json")

    @field_validator("device")
    @classmethod
    def _device_name(cls, value):
        return device_name(value)

    @field_validator("gt_particles_per_cell")
    @classmethod
    def _per_cell(cls, value):
        return check_particles_per_cell(value)

    @field_validator("body_spacing")
    @classmethod
    def _spacing(cls, value):
        return check_sample_count(value, BODY_VOLUME, 3, "body samples")

    @model_validator(mode="after")
    def _check(self):
        if self.spin_frames == 1:
            raise ValueError("spin_frames = 1: the spin clip needs >= 2 frames (0: no spin clip)")
        if self.action not in ACTIONS[self.object]:
            raise ValueError(f"action '{self.action}' is not supported for object '{self.object}' (supported: "
                             + ", ".join(f"{o} + {'|'.join(a)}" for o, a in ACTIONS.items()) + ")")
        for k, v in zip(("press_obs", "press_pred", "press_novel"), ACTIONS[self.object][self.action]):
            if getattr(self, k) is None:
                setattr(self, k, v)
        if self.object == "c_pillow":
            L, D, H = self.c_pillow_size
            if not (2 * self.c_thickness < H and self.c_thickness < D):
                raise ValueError(f"c_thickness = {self.c_thickness} m needs 2 x thickness < height ({H}) and "
                                 f"thickness < depth ({D}) of c_pillow_size")
        if self.object == "bag":
            L, W, H = self.bag_size
            if not (2 * self.bag_wall < min(W, H) and self.handle_length <= L):
                raise ValueError(f"bag_wall = {self.bag_wall} m needs 2 x wall < bag_size y and z ({W}, {H}), "
                                 f"handle_length = {self.handle_length} m <= bag_size x ({L})")
        if self.n_obs >= self.frames:
            raise ValueError(f"n_obs ({self.n_obs}) must be < frames ({self.frames})")
        if self.object == "pillow":
            feature, volume = ("the smallest side of pillow_size", min(self.pillow_size)), math.prod(self.pillow_size)
        elif self.object == "c_pillow":
            feature, volume = ("c_thickness", self.c_thickness), math.prod(self.c_pillow_size)
        else:
            L, W, H = self.bag_size
            feature = ("bag_wall", self.bag_wall)
            volume = L * W * H + self.handle_length * W * (self.handle_hole + self.bag_wall)
        check_simulation(self, feature, volume)
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
        tables = [k for k, v in raw.items() if isinstance(v, dict)]
        if tables and "synth" not in raw and "train" not in raw:  # a misspelt [trian]: not top-level keys
            import difflib

            near = difflib.get_close_matches(tables[0], ["synth", "train"], n=1)
            raise ConfigError(f"{p}: unknown table [{tables[0]}]" + (f"; did you mean [{near[0]}]?" if near else
                                                                     f" (a recon config has [{section}])"))
        if "synth" in raw or "train" in raw:
            table = raw.get(section, {})
            if not isinstance(table, dict):
                raise ConfigError(f"{p}: '{section}' must be a table ([{section}] with its keys), got "
                                  f"{section} = {table!r}")
            data = dict(table)
        else:
            data = raw
    data.update(overrides or {})
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, str(path or section + " config"), model, section,
                                                  data=data)) from None


def load_synth_config(path: str | Path | None, overrides: dict | None = None) -> SynthConfig:
    """Config from a TOML file (table [synth] or top level) and overrides; one-line errors, the scene's layout
    and camera included (:func:`scene_meta`)."""
    cfg = load_section_config(path, "synth", SynthConfig, overrides)
    try:
        scene_meta(cfg)
    except ConfigError as exc:
        raise ConfigError(f"{path or 'synth config'}: [synth] {exc}") from None
    return cfg


def _checker(X: np.ndarray, cell: float, c0, c1) -> np.ndarray:
    k = np.floor(X / cell).astype(np.int64).sum(1) % 2
    return np.where(k[:, None] == 0, np.asarray(c0), np.asarray(c1)).astype(np.float64)


def travel_sign(cfg: SynthConfig) -> float:
    """+1: the forearm travels down (press, squeeze); -1: up (lift)."""
    return -1.0 if cfg.action == "lift" else 1.0


def dynamic_depths(cfg: SynthConfig) -> np.ndarray:
    """Forearm drop (m, negative = rise) per frame of the dynamic clip."""
    f = np.arange(cfg.frames, dtype=np.float64)
    d = cfg.press_obs * S.smoothstep(f / (cfg.n_obs - 1))
    m = f >= cfg.n_obs
    d[m] = cfg.press_obs + (cfg.press_pred - cfg.press_obs) * S.smoothstep(
        (f[m] - cfg.n_obs + 1) / (cfg.frames - cfg.n_obs))
    return travel_sign(cfg) * d


def novel_depths(cfg: SynthConfig) -> np.ndarray:
    """Drop (m, negative = rise) of the forearm's midpoint per frame of the novel (tilted) clip."""
    f = np.arange(cfg.novel_frames, dtype=np.float64)
    return travel_sign(cfg) * cfg.press_novel * S.smoothstep(f / (0.7 * (cfg.novel_frames - 1)))


def clip_poses(cfg: SynthConfig, body) -> dict:
    """Pose sequences of the dynamic clip (key "") and of the novel action (key "novel")."""
    return {"": S.press_poses(body, dynamic_depths(cfg), "flat"),
            "novel": S.press_poses(body, novel_depths(cfg), "tilt")}


# ----------------------------------------------------------------------------------------------- objects
PARTS = {"pillow": ["soft half", "stiff half"], "c_pillow": ["lower prong", "spine", "upper prong"],
         "bag": ["filling", "shell", "handle"]}


def object_boxes_local(cfg: SynthConfig, r: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """The object's boxes relative to the midpoint of the forearm's axis at rest (radius r)."""
    V = lambda *v: np.array(v, dtype=np.float64)
    if cfg.object == "pillow":
        L, W, H = cfg.pillow_size
        top = -r - cfg.gap
        return [(V(-L / 2, -W / 2, top - H), V(L / 2, W / 2, top))]
    if cfg.object == "c_pillow":
        L, D, H = cfg.c_pillow_size
        t = cfg.c_thickness
        top = -r - cfg.gap
        bot = top - H
        y0 = -(D - t) / 2  # the forearm lies over the middle of the free upper prong
        y1 = y0 + D
        return [(V(-L / 2, y0, bot), V(L / 2, y1, bot + t)),  # lower prong
                (V(-L / 2, y1 - t, bot + t), V(L / 2, y1, top - t)),  # spine
                (V(-L / 2, y0, top - t), V(L / 2, y1, top))]  # upper prong
    L, W, H = cfg.bag_size
    w, hl, ho = cfg.bag_wall, cfg.handle_length, cfg.handle_hole
    if W - 2 * w < 2 * r + 0.01 or ho < 2 * r + 0.01:
        raise ConfigError(f"bag: the handle's tunnel ({W - 2 * w:.3f} x {ho:.3f} m, from bag_size y - 2 bag_wall "
                          f"and handle_hole) must clear the forearm (diameter {2 * r:.3f} m) by 1 cm")
    return [(V(-L / 2, -W / 2, -ho / 2 - H), V(L / 2, W / 2, -ho / 2)),  # body
            (V(-hl / 2, -W / 2, -ho / 2), V(hl / 2, -W / 2 + w, ho / 2)),  # front post
            (V(-hl / 2, W / 2 - w, -ho / 2), V(hl / 2, W / 2, ho / 2)),  # back post
            (V(-hl / 2, -W / 2, ho / 2), V(hl / 2, W / 2, ho / 2 + w))]  # bar


def object_material(cfg: SynthConfig, meta: dict, X: np.ndarray):
    """Ground-truth fields at world points X (N, 3) of the object: E (N,), fibre directions (N, 3) (zero row =
    none), fibre moduli (N,) and part index (N,) into PARTS[object] (see the module docstring)."""
    boxes = [(np.asarray(lo), np.asarray(hi)) for lo, hi in meta["object"]["boxes"]]
    n = len(X)
    fib = np.zeros((n, 3))
    if cfg.object == "pillow":
        lo, hi = boxes[0]
        part = (X[:, 0] >= 0.5 * (lo[0] + hi[0])).astype(np.int64)
        fib[:, 0] = 1.0
        stiff = part == 1
        has = np.ones(n, dtype=bool)
    elif cfg.object == "c_pillow":
        spine_y = boxes[1][0][1]
        zmid = 0.5 * (boxes[0][0][2] + boxes[2][1][2])
        stiff = X[:, 1] >= spine_y
        part = np.where(stiff, 1, np.where(X[:, 2] < zmid, 0, 2))
        fib[:] = np.where(stiff[:, None], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0])
        has = np.ones(n, dtype=bool)
    else:
        (blo, bhi), w = boxes[0], cfg.bag_wall
        in_body = np.all((X >= blo) & (X <= bhi), axis=1)
        inner = np.all((X > blo + w) & (X < bhi - w), axis=1)
        part = np.where(~in_body, 2, np.where(inner, 0, 1))
        stiff = part > 0
        bar = X[:, 2] > boxes[3][0][2]
        fib[:] = np.where(bar[:, None], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])
        has = stiff
    fib[~has] = 0.0
    E = np.where(stiff, cfg.E_stiff, cfg.E_soft)
    return E, fib, np.where(has, cfg.fiber_E, 0.0), part


def scene_meta(cfg: SynthConfig) -> dict:
    """scene.json of a config (layout checked against the MPM domain: one-line ConfigError)."""
    body = S.humanoid(cfg.height)
    r = float(body.radii[body.skeleton.index("forearm.R")])
    up = max(cfg.press_pred, cfg.press_novel) if cfg.action == "lift" else 0.0
    down = 0.0 if cfg.action == "lift" else max(cfg.press_pred, cfg.press_novel)
    lay = S.layout(cfg.height, object_boxes_local(cfg, r), cfg.domain_size, rise=up, drop=down)
    centre = 0.5 * (lay["object_min"] + lay["object_max"]) + np.array([0.0, 0.0, 0.5 * up])
    el, az = np.radians(cfg.camera_elevation_deg), np.radians(cfg.camera_azimuth_deg)
    eye = centre + cfg.camera_distance * np.array([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)])
    check_camera(cfg, eye, lay["origin"], lay["object_max"] - lay["object_min"])
    return {
        "format_version": S.FORMAT_VERSION,
        "kind": "physar.recon synthetic scene",
        "fps": cfg.fps, "frames": cfg.frames, "n_obs": cfg.n_obs, "novel_frames": cfg.novel_frames,
        "camera": S.look_at(eye, centre, cfg.fov_deg, cfg.image_size, cfg.image_size),
        "background": [0.3, 0.3, 0.35],
        "body": {"model": "capsule", "kind": "procedural_humanoid", "height": cfg.height,
                 "simulated_bones": ["forearm.R"], "E": cfg.human_E, "density": cfg.human_density},
        "object": {"shape": "box" if len(lay["boxes"]) == 1 else "box_union", "kind": cfg.object,
                   "action": cfg.action, "min": lay["object_min"].tolist(), "max": lay["object_max"].tolist(),
                   "boxes": [[lo.tolist(), hi.tolist()] for lo, hi in lay["boxes"]], "parts": PARTS[cfg.object],
                   "density": cfg.density, "nu": cfg.nu, "material": "fixed_corotated"},
        "sim": {"size": cfg.domain_size, "resolution": cfg.grid_resolution, "substeps": cfg.substeps,
                "origin": lay["origin"].tolist(), "gravity": [0.0, 0.0, cfg.gravity],
                "walls": sim_walls("separate" if cfg.action == "lift" else "sticky"), "kp": cfg.kp, "kd": cfg.kd},
        "synth_config": cfg.model_dump(exclude={"device"}),  # where it ran is not part of the scene
    }


def check_camera(cfg, eye: np.ndarray, origin: np.ndarray, object_size: np.ndarray) -> None:
    """ConfigError naming camera_distance when the camera is inside the MPM domain (cube ``origin`` +
    [0, domain_size]^3, where the simulated particles are: drawn from up close they cover the image and the
    renderer's memory grows with their size in pixels squared) or so far that the object (extents
    ``object_size``, m) spans fewer than :data:`MIN_OBJECT_PX` pixels (every mask would be empty)."""
    if np.all((eye > origin) & (eye < origin + cfg.domain_size)):
        raise ConfigError(f"camera_distance = {cfg.camera_distance:g} m puts the camera inside the MPM domain (the "
                          f"cube of domain_size = {cfg.domain_size:g} m around the object): move it farther")
    fx = 0.5 * cfg.image_size / math.tan(math.radians(cfg.fov_deg) / 2)
    px = fx * float(np.linalg.norm(object_size)) / cfg.camera_distance
    if px < MIN_OBJECT_PX:
        raise ConfigError(f"camera_distance = {cfg.camera_distance:g} m: the object would span {px:.2g} px of the "
                          f"{cfg.image_size} px image (< {MIN_OBJECT_PX:g}): move the camera closer")


def check_render_memory(points: np.ndarray, radius: np.ndarray, K, R, t, cfg, supersample: int = 2):
    """ConfigError when the sphere renderer (:func:`physar.recon.pointrender.render_spheres`) would need more
    memory than is available to draw ``points`` (F, N, 3) or (N, 3): it looks at a (2k + 3)^2 pixel window around
    every point, k the largest sphere radius in pixels (the nearest points to the camera)."""
    from physar.output import check_memory

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3) @ np.asarray(R).T + np.asarray(t)
    rad = np.broadcast_to(np.asarray(radius, dtype=np.float64), points.shape[:-1]).reshape(-1)
    ok = p[:, 2] > 1e-3
    if not np.any(ok):
        return
    rpx = float(np.max(K[0, 0] * supersample * rad[ok] / p[ok, 2]))
    n = int(ok.sum()) / max(1, points.shape[0] if points.ndim == 3 else 1)
    w = 2 * math.ceil(rpx) + 3
    check_memory(RENDER_BYTES_PER_CANDIDATE * n * w * w,
                 f"rendering {n:.3g} spheres up to {rpx:.3g} px in radius (image_size = {cfg.image_size}, "
                 f"camera_distance = {cfg.camera_distance:g} m: the nearest ones are drawn large)")


def _check_in_domain(meta: dict, name: str, x_world: np.ndarray) -> None:
    sim = meta["sim"]
    x = x_world - np.asarray(sim["origin"])
    dx = sim["size"] / sim["resolution"]
    lo, hi = x.reshape(-1, 3).min(0), x.reshape(-1, 3).max(0)
    if np.any(lo < -0.5 * dx) or np.any(hi > sim["size"] + 0.5 * dx):
        raise ConfigError(f"{name} leaves the MPM domain [0, {sim['size']}]^3 (reaches {np.round(lo, 3).tolist()} .. "
                          f"{np.round(hi, 3).tolist()} m): raise domain_size or reduce the forearm travel")


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


def simulate_clip(cfg: SynthConfig, meta: dict, body, poses: dict, progress=None, offset: int = 0,
                  total: int = 0, gate: np.ndarray | None = None) -> dict:
    """Fine ground-truth MPM run of one clip.  Returns world positions of the object ("xo", (F, No, 3)) and of the
    simulated forearm ("xh", (F, Nh, 3)), the object's rest points "Xo", fields "E", "fiber", "fiber_E", "part"
    and the particle spacing "h".  ``gate`` (Nh,): :func:`soft_tissue_gate` of the body points, when the caller
    has it already (computed here otherwise)."""
    sim = meta["sim"]
    origin = np.asarray(sim["origin"])
    dx = sim["size"] / sim["resolution"]
    h = dx / round(cfg.gt_particles_per_cell ** (1 / 3))
    Xo, vol_o = S.object_points(meta, h)
    E, fib, fib_E, part = object_material(cfg, meta, Xo)
    Xh = S.body_points(body, meta["body"]["simulated_bones"], h)
    rot, root = S.check_poses(poses, body.skeleton.n_bones)
    ref, _ = S.skin_sequence(body, Xh, rot, root)
    _check_in_domain(meta, "the forearm", ref)
    dt_f = 1.0 / meta["fps"]
    vref = S.central_velocities(ref, dt_f)
    no, nh = len(Xo), len(Xh)
    n = no + nh
    aniso = {}
    if np.any(fib_E > 0):  # isotropic scenes build exactly the model they always did
        aniso = {"fiber": np.r_[fib, np.zeros((nh, 3))], "fiber_E": np.r_[fib_E, np.zeros(nh)]}
    elastic, plastic, pp = np.zeros(n), np.zeros(n), np.zeros((n, 4))
    if getattr(cfg, "yield_stress", 0.0) > 0:  # plastic truth: Hencky + von Mises on the object (not the body)
        elastic[:no], plastic[:no], pp[:no, 0] = ELASTIC_HENCKY, PLASTIC_VON_MISES, cfg.yield_stress
    model = MPMModel(size=sim["size"], resolution=sim["resolution"], dt=dt_f / sim["substeps"],
                     substeps=sim["substeps"], mass=np.r_[np.full(no, vol_o * cfg.density),
                                                          np.full(nh, h**3 * cfg.human_density)],
                     volume=np.r_[np.full(no, vol_o), np.full(nh, h**3)], E=np.r_[E, np.full(nh, cfg.human_E)],
                     nu=np.full(n, cfg.nu), elastic=elastic, plastic=plastic,
                     plastic_params=pp, body=np.r_[np.zeros(no), np.ones(nh)],
                     gravity=(0.0, 0.0, cfg.gravity), walls=sim["walls"], device=getattr(cfg, "device", "cpu"),
                     **aniso)
    x0 = np.r_[Xo, ref[0]] - origin
    v0 = np.r_[np.zeros((no, 3)), vref[0]]
    solver = MPMSolver(model)
    st, scratch = model.state(x0, v0), model.state(x0, v0)
    if gate is None:
        gate = soft_tissue_gate(body, Xh, cfg.soft_layer)
    elif len(gate) != nh:
        raise ValueError(f"simulate_clip: gate has {len(gate)} entries for {nh} body particles")
    omega = np.r_[np.zeros(no), gate]
    xs = [x0]
    for f in range(len(rot) - 1):
        ctrl = Control(omega, np.r_[np.zeros((no, 3)), ref[f] - origin], np.r_[np.zeros((no, 3)), vref[f]],
                       kp=sim["kp"], kd=sim["kd"], hold=False)  # the truth's stiff tracking, not Alg. 2
        st, scratch = solver.simulate_frame(st, scratch, ctrl)
        xs.append(st.x.numpy().copy())
        if progress:
            progress(offset + f + 1, total)
    xs = np.stack(xs) + origin
    _check_in_domain(meta, f"the {cfg.object}", xs[:, :no])
    return {"xo": xs[:, :no], "xh": xs[:, no:], "Xo": Xo, "E": E, "fiber": fib, "fiber_E": fib_E, "part": part,
            "h": h, "mass": vol_o * cfg.density * no}


def soft_tissue_gate(body, Xh: np.ndarray, depth: float) -> np.ndarray:
    r"""Gate of the truth's simulated body particles, :math:`g_i = [\varphi(X_i) < -\delta]` with
    :math:`\varphi` = ``body.signed_distance`` (m, negative inside; for the capsule figure
    :math:`\min_k(|X - \text{segment}_k| - r_k)`) at the rest points ``Xh`` (Nh, 3) and :math:`\delta` =
    ``depth`` (m). The PD force of seed Eq. 7 is multiplied by it: 1 drives the particle towards its LBS target,
    0 leaves a passive layer under the rest surface that only elasticity (``human_E``) and contact move. Seed
    §4.2 keeps the PD force off the "exterior human surface" because the LBS reference is "imperfect, especially
    for non-rigid regions"; a truth with such a layer gives the reconstruction's own omega = 0 layer
    (``[train] surface_layer``) something to match. ``depth`` = 0: every particle is driven."""
    if depth <= 0:
        return np.ones(len(Xh))
    d = body.signed_distance(torch.as_tensor(Xh)).numpy()
    gate = (d < -depth).astype(np.float64)
    if not gate.any():
        raise ConfigError(f"synth.soft_layer = {depth:g} m: every simulated body particle lies within soft_layer "
                          f"of the body's rest surface (the deepest is {float(-d.min()):.4f} m deep), so nothing "
                          "would drive the body; lower soft_layer")
    return gate


def sim_walls(floor: str = "sticky") -> dict:
    """Domain walls: slip on the sides and the top, ``floor`` (sticky for press/squeeze, separate for a lift)."""
    w = {k: "slip" for k in ("x_min", "x_max", "y_min", "y_max", "z_max")}
    w["z_min"] = floor
    return w


def _render_clip(cfg, meta, body, poses, xo, xh, Xo, h, out_dir: Path):
    K, R, t = S.camera_matrices(meta)
    res = cfg.image_size
    col_o = _checker(Xo - Xo.min(0), 0.04, (0.85, 0.35, 0.3), (0.95, 0.85, 0.55))
    sim_bones = meta["body"]["simulated_bones"]
    Xb = S.body_points(body, [b for b in body.volume_bones() if b not in sim_bones], cfg.body_spacing,
                       exclude=sim_bones)
    rot, root = S.check_poses(poses, body.skeleton.n_bones)
    xb, _ = S.skin_sequence(body, Xb, rot, root)
    skin = np.array([0.55, 0.6, 0.85])  # a blue sleeve for the kinematic body
    arm = np.array([0.9, 0.7, 0.55])
    (out_dir / "rgb").mkdir(parents=True, exist_ok=True)
    (out_dir / "mask").mkdir(parents=True, exist_ok=True)
    frames = []
    check_render_memory(np.concatenate([xo, xh, xb], axis=1),
                        np.r_[np.full(xo.shape[1] + xh.shape[1], 0.75 * h), np.full(xb.shape[1], 0.75 * cfg.body_spacing)],
                        K, R, t, cfg)
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


# The entries of a DATA_DIR (module docstring): a folder holding only these (and scene.json) is a previous
# scene that `generate` may replace; any other entry makes it a user's folder, which is refused, never deleted.
DATA_DIR_FILES = own_names(r"scene\.json", r"(novel_|spin_)?poses\.npz", r"rgb", r"mask", r"spin", r"novel",
                           r"truth\.npz", r"video\.mp4")


def check_data_dir(out_dir: str | Path, inputs=()) -> Path:
    """``out_dir`` as the destination of :func:`generate`, checked before any work (one ConfigError line):
    new, empty, or a previous DATA_DIR (only the files ``generate`` writes); not a file, not unwritable."""
    return check_folder(out_dir, own=DATA_DIR_FILES, inputs=inputs, kind="DATA_DIR")


def generate(out_dir: str | Path, cfg: SynthConfig | None = None,
             progress: Callable[[int, int], None] | None = None) -> Path:
    """Simulate and render a synthetic scene into ``out_dir`` (see the module docstring). Returns the path.

    The scene is written into a hidden temporary folder that replaces ``out_dir`` once complete
    (:func:`physar.output.atomic_folder`): an error or an interrupt leaves ``out_dir`` as it was, and a
    folder holding anything else than a previous scene is refused (:func:`check_data_dir`)."""
    from physar.recon.io import write_mp4

    cfg = cfg or SynthConfig()
    out = check_data_dir(out_dir)
    body = S.humanoid(cfg.height)
    meta = scene_meta(cfg)
    clips = clip_poses(cfg, body)
    h = meta["sim"]["size"] / meta["sim"]["resolution"] / round(cfg.gt_particles_per_cell ** (1 / 3))
    gate = soft_tissue_gate(body, S.body_points(body, meta["body"]["simulated_bones"], h), cfg.soft_layer)  # a bad
    # layer is refused now, not after the spin clip's render
    with atomic_folder(out, own=DATA_DIR_FILES) as tmp:
        (tmp / "scene.json").write_text(json.dumps(meta, indent=1))
        total = cfg.frames + cfg.novel_frames - 2
        truth, offset, preview = {}, 0, None
        if cfg.spin_frames >= 2:  # spin clip: LBS only, the object at rest (seed §4.1, §5.1)
            sp = spin_poses(body, cfg)
            np.savez(tmp / "spin_poses.npz", **sp)
            sim = meta["sim"]
            h = sim["size"] / sim["resolution"] / round(cfg.gt_particles_per_cell ** (1 / 3))
            Xo, _ = S.object_points(meta, h)
            Xh = S.body_points(body, meta["body"]["simulated_bones"], h)
            xh, _ = S.skin_sequence(body, Xh, sp["rotations"], sp["root_translation"])
            _render_clip(cfg, meta, body, sp, np.broadcast_to(Xo, (cfg.spin_frames, *Xo.shape)), xh, Xo, h,
                         tmp / "spin")
        for name, poses in clips.items():
            np.savez(tmp / (f"{name}_poses.npz" if name else "poses.npz"), **poses)
            r = simulate_clip(cfg, meta, body, poses, progress, offset, total, gate=gate)
            xo = r["xo"]
            offset += len(xo) - 1
            frames = _render_clip(cfg, meta, body, poses, xo, r["xh"], r["Xo"], r["h"], tmp / name if name else tmp)
            key = name or "dynamic"
            truth[f"{key}_max_displacement"] = np.linalg.norm(xo - xo[:1], axis=2).max(1)
            truth[f"{key}_mean_displacement"] = np.linalg.norm(xo - xo[:1], axis=2).mean(1)
            truth[f"{key}_object_positions"] = xo.astype(np.float32)
            if not name:
                for k in ("E", "fiber", "fiber_E", "part"):
                    truth[k] = r[k]
                truth["rest_positions"] = r["Xo"]
                preview = frames
        np.savez(tmp / "truth.npz", **truth)
        write_mp4(tmp / "video.mp4", preview, cfg.fps)
    return out


__all__ = ["SynthConfig", "generate", "load_synth_config"]
