r"""Synthetic scene with the anny body pressing an object with both forearms and hands, written out in a user's
formats (issue 17 part 4; seed 002 §5.1): a video, label-mask PNGs, an SMPL pose file and an object mesh, to be
read back through ``physar recon import`` (the route of real data), plus the truth a benchmark needs.

Scene (``[synth]`` of a TOML such as ``examples/recon_anny_cpillow.toml``; :class:`AnnySceneConfig`):

* **Body**: anny (:func:`physar.skinning.load_body`, height ``height``), z up, facing -y. Its poses are made as
  SMPL parameters (the format a pose estimator writes) and retargeted onto anny by
  :func:`physar.recon.importer.retarget`, the same function ``recon import`` runs, so the imported poses equal
  the generator's. In the torso frame :math:`Q` (root yaw about z, then roll about y, at the pelvis), each SMPL
  joint's global rotation is :math:`G_j = Q\, W_j\, M` with :math:`M` = ``SMPL_TO_BODY``; :math:`W_j = I`
  except on the arms: shoulder, elbow and wrist get the smallest rotation taking SMPL's T-pose direction
  (:math:`\pm x`) onto the wanted direction of the upper arm :math:`u`, the forearm :math:`f` and the hand
  (:math:`f`: a straight wrist). :math:`u` puts the elbow at :math:`(\pm` ``elbow_out``, shoulder :math:`y -`
  ``elbow_forward``, below the shoulder at the upper arm's length); :math:`f \propto (\mp` ``forearm_inward``,
  :math:`-1, 0)`, horizontal. Locals :math:`L_j = G_{p(j)}^\top G_j`; ``transl`` = the pelvis, lowered by the
  press depth :math:`d(t)` (the whole body sinks, as with bent knees: the forearms descend level, without
  sliding along the object).
* **Clips**: spin (yaw :math:`\pm` ``spin_deg`` about the vertical through the pelvis, depth 0, object at rest,
  LBS only); dynamic (:math:`d` = ``press_obs`` at the end of the observed part, ``press_pred`` at the end;
  smoothstep); novel (roll ``novel_roll_deg`` about the forward axis while pressing ``press_novel`` with another
  timing: one forearm goes deeper than the other).
* **Object** (``object = "c_pillow"``): a C lying on its back, spine at +y next to the torso (back face
  ``torso_clearance`` in front of the torso), prongs pointing at the camera; its top ``gap`` below the lowest
  forearm/hand vertex of the first frame; material of :func:`physar.recon.synth.object_material` (stiff spine
  ``E_stiff``, soft prongs ``E_soft``, fibres tangent to the C's centreline, ``fiber_E``) and, with
  ``yield_stress`` > 0, Hencky elasticity with von Mises plasticity (:func:`physar.recon.synth.simulate_clip`):
  a material the reconstruction's isotropic elastic expert law cannot express.
* **Object** (``object = "bag"``, ``action = "lift"``): a bag body (``bag_size``) with a handle over its top: two
  posts at :math:`\pm x` outside both forearms and a bar along x above them, ``handle_length`` along y around the
  forearms' midpoints, a tunnel ``handle_hole`` high centred on the forearms; the body rises (negative depth), the
  forearms catch the bar and carry the bag off a ``separate`` support (``recon import --floor separate``);
  material of :func:`physar.recon.synth.object_material` (stiff shell ``bag_wall`` thick and handle, soft filling,
  fibres vertical in the shell and the posts, along y in the bar).
* **Truth dynamics**: :func:`physar.recon.synth.simulate_clip` on ``gt_particles_per_cell`` particles per cell
  (finer than the reconstruction's); the simulated bones are those whose skinned vertices come within one grid
  cell of the object in the clip and whose lattice stays in the MPM domain (the rule of the reconstruction's
  :class:`physar.recon.train.Rig`), actuated by the gated PD controller towards their LBS trajectory; with
  ``soft_layer`` > 0 the particles within that depth of the body's rest surface get no PD force
  (:func:`physar.recon.synth.soft_tissue_gate`, :math:`\omega = 0`, seed §4.2): a passive layer that only
  elasticity and contact move.
* **Images**: :func:`physar.recon.pointrender.render_spheres` (z-buffered shaded spheres, not Gaussians) of the
  fine object particles on the object's surface layer, the simulated body particles and samples of anny's skinned
  surface (area-uniform, ``body_spacing`` apart on average); a second flat-shaded pass gives per-pixel labels
  (person 1, object 2). The camera looks at the object from the -y side (azimuth 0, so that the imported world
  frame's axes are the generator's up to sign and the object's boxes stay on the voxel grid).
  With ``truth_splats = "ellipsoids"`` each object sphere is carried by the total deformation of its fine
  particle (:func:`lattice_deformation`, plastic flow included), so the drawn surface stretches with the
  material, as a real surface does (and as seed Eq. 4 deforms Gaussians: ``render_deformation = "state"``).

:func:`generate_anny` writes a DATA_DIR in the layout of :mod:`physar.recon.synth` (scene.json with
``body.model = "anny"``, poses, spin/, rgb/, mask/, novel/, truth.npz) plus ``smpl/`` (SMPL parameters of each
clip in world coordinates). :func:`export_user_files` writes what a user would have: ``clip.mp4`` (spin then
dynamic frames), ``masks/`` (palette label PNGs), ``smpl.npz`` (``global_orient``, ``body_pose`` axis-angle
(F, 69), ``betas``, ``transl``, camera coordinates), ``novel.mp4``/``novel_masks/``/``novel_smpl.npz``,
``object.obj`` (the object's boxes in camera coordinates) and ``import_args.json`` (the ``recon import``
flags: focal length, up vector, sizes). :func:`attach_truth` adds the novel clip and the truth (moved into the
imported world frame) to an imported DATA_DIR, for evaluation only.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from physar.errors import ConfigError, refuse_coercion
from physar.output import atomic_folder, own_names
from physar.recon import scene as S
from physar.recon.importer import retarget, rotation_between
from physar.recon.pointrender import render_spheres
from physar.recon.synth import (
    BODY_AREA,
    MAX_BODY_SPACING,
    MAX_FPS,
    MAX_GRAVITY,
    MAX_SEED,
    MAX_SUBSTEPS,
    PARTS,
    Size3,
    _checker,
    check_camera,
    check_particles_per_cell,
    check_render_memory,
    check_sample_count,
    check_simulation,
    load_section_config,
    sim_walls,
    simulate_clip,
    soft_tissue_gate,
)
from physar.skinning import SMPL_JOINTS, SMPL_PARENTS, SMPL_TO_BODY, load_body

Vec3 = tuple[float, float, float]
ARM_BONES = ("lowerarm", "wrist", "finger", "metacarpal")  # prefixes of the bones that may touch the object


class AnnySceneConfig(BaseModel):
    """Parameters of the anny scene (SI units; module docstring); numbers must be finite."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_coercion(cls, value, info):
        return refuse_coercion(value, cls.model_fields[info.field_name].annotation)

    body: Literal["anny"] = Field("anny", description="the body (anny: the default recon body)")
    object: Literal["c_pillow", "bag"] = Field("c_pillow", description="the object: c_pillow | bag")
    action: Literal["squeeze", "lift"] = Field("squeeze", description="squeeze (c_pillow: both forearms press the "
                                               "C's upper prong) | lift (bag: both forearms rise under its handle)")
    image_size: int = Field(256, ge=16, le=1024, description="square image side, px")
    fov_deg: float = Field(40.0, gt=5, lt=120, description="vertical field of view [deg]")
    camera_distance: float = Field(0.9, gt=0.1, description="m, from the object centre")
    camera_elevation_deg: float = Field(25.0, ge=-80, le=80, description="camera elevation [deg]")
    fps: float = Field(30.0, gt=0, le=MAX_FPS, description="frame rate [fps]")
    frames: int = Field(12, ge=3, le=2000, description="frames of the dynamic clip")
    n_obs: int = Field(8, ge=2, description="observed frames of the dynamic clip")
    novel_frames: int = Field(10, ge=2, le=2000, description="frames of the novel-action clip")
    spin_frames: int = Field(8, ge=2, le=2000, description="frames of the spin clip")
    spin_deg: float = Field(20.0, ge=0, le=90, description="yaw amplitude of the spin clip [deg]")
    height: float = Field(1.7, gt=0.5, lt=2.5, description="body height [m]")
    elbow_out: float = Field(0.21, gt=0, description="elbow distance from the body's midplane [m]")
    elbow_forward: float = Field(0.10, ge=0, description="elbow in front of the shoulder [m]")
    forearm_inward: float = Field(0.45, ge=0, description="forearm direction (-+inward, -1, 0): inward slope [-]")
    c_pillow_size: Size3 = Field((0.30, 0.24, 0.18), description="C pillow (x, y, z) [m]; multiples of the cell")
    c_thickness: float = Field(0.06, gt=0, description="prong and spine thickness [m]")
    torso_clearance: float = Field(0.05, ge=0, description="gap between the torso's front and the C's spine [m]")
    gap: float = Field(0.005, ge=0, description="gap between the lowest forearm/hand vertex and the object [m]")
    press_obs: float = Field(0.045, ge=0, description="press depth at the end of the observed part [m]")
    press_pred: float = Field(0.075, ge=0, description="press depth at the end of the dynamic clip [m]")
    press_novel: float = Field(0.065, ge=0, description="press depth of the novel action [m]")
    novel_roll_deg: float = Field(6.0, ge=-30, le=30, description="roll of the body in the novel action [deg]")
    depth_keys: list[tuple[float, float]] = Field(
        [], description="keyframes (frame, depth [m]) of the dynamic clip's press, smoothstep between them, held "
        "after the last; e.g. a press and a release: [[0, 0], [2, 0.05], [4, 0]] (empty: press_obs at the last "
        "observed frame, then press_pred)")
    novel_depth_keys: list[tuple[float, float]] = Field(
        [], description="keyframes (frame, depth [m]) of the novel action's press (empty: press_novel, smoothstep "
        "over the first 70 % of the clip); the roll follows depth / its largest value")
    E_soft: float = Field(3.0e3, gt=0, description="Young's modulus of the prongs [Pa]")
    E_stiff: float = Field(1.2e4, gt=0, description="Young's modulus of the spine [Pa]")
    fiber_E: float = Field(2.4e4, ge=0, description="fibre modulus [Pa]")
    yield_stress: float = Field(800.0, ge=0, description="von Mises yield stress of the object [Pa] (0: elastic)")
    nu: float = Field(0.3, gt=-1, lt=0.5, description="Poisson ratio of the object [-]")
    density: float = Field(200.0, gt=0, description="object density [kg/m^3]")
    human_E: float = Field(1.0e4, gt=0, description="Young's modulus of the simulated body [Pa]")
    human_density: float = Field(1000.0, gt=0, description="density of the simulated body [kg/m^3]")
    soft_layer: float = Field(0.0, ge=0, description="passive layer of the simulated body [m]: particles within "
                              "soft_layer of the body's rest surface get no PD force (omega = 0; moved by "
                              "elasticity and contact only, physar.recon.synth.soft_tissue_gate); 0: the whole "
                              "simulated body is driven")
    kp: float = Field(3.0e3, ge=0, description="PD gain of the truth [1/s^2]")
    kd: float = Field(110.0, ge=0, description="PD gain of the truth [1/s]")
    domain_size: float = Field(0.6, gt=0, description="MPM domain side [m]")
    grid_resolution: int = Field(20, ge=4, le=256, description="MPM cells per side")
    substeps: int = Field(32, ge=1, le=MAX_SUBSTEPS, description="MPM steps per frame")
    gravity: float = Field(-9.81, ge=-MAX_GRAVITY, le=MAX_GRAVITY, description="vertical acceleration [m/s^2]")
    gt_particles_per_cell: int = Field(27, description="particles per cell of the truth: 1, 8, 27 or 64")
    truth_splats: Literal["spheres", "ellipsoids"] = Field(
        "spheres", description="how the truth's object particles are drawn: rigid spheres, or ellipsoids carried by "
        "the material's total deformation (a surface that stretches with the object, as a real one does)")
    body_spacing: float = Field(0.008, gt=0, le=MAX_BODY_SPACING, description="mean spacing of the rendered body "
                                "surface samples [m] (at most 2e6 samples of the body's surface: >= 1.1 mm)")
    bag_size: Size3 = Field((0.54, 0.15, 0.12), description="bag body (x, y, z) below the handle [m]")
    bag_wall: float = Field(0.03, gt=0, description="bag: shell, posts and bar thickness [m]")
    handle_length: float = Field(0.09, gt=0, description="bag: extent of the handle along y [m]")
    handle_hole: float = Field(0.12, gt=0, description="bag: clear height under the handle's bar [m]")
    seed: int = Field(0, ge=0, le=MAX_SEED, description="seed of the body surface samples")

    @field_validator("gt_particles_per_cell")
    @classmethod
    def _per_cell(cls, value):
        return check_particles_per_cell(value)

    @field_validator("body_spacing")
    @classmethod
    def _spacing(cls, value):
        return check_sample_count(value, BODY_AREA, 2, "body surface samples")

    @model_validator(mode="after")
    def _check(self):
        if self.n_obs >= self.frames:
            raise ValueError(f"n_obs ({self.n_obs}) must be < frames ({self.frames})")
        if (self.object, self.action) not in (("c_pillow", "squeeze"), ("bag", "lift")):
            raise ValueError(f"action '{self.action}' is not supported for object '{self.object}' (c_pillow + "
                             "squeeze, bag + lift)")
        for name, keys, n in (("depth_keys", self.depth_keys, self.frames),
                              ("novel_depth_keys", self.novel_depth_keys, self.novel_frames)):
            if not keys:
                continue
            f = [k[0] for k in keys]
            if f[0] != 0 or any(b <= a for a, b in pairwise(f)) or f[-1] > n - 1:
                raise ValueError(f"{name} frames {f} must start at 0, increase and end by frame {n - 1}")
            if any(k[1] < 0 for k in keys):
                raise ValueError(f"{name} depths must be >= 0 (how far the body sinks, or rises for a lift)")
        L, D, H = self.c_pillow_size
        if not (2 * self.c_thickness < H and self.c_thickness < D):
            raise ValueError(f"c_thickness = {self.c_thickness} m needs 2 x thickness < height ({H}) and < depth ({D})")
        dx = self.domain_size / self.grid_resolution
        sizes = ((("c_pillow_size x", L), ("c_pillow_size y", D), ("c_pillow_size z", H), ("c_thickness",
                                                                                            self.c_thickness))
                 if self.object == "c_pillow" else tuple((f"bag_size {a}", v) for a, v in zip("xyz", self.bag_size))
                 + (("bag_wall", self.bag_wall), ("handle_length", self.handle_length),
                    ("handle_hole", self.handle_hole)))
        for name, v in sizes:
            if abs(v / dx - round(v / dx)) > 1e-6:
                raise ValueError(f"{name} = {v} m must be a multiple of the cell {dx:g} m (domain_size / "
                                 "grid_resolution): the imported voxels must give the same boxes")
        if self.object == "c_pillow":
            check_simulation(self, ("c_thickness", self.c_thickness), L * D * H)
        else:
            bl, bw, bh = self.bag_size
            check_simulation(self, ("bag_wall", self.bag_wall),
                             bl * bw * bh + bl * self.handle_length * (self.handle_hole + self.bag_wall))
        return self


def load_anny_config(path, overrides: dict | None = None) -> AnnySceneConfig:
    """[synth] table of a TOML (one-line errors)."""
    return load_section_config(path, "synth", AnnySceneConfig, overrides)


# ----------------------------------------------------------------------------------------------- poses
def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def arm_directions(cfg: AnnySceneConfig, body) -> dict:
    """Wanted world directions (torso frame) of each side's upper arm, forearm and hand: {side: (u, f, f)}."""
    sk = body.skeleton
    H = sk.rest_global[:, :3, 3].double().numpy()
    out = {}
    for s, sx in (("L", 1.0), ("R", -1.0)):
        S0, E0 = H[sk.index(f"upperarm01.{s}")], H[sk.index(f"lowerarm01.{s}")]
        Lu = np.linalg.norm(E0 - S0)
        dxy = np.array([sx * cfg.elbow_out - S0[0], -cfg.elbow_forward])
        if np.linalg.norm(dxy) >= Lu:
            raise ConfigError(f"elbow_out / elbow_forward put the elbow {np.linalg.norm(dxy):.3f} m from the shoulder "
                              f"sideways, beyond the upper arm's length {Lu:.3f} m")
        u = np.array([dxy[0], dxy[1], -np.sqrt(Lu**2 - dxy @ dxy)]) / Lu
        f = np.array([-sx * cfg.forearm_inward, -1.0, 0.0])
        out[s] = (u, f / np.linalg.norm(f), f / np.linalg.norm(f))
    return out


def smpl_world(cfg: AnnySceneConfig, body, depth, roll=None, yaw=None) -> dict:
    """SMPL parameters in world coordinates (module docstring): local rotations (F, 24, 3, 3) and ``transl``
    (F, 3) = the pelvis, for press depths ``depth`` (F,) m, roll and yaw angles (F,) rad."""
    depth = np.asarray(depth, dtype=np.float64)
    F = len(depth)
    roll = np.zeros(F) if roll is None else np.asarray(roll, dtype=np.float64)
    yaw = np.zeros(F) if yaw is None else np.asarray(yaw, dtype=np.float64)
    M = SMPL_TO_BODY
    dirs = arm_directions(cfg, body)
    W = {j: np.eye(3) for j in range(24)}
    for s, side, sx in (("L", "left", 1.0), ("R", "right", -1.0)):
        u, f, hnd = dirs[s]
        tx = np.array([sx, 0.0, 0.0])
        W[SMPL_JOINTS.index(f"{side}_shoulder")] = rotation_between(tx, u)
        W[SMPL_JOINTS.index(f"{side}_elbow")] = rotation_between(tx, f)
        W[SMPL_JOINTS.index(f"{side}_wrist")] = rotation_between(tx, hnd)
        W[SMPL_JOINTS.index(f"{side}_hand")] = W[SMPL_JOINTS.index(f"{side}_wrist")]
    G = np.empty((F, 24, 3, 3))
    for k in range(F):
        Q = _rz(yaw[k]) @ _ry(roll[k])
        for j in range(24):
            G[k, j] = Q @ W[j] @ M
    L = np.empty_like(G)
    for j, p in enumerate(SMPL_PARENTS):
        L[:, j] = G[:, j] if p < 0 else np.swapaxes(G[:, p], -1, -2) @ G[:, j]
    sk = body.skeleton
    pelvis = sk.rest_global[sk.index("root"), :3, 3].double().numpy()
    transl = pelvis[None] + np.outer(-depth, [0.0, 0.0, 1.0])
    return {"rotations": L, "transl": transl}


def body_poses(smpl: dict, body) -> dict:
    """anny poses of world-frame SMPL parameters (:func:`physar.recon.importer.retarget` with the identity
    camera)."""
    return retarget(smpl, body, np.eye(3), np.zeros(3))


def smpl_to_camera(smpl: dict, R: np.ndarray, t: np.ndarray) -> dict:
    """SMPL parameters in camera coordinates (p_C = R p_W + t) as a pose estimator writes them: axis-angle
    ``global_orient`` (F, 3), ``body_pose`` (F, 69), ``betas`` (F, 10) zeros, ``transl`` (F, 3)."""
    from scipy.spatial.transform import Rotation

    L = smpl["rotations"].copy()
    L[:, 0] = R @ L[:, 0]
    F = len(L)
    aa = Rotation.from_matrix(L.reshape(-1, 3, 3)).as_rotvec().reshape(F, 24, 3)
    return {"global_orient": aa[:, 0], "body_pose": aa[:, 1:].reshape(F, 69), "betas": np.zeros((F, 10)),
            "transl": smpl["transl"] @ R.T + t}


def keyed_depth(keys, frames: int) -> np.ndarray:
    """Depth (frames,) through keyframes ``keys`` [(frame, depth), ...]: smoothstep from each key to the next,
    held after the last."""
    f = np.arange(frames, dtype=np.float64)
    d = np.full(frames, float(keys[-1][1]))
    for (fa, da), (fb, db) in pairwise(keys):
        m = (f >= fa) & (f <= fb)
        d[m] = da + (db - da) * S.smoothstep((f[m] - fa) / (fb - fa))
    return d


def clip_depths(cfg: AnnySceneConfig) -> dict:
    """Press depth, roll and yaw (F,) of each clip: spin, dynamic (key ""), novel."""
    f = np.arange(cfg.frames, dtype=np.float64)
    if cfg.depth_keys:
        d = keyed_depth(cfg.depth_keys, cfg.frames)
    else:
        d = cfg.press_obs * S.smoothstep(f / (cfg.n_obs - 1))
        m = f >= cfg.n_obs
        d[m] = cfg.press_obs + (cfg.press_pred - cfg.press_obs) * S.smoothstep((f[m] - cfg.n_obs + 1)
                                                                               / (cfg.frames - cfg.n_obs))
    sign = -1.0 if cfg.action == "lift" else 1.0  # a lift raises the body: negative depth
    d = sign * d
    fn = np.arange(cfg.novel_frames, dtype=np.float64)
    if cfg.novel_depth_keys:  # the roll follows the press
        dn = keyed_depth(cfg.novel_depth_keys, cfg.novel_frames)
        sn = dn / max(dn.max(), 1e-12)
    else:
        sn = S.smoothstep(fn / (0.7 * (cfg.novel_frames - 1)))
        dn = cfg.press_novel * sn
    fs = np.arange(cfg.spin_frames, dtype=np.float64)
    ys = np.radians(cfg.spin_deg) * (2 * S.smoothstep(fs / max(cfg.spin_frames - 1, 1)) - 1)
    z = lambda n: np.zeros(n)
    return {"spin": (z(cfg.spin_frames), z(cfg.spin_frames), ys), "": (d, z(cfg.frames), z(cfg.frames)),
            "novel": (sign * dn, np.radians(cfg.novel_roll_deg) * sn, z(cfg.novel_frames))}


# ----------------------------------------------------------------------------------------------- layout
def arm_bone_ids(body) -> list[int]:
    return [k for k, n in enumerate(body.skeleton.names) if n.startswith(ARM_BONES)]


def scene_meta(cfg: AnnySceneConfig, body, poses0: dict) -> dict:
    """scene.json: the C placed under the forearms of the first dynamic frame, in front of the torso; or the bag
    with its handle's tunnel (along y) around the forearms' midpoints, its posts outside both forearms."""
    B = S.bone_transforms(body, poses0["rotations"][:1], poses0["root_translation"][:1])[0]
    V = body.skin_vertices(B).numpy()
    own = body.vertex_owner().numpy()
    arm = np.isin(own, arm_bone_ids(body))
    torso = np.isin(own, [k for k, n in enumerate(body.skeleton.names) if n.startswith(("spine", "root",
                                                                                             "pelvis"))])
    V3 = lambda *v: np.array(v, dtype=np.float64)
    travel = max(np.abs(v[0]).max() for k, v in clip_depths(cfg).items() if k != "spin")  # deepest press
    if cfg.object == "c_pillow":
        L, D, H = cfg.c_pillow_size
        t = cfg.c_thickness
        top = float(V[arm, 2].min()) - cfg.gap
        near = torso & (np.abs(V[:, 2] - top) < 0.15)
        back = float(V[near, 1].min()) - cfg.torso_clearance  # the C's spine face (+y)
        bot, y0, y1 = top - H, back - D, back
        boxes = [(V3(-L / 2, y0, bot), V3(L / 2, y1, bot + t)),  # lower prong
                 (V3(-L / 2, y1 - t, bot + t), V3(L / 2, y1, top - t)),  # spine
                 (V3(-L / 2, y0, top - t), V3(L / 2, y1, top))]  # upper prong
        rise = 0.0
    else:  # bag: both forearms in the handle's tunnel (along y), posts at +-x outside them, bar above
        L, D, H = cfg.bag_size
        w, hl, ho = cfg.bag_wall, cfg.handle_length, cfg.handle_hole
        sk = body.skeleton
        G = sk.pose(torch.as_tensor(poses0["rotations"][:1]), torch.as_tensor(poses0["root_translation"][:1]))[0]
        yc = 0.5 * float(G[sk.index("lowerarm01.L"), 1, 3] + G[sk.index("wrist.L"), 1, 3])
        band = arm & (np.abs(V[:, 1] - yc) < hl / 2 + 0.02)
        zb, zt, xm = float(V[band, 2].min()), float(V[band, 2].max()), float(np.abs(V[band, 0]).max())
        if zt - zb > ho - 0.01 or xm > L / 2 - w - 0.005:
            raise ConfigError(f"bag: the forearms ({zt - zb:.3f} m thick, reaching |x| = {xm:.3f} m) do not fit the "
                              f"handle's tunnel ({ho} m high, |x| < {L / 2 - w:.3f} m): raise handle_hole or bag_size x")
        mid = 0.5 * (zb + zt)
        bot = mid - ho / 2 - H
        y0, y1 = yc - D / 2, yc + D / 2
        torso_y = float(V[torso & (np.abs(V[:, 2] - mid) < 0.15), 1].min())
        if y1 > torso_y - cfg.torso_clearance:
            raise ConfigError(f"bag: its back (y = {y1:.3f} m) is within torso_clearance of the torso ({torso_y:.3f})")
        top = mid + ho / 2 + w
        boxes = [(V3(-L / 2, y0, bot), V3(L / 2, y1, mid - ho / 2)),  # body
                 (V3(-L / 2, yc - hl / 2, mid - ho / 2), V3(-L / 2 + w, yc + hl / 2, mid + ho / 2)),  # post (-x)
                 (V3(L / 2 - w, yc - hl / 2, mid - ho / 2), V3(L / 2, yc + hl / 2, mid + ho / 2)),  # post (+x)
                 (V3(-L / 2, yc - hl / 2, mid + ho / 2), V3(L / 2, yc + hl / 2, top))]  # bar
        rise = travel
    lo, hi = V3(-L / 2, y0, bot), V3(L / 2, y1, top)
    size = cfg.domain_size
    origin = V3(-size / 2, 0.5 * (y0 + y1) - size / 2, bot)
    if max(L, D) > 0.8 * size or (top - bot) + travel > 0.9 * size:
        raise ConfigError(f"domain_size = {size} m is too small for the object ({np.round(hi - lo, 3).tolist()} m) "
                          f"and the travel {travel} m")
    centre = 0.5 * (lo + hi) + V3(0.0, 0.0, 0.5 * rise)
    el = np.radians(cfg.camera_elevation_deg)
    eye = centre + cfg.camera_distance * np.array([0.0, -np.cos(el), np.sin(el)])
    check_camera(cfg, eye, origin, hi - lo)
    return {
        "format_version": S.FORMAT_VERSION, "kind": "physar.recon synthetic scene (anny)",
        "fps": cfg.fps, "frames": cfg.frames, "n_obs": cfg.n_obs, "novel_frames": cfg.novel_frames,
        "camera": S.look_at(eye, centre, cfg.fov_deg, cfg.image_size, cfg.image_size),
        "background": [0.3, 0.3, 0.35],
        "body": {"model": "anny", "kind": "mesh", "height": cfg.height, "simulated_bones": [],
                 "E": cfg.human_E, "density": cfg.human_density},
        "object": {"shape": "box_union", "kind": cfg.object, "action": cfg.action, "min": lo.tolist(),
                   "max": hi.tolist(), "boxes": [[a.tolist(), b.tolist()] for a, b in boxes],
                   "parts": PARTS[cfg.object], "density": cfg.density, "nu": cfg.nu, "material": "fixed_corotated"},
        "sim": {"size": size, "resolution": cfg.grid_resolution, "substeps": cfg.substeps, "origin": origin.tolist(),
                "gravity": [0.0, 0.0, cfg.gravity], "walls": sim_walls("separate" if cfg.action == "lift" else "sticky"),
                "kp": cfg.kp, "kd": cfg.kd},
        "synth_config": cfg.model_dump(),
    }


def simulated_bones(body, meta: dict, clips: list[dict], h: float) -> list[str]:
    """Bones within one grid cell of the object in some clip whose lattice (spacing h) stays in the domain."""
    sim = meta["sim"]
    dx = sim["size"] / sim["resolution"]
    origin = np.asarray(sim["origin"])
    boxes = S.object_boxes(meta)
    reach = set()
    for p in clips:
        reach |= set(S.reaching_bones(body, p["rotations"], p["root_translation"], boxes, dx))
    out = []
    for b in body.skeleton.names:
        if b not in reach:
            continue
        P = S.body_points(body, [b], h)
        if len(P) == 0:
            continue
        ok = all(np.all((x >= 0) & (x <= sim["size"])) for x in
                 (S.skin_sequence(body, P, p["rotations"], p["root_translation"])[0] - origin for p in clips))
        if ok:
            out.append(b)
    return out


# ----------------------------------------------------------------------------------------------- rendering
def surface_samples(body, spacing: float, exclude: list[str], seed: int = 0) -> np.ndarray:
    r"""Area-uniform points on the rest mesh (about one per :math:`\mathrm{spacing}^2`), without those owned by
    ``exclude``."""
    V, T = body.vertices.double().numpy(), body.faces.numpy()
    a = 0.5 * np.linalg.norm(np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]]), axis=1)
    rng = np.random.default_rng(seed)
    n = int(a.sum() / spacing**2)
    tri = rng.choice(len(T), n, p=a / a.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    P = (1 - s)[:, None] * V[T[tri, 0]] + (s * (1 - r2))[:, None] * V[T[tri, 1]] + (s * r2)[:, None] * V[T[tri, 2]]
    ex = [body.skeleton.index(b) for b in exclude]
    return P[~np.isin(body.owner(torch.as_tensor(P)).numpy(), ex)]


def surface_layer(X: np.ndarray, h: float) -> np.ndarray:
    """Lattice points (spacing h) with fewer than 6 face neighbours: the object's surface layer (the only
    visible ones)."""
    from scipy.spatial import cKDTree

    cnt = np.array([len(q) for q in cKDTree(X).query_ball_point(X, 1.01 * h)]) - 1
    return cnt < 6


SKIN, SLEEVE = (0.9, 0.7, 0.55), (0.55, 0.6, 0.85)


def lattice_deformation(X: np.ndarray, x: np.ndarray, h: float) -> np.ndarray:
    r"""Total deformation gradients (N, 3, 3) of lattice points X (N, 3) (spacing h) moved to x: per point,
    :math:`F = \big(\sum_j dx_j\, dX_j^\top\big)\big(\sum_j dX_j\, dX_j^\top\big)^{-1}` over its lattice
    neighbours (distance h); the identity where the neighbours do not span 3-D. Plastic flow included (the
    simulator's own F is the elastic part)."""
    from scipy.spatial import cKDTree

    pr = cKDTree(X).query_pairs(1.01 * h, output_type="ndarray")
    i, j = pr[:, 0], pr[:, 1]
    dX, dx = X[j] - X[i], x[j] - x[i]
    B, A = np.zeros((len(X), 3, 3)), np.zeros((len(X), 3, 3))
    for k in (i, j):
        np.add.at(B, k, dX[:, :, None] * dX[:, None, :])
        np.add.at(A, k, dx[:, :, None] * dX[:, None, :])
    F = np.tile(np.eye(3), (len(X), 1, 1))
    ok = np.linalg.matrix_rank(B, tol=1e-6 * h * h) == 3
    F[ok] = A[ok] @ np.linalg.inv(B[ok])
    return F


def render_frames(meta: dict, xo: np.ndarray, col_o: np.ndarray, ro: float, xh: np.ndarray, rh: float,
                  xb: np.ndarray, col_b: np.ndarray, rb: float, Fo: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """RGB uint8 (H, W, 3) and labels uint8 (H, W) (0 background, 1 person, 2 object) of one frame: object
    points xo (colours col_o, radius ro; with Fo (No, 3, 3) the ellipsoids of those deformations), simulated body
    particles xh (skin, rh), body surface samples xb (col_b, rb)."""
    K, R, t = S.camera_matrices(meta)
    W = H = int(meta["camera"]["width"])
    pts = np.concatenate([xo, xh, xb])
    rad = np.r_[np.full(len(xo), ro), np.full(len(xh), rh), np.full(len(xb), rb)]
    cols = np.concatenate([col_o, np.tile(SKIN, (len(xh), 1)), col_b])
    deform = None if Fo is None else np.concatenate([Fo, np.tile(np.eye(3), (len(xh) + len(xb), 1, 1))])
    rgb, mask = render_spheres(pts, cols, rad, K, R, t, W, H, background=meta["background"], deform=deform)
    lab = np.zeros((len(pts), 3))
    lab[: len(xo), 1] = 1.0
    lab[len(xo):, 0] = 1.0
    lc, _ = render_spheres(pts, lab, rad, K, R, t, W, H, background=(0, 0, 0), ambient=1.0, deform=deform)
    labels = np.where(mask, np.where(lc[..., 1] > lc[..., 0], 2, 1), 0).astype(np.uint8)
    return (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8), labels


# ----------------------------------------------------------------------------------------------- generate
DATA_DIR_FILES = own_names(r"scene\.json", r"(novel_|spin_)?poses\.npz", r"rgb", r"mask", r"spin", r"novel",
                           r"truth\.npz", r"video\.mp4", r"smpl", r"labels")


def generate_anny(out_dir, cfg: AnnySceneConfig | None = None,
                  progress: Callable[[str, int, int], None] | None = None) -> Path:
    """Simulate and render the anny scene into ``out_dir`` (module docstring); also ``labels/`` (the label
    PNGs of every clip) and ``smpl/`` (world-frame SMPL parameters). Returns the path."""
    from physar.recon.io import write_mp4

    cfg = cfg or AnnySceneConfig()
    out = Path(out_dir)
    body = load_body("anny", cfg.height)
    depths = clip_depths(cfg)
    smpl = {k: smpl_world(cfg, body, *v) for k, v in depths.items()}
    poses = {k: body_poses(v, body) for k, v in smpl.items()}
    meta = scene_meta(cfg, body, poses[""])
    sim = meta["sim"]
    dx = sim["size"] / sim["resolution"]
    h = dx / round(cfg.gt_particles_per_cell ** (1 / 3))
    meta["body"]["simulated_bones"] = simulated_bones(body, meta, [poses[""], poses["novel"]], h)
    if not meta["body"]["simulated_bones"]:
        raise ConfigError("no bone of anny reaches the object: check elbow_out / elbow_forward / gap")
    gate = soft_tissue_gate(body, S.body_points(body, meta["body"]["simulated_bones"], h), cfg.soft_layer)  # a bad
    # layer is refused now, before anything is rendered
    Xb = surface_samples(body, cfg.body_spacing, meta["body"]["simulated_bones"], cfg.seed)
    bare = np.isin(body.owner(torch.as_tensor(Xb)).numpy(), arm_bone_ids(body))  # hands and forearms: skin
    col_b = np.where(bare[:, None], SKIN, SLEEVE)
    prog = progress or (lambda *a: None)
    with atomic_folder(out, own=DATA_DIR_FILES) as tmp:
        (tmp / "scene.json").write_text(json.dumps(meta, indent=1))
        (tmp / "smpl").mkdir()
        truth, preview = {}, None
        for name in ("spin", "", "novel"):
            p = poses[name]
            key = name or "dynamic"
            np.savez(tmp / (f"{name}_poses.npz" if name else "poses.npz"), **p)
            np.savez(tmp / "smpl" / f"{key}.npz", **smpl[name])
            if name == "spin":
                Xo, _ = S.object_points(meta, h)
                Xh = S.body_points(body, meta["body"]["simulated_bones"], h)
                xh = S.skin_sequence(body, Xh, p["rotations"], p["root_translation"])[0]
                xo = np.broadcast_to(Xo, (len(xh), *Xo.shape))
            else:
                r = simulate_clip(cfg, meta, body, p, lambda i, n, key=key: prog(key, i, n), 0, len(p["rotations"]) - 1,
                                  gate=gate)
                xo, xh, Xo = r["xo"], r["xh"], r["Xo"]
                truth[f"{key}_max_displacement"] = np.linalg.norm(xo - xo[:1], axis=2).max(1)
                truth[f"{key}_mean_displacement"] = np.linalg.norm(xo - xo[:1], axis=2).mean(1)
                truth[f"{key}_object_positions"] = xo.astype(np.float32)
                truth[f"{key}_body_positions"] = xh.astype(np.float32)
                if not name:
                    for k in ("E", "fiber", "fiber_E", "part"):
                        truth[k] = r[k]
                    truth["rest_positions"] = r["Xo"]
            surf = surface_layer(Xo, h)
            col_o = _checker(Xo - Xo.min(0), 0.04, (0.85, 0.35, 0.3), (0.95, 0.85, 0.55))[surf]
            xb = S.skin_sequence(body, Xb, p["rotations"], p["root_translation"])[0]
            d = tmp / name if name else tmp
            for sub in ("rgb", "mask"):
                (d / sub).mkdir(parents=True, exist_ok=True)
            (tmp / "labels" / key).mkdir(parents=True)
            frames = []
            check_render_memory(np.concatenate([xo[:, surf], xh, xb], axis=1),
                                np.r_[np.full(int(surf.sum()) + xh.shape[1], 0.75 * h),
                                      np.full(xb.shape[1], 0.75 * cfg.body_spacing)], *S.camera_matrices(meta), cfg)
            for f in range(len(xo)):
                Fo = lattice_deformation(Xo, xo[f], h)[surf] if cfg.truth_splats == "ellipsoids" else None
                rgb, lab = render_frames(meta, xo[f][surf], col_o, 0.75 * h, xh[f], 0.75 * h, xb[f], col_b,
                                         0.75 * cfg.body_spacing, Fo)
                cv2.imwrite(str(d / "rgb" / f"{f:04d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
                cv2.imwrite(str(d / "mask" / f"{f:04d}.png"), (lab > 0).astype(np.uint8) * 255)
                cv2.imwrite(str(tmp / "labels" / key / f"{f:04d}.png"), lab)
                frames.append(rgb)
                prog(f"render {key}", f + 1, len(xo))
            if not name:
                preview = frames
        np.savez(tmp / "truth.npz", **truth)
        write_mp4(tmp / "video.mp4", preview, cfg.fps)
    return out


# ----------------------------------------------------------------------------------------------- user files
def _label_png(path: Path, labels: np.ndarray) -> None:
    from PIL import Image

    im = Image.fromarray(labels.astype(np.uint8), mode="P")
    im.putpalette([0, 0, 0, 200, 50, 50, 50, 200, 50] + [0] * 759)
    im.save(path)


def export_user_files(data_dir, out_dir) -> dict:
    """A generated DATA_DIR as a user's files (module docstring); returns the ``recon import`` arguments of the
    dynamic clip (``args``) and of the novel clip (``novel_args``), without ``--out``."""
    from physar.recon.io import read_pngs, write_mp4

    src, out = Path(data_dir), Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meta = json.loads((src / "scene.json").read_text())
    cfg = AnnySceneConfig.model_validate(meta["synth_config"])
    c = meta["camera"]
    R, t = np.asarray(c["R"]), np.asarray(c["t"])
    lab = lambda key, n: [cv2.imread(str(src / "labels" / key / f"{f:04d}.png"), cv2.IMREAD_GRAYSCALE)
                          for f in range(n)]
    clips = {"clip": [("spin", "spin", cfg.spin_frames), ("dynamic", "", cfg.frames)],
             "novel": [("novel", "novel", cfg.novel_frames)]}
    for stem, parts in clips.items():
        rgb, labels, sm = [], [], []
        for key, sub, n in parts:
            rgb += [(f * 255 + 0.5).astype(np.uint8) for f in read_pngs(src / sub / "rgb" if sub else src / "rgb", n)]
            labels += lab(key, n)
            with np.load(src / "smpl" / f"{key}.npz") as z:
                sm.append({k: z[k] for k in z.files})
        if not write_mp4(out / f"{stem}.mp4", rgb, cfg.fps):
            raise ConfigError("PyAV has no MP4 encoder: cannot write the user's video")
        mdir = out / ("masks" if stem == "clip" else "novel_masks")
        if mdir.exists():
            shutil.rmtree(mdir)
        mdir.mkdir()
        for i, L in enumerate(labels):
            _label_png(mdir / f"frame_{i:05d}.png", L)
        s = {"rotations": np.concatenate([x["rotations"] for x in sm]),
             "transl": np.concatenate([x["transl"] for x in sm])}
        np.savez(out / ("smpl.npz" if stem == "clip" else "novel_smpl.npz"), **smpl_to_camera(s, R, t))
    import trimesh

    parts = []
    for lo, hi in meta["object"]["boxes"]:
        lo, hi = np.array(lo), np.array(hi)
        b = trimesh.creation.box(extents=hi - lo)
        b.apply_translation((lo + hi) / 2)
        b.vertices = np.asarray(b.vertices) @ R.T + t
        parts.append(b)
    trimesh.util.concatenate(parts).export(out / "object.obj")
    up = ",".join(repr(float(v)) for v in R[:, 2])  # world +z in camera coordinates
    common = ["--object-mesh", out / "object.obj", f"--focal-px={c['fx']!r}", f"--up={up}",
              "--domain-size", meta["sim"]["size"], "--grid-resolution", meta["sim"]["resolution"],
              "--height", cfg.height, "--density", cfg.density, "--nu", cfg.nu,
              "--floor", "separate" if cfg.action == "lift" else "sticky"]
    args = [out / "clip.mp4", "--masks", out / "masks", "--poses", out / "smpl.npz", "--spin-frames",
            cfg.spin_frames, "--n-obs", cfg.n_obs, *common]
    nargs = [out / "novel.mp4", "--masks", out / "novel_masks", "--poses", out / "novel_smpl.npz",
             "--n-obs", cfg.novel_frames - 1, *common]
    res = {"args": [str(a) for a in args], "novel_args": [str(a) for a in nargs]}
    (out / "import_args.json").write_text(json.dumps(res, indent=1))
    return res


def world_map(src_meta: dict, dst_meta: dict) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) with p_dst = A p_src + b: the generator's world to an imported scene's world (same camera)."""
    R0, t0 = np.asarray(src_meta["camera"]["R"]), np.asarray(src_meta["camera"]["t"])
    R1, t1 = np.asarray(dst_meta["camera"]["R"]), np.asarray(dst_meta["camera"]["t"])
    return R1.T @ R0, R1.T @ (t0 - t1)


def attach_truth(imported_dir, novel_dir, data_dir) -> dict:
    """Add the novel clip (imported separately with the same flags) and the truth, moved into the imported world
    frame, to an imported DATA_DIR (evaluation only: ``recon fit`` never reads truth.npz). Returns the map
    {"A", "b"}."""
    dst, nov, src = Path(imported_dir), Path(novel_dir), Path(data_dir)
    m1 = json.loads((dst / "scene.json").read_text())
    m0 = json.loads((src / "scene.json").read_text())
    A, b = world_map(m0, m1)
    mn = json.loads((nov / "scene.json").read_text())
    An, bn = world_map(mn, m1)
    if np.abs(An - np.eye(3)).max() > 1e-9 or np.abs(bn).max() > 1e-9:
        raise ConfigError(f"{nov}: the novel clip's import has another world frame than {dst}")
    with np.load(src / "truth.npz") as z:
        tr = {k: z[k] for k in z.files}
    for k in list(tr):
        if k.endswith("_positions"):
            tr[k] = (np.asarray(tr[k], dtype=np.float64) @ A.T + b).astype(tr[k].dtype)
    tr["fiber"] = tr["fiber"] @ A.T
    np.savez(dst / "truth.npz", **tr)
    with np.load(nov / "poses.npz") as z:
        np.savez(dst / "novel_poses.npz", **{k: z[k] for k in z.files})
    if (dst / "novel").exists():
        shutil.rmtree(dst / "novel")
    (dst / "novel").mkdir()
    for sub in ("rgb", "mask"):
        shutil.copytree(nov / sub, dst / "novel" / sub)
    return {"A": A, "b": b}


__all__ = ["AnnySceneConfig", "attach_truth", "export_user_files", "generate_anny", "load_anny_config",
           "smpl_world"]
