"""Training pipeline of seed 002 §4 (PhysHO), reduced to what runs on a small CPU, and its baselines.

Stages (``fit``):

1. **appearance** (§4.1, Eq. 5): Gaussians = MPM particles of the object and of the simulated body part,
   plus LBS-driven Gaussians of the rest of the body; their colours (SH degree 0), opacities and scales are
   fitted to frame 0 with L_RGB = |I - I*|_1 (+ a mask term).  The canonical geometry (object box, body
   model, poses) is read from ``scene.json``/``poses.npz``; the spin-clip canonical reconstruction of §4.1
   is not reproduced (the synthetic scenes give the geometry).
2. **flow** (§4.4, Eq. 9): per-frame object particle positions x'_n optimised with RGB + mask losses and a
   rigidity term (squared change of rest edge lengths to lattice neighbours, the as-rigid-as-possible
   prior in its edge form); F of each particle from a least-squares fit to its neighbours' positions
   enters the covariance (Eq. 3).  No optical-flow term (DIS/RAFT) in this reduced pipeline.  These
   positions are also the **4DGS-like baseline** (per-frame optimised Gaussian deformation; it cannot
   predict: it holds the last observed frame).
3. **physics** (§4.2-4.4, Eq. 6-11): per-particle Young's modulus E of the object (log-parameterised) and
   the LBS-impact factor omega of the simulated body particles (omega = g_i 2 sigmoid(l_i), g_i = 1 strictly
   inside the body, 0 elsewhere: object particles are never actuated) are learned through the
   differentiable MPM (:mod:`physar.mpm.torch_bridge`) and the rasteriser with
   L_E2E = lambda_rgb |I - I*|_1 + lambda_mask |A - M|_1 + lambda_3Dflow |x_{n+1} - x'_{n+1}|_1   (Eq. 10)
   + R = lambda_omega ||omega||_2 [+ lambda_law (||E_theta|| + ||P_theta||) with the residual laws]  (Eq. 11),
   progressive (the frame window grows every ``window_grow_every`` iterations) and loss-balanced
   (each frame's loss is weighted by its previous loss relative to the mean).

Baselines in the same harness: ``lbs`` (kinematic: the body follows LBS, the object never moves) and
``4dgs`` (stage 2's per-frame positions).  Prediction (``predict``) runs the learned simulator on any pose
sequence (future frames of the clip, or a novel action).

Outputs users load are npz/PLY/JSON/MP4 (no pickle); ``checkpoint.pt`` (torch.save of tensors) is only for
resuming an interrupted ``fit``.
"""

from __future__ import annotations

import json
import math
import os
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from scipy.spatial import cKDTree

from physar.errors import ConfigError, PhysarError
from physar.gaussians import Camera, Gaussians, render, rgb_to_sh0, save_ply
from physar.mpm import torch_bridge as tb
from physar.mpm.model import MPMModel
from physar.recon import scene as S
from physar.recon.io import read_pngs, save_json_atomic, save_npz_atomic, write_mp4

MODEL_FORMAT = 1
Progress = Callable[[str, int, int, float], None]


class TrainConfig(BaseModel):
    """Training settings (TOML table [train]); lengths in m."""

    model_config = ConfigDict(extra="forbid")
    particles_per_cell: int = Field(1, description="object/body MPM particles per grid cell: 1, 8 or 27")
    body_spacing: float = Field(0.03, gt=0, description="spacing of the kinematic body Gaussians, m")
    appearance_iters: int = Field(150, ge=0)
    appearance_lr: float = Field(0.05, gt=0)
    flow_iters: int = Field(30, ge=0, description="per frame (Eq. 9; also the 4DGS-like baseline)")
    flow_lr: float = Field(2e-3, gt=0, description="Adam step on positions, m")
    rigidity: float = Field(1.0e3, ge=0, description="weight of the edge-length (ARAP) term, 1/m^2")
    physics_iters: int = Field(40, ge=0)
    physics_lr: float = Field(0.15, gt=0, description="Adam step on log E and omega logits")
    E_init: float = Field(6.0e3, gt=0, description="initial Young's modulus of the object, Pa")
    E_min: float = Field(5.0e2, gt=0)
    E_max: float = Field(3.0e4, gt=0, description="upper bound (keep the explicit MPM step stable)")
    omega_init: float = Field(1.0, gt=0, lt=2)
    window_start: int = Field(3, ge=2, description="frames in the first training window (progressive)")
    window_grow_every: int = Field(4, ge=1, description="iterations between window extensions")
    loss_balanced: bool = True
    lambda_rgb: float = Field(1.0, ge=0)
    lambda_mask: float = Field(1.0, ge=0)
    lambda_flow: float = Field(20.0, ge=0, description="3-D flow term of Eq. 10, 1/m")
    lambda_omega: float = Field(1.0e-5, ge=0, description="Eq. 11 (per-pixel mean losses: keep it small)")
    residual: bool = Field(False, description="neural residual laws E_theta with latents l_e (Eq. 8)")
    latent_dim: int = Field(16, ge=1)
    lambda_law: float = Field(1.0e-4, ge=0, description="Eq. 11, residual magnitude")
    checkpoint_every: int = Field(5, ge=1, description="physics iterations between checkpoints")
    seed: int = 0


def load_train_config(path: str | Path | None, overrides: dict | None = None) -> TrainConfig:
    data = {}
    if path is not None:
        p = Path(path)
        if not p.exists():
            raise ConfigError(f"config file '{p}' does not exist")
        try:
            raw = tomllib.loads(p.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: invalid TOML: {exc}") from None
        data = dict(raw.get("train", {})) if ("train" in raw or "synth" in raw) else raw
    data.update(overrides or {})
    try:
        return TrainConfig.model_validate(data)
    except ValidationError as exc:
        e = exc.errors()[0]
        raise ConfigError(f"{path or 'train config'}: field '{'.'.join(map(str, e['loc']))}': {e['msg']} "
                          f"(got {e.get('input')!r})") from None


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

    @property
    def n_obs(self) -> int:
        return int(self.meta["n_obs"])


def load_dataset(path: str | Path, with_truth: bool = True) -> Dataset:
    root = Path(path)
    sj = root / "scene.json"
    if not sj.exists():
        raise ConfigError(f"'{root}' is not a recon DATA_DIR: missing scene.json")
    try:
        meta = json.loads(sj.read_text())
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{sj}: invalid JSON: {exc}") from None
    for key in ("camera", "sim", "body", "object", "n_obs", "fps"):
        if key not in meta:
            raise ConfigError(f"{sj}: missing field '{key}'")
    if meta.get("format_version") != S.FORMAT_VERSION:
        raise ConfigError(f"{sj}: format_version {meta.get('format_version')} (expected {S.FORMAT_VERSION})")
    body = S.humanoid(meta["body"]["height"])
    nb = body.skeleton.n_bones
    rot, rt = S.check_poses(_npz(root / "poses.npz"), nb, str(root / "poses.npz"))
    n = len(rot)
    if not 2 <= meta["n_obs"] <= n:
        raise ConfigError(f"{sj}: n_obs = {meta['n_obs']} must be in [2, {n}]")
    rgb, mask = read_pngs(root / "rgb", n), read_pngs(root / "mask", n, gray=True)
    novel = None
    if (root / "novel_poses.npz").exists():
        r2, t2 = S.check_poses(_npz(root / "novel_poses.npz"), nb, str(root / "novel_poses.npz"))
        novel = {"rotations": r2, "root_t": t2, "rgb": read_pngs(root / "novel" / "rgb", len(r2)),
                 "mask": read_pngs(root / "novel" / "mask", len(r2), gray=True)}
    truth = _npz(root / "truth.npz") if with_truth and (root / "truth.npz").exists() else None
    return Dataset(root, meta, rgb, mask, rot, rt, novel, truth)


def _npz(path: Path) -> dict:
    if not path.exists():
        raise ConfigError(f"missing file '{path}'")
    try:
        with np.load(path, allow_pickle=False) as d:
            return {k: d[k] for k in d.files}
    except (ValueError, OSError) as exc:
        raise ConfigError(f"'{path}' is not a readable npz file: {exc}") from None


# ----------------------------------------------------------------------------------------------- rig
class Rig:
    """Particles, MPM model, camera and LBS machinery of a scene at the reconstruction's sampling."""

    def __init__(self, meta: dict, cfg: TrainConfig):
        k = round(cfg.particles_per_cell ** (1 / 3))
        if k**3 != cfg.particles_per_cell:
            raise ConfigError(f"train.particles_per_cell = {cfg.particles_per_cell} must be 1, 8, 27 or 64")
        self.meta, self.cfg = meta, cfg
        sim = meta["sim"]
        self.body = S.humanoid(meta["body"]["height"])
        self.origin = np.asarray(sim["origin"], dtype=np.float64)
        dx = sim["size"] / sim["resolution"]
        self.h = h = dx / k
        lo, hi = S.object_box(meta)
        self.Xo, vol_o = S.lattice_box(lo, hi, h)
        bones = meta["body"]["simulated_bones"]
        self.Xh = S.capsule_points(self.body, bones, h)
        if len(self.Xh) == 0:
            raise ConfigError(f"no body particles inside {bones} at spacing {h:.3f} m: raise particles_per_cell")
        self.no, self.nh = len(self.Xo), len(self.Xh)
        n = self.no + self.nh
        # gating mask of Eq. 7: 1 strictly inside the body (at rest), 0 elsewhere (object, surface)
        self.gate = self.body.inside(torch.as_tensor(self.Xh)).to(torch.float64)
        c = meta["camera"]
        self.cam = Camera(c["fx"], c["fy"], c["cx"], c["cy"], int(c["width"]), int(c["height"]),
                          torch.tensor(c["R"], dtype=torch.float32), torch.tensor(c["t"], dtype=torch.float32))
        self.background = torch.tensor(meta.get("background", [0.0, 0.0, 0.0]), dtype=torch.float32)
        names = [b for b, r in zip(self.body.skeleton.names, self.body.radii.tolist()) if r > 0 and b not in bones]
        Xb = S.capsule_points(self.body, names, cfg.body_spacing, exclude=bones)
        self.Xb = Xb[self._in_view(Xb)]
        self.nb = len(self.Xb)
        od, hd = meta["object"]["density"], meta["body"]["density"]
        nu = meta["object"]["nu"]
        self.model = MPMModel(
            size=sim["size"], resolution=sim["resolution"], dt=1.0 / meta["fps"] / sim["substeps"],
            substeps=sim["substeps"], mass=np.r_[np.full(self.no, vol_o * od), np.full(self.nh, h**3 * hd)],
            volume=np.r_[np.full(self.no, vol_o), np.full(self.nh, h**3)],
            E=np.r_[np.full(self.no, cfg.E_init), np.full(self.nh, meta["body"]["E"])], nu=np.full(n, nu),
            elastic=np.zeros(n), plastic=np.zeros(n), plastic_params=np.zeros((n, 4)),
            body=np.r_[np.zeros(self.no), np.ones(self.nh)], gravity=tuple(sim["gravity"]),
            walls=sim.get("walls", {}))
        self.kp, self.kd = float(sim["kp"]), float(sim["kd"])
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
        t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
        return {"ref": t(ref), "vref": t(vref), "A_h": t(Ah), "xb": t(xb), "A_b": t(Ab), "frames": len(ref)}

    def deformation_from_neighbours(self, x: torch.Tensor) -> torch.Tensor:
        """Least-squares F_i = (sum_j dx_ij dX_ij^T) (sum_j dX_ij dX_ij^T)^-1 over lattice neighbours j."""
        X = torch.as_tensor(self.Xo)
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        dX, dx = X[j] - X[i], x[j] - x[i]
        P = dx[:, :, None] * dX[:, None, :]
        A = torch.zeros(self.no, 3, 3, dtype=x.dtype).index_add(0, i, P).index_add(0, j, P)
        return A @ self.B_inv

    def rigidity(self, x: torch.Tensor) -> torch.Tensor:
        d = x[self.pairs[:, 1]] - x[self.pairs[:, 0]]
        return ((torch.linalg.vector_norm(d, dim=1) - self.rest_len) ** 2).mean()


@dataclass
class Appearance:
    """Per-Gaussian appearance over [object | simulated body | kinematic body] (float32 tensors)."""

    sh: torch.Tensor
    opacity_logits: torch.Tensor
    log_scales: torch.Tensor

    @classmethod
    def init(cls, rig: Rig) -> "Appearance":
        n = rig.no + rig.nh + rig.nb
        s = np.r_[np.full(rig.no + rig.nh, 0.5 * rig.h), np.full(rig.nb, 0.5 * rig.cfg.body_spacing)]
        return cls(rgb_to_sh0(torch.full((n, 1, 3), 0.5)), torch.full((n,), 1.5),
                   torch.log(torch.as_tensor(s, dtype=torch.float32))[:, None].repeat(1, 3))

    def params(self):
        return [self.sh, self.opacity_logits, self.log_scales]


def render_scene(rig: Rig, app: Appearance, x_obj, F_obj, x_hum, F_hum, x_kin, A_kin):
    """Render one frame: positions (world, m) and deformation gradients of the three Gaussian groups (Eq. 3)."""
    means = torch.cat([x_obj, x_hum, x_kin]).float()
    F = torch.cat([F_obj, F_hum, A_kin]).float()
    n = means.shape[0]
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1.0
    g = Gaussians(means, quats, app.log_scales, app.opacity_logits, app.sh)
    return render(g, rig.cam, F=F, background=rig.background)


def image_loss(res, rgb_gt: torch.Tensor, mask_gt: torch.Tensor, cfg: TrainConfig) -> torch.Tensor:
    return cfg.lambda_rgb * (res.rgb - rgb_gt).abs().mean() + cfg.lambda_mask * (res.alpha - mask_gt).abs().mean()


# ----------------------------------------------------------------------------------------------- physics
@dataclass
class Physics:
    """Learned physical parameters: log E of the object (No,), omega logits of the body (Nh,), optional
    neural residual with latents."""

    log_E: torch.Tensor
    omega_logit: torch.Tensor
    nets: object = None
    l_e: torch.Tensor | None = None

    @classmethod
    def init(cls, rig: Rig) -> "Physics":
        cfg = rig.cfg
        le = torch.full((rig.no,), math.log(cfg.E_init), dtype=torch.float64)
        w = cfg.omega_init / 2
        ol = torch.full((rig.nh,), math.log(w / (1 - w)), dtype=torch.float64)
        nets = l_e = None
        if cfg.residual:
            from physar.mpm.neural import NeuralResidual

            torch.manual_seed(cfg.seed)
            nets = NeuralResidual(elastic=True, plastic=False, latent_dim=cfg.latent_dim)
            l_e = torch.zeros(rig.no + rig.nh, cfg.latent_dim, dtype=torch.float64)
        return cls(le, ol, nets, l_e)

    def leaves(self):
        out = [self.log_E, self.omega_logit]
        if self.nets is not None:
            out += [self.l_e, *self.nets.parameters()]
        return out

    def omega(self, rig: Rig) -> torch.Tensor:
        """Full omega (No + Nh,): 0 on the object, gate * 2 sigmoid(l) on the body (Eq. 7)."""
        return torch.cat([torch.zeros(rig.no, dtype=torch.float64), rig.gate * 2 * torch.sigmoid(self.omega_logit)])

    def params(self, rig: Rig) -> tb.Params:
        E = torch.cat([torch.exp(self.log_E), rig.E_human])
        return tb.Params(E=E, nu=rig.nu, omega=self.omega(rig), l_e=self.l_e, kp=rig.kp, kd=rig.kd)


def simulate_clip(rig: Rig, phys: Physics, kin: dict, frames: int, grad: bool = True):
    """Differentiable MPM over ``frames`` frames from the rest object and the LBS body of frame 0.

    Yields per frame n = 1 .. frames-1: (x_obj, F_obj, x_hum, F_hum) in world coordinates."""
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
                                              C0=C, F0=F, Jp0=Jp)
            xw = x + o
            yield f + 1, xw[:rig.no], F[:rig.no], xw[rig.no:], F[rig.no:]


# ----------------------------------------------------------------------------------------------- fit
@dataclass
class FitState:
    stage: str = "appearance"
    iteration: int = 0
    app: Appearance | None = None
    flow: list = field(default_factory=list)  # per observed frame: object positions (No, 3) float64
    phys: Physics | None = None
    opt_state: dict | None = None
    history: dict = field(default_factory=lambda: {"appearance": [], "flow": [], "physics": []})
    frame_loss: list | None = None
    seconds: float = 0.0


def _save_checkpoint(run_dir: Path, st: FitState, cfg: TrainConfig, opt=None) -> None:
    d = {"config": cfg.model_dump(), "stage": st.stage, "iteration": st.iteration,
         "app": [t.detach() for t in st.app.params()] if st.app else None,
         "flow": [t.detach() for t in st.flow],
         "phys": [t.detach() for t in st.phys.leaves()] if st.phys else None,
         "opt": opt.state_dict() if opt is not None else None, "history": st.history,
         "frame_loss": st.frame_loss, "seconds": st.seconds}
    tmp = run_dir / "tmp_checkpoint.pt"
    torch.save(d, tmp)
    os.replace(tmp, run_dir / "checkpoint.pt")


def _load_checkpoint(run_dir: Path, rig: Rig, cfg: TrainConfig) -> FitState | None:
    p = run_dir / "checkpoint.pt"
    if not p.exists():
        return None
    d = torch.load(p, weights_only=True)
    if d["config"] != cfg.model_dump():
        raise ConfigError(f"{p}: checkpoint was made with another configuration; use a new --out folder "
                          "or --restart")
    st = FitState(stage=d["stage"], iteration=d["iteration"], history=d["history"], frame_loss=d["frame_loss"],
                  seconds=d["seconds"])
    if d["app"] is not None:
        st.app = Appearance(*d["app"])
    st.flow = list(d["flow"])
    if d["phys"] is not None:
        st.phys = Physics.init(rig)
        with torch.no_grad():
            for a, b in zip(st.phys.leaves(), d["phys"]):
                a.copy_(b)
    st.opt_state = d["opt"]
    return st


def fit(data_dir: str | Path, run_dir: str | Path, cfg: TrainConfig | None = None,
        progress: Progress | None = None, restart: bool = False) -> dict:
    """Run the three stages on DATA_DIR and write RUN_DIR (model.npz, gaussians.ply, report.json,
    preview.mp4).  Resumes from RUN_DIR/checkpoint.pt unless ``restart``.  Returns the report dict."""
    cfg = cfg or TrainConfig()
    ds = load_dataset(data_dir)
    run = Path(run_dir)
    run.mkdir(parents=True, exist_ok=True)
    if restart:
        (run / "checkpoint.pt").unlink(missing_ok=True)
    torch.manual_seed(cfg.seed)
    rig = Rig(ds.meta, cfg)
    kin = rig.kinematics(ds.rotations, ds.root_t)
    st = _load_checkpoint(run, rig, cfg) or FitState()
    rgb = torch.as_tensor(ds.rgb)
    mask = torch.as_tensor(ds.mask)
    prog = progress or (lambda *a: None)
    t0 = time.perf_counter() - st.seconds
    Xo = torch.as_tensor(rig.Xo)
    I_o = torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3)

    # ---- stage 1: appearance on frame 0 (Eq. 5)
    if st.stage == "appearance":
        st.app = st.app or Appearance.init(rig)
        for t in st.app.params():
            t.requires_grad_(True)
        opt = torch.optim.Adam(st.app.params(), lr=cfg.appearance_lr)
        for it in range(cfg.appearance_iters):
            res = render_scene(rig, st.app, Xo, I_o, kin["ref"][0], kin["A_h"][0], kin["xb"][0], kin["A_b"][0])
            loss = image_loss(res, rgb[0], mask[0], cfg)
            opt.zero_grad()
            loss.backward()
            opt.step()
            st.history["appearance"].append(float(loss.detach()))
            prog("appearance", it + 1, cfg.appearance_iters, float(loss.detach()))
        st.stage, st.iteration, st.flow = "flow", 0, [Xo.clone()]
        st.seconds = time.perf_counter() - t0
        _save_checkpoint(run, st, cfg)
    app = Appearance(*[t.detach() for t in st.app.params()])

    # ---- stage 2: structure-preserving per-frame positions (Eq. 9) = 4DGS-like baseline
    if st.stage == "flow":
        for f in range(len(st.flow), ds.n_obs):
            x = st.flow[-1].clone().requires_grad_(True)
            opt = torch.optim.Adam([x], lr=cfg.flow_lr)
            for it in range(cfg.flow_iters):
                res = render_scene(rig, app, x, rig.deformation_from_neighbours(x), kin["ref"][f], kin["A_h"][f],
                                   kin["xb"][f], kin["A_b"][f])
                loss = image_loss(res, rgb[f], mask[f], cfg) + cfg.rigidity * rig.rigidity(x)
                opt.zero_grad()
                loss.backward()
                opt.step()
            st.history["flow"].append(float(loss.detach()))
            st.flow.append(x.detach())
            prog("flow", f, ds.n_obs - 1, float(loss.detach()))
            st.seconds = time.perf_counter() - t0
            _save_checkpoint(run, st, cfg)
        st.stage, st.iteration = "physics", 0
        _save_checkpoint(run, st, cfg)

    # ---- stage 3: end-to-end physics (Eq. 10-11), progressive and loss-balanced
    if st.stage == "physics":
        st.phys = st.phys or Physics.init(rig)
        leaves = st.phys.leaves()
        for t in leaves:
            t.requires_grad_(True)
        opt = torch.optim.Adam(leaves, lr=cfg.physics_lr)
        if st.opt_state is not None:
            opt.load_state_dict(st.opt_state)
        lo_E, hi_E = math.log(cfg.E_min), math.log(cfg.E_max)
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
                if cfg.lambda_flow > 0 and f < len(st.flow):
                    lf = lf + cfg.lambda_flow * (xo - st.flow[f]).abs().mean()
                per.append(float(lf.detach()))
                total = total + wts[f] * lf / (W - 1)
            reg = cfg.lambda_omega * torch.linalg.vector_norm(st.phys.omega(rig))
            if st.phys.nets is not None:
                reg = reg + cfg.lambda_law * _residual_norm(st.phys, Fo)
            loss = total + reg
            opt.zero_grad()
            loss.backward()
            opt.step()
            with torch.no_grad():
                st.phys.log_E.clamp_(lo_E, hi_E)
            fl_prev = list(st.frame_loss or [])
            st.frame_loss = per + fl_prev[len(per):]
            st.history["physics"].append(float(loss.detach()))
            st.iteration += 1
            prog("physics", st.iteration, cfg.physics_iters, float(loss))
            if st.iteration % cfg.checkpoint_every == 0 or st.iteration == cfg.physics_iters:
                st.seconds = time.perf_counter() - t0
                _save_checkpoint(run, st, cfg, opt)
        st.stage = "done"
        st.seconds = time.perf_counter() - t0
        _save_checkpoint(run, st, cfg, opt)

    recon = Reconstruction(rig, app, st.flow, st.phys, ds.root)
    recon.save(run / "model.npz", cfg, st)
    canon = render_gaussians_canonical(rig, app, kin)
    save_ply(run / "gaussians.ply", canon)
    report = evaluate(recon, ds, progress=progress)
    report["train_seconds"] = st.seconds
    report["history_final"] = {k: (v[-1] if v else None) for k, v in st.history.items()}
    report["history_first"] = {k: (v[0] if v else None) for k, v in st.history.items()}
    save_json_atomic(run / "report.json", report)
    _preview(recon, ds, run / "preview.mp4")
    return report


def _residual_norm(phys: Physics, F_obj: torch.Tensor) -> torch.Tensor:
    """||E_theta(F, l_e)||_2 of Eq. 11 at the object's last deformation gradients."""
    from physar.mpm.neural import invariant_features

    sv = torch.linalg.svdvals(F_obj.detach())  # features only; the residual's weights get the gradient
    feat = invariant_features(F_obj, sv)
    out = phys.nets.elastic(feat, phys.l_e[:F_obj.shape[0]])
    return torch.linalg.vector_norm(out)


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
    """A fitted scene: rig, appearance, per-frame flow (4DGS baseline) and learned physics."""

    rig: Rig
    app: Appearance
    flow: list
    phys: Physics
    data_dir: Path | None = None

    def save(self, path: Path, cfg: TrainConfig, st: FitState) -> None:
        arrays = {
            "format_version": np.array(MODEL_FORMAT), "meta_json": np.array(json.dumps(self.rig.meta)),
            "config_json": np.array(json.dumps(cfg.model_dump())),
            "data_dir": np.array(str(self.data_dir or "")),
            "sh": self.app.sh.numpy(), "opacity_logits": self.app.opacity_logits.numpy(),
            "log_scales": self.app.log_scales.numpy(),
            "flow": torch.stack(self.flow).numpy(),
            "E": torch.exp(self.phys.log_E).detach().numpy(), "omega": self.phys.omega(self.rig).detach().numpy(),
            "omega_logit": self.phys.omega_logit.detach().numpy(),
            "object_rest": self.rig.Xo, "body_rest": self.rig.Xh,
            "loss_physics": np.asarray(st.history["physics"], dtype=np.float64),
        }
        if self.phys.nets is not None:
            arrays["l_e"] = self.phys.l_e.detach().numpy()
            for k, v in self.phys.nets.state_dict().items():
                arrays[f"net.{k}"] = v.numpy()
        save_npz_atomic(path, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "Reconstruction":
        path = Path(path)
        if path.is_dir():
            path = path / "model.npz"
        d = _npz(path)
        if int(d.get("format_version", -1)) != MODEL_FORMAT:
            raise ConfigError(f"{path}: not a physar recon model (format_version {d.get('format_version')})")
        meta, cfg = json.loads(str(d["meta_json"])), TrainConfig.model_validate(json.loads(str(d["config_json"])))
        rig = Rig(meta, cfg)
        app = Appearance(torch.as_tensor(d["sh"]), torch.as_tensor(d["opacity_logits"]),
                         torch.as_tensor(d["log_scales"]))
        phys = Physics.init(rig)
        with torch.no_grad():
            phys.log_E.copy_(torch.log(torch.as_tensor(d["E"])))
            phys.omega_logit.copy_(torch.as_tensor(d["omega_logit"]))
            if phys.nets is not None:
                phys.l_e.copy_(torch.as_tensor(d["l_e"]))
                phys.nets.load_state_dict({k[4:]: torch.as_tensor(v) for k, v in d.items() if k.startswith("net.")})
        return cls(rig, app, list(torch.as_tensor(d["flow"])), phys, Path(str(d["data_dir"])) or None)

    def predict(self, rotations: np.ndarray, root: np.ndarray, method: str = "physics",
                progress: Progress | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Render a pose sequence (F frames) with ``method`` in physics | lbs | 4dgs.

        Returns rgb (F, H, W, 3) and alpha (F, H, W) as float32 numpy arrays; frame 0 is the canonical scene."""
        rig = self.rig
        rotations, root = S.check_poses({"rotations": rotations, "root_translation": root},
                                        rig.body.skeleton.n_bones)
        kin = rig.kinematics(rotations, root)
        n = kin["frames"]
        Xo = torch.as_tensor(rig.Xo)
        I_o = torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3)
        out_rgb, out_a = [], []

        def emit(f, xo, Fo, xh, Fh):
            with torch.no_grad():
                r = render_scene(rig, self.app, xo, Fo, xh, Fh, kin["xb"][f], kin["A_b"][f])
            out_rgb.append(r.rgb.numpy())
            out_a.append(r.alpha.numpy())
            if progress:
                progress(method, f + 1, n, 0.0)

        emit(0, Xo, I_o, kin["ref"][0], kin["A_h"][0])
        if method == "physics":
            for f, xo, Fo, xh, Fh in simulate_clip(rig, self.phys, kin, n, grad=False):
                emit(f, xo, Fo, xh, Fh)
        elif method in ("lbs", "4dgs"):
            for f in range(1, n):
                if method == "lbs":
                    xo, Fo = Xo, I_o
                else:
                    xo = self.flow[min(f, len(self.flow) - 1)]
                    Fo = rig.deformation_from_neighbours(xo)
                emit(f, xo, Fo, kin["ref"][f], kin["A_h"][f])
        else:
            raise PhysarError(f"unknown method '{method}': use physics, lbs or 4dgs")
        return np.stack(out_rgb), np.stack(out_a)


METHODS = ("physics", "lbs", "4dgs")


def evaluate(recon: Reconstruction, ds: Dataset, methods=METHODS, progress: Progress | None = None) -> dict:
    """Metrics of each method on reconstruction (observed frames 1..n_obs-1), prediction (future frames) and
    the novel action, on all frames and on the large-deformation subsets; E error against the truth."""
    from physar.recon.metrics import large_deformation_frames, sequence_metrics

    out = {"methods": {}, "lpips": "unavailable (no backbone weights offline)"}
    n, no = len(ds.rgb), ds.n_obs
    disp = ds.truth["dynamic_max_displacement"] if ds.truth else None
    sets = {"recon": list(range(1, no)), "pred": list(range(no, n))}
    for m in methods:
        rgb, a = recon.predict(ds.rotations, ds.root_t, m, progress)
        res = {}
        for name, fr in sets.items():
            res[name] = sequence_metrics(rgb, a, ds.rgb, ds.mask, fr)
            if disp is not None:
                res[name + "_large"] = sequence_metrics(rgb, a, ds.rgb, ds.mask, large_deformation_frames(disp, fr))
        if ds.novel is not None:
            m2 = "lbs" if m == "4dgs" else m  # a per-frame deformation cannot follow new poses
            rgb2, a2 = recon.predict(ds.novel["rotations"], ds.novel["root_t"], m2, progress)
            fr = list(range(1, len(rgb2)))
            res["novel"] = sequence_metrics(rgb2, a2, ds.novel["rgb"], ds.novel["mask"], fr)
            if ds.truth is not None:
                res["novel_large"] = sequence_metrics(rgb2, a2, ds.novel["rgb"], ds.novel["mask"],
                                                      large_deformation_frames(ds.truth["novel_max_displacement"], fr))
        out["methods"][m] = res
    if ds.truth is not None:
        out["material"] = material_error(recon, ds.truth)
    om = recon.phys.omega(recon.rig).detach().numpy()
    out["omega"] = {"object_max_abs": float(np.abs(om[:recon.rig.no]).max()),
                    "body_mean": float(om[recon.rig.no:].mean())}
    return out


def material_error(recon: Reconstruction, truth: dict) -> dict:
    """Learned vs true E at the reconstruction's particles (nearest fine particle): mean |log10 ratio|
    for the learned field and the initial guess, and the means over the soft/stiff halves."""
    rig = recon.rig
    idx = cKDTree(truth["rest_positions"]).query(rig.Xo)[1]
    Et = truth["E"][idx]
    E = torch.exp(recon.phys.log_E).detach().numpy()
    soft = Et <= np.median(Et) if Et.min() == Et.max() else Et == Et.min()
    return {"mean_abs_log10_error": float(np.mean(np.abs(np.log10(E / Et)))),
            "initial_mean_abs_log10_error": float(np.mean(np.abs(np.log10(rig.cfg.E_init / Et)))),
            "E_soft_true": float(Et[soft].mean()), "E_stiff_true": float(Et[~soft].mean()),
            "E_soft_learned_geomean": float(np.exp(np.log(E[soft]).mean())),
            "E_stiff_learned_geomean": float(np.exp(np.log(E[~soft]).mean()))}


def _preview(recon: Reconstruction, ds: Dataset, path: Path) -> bool:
    cols = [ds.rgb]
    for m in METHODS:
        cols.append(recon.predict(ds.rotations, ds.root_t, m)[0])
    frames = np.concatenate(cols, axis=2)
    return write_mp4(path, (np.clip(frames, 0, 1) * 255 + 0.5).astype(np.uint8), ds.meta["fps"])
