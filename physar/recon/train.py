r"""Training pipeline of seed 002 §4 (PhysHO), reduced to what runs on a small CPU, and its baselines.

Stages (``fit``):

1. **appearance** (§4.1, Eq. 5): Gaussians = MPM particles of the object and of the simulated body part,
   plus LBS-driven Gaussians of the rest of the body.  Canonical Gaussians: their colours (SH degree 0),
   opacities and scales are fitted on the **spin clip** (``spin/``) with fixed skinning (:math:`F` = the LBS
   rotation blend, object at rest), :math:`L_\text{RGB} = |I - I^*|_1` (+ a mask term); then the
   **physics-aware fine-tuning** renders the spin clip with the deformation gradients of Alg. 1 run with
   :math:`\sigma = 0` on the central-difference velocities (Eq. 4, :mod:`physar.recon.canonical`) and refits
   the same parameters (Eq. 5).  Without a spin clip, frame 0 of the dynamic clip is used.  The canonical
   geometry (object boxes, body model, poses) is read from ``scene.json``/``poses.npz`` (the synthetic scenes
   give it).
2. **flow**: (a) the **4DGS-like baseline**: per-frame object positions optimised with RGB + mask losses and
   an edge-length rigidity term (:math:`F` from a least-squares fit to lattice neighbours enters Eq. 3); it
   cannot predict (it holds the last observed frame).  (b) the **structure-preserving 3-D flow** of §4.4,
   Eq. 9 (:mod:`physar.recon.flow`): per-frame positions :math:`x'_n` optimised with RGB + mask, OpenCV-DIS
   optical flow between consecutive observed frames, ARAP w.r.t. the rest lattice and (not in the seed) a
   penalty on motion along the camera rays, which the 2-D flow does not observe (``lambda_ray``); each frame
   starts from the previous two extrapolated at constant velocity; :math:`x'_n` supervises stage 3.
3. **physics** (§4.2-4.4, Eq. 6-11, Alg. 2): per-particle Young's modulus :math:`E` of the object
   (log-parameterised), its Poisson ratio :math:`\nu`
   (:math:`\nu_\text{min} + (\nu_\text{max} - \nu_\text{min}) \operatorname{sigmoid}(z)`, bounds 0.2-0.4 of
   seed App. B), the Young's modulus of the simulated body particles and the LBS-impact factor :math:`\omega`
   of the simulated body particles (:math:`\omega = g_i\, 2 \operatorname{sigmoid}(l_i)`, :math:`g_i = 1`
   inside the body deeper than the surface layer ``surface_layer``, 0 on that layer and on the object: object
   particles are never actuated) are learned through the differentiable MPM (:mod:`physar.mpm.torch_bridge`;
   the PD force of Eq. 6-7 held over each frame's substeps as in Alg. 2, gains ``kp``/``kd``) and the
   rasteriser with

   .. math::

       L_\text{E2E} = \lambda_\text{rgb} |I - I^*|_1 + \lambda_\text{mask} |A - M|_1
       + \lambda_\text{3Dflow} |x_{n+1} - x'_{n+1}|_1 \quad \text{(Eq. 10)} \quad + R

   (:math:`R`: Eq. 11 and :math:`R_\text{feat}` of App. A, :func:`physics_regulariser`); with ``residual``
   the residual laws :math:`E_\theta` and :math:`P_\theta` of Eq. 8 (latents :math:`l_e, l_p`), truncated by
   Eq. 12 at inference.  Simulated bones: those of ``scene.json`` and every bone whose posed capsule reaches
   the object (both hands when both touch it, :func:`physar.recon.scene.reaching_bones`); :math:`\log E` and
   the :math:`\nu` logits live on a coarse voxel grid interpolated trilinearly to the particles (the
   "material space" of seed App. C.3) unless ``material_grid`` is 0; progressive (the frame window grows
   every ``window_grow_every`` iterations) and loss-balanced (each frame's loss is weighted by its previous
   loss relative to the mean).

Baselines in the same harness: ``lbs`` (kinematic: the body follows LBS, the object never moves) and
``4dgs`` (stage 2's per-frame positions).  Prediction (``predict``) runs the learned simulator on any pose
sequence (future frames of the clip, or a novel action).

Outputs users load are npz/PLY/JSON/MP4 (no pickle); ``checkpoint.pt`` (torch.save of tensors) is only for
resuming an interrupted ``fit``.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
import warnings
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from scipy.spatial import cKDTree

from physar.errors import ConfigError, PhysarError, PhysarWarning, refuse_coercion
from physar.gaussians import Camera, Gaussians, render, rgb_to_sh0, save_ply
from physar.gaussians.rasterize import RenderResult
from physar.mpm import torch_bridge as tb
from physar.mpm.model import MPMModel, device_name, resolve_device
from physar.output import atomic_path, check_folder, write_json, write_npz
from physar.recon import scene as S
from physar.recon.io import read_pngs, write_mp4

MODEL_FORMAT = 2
CHECKPOINT_FORMAT = 1  # checkpoint.pt / stages.pt: _state_dict + format + data_hash (data_fingerprint)
Progress = Callable[[str, int, int, float], None]


MAX_MATERIAL_NODES = 4096  # train.material_grid: nodes in all (16^3); each is a column of a dense (N, G) matrix
MAX_LATENT_DIM = 1024  # train.latent_dim (the seed: 64, App. A.2); the latents are two (N, latent_dim) float64
# arrays (N: the particles the residual laws act on, residual_on)


class TrainConfig(BaseModel):
    """Training settings (TOML table [train]); lengths in m; numbers must be finite (inf is refused as nan is)."""

    @model_validator(mode="after")
    def _check_nu(self):
        if not self.nu_min < self.nu_max:
            raise ValueError(f"nu_min ({self.nu_min}) must be < nu_max ({self.nu_max})")
        if not self.E_min < self.E_max:
            raise ValueError(f"E_min ({self.E_min:g} Pa) must be < E_max ({self.E_max:g} Pa)")
        if not self.E_min <= self.E_init <= self.E_max:
            raise ValueError(f"E_init ({self.E_init:g} Pa) must be in [E_min, E_max] = [{self.E_min:g}, "
                             f"{self.E_max:g}] Pa")
        if self.nu_init is not None and not self.nu_min <= self.nu_init <= self.nu_max:
            raise ValueError(f"nu_init ({self.nu_init:g}) must be in [nu_min, nu_max] = [{self.nu_min:g}, "
                             f"{self.nu_max:g}]")
        return self

    @field_validator("particles_per_cell")
    @classmethod
    def _per_cell(cls, value):
        from physar.recon.synth import check_particles_per_cell

        return check_particles_per_cell(value)

    @field_validator("body_spacing")
    @classmethod
    def _spacing(cls, value):
        from physar.recon.synth import BODY_VOLUME, check_sample_count

        return check_sample_count(value, BODY_VOLUME, 3, "kinematic body Gaussians")

    @field_validator("material_grid")
    @classmethod
    def _material_grid(cls, value):
        if any(k != 0 for k in value) and any(k < 1 for k in value):
            raise ValueError(f"{list(value)}: use >= 1 node per axis, or [0, 0, 0] (one value per particle)")
        nodes = math.prod(value)
        if nodes > MAX_MATERIAL_NODES:
            raise ValueError(f"{list(value)} is {nodes:.3g} nodes: the trilinear weights (a dense particles x nodes "
                             f"float64 matrix) would take {8 * nodes / 2**20:.3g} MiB per object particle; use at "
                             f"most {MAX_MATERIAL_NODES} nodes (a coarse material space), or [0, 0, 0] (one value "
                             "per particle)")
        return value

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    @field_validator("*", mode="before")
    @classmethod
    def _no_coercion(cls, value, info):  # E = true, E = "69e9" and cells = ["40", 2, 2] are errors, not numbers
        return refuse_coercion(value, cls.model_fields[info.field_name].annotation)

    @field_validator("render_device", "mpm_device")
    @classmethod
    def _device_name(cls, value):
        return device_name(value)

    particles_per_cell: int = Field(1, description="object/body MPM particles per grid cell: 1, 8, 27 or 64")
    body_spacing: float = Field(0.03, gt=0, le=0.1, description="spacing of the kinematic body Gaussians (at most "
                                "2e6 of them in the body's volume: >= 3.7 mm; <= 0.1 m, coarser misses limbs) [m]")
    appearance_iters: int = Field(150, ge=0, description="Adam iterations of the canonical appearance fit on the "
                                                         "spin clip (§4.1, Eq. 5)")
    appearance_lr: float = Field(0.05, gt=0, description="Adam step of the appearance fit on colours, opacity "
                                                         "logits and log scales (0.3 of it in the fine-tuning) [-]")
    finetune_iters: int = Field(60, ge=0, description="physics-aware fine-tuning on the spin clip (Eq. 4-5)")
    spin_stride: int = Field(1, ge=1, description="use every k-th spin frame")
    render_device: str = Field("cpu", description="torch device of the Gaussian rasteriser: 'cpu' (tile backend) "
                               "or 'cuda'/'cuda:N' (gsplat when installed, else the tile backend on the GPU); images "
                               "come back to the CPU, the rest of training stays there")
    mpm_device: str = Field("cpu", description="Warp device of the MPM ('cpu', 'cuda' or 'cuda:N'); the torch tensors "
                            "of training stay on the CPU, the bridge copies them to and from it")
    flow_iters: int = Field(30, ge=0, description="per frame (Eq. 9; also the 4DGS-like baseline)")
    flow_lr: float = Field(2e-3, gt=0, description="Adam step on positions, m")
    rigidity: float = Field(1.0e3, ge=0, description="4DGS-like baseline: weight of the edge-length term, 1/m^2")
    spflow_iters: int = Field(30, ge=0, description="per frame, structure-preserving 3-D flow (Eq. 9)")
    lambda_of: float = Field(3.0, ge=0, description="Eq. 9 optical-flow (DIS) term [1/px]")
    lambda_arap: float = Field(3.0e5, ge=0, description="Eq. 9 ARAP term, 1/m^2")
    lambda_ray: float = Field(3.0e5, ge=0, description="Eq. 9 addition (not in the seed): squared motion along "
                              "the camera rays, which the 2-D flow does not observe [1/m^2]")
    physics_iters: int = Field(40, ge=0, description="Adam iterations of the physics stage (§4.2-4.4, Alg. 2)")
    physics_lr: float = Field(0.15, gt=0, description="Adam step on log E, the nu logits, the omega logits (unless "
                              "learn_omega is false) and log E of the body [-]")
    appearance_refit_iters: int = Field(150, ge=0, description="after the physics stage: Adam iterations of one "
                                        "shared appearance refit per method (physics, LBS-only, the per-frame "
                                        "fits) on the observed dynamic frames, that method's motion held fixed; "
                                        "0 = render every method with the spin clip's appearance (seed §4). "
                                        "physar's stage, not in the seed")
    appearance_refit_colours_only: bool = Field(True, description="the refit changes the SH colours only; opacity "
                                                "and scales stay as the spin clip fitted them, so no method can "
                                                "reshape its silhouette to stand in for motion (false: all three)")
    E_init: float = Field(6.0e3, gt=0, description="initial Young's modulus of the object, Pa")
    E_min: float = Field(5.0e2, gt=0, description="lower bound of the learned Young's moduli (object and body) "
                                                  "[Pa]")
    E_max: float = Field(3.0e4, gt=0, description="upper bound of the learned Young's moduli (keeps the explicit "
                                                  "MPM step stable) [Pa]")
    learn_nu: bool = Field(True, description="learn a spatially varying Poisson ratio (seed 002 §4.3, App. B)")
    nu_min: float = Field(0.2, gt=-1, lt=0.5, description="lower bound of the learned Poisson ratio (seed App. B) [-]")
    nu_max: float = Field(0.4, gt=-1, lt=0.5, description="upper bound of the learned Poisson ratio (seed App. B) [-]")
    nu_init: float | None = Field(None, gt=-1, lt=0.5, description="initial Poisson ratio of the object [-] "
                                  "(default: the scene's object.nu, clipped to [nu_min, nu_max]; a value given here must lie in them)")
    material_grid: tuple[int, int, int] = Field((4, 3, 2), description="voxel nodes of the log E field per "
                                                "axis over the object box; (0, 0, 0): one value per particle")
    omega_init: float = Field(1.0, gt=0, lt=2, description="initial LBS-impact factor omega of the actuated body "
                                                           "particles (omega = 2 sigmoid(l), in (0, 2)) [-]")
    kp: float = Field(2.0e2, ge=0, description="PD gain of Eq. 6 [1/s^2] (mass-scaled; seed App. A.3: 2e2)")
    kd: float = Field(2.0e1, ge=0, description="PD gain of Eq. 6 [1/s] (mass-scaled; seed App. A.3: 2e1)")
    pd_hold: bool = Field(True, description="PD force evaluated once per frame and held over its substeps "
                          "(seed Alg. 2); false: recomputed every substep")
    surface_layer: float | None = Field(None, ge=0, description="omega = 0 on body particles within this depth "
                                        "of the body surface (seed §4.2) [m]; default: half the particle spacing")
    reach_margin: float | None = Field(None, ge=0, description="bones whose posed capsule comes this close to the "
                                       "object are simulated and actuated [m]; default: one grid cell")
    learn_human_E: bool = Field(True, description="learn the Young's modulus of the simulated body particles")
    learn_omega: bool = Field(True, description="learn the LBS-impact factors omega of the actuated body particles "
                              "(Eq. 7); false keeps omega_init (and the omega = 0 layer), and lambda_omega then has no effect")
    window_start: int = Field(3, ge=2, description="frames in the first training window (progressive)")
    window_grow_every: int = Field(4, ge=1, description="iterations between window extensions")
    loss_balanced: bool = Field(True, description="weight each frame's loss by its previous loss relative to the "
                                                  "mean (progressive training)")
    lambda_rgb: float = Field(1.0, ge=0, description="weight of the mean L1 colour loss (Eq. 10, also Eq. 5 and "
                                                     "Eq. 9) [-]")
    lambda_mask: float = Field(1.0, ge=0, description="weight of the mean L1 mask loss (Eq. 10, also Eq. 5 and "
                                                      "Eq. 9) [-]")
    lambda_flow: float = Field(20.0, ge=0, description="3-D flow term of Eq. 10 (vs the Eq. 9 flow), 1/m")
    flow_target: Literal["all", "visible", "observed"] = Field(
        "observed", description="which part of the Eq. 9 flow the Eq. 10 term compares: observed (the particles "
        "visible in the previous frame, whose motion into this one the optical flow saw, and only their motion "
        "across the camera rays; physar's default) | visible (those particles, every coordinate) | all (every "
        "coordinate of every object particle, as the seed writes Eq. 10). The rest of the Eq. 9 flow is ARAP's "
        "extrapolation and the ray term's prior, less accurate than the simulator (benchmarks/RESULTS.md, issue 17)")
    lambda_omega: float = Field(1.0e-5, ge=0, description="Eq. 11 weight of |omega| (per-pixel mean losses: keep "
                                                          "it small) [-]")
    residual: bool = Field(False, description="neural residual laws E_theta, P_theta with latents (Eq. 8)")
    residual_plastic: bool = Field(True, description="with residual: the plastic residual P_theta too (Eq. 8)")
    latents: bool = Field(True, description="per-particle latents l_e, l_p of the residual laws (ablation: False)")
    residual_rest_free: bool = Field(False, description="with residual: subtract each network's output at F = I "
                                     "(same latent), so the residual laws neither stress undeformed material nor "
                                     "drift its F (physar's option, not in the seed)")
    residual_objective: bool = Field(True, description="with residual: frame-indifferent residual laws (material-"
                                     "frame outputs pushed forward by F, physar.mpm.neural); false: physar's world-"
                                     "frame form before 2026-11-29 (models fitted before the option load with it)")
    residual_on: Literal["all", "object"] = Field(
        "all", description="with residual: the particles the residual laws act on: all (object and body, the "
        "form before the option) | object (the body keeps its expert law; latents, and the Eq. 11 law term, for "
        "the object only)")
    latent_dim: int = Field(16, ge=1, le=MAX_LATENT_DIM, description="size of each particle's latents l_e, l_p (Eq. 8)")
    render_deformation: Literal["none", "state", "positions"] = Field(
        "none", description="deformation gradient that shapes the object's Gaussians whenever the object is "
        "rendered (every method, its fit and its evaluation: the Eq. 9 flow stages, physics, refit, predict): none (F = I: the Gaussians move "
        "with their particles, undeformed; physar's default) | state (seed Eq. 4: the simulator's F, the elastic "
        "part after the plastic return map; a per-frame fit uses its least-squares F) | positions (the total "
        "deformation, least squares over lattice neighbours as in the Eq. 9 flow stage). The canonical Gaussians "
        "are fitted on the spin clip at rest and come out long and thin; deformed by F they smear, and the loss "
        "then prefers a motion 3 mm further from the truth than the true one (benchmarks/RESULTS.md, issue 17)")
    net_lr: float = Field(1.0e-3, gt=0, description="Adam step of the residual network and the latents [-]")
    lambda_law: float = Field(1.0e-4, ge=0, description="Eq. 11 weight of the residual magnitudes |E_theta| (a "
                                                        "stress, Pa) and |P_theta| (dimensionless): loss per unit "
                                                        "of each")
    lambda_feat: float = Field(1.0e-4, ge=0, description="App. A weight of the latent magnitudes |l_e|, |l_p| [-]")
    checkpoint_every: int = Field(5, ge=1, description="physics iterations between checkpoints")
    seed: int = Field(0, ge=0, le=2**63 - 1, description="seed of torch's random draws (initial residual networks and latents, "
                                     "the spin frames sampled by the appearance fit)")


def load_train_config(path: str | Path | None, overrides: dict | None = None) -> TrainConfig:
    """Config from a TOML file (table [train] or top level) and overrides; one-line errors."""
    from physar.recon.synth import load_section_config

    return load_section_config(path, "train", TrainConfig, overrides)


# ----------------------------------------------------------------------------------------------- data
@dataclass
class Dataset:
    """A DATA_DIR: images (F, H, W, 3) and masks (F, H, W) in [0, 1], poses, optional novel clip/truth."""

    root: Path
    meta: dict
    rgb: np.ndarray
    mask: np.ndarray
    rotations: np.ndarray
    root_t: np.ndarray
    novel: dict | None = None
    truth: dict | None = None
    spin: dict | None = None

    @property
    def n_obs(self) -> int:
        return int(self.meta["n_obs"])


def load_dataset(path: str | Path, with_truth: bool = True) -> Dataset:
    """Read a scene folder written by ``physar recon synth`` (``truth.npz`` too when ``with_truth``)."""
    root = Path(path)
    sj = root / "scene.json"
    if not sj.exists():
        raise ConfigError(f"'{root}': DATA_DIR not found" if not Path(root).exists() else
                          f"'{root}' is not a recon DATA_DIR: missing scene.json")
    try:
        meta = json.loads(sj.read_text())
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{sj}: invalid JSON: {exc}") from None
    for key in ("camera", "sim", "body", "object", "n_obs", "fps"):
        if key not in meta:
            raise ConfigError(f"{sj}: missing field '{key}'")
    if meta.get("format_version") != S.FORMAT_VERSION:
        raise ConfigError(f"{sj}: format_version {meta.get('format_version')} (expected {S.FORMAT_VERSION})")
    S.check_meta(meta, str(sj))
    body = S.load_body(meta, str(sj))
    nb = body.skeleton.n_bones
    rot, rt = S.check_poses(_npz(root / "poses.npz"), nb, str(root / "poses.npz"))
    n = len(rot)
    if not 2 <= meta["n_obs"] <= n:
        raise ConfigError(f"{sj}: n_obs = {meta['n_obs']} must be in [2, {n}]")
    wh = (meta["camera"]["width"], meta["camera"]["height"])
    rgb, mask = read_pngs(root / "rgb", n, size=wh), read_pngs(root / "mask", n, gray=True, size=wh)
    novel = None
    if (root / "novel_poses.npz").exists():
        r2, t2 = S.check_poses(_npz(root / "novel_poses.npz"), nb, str(root / "novel_poses.npz"))
        novel = {"rotations": r2, "root_t": t2, "rgb": read_pngs(root / "novel" / "rgb", len(r2), size=wh),
                 "mask": read_pngs(root / "novel" / "mask", len(r2), gray=True, size=wh)}
    truth = None
    if with_truth and (root / "truth.npz").exists():
        truth = check_truth(_npz(root / "truth.npz"), n, None if novel is None else len(novel["rgb"]),
                            root / "truth.npz")
    spin = None
    if (root / "spin_poses.npz").exists():
        r3, t3 = S.check_poses(_npz(root / "spin_poses.npz"), nb, str(root / "spin_poses.npz"))
        spin = {"rotations": r3, "root_t": t3, "rgb": read_pngs(root / "spin" / "rgb", len(r3), size=wh),
                "mask": read_pngs(root / "spin" / "mask", len(r3), gray=True, size=wh)}
    return Dataset(root, meta, rgb, mask, rot, rt, novel, truth, spin)


def check_truth(truth: dict, n: int, n_novel: int | None, path: Path) -> dict:
    """The arrays of a DATA_DIR's ``truth.npz`` that :func:`evaluate` reads, checked (ConfigError naming the file
    and the array): fine rest positions (N, 3), E (N,) > 0, the per-frame maximum object displacement of the
    dynamic clip (n,) and of the novel clip (n_novel,) when there is one, the fine object positions (n, N, 3)
    when stored; all finite."""
    N = np.shape(truth.get("rest_positions", np.zeros((0, 3))))[0]
    want = {"rest_positions": (N, 3), "E": (N,), "dynamic_max_displacement": (n,)}
    if n_novel is not None:
        want["novel_max_displacement"] = (n_novel,)
    if "dynamic_object_positions" in truth:
        want["dynamic_object_positions"] = (n, N, 3)
    for k, shape in want.items():
        if k not in truth:
            raise ConfigError(f"{path}: missing array '{k}' {shape}")
        a = np.asarray(truth[k])
        if a.dtype.kind not in "fiu" or a.shape != shape or not np.all(np.isfinite(a)):
            raise ConfigError(f"{path}: array '{k}' must be {shape} finite numbers, got {a.shape} {a.dtype}"
                              + (" with non-finite values" if a.dtype.kind in "fiu" and a.shape == shape else ""))
    if N == 0 or np.any(np.asarray(truth["E"]) <= 0):
        raise ConfigError(f"{path}: array 'E' must hold positive moduli [Pa] of at least one particle")
    return truth


def _npz(path: Path) -> dict:
    if not path.exists():
        raise ConfigError(f"missing file '{path}'")
    try:
        d = np.load(path, allow_pickle=False)
        arrays = None
        if isinstance(d, np.lib.npyio.NpzFile):
            with d:
                arrays = {k: d[k] for k in d.files}
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        detail = "not a NumPy .npz archive" if "pickle" in str(exc) else " ".join(str(exc).split())[:120]
        raise ConfigError(f"'{path}' is not a readable npz file ({detail})") from None
    if arrays is None:
        raise ConfigError(f"'{path}' is not a readable npz file (a single .npy array)")
    return arrays


# ----------------------------------------------------------------------------------------------- rig
_DEVICE_FIELDS = ("render_device", "mpm_device")


def check_render_device(device: str) -> None:
    """ConfigError naming ``train.render_device`` when torch cannot use that CUDA device."""
    n = torch.cuda.device_count() if torch.cuda.is_available() else 0
    idx = int(device.split(":")[1]) if ":" in device else 0
    if idx >= n:
        raise ConfigError(f"train.render_device = {device!r}: torch sees {n} CUDA device(s)"
                          + ("" if n else " (a CPU-only torch build or no GPU); use 'cpu'"))


def _usable_devices(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with each device field this machine cannot use set to "cpu" (one warning line): a model fitted on a
    GPU renders and predicts on a CPU-only machine, with the same results (to 2e-13)."""
    upd = {}
    for name in _DEVICE_FIELDS:
        dev = getattr(cfg, name)
        if dev == "cpu":
            continue
        try:
            if name == "render_device":
                check_render_device(dev)
            else:
                resolve_device(dev)
        except ConfigError:
            upd[name] = "cpu"
    if upd:
        warnings.warn(f"the model was fitted with {', '.join(f'{k} = {getattr(cfg, k)!r}' for k in upd)}, which "
                      "this machine does not have: using the CPU", PhysarWarning, stacklevel=3)
    return cfg.model_copy(update=upd)


class Rig:
    """Particles, MPM model, camera and LBS machinery of a scene at the reconstruction's sampling.

    ``poses`` = (rotations, root translations) of the clip: the simulated bones are those of ``scene.json``
    plus every bone whose LBS impact reaches the object in that clip (:func:`physar.recon.scene.reaching_bones`,
    margin ``cfg.reach_margin``) and whose particles stay in the MPM domain; ``self.meta`` records the list
    (a saved model rebuilds the same rig)."""

    def __init__(self, meta: dict, cfg: TrainConfig, poses: tuple[np.ndarray, np.ndarray] | None = None):
        k = round(cfg.particles_per_cell ** (1 / 3))
        if k**3 != cfg.particles_per_cell:
            raise ConfigError(f"train.particles_per_cell = {cfg.particles_per_cell} must be 1, 8, 27 or 64")
        self.cfg = cfg
        if cfg.render_device != "cpu":
            check_render_device(cfg.render_device)
        sim = meta["sim"]
        self.body = S.load_body(meta)
        self.origin = np.asarray(sim["origin"], dtype=np.float64)
        dx = sim["size"] / sim["resolution"]
        self.h = h = dx / k
        lo, hi = S.object_box(meta)
        self.Xo, vol_o = S.object_points(meta, h)  # the canonical shape: the same sampler as the generator
        bones = list(meta["body"]["simulated_bones"])
        if poses is not None:
            margin = dx if cfg.reach_margin is None else cfg.reach_margin
            bones, leaving = S.simulated_bones(self.body, meta, *poses, margin, h)
            if not bones:
                if leaving:
                    raise ConfigError("scene.json: " + S.domain_problem(self.body, meta, leaving, *poses, h))
                raise ConfigError("scene.json: no bone of the body comes within the reach margin "
                                  f"({margin:.3f} m) of the object in the dynamic clip (poses, camera or object "
                                  "placement wrong? `physar recon check` lists the reaching bones)")
        self.meta = {**meta, "body": {**meta["body"], "simulated_bones": bones}}
        self.Xh = S.capsule_points(self.body, bones, h)
        if len(self.Xh) == 0:
            raise ConfigError(f"no body particles inside {bones} at spacing {h:.3f} m: raise particles_per_cell")
        self.no, self.nh = len(self.Xo), len(self.Xh)
        n = self.no + self.nh
        # gating mask of Eq. 7 (seed §4.2): 1 strictly inside the body deeper than the surface layer, 0 on the
        # layer at the body's surface (within ``surface_layer`` of it) and on the object
        layer = 0.5 * h if cfg.surface_layer is None else cfg.surface_layer
        self.gate = (self.body.signed_distance(torch.as_tensor(self.Xh)) < -layer).to(torch.float64)
        c = meta["camera"]
        self.cam = Camera(c["fx"], c["fy"], c["cx"], c["cy"], int(c["width"]), int(c["height"]),
                          torch.tensor(c["R"], dtype=torch.float32), torch.tensor(c["t"], dtype=torch.float32))
        self.background = torch.tensor(meta.get("background", [0.0, 0.0, 0.0]), dtype=torch.float32)
        names = [b for b in self.body.volume_bones() if b not in bones]
        Xb = S.capsule_points(self.body, names, cfg.body_spacing, exclude=bones)
        self.Xb = Xb[self._in_view(Xb)]
        self.nb = len(self.Xb)
        od, hd = meta["object"]["density"], meta["body"]["density"]
        nu = meta["object"]["nu"]
        if cfg.mpm_device != "cpu":
            try:
                resolve_device(cfg.mpm_device)
            except ConfigError as exc:
                raise ConfigError(f"train.mpm_device = {cfg.mpm_device!r}: {exc}") from None
        self.model = MPMModel(
            size=sim["size"], resolution=sim["resolution"], dt=1.0 / meta["fps"] / sim["substeps"],
            substeps=sim["substeps"], mass=np.r_[np.full(self.no, vol_o * od), np.full(self.nh, h**3 * hd)],
            volume=np.r_[np.full(self.no, vol_o), np.full(self.nh, h**3)],
            E=np.r_[np.full(self.no, cfg.E_init), np.full(self.nh, meta["body"]["E"])], nu=np.full(n, nu),
            elastic=np.zeros(n), plastic=np.zeros(n), plastic_params=np.zeros((n, 4)),
            body=np.r_[np.zeros(self.no), np.ones(self.nh)], gravity=tuple(sim["gravity"]),
            walls=sim.get("walls", {}), device=cfg.mpm_device)
        self.kp, self.kd = float(cfg.kp), float(cfg.kd)  # the reconstruction's gains (not the generator's)
        if cfg.pd_hold and 2.0 * self.kd * self.model.frame_dt >= 2.0:
            raise ConfigError(f"train.kd = {self.kd:g} 1/s: a PD force held over a frame of {self.model.frame_dt:.3g} s "
                              f"is unstable for omega kd dt >= 2 (omega <= 2); lower kd below "
                              f"{1.0 / self.model.frame_dt:.3g} 1/s or set pd_hold = false")
        self.nu = torch.full((n,), nu, dtype=torch.float64)
        self.E_human = torch.full((self.nh,), float(meta["body"]["E"]), dtype=torch.float64)
        # lattice neighbours of the object (rigidity term, least-squares F)
        pairs = cKDTree(self.Xo).query_pairs(1.01 * math.sqrt(3) * h, output_type="ndarray")
        self.pairs = torch.as_tensor(pairs, dtype=torch.long)
        X = torch.as_tensor(self.Xo)
        d = X[self.pairs[:, 1]] - X[self.pairs[:, 0]]
        self.rest_len = torch.linalg.vector_norm(d, dim=1)
        B = torch.zeros(self.no, 3, 3, dtype=torch.float64)
        dd = d[:, :, None] * d[:, None, :]
        B.index_add_(0, self.pairs[:, 0], dd)
        B.index_add_(0, self.pairs[:, 1], dd)
        self.B_inv = torch.linalg.inv(B + 1e-12 * torch.eye(3, dtype=torch.float64))
        self.material_W = _trilinear_matrix(self.Xo, lo, hi, cfg.material_grid)

    def _in_view(self, X: np.ndarray, margin: float = 0.3) -> np.ndarray:
        K, R, t = S.camera_matrices(self.meta)
        p = X @ R.T + t
        z = np.maximum(p[:, 2], 1e-6)
        u, v = K[0, 0] * p[:, 0] / z + K[0, 2], K[1, 1] * p[:, 1] / z + K[1, 2]
        W, H = self.cam.width, self.cam.height
        return (p[:, 2] > 0.01) & (u > -margin * W) & (u < (1 + margin) * W) & (v > -margin * H) & (v < (1 + margin) * H)

    def kinematics(self, rotations: np.ndarray, root: np.ndarray) -> dict:
        """LBS trajectories (torch float64, world): human particle refs/velocities/A_rot, body Gaussians."""
        ref, Ah = S.skin_sequence(self.body, self.Xh, rotations, root)
        xb, Ab = S.skin_sequence(self.body, self.Xb, rotations, root)
        vref = S.central_velocities(ref, 1.0 / self.meta["fps"])
        t = lambda a: torch.as_tensor(a, dtype=torch.float64)
        return {"ref": t(ref), "vref": t(vref), "A_h": t(Ah), "xb": t(xb), "A_b": t(Ab), "frames": len(ref)}

    def deformation_from_neighbours(self, x: torch.Tensor) -> torch.Tensor:
        r"""Least-squares
        :math:`F_i = \big(\sum_j dx_{ij}\, dX_{ij}^\top\big) \big(\sum_j dX_{ij}\, dX_{ij}^\top\big)^{-1}`
        over lattice neighbours :math:`j`."""
        X = torch.as_tensor(self.Xo)
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        dX, dx = X[j] - X[i], x[j] - x[i]
        P = dx[:, :, None] * dX[:, None, :]
        A = torch.zeros(self.no, 3, 3, dtype=x.dtype).index_add(0, i, P).index_add(0, j, P)
        return A @ self.B_inv

    def rigidity(self, x: torch.Tensor) -> torch.Tensor:
        d = x[self.pairs[:, 1]] - x[self.pairs[:, 0]]
        return ((torch.linalg.vector_norm(d, dim=1) - self.rest_len) ** 2).mean()


def _trilinear_matrix(X: np.ndarray, lo, hi, nodes) -> torch.Tensor | None:
    """(N, G) trilinear interpolation weights of points X from a node grid spanning the box [lo, hi]
    (``nodes`` per axis, >= 2; an axis with 1 node is constant); None for a per-particle field."""
    nodes = tuple(int(k) for k in nodes)
    if all(k == 0 for k in nodes):
        return None
    if any(k < 1 for k in nodes):
        raise ConfigError(f"train.material_grid = {nodes}: use >= 1 node per axis, or (0, 0, 0)")
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    per_axis = []
    for a, k in enumerate(nodes):
        if k == 1:
            per_axis.append(np.ones((len(X), 1)))
            continue
        s = np.clip((X[:, a] - lo[a]) / (hi[a] - lo[a]), 0, 1) * (k - 1)
        i0 = np.minimum(np.floor(s).astype(int), k - 2)
        t = s - i0
        w = np.zeros((len(X), k))
        w[np.arange(len(X)), i0] = 1 - t
        w[np.arange(len(X)), i0 + 1] += t
        per_axis.append(w)
    W = np.einsum("ni,nj,nk->nijk", *per_axis).reshape(len(X), -1)
    return torch.as_tensor(W, dtype=torch.float64)


@dataclass
class Appearance:
    """Per-Gaussian appearance over [object | simulated body | kinematic body] (float32 tensors)."""

    sh: torch.Tensor
    opacity_logits: torch.Tensor
    log_scales: torch.Tensor

    @classmethod
    def init(cls, rig: Rig) -> Appearance:
        n = rig.no + rig.nh + rig.nb
        s = np.r_[np.full(rig.no + rig.nh, 0.5 * rig.h), np.full(rig.nb, 0.5 * rig.cfg.body_spacing)]
        return cls(rgb_to_sh0(torch.full((n, 1, 3), 0.5)), torch.full((n,), 1.5),
                   torch.log(torch.as_tensor(s, dtype=torch.float32))[:, None].repeat(1, 3))

    def params(self):
        return [self.sh, self.opacity_logits, self.log_scales]


def render_scene(rig: Rig, app: Appearance, x_obj, F_obj, x_hum, F_hum, x_kin, A_kin):
    """Render one frame: positions (world, m) and deformation gradients of the three Gaussian groups (Eq. 3); the
    object's F (the simulator's, or None for per-frame positions: their least-squares F, computed only when the
    rule uses it) passes through the run's rule :func:`object_deformation` first."""
    F_obj = object_deformation(rig, x_obj, F_obj)
    means = torch.cat([x_obj, x_hum, x_kin]).float()
    F = torch.cat([F_obj, F_hum, A_kin]).float()
    n = means.shape[0]
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1.0
    g = Gaussians(means, quats, app.log_scales, app.opacity_logits, app.sh)
    dev = rig.cfg.render_device
    if dev == "cpu":
        return render(g, rig.cam, F=F, background=rig.background)
    # differentiable copies to the GPU and back (autograd carries the gradients across); backend "auto"
    # takes gsplat there when it imports (checked against the tile backend: benchmarks/gpu_check_gsplat.py)
    res = render(g.to(dev), rig.cam, F=F.to(dev), background=rig.background)
    return RenderResult(res.rgb.cpu(), res.alpha.cpu(), res.depth.cpu())


def image_loss(res, rgb_gt: torch.Tensor, mask_gt: torch.Tensor, cfg: TrainConfig) -> torch.Tensor:
    """Weighted L1 loss of a render against the images and masks (``lambda_rgb``, ``lambda_mask``)."""
    return cfg.lambda_rgb * (res.rgb - rgb_gt).abs().mean() + cfg.lambda_mask * (res.alpha - mask_gt).abs().mean()


# ----------------------------------------------------------------------------------------------- physics
@dataclass
class Physics:
    r"""Learned physical parameters: :math:`\log E` of the object (No,), :math:`\omega` logits of the body
    (Nh,), optional neural residual with latents l_e, l_p (No + Nh, latent), or (No, latent) with
    ``residual_on = "object"``."""

    log_E: torch.Tensor
    omega_logit: torch.Tensor
    nets: object = None
    l_e: torch.Tensor | None = None
    nu_logit: torch.Tensor | None = None
    log_E_human: torch.Tensor | None = None  # (Nh,) log Pa, learned when cfg.learn_human_E
    l_p: torch.Tensor | None = None

    @classmethod
    def init(cls, rig: Rig) -> Physics:
        cfg = rig.cfg
        n_e = rig.no if rig.material_W is None else rig.material_W.shape[1]
        le = torch.full((n_e,), math.log(cfg.E_init), dtype=torch.float64)
        w = cfg.omega_init / 2
        ol = torch.full((rig.nh,), math.log(w / (1 - w)), dtype=torch.float64)
        nets = l_e = l_p = None
        if cfg.residual:
            from physar.mpm.neural import NeuralResidual

            torch.manual_seed(cfg.seed)
            nets = NeuralResidual(elastic=True, plastic=cfg.residual_plastic, latent_dim=cfg.latent_dim,
                                  rest_free=cfg.residual_rest_free, objective=cfg.residual_objective)
            if cfg.latents:  # small random latents break the symmetry between particles
                g = torch.Generator().manual_seed(cfg.seed)
                n = rig.no + (rig.nh if cfg.residual_on == "all" else 0)
                l_e = 0.1 * torch.randn(n, cfg.latent_dim, dtype=torch.float64, generator=g)
                if cfg.residual_plastic:
                    l_p = 0.1 * torch.randn(n, cfg.latent_dim, dtype=torch.float64, generator=g)
        nl = None
        if cfg.learn_nu:  # nu = nu_min + (nu_max - nu_min) sigmoid(z) on the same material grid as log E
            nu0 = rig.meta["object"]["nu"] if cfg.nu_init is None else cfg.nu_init
            s = (min(max(nu0, cfg.nu_min), cfg.nu_max) - cfg.nu_min) / (cfg.nu_max - cfg.nu_min)
            s = min(max(s, 1e-3), 1 - 1e-3)
            nl = torch.full((n_e,), math.log(s / (1 - s)), dtype=torch.float64)
        leh = rig.E_human.log().clone() if cfg.learn_human_E else None
        return cls(le, ol, nets, l_e, nl, leh, l_p)

    def material_leaves(self) -> list:
        r""":math:`\log E`, the :math:`\omega` logits, the :math:`\nu` logits and :math:`\log E` of the body
        (the physics_lr group; ``fit`` leaves the omega logits out of it when ``learn_omega`` is false)."""
        return [t for t in (self.log_E, self.omega_logit, self.nu_logit, self.log_E_human) if t is not None]

    def leaves(self):
        out = self.material_leaves()
        if self.nets is not None:
            out += [t for t in (self.l_e, self.l_p) if t is not None] + [*self.nets.parameters()]
        return out

    def E_human(self, rig: Rig) -> torch.Tensor:
        """Young's modulus of the simulated body particles (Nh,), Pa (learned, or the scene's value)."""
        return rig.E_human if self.log_E_human is None else torch.exp(self.log_E_human)

    def E_object(self, rig: Rig) -> torch.Tensor:
        r"""Young's modulus of the object particles (No,), Pa: :math:`\exp` of the (interpolated)
        :math:`\log E` field."""
        return torch.exp(self.log_E if rig.material_W is None else rig.material_W @ self.log_E)

    def nu_object(self, rig: Rig) -> torch.Tensor:
        r"""Poisson ratio of the object particles (No,):
        :math:`\nu_\text{min} + (\nu_\text{max} - \nu_\text{min}) \operatorname{sigmoid}` of the
        (interpolated) logit field, or the scene's value when :math:`\nu` is not learned."""
        if self.nu_logit is None:
            return rig.nu[:rig.no]
        z = self.nu_logit if rig.material_W is None else rig.material_W @ self.nu_logit
        return rig.cfg.nu_min + (rig.cfg.nu_max - rig.cfg.nu_min) * torch.sigmoid(z)

    def omega(self, rig: Rig) -> torch.Tensor:
        r"""Full :math:`\omega` (No + Nh,): 0 on the object,
        :math:`\mathrm{gate} \cdot 2 \operatorname{sigmoid}(l)` on the body (Eq. 7)."""
        return torch.cat([torch.zeros(rig.no, dtype=torch.float64), rig.gate * 2 * torch.sigmoid(self.omega_logit)])

    def params(self, rig: Rig) -> tb.Params:
        """Per-particle parameters of the simulator; with ``residual_on = "object"`` the residual laws act on the
        object particles only (the body's latent rows are zeros, never read)."""
        E = torch.cat([self.E_object(rig), self.E_human(rig)])
        nu = torch.cat([self.nu_object(rig), rig.nu[rig.no:]])
        l_e, l_p, on = self.l_e, self.l_p, None
        if self.nets is not None and rig.cfg.residual_on == "object":
            on = torch.arange(rig.no)
            pad = lambda l: l if l is None else torch.cat([l, l.new_zeros(rig.nh, l.shape[1])])
            l_e, l_p = pad(l_e), pad(l_p)
        return tb.Params(E=E, nu=nu, omega=self.omega(rig), l_e=l_e, l_p=l_p, kp=rig.kp, kd=rig.kd,
                         hold=rig.cfg.pd_hold, residual_on=on)


def object_deformation(rig: Rig, x: torch.Tensor, F: torch.Tensor | None) -> torch.Tensor:
    """The F (No, 3, 3) that shapes the object's Gaussians at positions x, by ``render_deformation``; one rule for
    every render of the object (:func:`render_scene`: every method, its fit and its evaluation): "state": F as
    given (the simulator's, seed Eq. 4), or for F = None (per-frame positions) the least-squares deformation of x;
    "positions": the least-squares deformation of x; "none": I."""
    mode = rig.cfg.render_deformation
    if mode == "none":
        return torch.eye(3, dtype=x.dtype).expand(rig.no, 3, 3)
    if mode == "positions" or F is None:
        return rig.deformation_from_neighbours(x)
    return F


def simulate_clip(rig: Rig, phys: Physics, kin: dict, frames: int, grad: bool = True):
    """Differentiable MPM over ``frames`` frames from the rest object and the LBS body of frame 0.

    Yields per frame n = 1 .. frames-1: (x_obj, F_obj, x_hum, F_hum) in world coordinates, F the simulator's
    (what the Eq. 11 regulariser evaluates; :func:`render_scene` applies the rendering rule).  Without gradients
    (inference) the residual outputs are truncated as in seed Eq. 12."""
    o = torch.as_tensor(rig.origin)
    x = torch.cat([torch.as_tensor(rig.Xo), kin["ref"][0]]) - o
    v = torch.cat([torch.zeros(rig.no, 3, dtype=torch.float64), kin["vref"][0]])
    C = F = Jp = None
    p = phys.params(rig)
    zeros = torch.zeros(rig.no, 3, dtype=torch.float64)
    with torch.set_grad_enabled(grad):
        for f in range(frames - 1):
            p.x_ref = torch.cat([zeros, kin["ref"][f] - o])
            p.v_ref = torch.cat([zeros, kin["vref"][f]])
            _, (x, v, C, F, Jp) = tb.simulate(rig.model, x, v, p, 1, nets=phys.nets, checkpoint=grad,
                                              C0=C, F0=F, Jp0=Jp, truncate=not grad)
            xw = x + o
            yield f + 1, xw[:rig.no], F[:rig.no], xw[rig.no:], F[rig.no:]


# ----------------------------------------------------------------------------------------------- fit
# configuration fields that stages 1-2 depend on (a physics-only variant may reuse those stages)
_PRE_PHYSICS = ("particles_per_cell", "body_spacing", "render_deformation", "appearance_iters", "appearance_lr", "finetune_iters",
                "spin_stride", "flow_iters", "flow_lr", "rigidity", "spflow_iters", "lambda_of", "lambda_arap",
                "lambda_ray", "lambda_rgb", "lambda_mask", "seed")


@dataclass
class FitState:
    stage: str = "appearance"
    iteration: int = 0
    app: Appearance | None = None
    flow: list = field(default_factory=list)  # 4DGS-like baseline: per observed frame object positions
    spflow: list = field(default_factory=list)  # Eq. 9 structure-preserving 3-D flow x'_n
    phys: Physics | None = None
    opt_state: dict | None = None
    history: dict = field(default_factory=lambda: {"appearance": [], "finetune": [], "flow": [], "spflow": [],
                                                   "physics": []})
    frame_loss: list | None = None
    seconds: float = 0.0
    info: dict = field(default_factory=dict)


def _state_dict(st: FitState, cfg: TrainConfig, opt=None) -> dict:
    return {"config": cfg.model_dump(), "stage": st.stage, "iteration": st.iteration,
            "app": [t.detach() for t in st.app.params()] if st.app else None,
            "flow": [t.detach() for t in st.flow], "spflow": [t.detach() for t in st.spflow],
            "phys": [t.detach() for t in st.phys.leaves()] if st.phys else None,
            "opt": opt.state_dict() if opt is not None else None, "history": st.history,
            "frame_loss": st.frame_loss, "seconds": st.seconds, "info": st.info}


def _save_checkpoint(run_dir: Path, st: FitState, cfg: TrainConfig, opt=None, name: str = "checkpoint.pt",
                     data_hash: str = "") -> None:
    with atomic_path(run_dir / name) as tmp:
        torch.save({**_state_dict(st, cfg, opt), "format": CHECKPOINT_FORMAT, "data_hash": data_hash}, tmp)


def data_fingerprint(ds: Dataset) -> str:
    """SHA-256 of what ``fit`` learns from: scene.json's content, the poses and the observed images and masks
    (a checkpoint resumes only on the same data)."""
    h = hashlib.sha256(json.dumps(ds.meta, sort_keys=True).encode())
    for a in (ds.rotations, ds.root_t, ds.rgb, ds.mask):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


_CHECKPOINT_KEYS = ("config", "stage", "iteration", "app", "flow", "phys", "opt", "history", "frame_loss", "seconds")


def _read_checkpoint(p: Path) -> dict:
    """A physar checkpoint (torch.load with weights_only=True: tensors and plain containers, never code), or
    one ConfigError line for any other file."""
    try:
        with warnings.catch_warnings():  # torch warns about foreign pickle protocols before refusing them
            warnings.simplefilter("ignore")
            d = torch.load(p, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises UnpicklingError, RuntimeError, EOFError, ...
        raise ConfigError(f"{p}: not a physar checkpoint (torch.load with weights_only=True refuses it: "
                          f"{type(exc).__name__}); remove it or use --restart") from None
    if not isinstance(d, dict) or any(k not in d for k in _CHECKPOINT_KEYS) or not isinstance(d["config"], dict):
        raise ConfigError(f"{p}: not a physar checkpoint (missing fields); remove it or use --restart")
    return d


STAGES = ("appearance", "flow", "spflow", "physics", "done")  # fit's stages, in order (FitState.stage)


def _check_tensors(p: Path, what: str, got, shapes: list) -> None:
    """``got`` must be a list of finite tensors of the given shapes (a checkpoint's arrays against this run's)."""
    if not isinstance(got, (list, tuple)) or len(got) != len(shapes):
        raise ConfigError(f"{p}: not a checkpoint of this run ({what}: {len(got) if isinstance(got, (list, tuple)) else type(got).__name__} "
                          f"arrays, this run has {len(shapes)}); remove it or use --restart")
    for i, (t, shape) in enumerate(zip(got, shapes)):
        if not isinstance(t, torch.Tensor) or tuple(t.shape) != tuple(shape) or not bool(torch.isfinite(t).all()):
            found = tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
            raise ConfigError(f"{p}: not a checkpoint of this run ({what} array {i}: {found}, expected finite "
                              f"{tuple(shape)}); remove it or use --restart")


def _load_optimiser(opt: torch.optim.Optimizer, state: dict, p: Path) -> None:
    """Adam's stored moments into ``opt``, checked against its parameters (torch accepts moments of another shape
    and fails at the first step)."""
    try:
        opt.load_state_dict(state)
        ok = all(not torch.is_tensor(v) or v.ndim == 0 or v.shape == q.shape
                 for g in opt.param_groups for q in g["params"] for v in opt.state.get(q, {}).values())
    except (ValueError, KeyError, TypeError, RuntimeError, IndexError):
        ok = False
    if not ok:
        raise ConfigError(f"{p}: not a checkpoint of this run (optimiser state); remove it or use --restart")


def _state_from(d: dict, rig: Rig, p: Path) -> FitState:
    """The FitState stored in checkpoint ``p`` (read by :func:`_read_checkpoint`), its stage, counters and arrays
    checked against this run's rig (one ConfigError line naming ``p``: a damaged or foreign file, never a crash
    half-way through a resumed run)."""
    stage, it = d["stage"], d["iteration"]
    if stage not in STAGES or not isinstance(it, int) or isinstance(it, bool) or it < 0:
        raise ConfigError(f"{p}: not a checkpoint of this run (stage {stage!r}, iteration {it!r}); remove it or use "
                          "--restart")
    later = STAGES.index(stage)
    if later > 0 and d["app"] is None:
        raise ConfigError(f"{p}: not a checkpoint of this run (stage {stage!r} without appearance); remove it or use "
                          "--restart")
    hist = d["history"]
    if not isinstance(hist, dict) or any(not isinstance(hist.get(k), list) for k in FitState().history) \
            or not isinstance(d["seconds"], (int, float)) or not isinstance(d["opt"], (dict, type(None))):
        raise ConfigError(f"{p}: not a checkpoint of this run (history, seconds or optimiser state); remove it or "
                          "use --restart")
    fl = d["frame_loss"]
    if fl is not None and (not isinstance(fl, list) or not all(isinstance(v, (int, float)) for v in fl)):
        raise ConfigError(f"{p}: not a checkpoint of this run (frame losses); remove it or use --restart")
    n, n_obs = rig.no + rig.nh + rig.nb, int(rig.meta["n_obs"])
    if d["app"] is not None:
        _check_tensors(p, "appearance", d["app"], [(n, 1, 3), (n,), (n, 3)])
    # frames of the per-frame flows: stage "flow" ("spflow") extends flow (spflow) from its last frame; later
    # stages read every observed frame of flow (spflow may be shorter: runs before the Eq. 9 stage had none)
    need = {"flow": ((1, n_obs), (0, n_obs)), "spflow": ((n_obs, n_obs), (1, n_obs))}.get(
        stage, ((0, n_obs), (0, n_obs)) if stage == "appearance" else ((n_obs, n_obs), (0, n_obs)))
    for key, (lo, hi) in zip(("flow", "spflow"), need):
        got = d.get(key, [])
        if not isinstance(got, (list, tuple)) or not lo <= len(got) <= hi:
            raise ConfigError(f"{p}: not a checkpoint of this run (stage {stage!r} with "
                              f"{len(got) if isinstance(got, (list, tuple)) else type(got).__name__} {key} frames, "
                              f"expected {lo}..{hi}); remove it or use --restart")
        _check_tensors(p, key, list(got), [(rig.no, 3)] * len(got))
    if stage == "done" and d["phys"] is None:
        raise ConfigError(f"{p}: not a checkpoint of this run (stage 'done' without physics); remove it or use "
                          "--restart")
    st = FitState(stage=stage, iteration=it, history=hist, frame_loss=d["frame_loss"], seconds=d["seconds"],
                  info=d.get("info", {}))
    if d["app"] is not None:
        st.app = Appearance(*d["app"])
    st.flow, st.spflow = list(d["flow"]), list(d.get("spflow", []))
    if d["phys"] is not None:
        st.phys = Physics.init(rig)
        _check_tensors(p, "physics", d["phys"], [t.shape for t in st.phys.leaves()])
        with torch.no_grad():
            for a, b in zip(st.phys.leaves(), d["phys"]):
                a.copy_(b)
    st.opt_state = d["opt"]
    return st


def _with_pre_option_defaults(config: dict) -> dict:
    """A stored configuration with the options added since filled in as the run behaved: render_deformation
    "state" (the seed's rule, the only one before the option), learn_omega true, flow_target "all" (the seed's
    Eq. 10, the only form before the option), residual_objective false (the world-frame residual laws),
    residual_on "all"."""
    return {"render_deformation": "state", "learn_omega": True, "flow_target": "all", "residual_objective": False,
            "residual_on": "all", **config}


def _result_fields(config: dict) -> dict:
    """A configuration without the fields its results do not depend on: the devices (CUDA matches the CPU to
    2e-13, benchmarks/RESULTS.md "Gaussians and MPM on CUDA"), so a run may resume, or a model load, on another
    device; flow_target when the 3-D flow term is off (lambda_flow = 0), and residual_objective and
    residual_on without the residual laws."""
    drop = (_DEVICE_FIELDS + (("flow_target",) if config.get("lambda_flow") == 0 else ())
            + (("residual_objective", "residual_on") if not config.get("residual") else ()))
    return {k: v for k, v in config.items() if k not in drop}


def _load_checkpoint(run_dir: Path, cfg: TrainConfig, data_hash: str) -> dict | None:
    """RUN_DIR/checkpoint.pt checked against the configuration and the data (refused, nothing written,
    when it was made from others); None when there is none."""
    p = run_dir / "checkpoint.pt"
    if not p.exists():
        return None
    d = _read_checkpoint(p)
    old, new = _result_fields(_with_pre_option_defaults(d["config"])), _result_fields(cfg.model_dump())
    if old != new:
        diff = ", ".join(f"{k} = {old.get(k, '(none)')!r} there, {new.get(k, '(none)')!r} now"
                         for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k))
        raise ConfigError(f"{p}: checkpoint was made with another configuration ({diff}); use a new --out folder "
                          "or --restart")
    if d.get("data_hash") != data_hash:
        raise ConfigError(f"{p}: checkpoint was made from another DATA_DIR (or its files changed); use a new "
                          "--out folder or --restart")
    return d


def _load_stages(reuse: Path, rig: Rig, cfg: TrainConfig) -> FitState:
    """Stages 1-2 of another run (RUN_DIR/stages.pt), for physics-only variants (ablations)."""
    p = Path(reuse) / "stages.pt"
    if not p.exists():
        raise ConfigError(f"--reuse {reuse}: missing {p} (that run has not finished its flow stages)")
    d = _read_checkpoint(p)
    mine = cfg.model_dump()
    stored = _with_pre_option_defaults(d["config"])
    default = TrainConfig().model_dump()  # a field newer than the stored run: it ran at the default
    bad = [k for k in _PRE_PHYSICS if stored.get(k, default[k]) != mine[k]]
    if bad:
        raise ConfigError(f"--reuse {reuse}: its stages were fitted with other settings ({', '.join(bad)})")
    st = _state_from(d, rig, p)
    st.phys, st.opt_state, st.frame_loss, st.iteration, st.stage = None, None, None, 0, "physics"
    st.history["physics"] = []
    return st


def _spin_kinematics(rig: Rig, spin: dict, stride: int) -> dict:
    """Spin-clip LBS of the simulated and kinematic body Gaussians, their LBS rotations (fixed skinning) and
    the Alg. 1 (sigma = 0) deformation gradients of Eq. 4-5 (:mod:`physar.recon.canonical`)."""
    from physar.recon.canonical import zero_stress_deformation

    kin = rig.kinematics(spin["rotations"], spin["root_t"])
    sim = rig.meta["sim"]
    x = torch.cat([kin["ref"], kin["xb"]], 1)
    F = zero_stress_deformation(x, 1.0 / rig.meta["fps"], sim["substeps"], max(rig.h, rig.cfg.body_spacing))
    sel = list(range(0, kin["frames"], stride))
    return {"frames": sel, "ref": kin["ref"], "A_h": kin["A_h"], "xb": kin["xb"], "A_b": kin["A_b"],
            "F_h": F[:, :rig.nh], "F_b": F[:, rig.nh:], "rgb": torch.as_tensor(spin["rgb"]),
            "mask": torch.as_tensor(spin["mask"])}


def _spin_psnr(rig: Rig, app: Appearance, sk: dict, physics_F: bool) -> float:
    from physar.recon.metrics import psnr

    Xo = torch.as_tensor(rig.Xo)
    I_o = torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3)
    vals = []
    with torch.no_grad():
        for f in sk["frames"]:
            Fh, Fb = (sk["F_h"][f], sk["F_b"][f]) if physics_F else (sk["A_h"][f], sk["A_b"][f])
            r = render_scene(rig, app, Xo, I_o, sk["ref"][f], Fh, sk["xb"][f], Fb)
            vals.append(psnr(r.rgb.numpy(), sk["rgb"][f].numpy()))
    return float(np.mean(vals))


def _visible_at(rig: Rig, app: Appearance, kin: dict, f: int, x: torch.Tensor, K, Rc, tc) -> torch.Tensor:
    """Object particles x (frame f's positions) visible in frame f: rendered with the body of that frame
    (:func:`physar.recon.flow.visible`, tolerance one grid cell)."""
    from physar.recon.flow import project, visible

    with torch.no_grad():
        r = render_scene(rig, app, x, None, kin["ref"][f], kin["A_h"][f], kin["xb"][f], kin["A_b"][f])
    uv, z = project(x, K, Rc, tc)
    return visible(uv, z, r.depth.double(), r.alpha.double(), tol=rig.h)


def _flow_selection(rig: Rig, app: Appearance, kin: dict, spflow: list, target: str) -> dict:
    """Per frame f of the Eq. 9 flow (from 1; from 0 for all), the (particles, camera centre) that the Eq. 10 flow
    term compares (``TrainConfig.flow_target``): all -> (None, None); visible -> the particles of x'_{f-1} visible in frame
    f - 1 (those whose motion into frame f the Eq. 9 optical-flow term saw); observed -> the same and the camera
    centre, so that only the motion across the rays is compared."""
    if target == "all":
        return {f: (None, None) for f in range(len(spflow))}
    K, Rc, tc = (torch.as_tensor(a) for a in S.camera_matrices(rig.meta))
    centre = -(Rc.T @ tc) if target == "observed" else None
    return {f: (_visible_at(rig, app, kin, f - 1, spflow[f - 1], K, Rc, tc), centre) for f in range(1, len(spflow))}


def _fit_positions(rig: Rig, app: Appearance, kin: dict, f: int, rgb_f, mask_f, x0: torch.Tensor, iters: int,
                   lr: float, prior: Callable[[torch.Tensor], torch.Tensor]) -> tuple[torch.Tensor, float]:
    """Object positions of frame f by Adam from ``x0``: image loss (RGB + mask) of the frame rendered with F from
    the lattice neighbours, plus ``prior(x)`` (the 4DGS-like rigidity, or the Eq. 9 flow + ARAP terms).
    Returns the positions and the last loss."""
    x = x0.clone().requires_grad_(True)
    opt = torch.optim.Adam([x], lr=lr)
    loss = torch.zeros(())
    for _ in range(iters):
        res = render_scene(rig, app, x, None, kin["ref"][f], kin["A_h"][f], kin["xb"][f], kin["A_b"][f])
        loss = image_loss(res, rgb_f, mask_f, rig.cfg) + prior(x)
        opt.zero_grad()
        loss.backward()
        opt.step()
    return x.detach(), float(loss.detach())


RUN_MARKERS = ("checkpoint.pt", "stages.pt", "model.npz")  # a folder holding one of these is an earlier run
RUN_OUTPUTS = ("model.npz", "gaussians.ply", "report.json", "preview.mp4")  # what fit writes at the end


def _check_run_dir(run: Path) -> None:
    """``fit`` resumes in an earlier run's RUN_DIR (one holding one of :data:`RUN_MARKERS`) and replaces its
    outputs; in any other folder an existing file of the same name as an output (:data:`RUN_OUTPUTS`) would be
    the user's and is refused. Other files (a config, .DS_Store, a crashed save's temporary) are left alone. A
    marker counts only when it is a zip archive, as torch.save and np.savez write them (a stray text file named
    stages.pt made a folder of the user's count as a run)."""
    if not run.is_dir() or any((run / m).is_file() and zipfile.is_zipfile(run / m) for m in RUN_MARKERS):
        return
    theirs = [n for n in RUN_OUTPUTS if (run / n).exists()]
    if theirs:
        raise ConfigError(f"{run}: RUN_DIR holds {', '.join(theirs)} but no earlier run (none of "
                          f"{', '.join(RUN_MARKERS)}): fit would replace it; choose a new or empty folder")


def fit(data_dir: str | Path, run_dir: str | Path, cfg: TrainConfig | None = None,
        progress: Progress | None = None, restart: bool = False, reuse: str | Path | None = None) -> dict:
    """Run the stages on DATA_DIR and write RUN_DIR (model.npz, gaussians.ply, report.json, preview.mp4).
    A RUN_DIR holding one of those outputs but no earlier run is refused (:func:`_check_run_dir`).
    Resumes from RUN_DIR/checkpoint.pt unless ``restart``; ``reuse`` = another RUN_DIR whose stages 1-2
    (appearance, flows) are taken as they are (physics-only variants such as the ablations).  Returns the
    report dict."""
    cfg = cfg or TrainConfig()
    run = check_folder(run_dir, inputs=[data_dir], kind="RUN_DIR")
    if run.resolve().is_relative_to(Path(data_dir).resolve()):
        raise ConfigError(f"{run_dir}: RUN_DIR inside the DATA_DIR {data_dir}: choose a folder outside it (the "
                          "DATA_DIR holds the scene's files only)")
    _check_run_dir(run)
    ds = load_dataset(data_dir)
    data_hash = data_fingerprint(ds)
    saved = None if restart else _load_checkpoint(run, cfg, data_hash)  # refused before anything is written
    torch.manual_seed(cfg.seed)
    rig = Rig(ds.meta, cfg, poses=(ds.rotations, ds.root_t))
    kin = rig.kinematics(ds.rotations, ds.root_t)
    if saved is not None:
        st = _state_from(saved, rig, run / "checkpoint.pt")
    else:
        st = _load_stages(reuse, rig, cfg) if reuse is not None else FitState()
    run.mkdir(parents=True, exist_ok=True)
    if restart:
        (run / "checkpoint.pt").unlink(missing_ok=True)
    save = lambda st, opt=None, name="checkpoint.pt": _save_checkpoint(run, st, cfg, opt, name, data_hash)
    rgb = torch.as_tensor(ds.rgb)
    mask = torch.as_tensor(ds.mask)
    prog = progress or (lambda *a: None)
    t0 = time.perf_counter() - st.seconds
    Xo = torch.as_tensor(rig.Xo)
    I_o = torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3)

    # ---- stage 1: canonical Gaussians (spin clip, fixed skinning) and physics-aware fine-tuning (§4.1)
    if st.stage == "appearance":
        st.app = st.app or Appearance.init(rig)
        for t in st.app.params():
            t.requires_grad_(True)
        sk = _spin_kinematics(rig, ds.spin, cfg.spin_stride) if ds.spin is not None else None
        gen = torch.Generator().manual_seed(cfg.seed)

        def frame_loss(physics_F: bool):
            if sk is None:
                res = render_scene(rig, st.app, Xo, I_o, kin["ref"][0], kin["A_h"][0], kin["xb"][0], kin["A_b"][0])
                return image_loss(res, rgb[0], mask[0], cfg)
            f = sk["frames"][int(torch.randint(len(sk["frames"]), (1,), generator=gen))]
            Fh, Fb = (sk["F_h"][f], sk["F_b"][f]) if physics_F else (sk["A_h"][f], sk["A_b"][f])
            res = render_scene(rig, st.app, Xo, I_o, sk["ref"][f], Fh, sk["xb"][f], Fb)
            return image_loss(res, sk["rgb"][f], sk["mask"][f], cfg)

        for name, iters, physics_F in (("appearance", cfg.appearance_iters, False),
                                       ("finetune", cfg.finetune_iters if sk is not None else 0, True)):
            opt = torch.optim.Adam(st.app.params(), lr=cfg.appearance_lr if name == "appearance"
                                   else 0.3 * cfg.appearance_lr)
            if name == "finetune" and sk is not None:  # no spin clip (the importer's default): no finetune
                st.info["spin_psnr_lbs_F"] = _spin_psnr(rig, st.app, sk, False)
                st.info["spin_psnr_physics_F_before_finetune"] = _spin_psnr(rig, st.app, sk, True)
            for it in range(iters):
                loss = frame_loss(physics_F)
                opt.zero_grad()
                loss.backward()
                opt.step()
                st.history[name].append(float(loss.detach()))
                prog(name, it + 1, iters, float(loss.detach()))
            if name == "finetune" and sk is not None:
                st.info["spin_psnr_physics_F_after_finetune"] = _spin_psnr(rig, st.app, sk, True)
        st.stage, st.iteration, st.flow = "flow", 0, [Xo.clone()]
        st.seconds = time.perf_counter() - t0
        save(st)
    app = Appearance(*[t.detach() for t in st.app.params()])

    # ---- stage 2a: per-frame positions with RGB + mask + edge rigidity = the 4DGS-like baseline
    if st.stage == "flow":
        for f in range(len(st.flow), ds.n_obs):
            x, loss = _fit_positions(rig, app, kin, f, rgb[f], mask[f], st.flow[-1], cfg.flow_iters, cfg.flow_lr,
                                     lambda x: cfg.rigidity * rig.rigidity(x))
            st.history["flow"].append(loss)
            st.flow.append(x)
            prog("flow", f, ds.n_obs - 1, loss)
            st.seconds = time.perf_counter() - t0
            save(st)
        st.stage, st.iteration, st.spflow = "spflow", 0, [Xo.clone()]
        save(st)

    # ---- stage 2b: structure-preserving 3-D flow, RGB + DIS optical flow + ARAP (Eq. 9) + motion along the rays
    if st.stage == "spflow":
        from physar.recon.flow import dis_flow, sp_flow_prior

        K, Rc, tc = (torch.as_tensor(a) for a in S.camera_matrices(rig.meta))
        for f in range(len(st.spflow), ds.n_obs):
            xp = st.spflow[-1]
            x0 = 2 * xp - st.spflow[-2] if len(st.spflow) >= 2 else xp  # warm start: constant velocity
            vis = _visible_at(rig, app, kin, f - 1, xp, K, Rc, tc)
            of = torch.as_tensor(dis_flow(ds.rgb[f - 1], ds.rgb[f]), dtype=torch.float64)
            x, loss = _fit_positions(
                rig, app, kin, f, rgb[f], mask[f], x0, cfg.spflow_iters, cfg.flow_lr,
                lambda x, xp=xp, of=of, vis=vis: sp_flow_prior(x, xp, of, vis, K, Rc, tc, Xo, rig.pairs, cfg.lambda_of,
                                                               cfg.lambda_arap, cfg.lambda_ray))
            st.history["spflow"].append(loss)
            st.spflow.append(x)
            prog("spflow", f, ds.n_obs - 1, loss)
            st.seconds = time.perf_counter() - t0
            save(st)
        st.stage, st.iteration = "physics", 0
        st.seconds = time.perf_counter() - t0
        st.info["stages_seconds"] = st.seconds
        save(st)
        save(st, name="stages.pt")

    # ---- stage 3: end-to-end physics (Eq. 10-11), progressive and loss-balanced
    if st.stage == "physics":
        st.phys = st.phys or Physics.init(rig)
        leaves = st.phys.leaves()
        for t in leaves:
            t.requires_grad_(True)
        k = len(st.phys.material_leaves())
        if not cfg.learn_omega:  # kept in the leaves (the checkpoint's layout), left out of the optimiser
            st.phys.omega_logit.requires_grad_(False)
        groups = [{"params": [t for t in leaves[:k] if t.requires_grad], "lr": cfg.physics_lr}]
        if len(leaves) > k:
            groups.append({"params": leaves[k:], "lr": cfg.net_lr})
        opt = torch.optim.Adam(groups)
        if st.opt_state is not None:
            _load_optimiser(opt, st.opt_state, run / "checkpoint.pt")
        lo_E, hi_E = math.log(cfg.E_min), math.log(cfg.E_max)
        from physar.recon.flow import flow_target_loss

        flow_sel = _flow_selection(rig, app, kin, st.spflow, cfg.flow_target) if cfg.lambda_flow > 0 else {}
        counts = [int(v.sum()) for f, (v, _) in sorted(flow_sel.items()) if v is not None]
        if counts:
            st.info["flow_target_particles"] = counts  # per observed frame 1.., in the report's "canonical"
            if not any(counts):
                warnings.warn(f"flow_target = {cfg.flow_target!r}: no object particle is visible in any observed "
                              "frame, so the 3-D flow term (lambda_flow) compares nothing", PhysarWarning, stacklevel=2)
        while st.iteration < cfg.physics_iters:
            it = st.iteration
            W = min(ds.n_obs, cfg.window_start + it // cfg.window_grow_every)
            wts = np.ones(W)
            if cfg.loss_balanced and st.frame_loss is not None and len(st.frame_loss) >= W - 1:
                fl = np.asarray(st.frame_loss[:W - 1])
                wts[1:] = fl / max(fl.mean(), 1e-12)
            total, per = 0.0, []
            for f, xo, Fo, xh, Fh in simulate_clip(rig, st.phys, kin, W):
                res = render_scene(rig, app, xo, Fo, xh, Fh, kin["xb"][f], kin["A_b"][f])
                lf = image_loss(res, rgb[f], mask[f], cfg)
                if cfg.lambda_flow > 0 and f < len(st.spflow):
                    lf = lf + cfg.lambda_flow * flow_target_loss(xo, st.spflow[f], *flow_sel[f])
                per.append(float(lf.detach()))
                total = total + wts[f] * lf / (W - 1)
            loss = total + physics_regulariser(st.phys, rig, torch.cat([Fo, Fh]))
            opt.zero_grad()
            loss.backward()
            opt.step()
            with torch.no_grad():
                st.phys.log_E.clamp_(lo_E, hi_E)
                if st.phys.log_E_human is not None:
                    st.phys.log_E_human.clamp_(lo_E, hi_E)
            fl_prev = list(st.frame_loss or [])
            st.frame_loss = per + fl_prev[len(per):]
            st.history["physics"].append(float(loss.detach()))
            st.iteration += 1
            prog("physics", st.iteration, cfg.physics_iters, float(loss.detach()))
            if st.iteration % cfg.checkpoint_every == 0 or st.iteration == cfg.physics_iters:
                st.seconds = time.perf_counter() - t0
                save(st, opt)
        st.stage = "done"
        st.seconds = time.perf_counter() - t0
        save(st, opt)

    recon = Reconstruction(rig, app, st.flow, st.phys, ds.root.resolve(), st.spflow)  # eval from any folder
    if cfg.appearance_refit_iters > 0:
        t1 = time.perf_counter()
        recon.apps = refit_appearances(recon, ds, kin, cfg.appearance_refit_iters, progress=prog,
                                       colours_only=cfg.appearance_refit_colours_only)
        st.info["appearance_refit_seconds"] = time.perf_counter() - t1
        st.seconds += st.info["appearance_refit_seconds"]  # training time includes the refit
    recon.save(run / "model.npz", cfg, st)
    canon = render_gaussians_canonical(rig, recon.appearance("physics"), kin)
    save_ply(run / "gaussians.ply", canon)
    renders: dict = {}
    report = evaluate(recon, ds, progress=progress, renders=renders)
    report["train_seconds"] = st.seconds
    report["canonical"] = st.info
    report["history_final"] = {k: (v[-1] if v else None) for k, v in st.history.items()}
    report["history_first"] = {k: (v[0] if v else None) for k, v in st.history.items()}
    write_json(run / "report.json", report)
    _preview(recon, ds, run / "preview.mp4", renders)
    return report


def refit_appearances(recon: Reconstruction, ds: Dataset, kin: dict, iters: int, methods=None,
                      progress: Progress | None = None, colours_only: bool = False) -> dict[str, Appearance]:
    r"""One appearance per method, refitted on the observed dynamic frames with that method's motion fixed.

    Stage 1 fits the canonical appearance on the spin clip alone, and the physics stage keeps it fixed (seed §4:
    the appearance must not absorb motion while the physics is learned). Afterwards, each method's object
    motion on the observed frames 1..n_obs-1 (the learned simulation; the object at rest for LBS-only; the
    per-frame positions of the 4DGS-like fit and of Eq. 9) is held fixed and the canonical SH colours (with
    ``colours_only``; else also the opacity logits and log-scales; never a per-frame parameter) are refitted by
    Adam on the image loss of one random observed frame per iteration, from the canonical appearance, at 0.3 x
    ``appearance_lr``. Every method gets the same treatment. Colours only is the configuration's default:
    refitted opacities and scales let LBS-only (the object at rest) grow its silhouette over the pressed
    object, which raised its mask IoU in a novel action above the physics model's on one of two seeds.
    physar's stage, not in the seed; measured in benchmarks/RESULTS.md ("appearance refit")."""
    rig = recon.rig
    obs = list(range(1, ds.n_obs))
    methods = [m for m in (methods or METHODS) if m != "spflow" or recon.spflow]
    if not obs or iters <= 0:
        return {}
    Xo = torch.as_tensor(rig.Xo)
    I_o = torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3)
    with torch.no_grad():
        sim = {f: (xo, Fo, xh, Fh) for f, xo, Fo, xh, Fh in simulate_clip(rig, recon.phys, kin, ds.n_obs, grad=False)}

    def per_frame(xs):
        return {f: (xs[min(f, len(xs) - 1)], None, kin["ref"][f], kin["A_h"][f]) for f in obs}

    motions = {"physics": sim, "lbs": {f: (Xo, I_o, kin["ref"][f], kin["A_h"][f]) for f in obs},
               "4dgs": per_frame(recon.flow), "spflow": per_frame(recon.spflow or recon.flow)}
    return {m: refit_appearance(rig, recon.app, motions[m], ds, kin, iters, colours_only,
                                progress=progress and (lambda _, *a, m=m: progress(f"appearance refit ({m})", *a)))
            for m in methods}


def refit_appearance(rig: Rig, app: Appearance, motion: dict, ds: Dataset, kin: dict, iters: int,
                     colours_only: bool = True, seed: int | None = None, lr: float | None = None,
                     progress: Progress | None = None) -> Appearance:
    """``app`` refitted by Adam on the image loss of one random frame of ``motion`` per iteration (``motion``:
    frame -> (object positions, object F or None (least squares), body positions, body F), the body's kinematic
    Gaussians from ``kin``);
    the SH colours only, or also the opacity logits and log-scales. Step ``lr`` (default 0.3 x
    ``appearance_lr``), frames drawn with ``seed`` (default the configuration's). See :func:`refit_appearances`."""
    cfg = rig.cfg
    frames = sorted(motion)
    new = Appearance(*[t.detach().clone().requires_grad_(not colours_only or k == 0)
                       for k, t in enumerate(app.params())])
    opt = torch.optim.Adam([t for t in new.params() if t.requires_grad],
                           lr=0.3 * cfg.appearance_lr if lr is None else lr)
    gen = torch.Generator().manual_seed(cfg.seed if seed is None else seed)
    for it in range(iters):
        f = frames[int(torch.randint(len(frames), (1,), generator=gen))]
        res = render_scene(rig, new, *motion[f], kin["xb"][f], kin["A_b"][f])
        loss = image_loss(res, torch.as_tensor(ds.rgb[f]), torch.as_tensor(ds.mask[f]), cfg)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if progress:
            progress("appearance refit", it + 1, iters, float(loss.detach()))
    return Appearance(*[t.detach() for t in new.params()])


def physics_regulariser(phys: Physics, rig: Rig, F: torch.Tensor) -> torch.Tensor:
    r""":math:`R` of seed Eq. 11 (+ :math:`R_\text{feat}` of App. A) through
    :func:`physar.mpm.neural.regulariser`, with the weights of the configuration: the residuals evaluated at
    the deformation gradients :math:`F` (No + Nh, 3, 3) of the last simulated frame (physar's choice:
    :math:`F` also stands for :math:`F_\text{trial}`, which lives inside a substep), :math:`\omega` of all
    particles; with ``residual_on = "object"`` the residuals at the object's F only."""
    from physar.mpm.neural import regulariser

    cfg = rig.cfg
    if cfg.residual_on == "object":
        F = F[:rig.no]
    return regulariser(phys.nets, phys.omega(rig), F=F, l_e=phys.l_e, F_trial=F, l_p=phys.l_p,
                       lam_law=cfg.lambda_law, lam_omega=cfg.lambda_omega, lam_feat=cfg.lambda_feat)


def render_gaussians_canonical(rig: Rig, app: Appearance, kin: dict) -> Gaussians:
    """Canonical (frame 0) Gaussians with covariances baked in (for the PLY file)."""
    means = torch.cat([torch.as_tensor(rig.Xo), kin["ref"][0], kin["xb"][0]]).float()
    n = means.shape[0]
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1.0
    return Gaussians(means, quats, app.log_scales.detach(), app.opacity_logits.detach(), app.sh.detach())


# ----------------------------------------------------------------------------------------------- predict
@dataclass
class Reconstruction:
    """A fitted scene: rig, appearance, per-frame flows (4DGS-like baseline, Eq. 9) and learned physics."""

    rig: Rig
    app: Appearance
    flow: list
    phys: Physics
    data_dir: Path | None = None
    spflow: list = field(default_factory=list)
    apps: dict = field(default_factory=dict)  # method -> Appearance refitted with its motion (refit_appearances)

    def appearance(self, method: str) -> Appearance:
        """The appearance ``method`` renders with: its refit when there is one, else the canonical one."""
        return self.apps.get(method, self.app)

    def save(self, path: Path, cfg: TrainConfig, st: FitState) -> None:
        arrays = {
            "format_version": np.array(MODEL_FORMAT), "meta_json": np.array(json.dumps(self.rig.meta)),
            "config_json": np.array(json.dumps(cfg.model_dump())),
            "data_dir": np.array(str(self.data_dir or "")),
            "sh": self.app.sh.numpy(), "opacity_logits": self.app.opacity_logits.numpy(),
            "log_scales": self.app.log_scales.numpy(),
            **{f"app.{m}.{k}": t.numpy() for m, a in self.apps.items()
               for k, t in zip(("sh", "opacity_logits", "log_scales"), a.params())},
            "flow": torch.stack(self.flow).numpy(),
            "spflow": torch.stack(self.spflow or self.flow).numpy(),
            "log_E_param": self.phys.log_E.detach().numpy(),
            **({"nu_logit_param": self.phys.nu_logit.detach().numpy()} if self.phys.nu_logit is not None else {}),
            "E": self.phys.E_object(self.rig).detach().numpy(), "omega": self.phys.omega(self.rig).detach().numpy(),
            "omega_logit": self.phys.omega_logit.detach().numpy(),
            "nu": self.phys.nu_object(self.rig).detach().numpy(),
            "E_human": self.phys.E_human(self.rig).detach().numpy(),
            "object_rest": self.rig.Xo, "body_rest": self.rig.Xh,
            "loss_physics": np.asarray(st.history["physics"], dtype=np.float64),
        }
        if self.phys.nets is not None:
            if self.phys.l_e is not None:
                arrays["l_e"] = self.phys.l_e.detach().numpy()
            if self.phys.l_p is not None:
                arrays["l_p"] = self.phys.l_p.detach().numpy()
            for k, v in self.phys.nets.state_dict().items():
                arrays[f"net.{k}"] = v.numpy()
        write_npz(path, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Reconstruction:
        path = Path(path)
        if path.is_dir():
            path = path / "model.npz"
        d = _npz(path)
        try:
            version = int(d.get("format_version", -1))
        except (TypeError, ValueError):
            version = None
        if version != MODEL_FORMAT:
            raise ConfigError(f"{path}: not a physar recon model (format_version {d.get('format_version')})")
        try:
            return cls._from_arrays(d)
        except (KeyError, ValueError, TypeError, RuntimeError, IndexError) as exc:  # json, pydantic, torch shapes
            what = f"missing array {exc}" if isinstance(exc, KeyError) else " ".join(str(exc).split())[:120]
            raise ConfigError(f"{path}: not a valid physar recon model ({what})") from None

    @classmethod
    def _from_arrays(cls, d: dict) -> Reconstruction:
        stored = _with_pre_option_defaults(json.loads(str(d["config_json"])))
        meta, cfg = json.loads(str(d["meta_json"])), TrainConfig.model_validate(stored)
        cfg = _usable_devices(cfg)
        rig = Rig(meta, cfg)
        app = Appearance(torch.as_tensor(d["sh"]), torch.as_tensor(d["opacity_logits"]),
                         torch.as_tensor(d["log_scales"]))
        phys = Physics.init(rig)
        with torch.no_grad():
            phys.log_E.copy_(torch.as_tensor(d["log_E_param"]))
            phys.omega_logit.copy_(torch.as_tensor(d["omega_logit"]))
            if phys.nu_logit is not None:
                phys.nu_logit.copy_(torch.as_tensor(d["nu_logit_param"]))
            if phys.l_e is not None:
                phys.l_e.copy_(torch.as_tensor(d["l_e"]))
            if phys.l_p is not None:
                phys.l_p.copy_(torch.as_tensor(d["l_p"]))
            if phys.log_E_human is not None:
                phys.log_E_human.copy_(torch.log(torch.as_tensor(d["E_human"])))
            if phys.nets is not None:
                phys.nets.load_state_dict({k[4:]: torch.as_tensor(v) for k, v in d.items() if k.startswith("net.")})
        apps = {m: Appearance(*(torch.as_tensor(d[f"app.{m}.{k}"]) for k in ("sh", "opacity_logits", "log_scales")))
                for m in METHODS if f"app.{m}.sh" in d}
        for m, a in apps.items():
            if any(t.shape != c.shape for t, c in zip(a.params(), app.params())):
                raise ValueError(f"the appearance refit of {m} does not match the Gaussians")
        for k in ("flow", "spflow"):  # per observed frame object positions (4DGS-like baseline, Eq. 9)
            a = np.asarray(d[k])
            if a.ndim != 3 or not len(a) or a.shape[1:] != (rig.no, 3) or not np.all(np.isfinite(a)):
                raise ValueError(f"array '{k}' must be (frames >= 1, {rig.no}, 3) finite positions, got {a.shape}")
        for k in ("sh", "opacity_logits", "log_scales"):
            if not np.all(np.isfinite(np.asarray(d[k]))):
                raise ValueError(f"array '{k}' holds non-finite values")
        return cls(rig, app, list(torch.as_tensor(d["flow"])), phys, Path(str(d["data_dir"])) if str(d["data_dir"]) else None,
                   list(torch.as_tensor(d["spflow"])), apps)

    def predict(self, rotations: np.ndarray, root: np.ndarray, method: str = "physics",
                progress: Progress | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Render a pose sequence (F frames) with ``method`` in physics | lbs | 4dgs | spflow (the per-frame
        methods hold their last observed frame).

        Returns rgb (F, H, W, 3) and alpha (F, H, W) as float32 numpy arrays; frame 0 is the canonical scene."""
        return self.render_sequence(self.kinematics(rotations, root), method, progress)

    def kinematics(self, rotations: np.ndarray, root: np.ndarray) -> dict:
        """Checked poses -> :meth:`Rig.kinematics` (LBS of the pose sequence), to share between renders."""
        rotations, root = S.check_poses({"rotations": rotations, "root_translation": root},
                                        self.rig.body.skeleton.n_bones)
        return self.rig.kinematics(rotations, root)

    def render_sequence(self, kin: dict, method: str = "physics", progress: Progress | None = None,
                        objects: list | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`predict` from precomputed kinematics (:meth:`kinematics`); ``objects``, when given, receives
        the object particle positions of every frame ((No, 3) float64 numpy arrays, frame 0 = rest)."""
        rig = self.rig
        n = kin["frames"]
        Xo = torch.as_tensor(rig.Xo)
        I_o = torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3)
        out_rgb, out_a = [], []
        app = self.appearance(method)

        def emit(f, xo, Fo, xh, Fh):
            if objects is not None:
                objects.append(xo.detach().numpy())
            with torch.no_grad():
                r = render_scene(rig, app, xo, Fo, xh, Fh, kin["xb"][f], kin["A_b"][f])
            out_rgb.append(r.rgb.numpy())
            out_a.append(r.alpha.numpy())
            if progress:
                progress(method, f + 1, n, 0.0)

        emit(0, Xo, I_o, kin["ref"][0], kin["A_h"][0])
        if method == "physics":
            for f, xo, Fo, xh, Fh in simulate_clip(rig, self.phys, kin, n, grad=False):
                emit(f, xo, Fo, xh, Fh)
        elif method in ("lbs", "4dgs", "spflow"):
            per_frame = self.flow if method == "4dgs" else (self.spflow or self.flow)
            for f in range(1, n):
                if method == "lbs":
                    xo, Fo = Xo, I_o
                else:
                    xo, Fo = per_frame[min(f, len(per_frame) - 1)], None  # render_scene: least squares if used
                emit(f, xo, Fo, kin["ref"][f], kin["A_h"][f])
        else:
            raise PhysarError(f"unknown method '{method}': use physics, lbs, 4dgs or spflow")
        return np.stack(out_rgb), np.stack(out_a)


METHODS = ("physics", "lbs", "4dgs", "spflow")


SCENE_KEYS = ("fps", "frames", "n_obs", "camera", "body.model", "body.height", "object", "sim")  # fitted to


def check_same_scene(recon: Reconstruction, ds: Dataset) -> None:
    """ConfigError when ``ds`` is not the scene ``recon`` was fitted on: its scene.json differs from the one
    stored in the model in one of :data:`SCENE_KEYS` (the rig completes the rest of ``body``, e.g. the
    simulated bones of an imported scene)."""
    def get(meta: dict, key: str):
        for k in key.split("."):
            meta = meta.get(k) if isinstance(meta, dict) else None
        return json.dumps(meta, sort_keys=True)

    a, b = recon.rig.meta, ds.meta
    diff = [k for k in SCENE_KEYS if get(a, k) != get(b, k)]
    if diff:
        raise ConfigError(f"{ds.root}: not the DATA_DIR this model was fitted on (its scene.json differs in "
                          f"{', '.join(diff)}); pass the fit's DATA_DIR with --data")


def evaluate(recon: Reconstruction, ds: Dataset, methods=METHODS, progress: Progress | None = None,
             renders: dict | None = None) -> dict:
    """Metrics of each method on reconstruction (observed frames 1..n_obs-1), prediction (future frames) and
    the novel action, on all frames and on the large-deformation subsets (frames whose true maximum object
    displacement is >= half the maximum over that subset's own frames,
    :func:`physar.recon.metrics.large_deformation_frames`); E error against the truth.

    Each sequence is rendered once: the kinematics of each pose set are computed once, the novel action of the
    per-frame methods (which follow LBS there) reuses the LBS render and its metrics, and the 3-D object error
    of physics takes the positions of its clip render.  ``renders``, when given, receives each method's
    dynamic-clip RGB (F, H, W, 3) (the preview of :func:`fit` reuses them)."""
    from physar.recon.metrics import large_deformation_frames, lpips_model, sequence_metrics

    check_same_scene(recon, ds)
    try:
        lp = lpips_model()
        out = {"methods": {}, "lpips": "computed (AlexNet backbone)"}
    except PhysarError as exc:
        lp, out = None, {"methods": {}, "lpips": str(exc)}
    metrics = lambda *a, cache: sequence_metrics(*a, lpips_fn=lp, cache=cache)  # per-frame values computed once
    n, no = len(ds.rgb), ds.n_obs
    disp = ds.truth["dynamic_max_displacement"] if ds.truth else None
    sets = {"recon": list(range(1, no)), "pred": list(range(no, n))}
    kin = recon.kinematics(ds.rotations, ds.root_t)
    kin_novel = recon.kinematics(ds.novel["rotations"], ds.novel["root_t"]) if ds.novel is not None else None
    novel_res: dict[str, dict] = {}
    physics_objects: list | None = None
    for m in methods:
        objects = [] if m == "physics" else None
        rgb, a = recon.render_sequence(kin, m, progress, objects)
        if objects is not None:
            physics_objects = objects
        if renders is not None:
            renders[m] = rgb
        res, mc = {}, {}
        for name, fr in sets.items():
            res[name] = metrics(rgb, a, ds.rgb, ds.mask, fr, cache=mc)
            if disp is not None:
                res[name + "_large"] = metrics(rgb, a, ds.rgb, ds.mask, large_deformation_frames(disp, fr), cache=mc)
        if ds.novel is not None:
            m2 = "lbs" if m in ("4dgs", "spflow") else m  # a per-frame deformation cannot follow new poses
            if m2 not in novel_res:
                rgb2, a2 = recon.render_sequence(kin_novel, m2, progress)
                fr, mc = list(range(1, len(rgb2))), {}
                nr = {"novel": metrics(rgb2, a2, ds.novel["rgb"], ds.novel["mask"], fr, cache=mc)}
                if ds.truth is not None:
                    nr["novel_large"] = metrics(rgb2, a2, ds.novel["rgb"], ds.novel["mask"],
                                                large_deformation_frames(ds.truth["novel_max_displacement"], fr),
                                                cache=mc)
                novel_res[m2] = nr
            res.update({k: dict(v) for k, v in novel_res[m2].items()})
        out["methods"][m] = res
    if ds.truth is not None:
        out["material"] = material_error(recon, ds.truth)
        if "dynamic_object_positions" in ds.truth:
            out["object_3d_error_mm"] = object_3d_errors(recon, ds, kin, physics_objects)
    om = recon.phys.omega(recon.rig).detach().numpy()
    out["omega"] = {"object_max_abs": float(np.abs(om[:recon.rig.no]).max()),
                    "body_mean": float(om[recon.rig.no:].mean())}
    return out


def cell_average_truth(rig: Rig, truth: dict) -> np.ndarray:
    """Ground-truth object trajectories (F, No, 3) at the reconstruction's particles: mean of the fine
    particles whose nearest reconstruction particle (at rest) it is."""
    idx = cKDTree(rig.Xo).query(truth["rest_positions"])[1]
    cnt = np.bincount(idx, minlength=rig.no).astype(np.float64)
    xt = np.asarray(truth["dynamic_object_positions"], dtype=np.float64)
    out = np.zeros((len(xt), rig.no, 3))
    for f in range(len(xt)):
        for a in range(3):
            out[f, :, a] = np.bincount(idx, weights=xt[f, :, a], minlength=rig.no)
    return out / np.maximum(cnt, 1)[None, :, None]


def object_3d_errors(recon: Reconstruction, ds: Dataset, kin: dict | None = None,
                     physics_objects: list | None = None) -> dict:
    """Mean 3-D distance (mm) of the object particles to the cell-averaged truth over the observed frames
    1..n_obs-1, per method (lbs = the object at rest), and the floor of the discretisation (frame 0).

    ``physics_objects``: the object positions of a physics render of the clip (frames 0..; from
    :meth:`Reconstruction.render_sequence`), used instead of simulating the observed frames again; ``kin``:
    the clip's kinematics (:meth:`Reconstruction.kinematics`)."""
    rig = recon.rig
    gt = cell_average_truth(rig, ds.truth)
    frames = range(1, ds.n_obs)
    err = lambda x, f: float(np.linalg.norm(np.asarray(x) - gt[f], axis=1).mean() * 1e3)
    out = {"floor_frame0": err(rig.Xo, 0), "lbs": float(np.mean([err(rig.Xo, f) for f in frames])),
           "4dgs": float(np.mean([err(recon.flow[f], f) for f in frames]))}
    if recon.spflow:
        out["spflow"] = float(np.mean([err(recon.spflow[f], f) for f in frames]))
    if physics_objects is not None and len(physics_objects) >= ds.n_obs:
        sim = dict(enumerate(physics_objects))
    else:
        kin = kin if kin is not None else recon.kinematics(ds.rotations, ds.root_t)
        sim = {f: xo.numpy() for f, xo, *_ in simulate_clip(rig, recon.phys, kin, ds.n_obs, grad=False)}
    out["physics"] = float(np.mean([err(sim[f], f) for f in frames]))
    return out


def material_error(recon: Reconstruction, truth: dict) -> dict:
    r"""Learned vs true E at the reconstruction's particles (nearest fine particle):
    :math:`\operatorname{mean} |\log_{10} \text{ratio}|` for the learned field and the initial guess, and the
    means over the soft/stiff parts (the two values of a two-valued truth: pillow halves, C prongs/spine, bag
    filling/shell). The reconstruction's law is isotropic: the truth's fibre modulus (``fiber_E``, when
    stored) is reported, not compared."""
    rig = recon.rig
    idx = cKDTree(truth["rest_positions"]).query(rig.Xo)[1]
    Et = truth["E"][idx]
    E = recon.phys.E_object(rig).detach().numpy()
    soft = Et <= np.median(Et) if Et.min() == Et.max() else Et == Et.min()
    return {"mean_abs_log10_error": float(np.mean(np.abs(np.log10(E / Et)))),
            "initial_mean_abs_log10_error": float(np.mean(np.abs(np.log10(rig.cfg.E_init / Et)))),
            "E_soft_true": float(Et[soft].mean()), "E_stiff_true": float(Et[~soft].mean()),
            "E_soft_learned_geomean": float(np.exp(np.log(E[soft]).mean())),
            "E_stiff_learned_geomean": float(np.exp(np.log(E[~soft]).mean())),
            "stiff_soft_ratio_true": float(np.exp(np.log(Et[~soft]).mean() - np.log(Et[soft]).mean())),
            "stiff_soft_ratio_learned": float(np.exp(np.log(E[~soft]).mean() - np.log(E[soft]).mean())),
            "fiber_E_true_max": float(np.max(truth["fiber_E"])) if "fiber_E" in truth else 0.0,
            "nu_true": float(rig.meta["object"]["nu"]),
            "nu_learned_mean": float(recon.phys.nu_object(rig).detach().mean()),
            "nu_learned_range": [float(recon.phys.nu_object(rig).detach().min()),
                                 float(recon.phys.nu_object(rig).detach().max())]}


def _preview(recon: Reconstruction, ds: Dataset, path: Path, renders: dict | None = None) -> bool:
    """Side-by-side MP4 of the clip and each method's render (``renders`` from :func:`evaluate`; a method
    missing there is rendered)."""
    renders = renders or {}
    cols = [ds.rgb]
    for m in METHODS:
        cols.append(renders[m] if m in renders else recon.predict(ds.rotations, ds.root_t, m)[0])
    frames = np.concatenate(cols, axis=2)
    return write_mp4(path, (np.clip(frames, 0, 1) * 255 + 0.5).astype(np.uint8), ds.meta["fps"])


__all__ = ["Appearance", "Dataset", "Physics", "Reconstruction", "Rig", "TrainConfig", "evaluate", "fit",
           "load_dataset", "load_train_config", "render_scene"]
