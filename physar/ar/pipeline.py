"""The AR frame loop (seed 000 §2.1, §4, §5.1): decode -> markers/pose -> dots -> observations u* ->
assimilation mu* = argmin ||u* - C u(mu)||² on the reduced model -> overlay -> encode.

Three threads overlap (PyAV and OpenCV release the GIL while they work): the decoder (which also hands over
its luma plane as the grey image), the estimation and overlay on the calling thread (markers followed by
sub-pixel corner refinement with a bit check, ArUco detection only as fallback; dots re-centred around their
pose projection, KLT only when that misses), and the encoder thread (the overlay can be drawn there too, see
:meth:`ARPipeline.run`). Per-stage latencies are recorded for every frame.
"""
from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from physar.ar.runner import run_video
from physar.assimilation.filters import IMMFilter
from physar.errors import ConfigError
from physar.vision.camera import Camera
from physar.vision.dots import DotTracker
from physar.vision.markers import MarkerBoard, MarkerTracker
from physar.vision.observation import surface_observation_matrix

STAGES = ("decode", "markers_pose", "dots", "assimilate", "overlay", "encode")


@dataclass
class BeamObject:
    """What the pipeline knows about the filmed object: a box beam [0, L]x[0, W]x[0, H] clamped at x = 0,
    its reduced model's mesh (cells, element), material, dot centres (n, 3) on the front face y = 0 and the
    marker board. Stored as JSON in the reduced model's metadata ("ar_object")."""

    length: float
    width: float
    height: float
    cells: tuple
    element: str
    E: float
    nu: float
    dots: list
    marker_ids: list
    marker_corners: list
    dictionary: str
    load: float = 1.0

    def board(self) -> MarkerBoard:
        return MarkerBoard(self.marker_ids, self.marker_corners, self.dictionary)

    def space(self):
        from physar.fem import FESpace
        from physar.geometry import box_mesh

        return FESpace(box_mesh((self.length, self.width, self.height), tuple(self.cells)), self.element)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> BeamObject:
        try:
            d = json.loads(text)
            return cls(**d)
        except (json.JSONDecodeError, TypeError) as e:
            raise ConfigError(f"reduced model: invalid ar_object metadata ({e})") from None

    @classmethod
    def from_scene(cls, spec) -> BeamObject:
        b, board = spec.beam, spec.board()
        return cls(b.length, b.width, b.height, tuple(b.model_cells), "P2", b.E, b.nu,
                   spec.dot_positions().tolist(), board.ids.tolist(), board.corners.tolist(),
                   board.dictionary, b.load)


def build_scene_model(spec, progress: Callable[[int, int], None] | None = None, points: int = 81,
                      max_modes: int = 20, tol: float = 1e-4):
    """Reduced model u(x; s) of the scene's beam on its (coarser) model mesh, by intrusive PGD
    (physar.rom.elastic.build_moving_load_pgd), with the AR object description in its metadata."""
    from physar.fem import ElasticModel, LinearElastic, fixed_dofs
    from physar.rom.elastic import build_moving_load_pgd

    obj = BeamObject.from_scene(spec)
    space = obj.space()
    model = ElasticModel(space, LinearElastic(obj.E, obj.nu))
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, obj.width, obj.height]])
    if progress:
        progress(0, 1)
    rom, info = build_moving_load_pgd(model, fixed, spec.load_path(), points=points, load=(0, 0, -spec.beam.load),
                                      radius=spec.beam.load_radius, max_modes=max_modes, tol=tol)
    rom.metadata["ar_object"] = obj.to_json()
    if progress:
        progress(1, 1)
    return rom, obj, space, info


def object_from_model(rom) -> BeamObject:
    """The AR object (beam geometry, markers, dots) stored in a reduced model's metadata."""
    text = rom.metadata.get("ar_object")
    if not text:
        raise ConfigError("reduced model has no AR object description (metadata 'ar_object'); build it with "
                          "`physar scene model SCENE.toml -o model.npz`")
    return BeamObject.from_json(text)


class _Projected:
    """W C as an operator: (W C) @ B = W (C B), so that W (dense, small) never multiplies the sparse C
    (observations x all dofs) densely; set_observation only needs (W C) @ F^T."""

    def __init__(self, W, C):
        self.W, self.C = W, C

    def __matmul__(self, B):
        return self.W @ np.asarray(self.C @ B)


@dataclass
class FrameResult:
    frame: int
    status: str            # tracking | hold | lost
    mu: np.ndarray
    std: np.ndarray
    residual_mm: float
    n_markers: int
    n_dots: int
    latency_ms: float
    stages_ms: dict = field(default_factory=dict)
    cpu_ms: float = float("nan")  # CPU time of this thread for the frame's compute (less load-sensitive)


class ARPipeline:
    """The frame loop on one reduced model (load position s, optionally magnitude P).

    ``min_dots``: fraction of dots that must be seen to assimilate a frame (else the estimate is held).
    ``nuisance``: displacements of the observed dots that the camera pose cannot tell from deformation
    and that are estimated away: "offset" (uniform in-plane offset b: pose bias, fixture drift), "rigid"
    (offset and a small in-plane rotation w about y, u_z += -w (x - x_c), u_x += w (z - z_c)) or "none".
    mu* = argmin_mu min_b ||u* - C u(mu) - A b||²/sigma_d² + w²/sigma_w², solved by variable projection:
    the offsets are projected out (P = I - Q Q^T) and the rotation column a (orthogonalised, unit â) is
    down-weighted by generalised least squares with the noise covariance sigma_d² I + sigma_w² a a^T,
    W = P - (1 - sigma_d / sqrt(sigma_d² + sigma_w² |a|²)) â â^T, applied to the observations and to C.
    sigma_w is the camera pose's in-plane angle error (a rotation error of the pose shows up as a rigid
    rotation of all dots): the larger of ``rotation_sigma_deg`` and the PnP estimate of the frame
    (:func:`physar.vision.markers.rotation_std`; ~0.01° with four markers at 720p, ~0.08° with two);
    ``dot_sigma_px`` is the dot centroid noise, sigma_d = dot_sigma_px · depth / f at the object's depth.
    "pose" (default): offsets projected out as above, and the whole camera pose error modelled as noise of
    the observations: sigma_d² I + G Σ G^T + sigma_w0² a a^T, where Σ (6x6) is the PnP covariance of the
    frame's pose from the seen marker corners and G the first-order change of the back-projected dots per
    pose error (:meth:`_pose_weighting`). With two markers the pose is weak in a yaw + depth direction
    (measured on scene (a): up to 0.7° and 3 mm), which moves the back-projected dots non-rigidly (a
    quadratic-like pattern in x, not a rotation); "rigid" leaves that in the residual (1-2.4 mm instead of
    0.17 mm, so the assimilation's std becomes 25-45 mm), "pose" explains it and reports the honest std
    (~3.5 mm with two markers, ~1 mm with four).
    ``filter``: temporal filter of the estimate, "imm" (default; two-model interacting multiple model
    filter using each frame's std, see :meth:`_filter_imm`, with ``dwell_sigma``, ``motion_accel``,
    ``switch``) or "alpha-beta" (fixed gain a = ``smoothing``, 1 = none, see :meth:`_filter_ab`). A change
    larger than ``jump_sigma`` standard deviations re-initialises the filter at the measurement.
    ``joint_pose``: refine the camera pose and the parameters together from the marker corners and the
    dots' pixels (:meth:`_joint_refine`) and pass that estimate and its std to the filter: in every frame with
    markers (True); with fewer than three markers seen (two stacked markers leave the pose weak in a yaw +
    depth direction) and in frames whose estimate is more than ``joint_gate`` combined standard deviations
    from the filtered one (:meth:`_surprising`: the start of a move, or a pose error the frame's std does not
    cover) ("gated", the default); with fewer than three markers only ("weak"); or never (False). The
    overlay of refined frames is drawn with the refined pose (the marker tracker keeps its own). Over the
    demo's scene noise seeds 0-9 (benchmarks/bench_ar_noise_seeds.py), judged frames within 5 mm and worst:
    "gated" 3470/3470, 4.47 mm; True 3470/3470, 4.12 mm; "weak" 3467/3470, 5.94 mm. Demo frame rate, same
    process: "gated" 153-156 fps, "weak" 157-169, True 135.
    Dots not seen in a frame are searched for next at the reduced model's displacement for the current
    estimate (:meth:`_predict_unseen`).
    ``track_markers``: follow the marker corners by sub-pixel refinement of their predictions (bit-checked,
    ArUco detection as fallback, see :class:`MarkerTracker`) instead of detecting them in every frame.
    ``dot_flow``: KLT for the dots always (True), never (False) or "auto" (when the pose projection of the
    last displacements missed the dots, see :class:`DotTracker`).
    """

    def __init__(self, rom, camera: Camera, obj: BeamObject | None = None, field: str = "von_mises",
                 exaggeration: float = 1.0, min_dots: float = 0.5, overlay: bool = True, nuisance: str = "pose",
                 rotation_sigma_deg: float = 0.005, dot_sigma_px: float = 0.07,
                 smoothing: float = 0.6, jump_sigma: float = 4.0, track_markers: bool = True,
                 dot_flow: bool | str = "auto", filter: str = "imm", dwell_sigma: float = 1e-4,
                 motion_accel: float = 5e-3, switch: tuple = (0.05, 0.1), joint_pose: bool | str = "gated",
                 joint_gate: float = 1.0):
        from physar.ar.overlay import BeamOverlay

        self.rom, self.camera = rom, camera
        self._lo, self._hi = (np.array(b, float) for b in zip(*rom.ranges))  # parameter bounds
        self.obj = obj or object_from_model(rom)
        self.space = self.obj.space()
        if rom.F.shape[1] != self.space.n_dofs:
            raise ConfigError(f"reduced model has {rom.F.shape[1]} dofs, its mesh {self.space.n_dofs}")
        dots = np.asarray(self.obj.dots, float)
        self.markers = MarkerTracker(camera, self.obj.board(), track=track_markers)
        self.dots = DotTracker(camera, dots, [0, 0, 0], [0, 1.0, 0],
                               radius_px=self._dot_radius_px(dots), flow=dot_flow)
        self.C = surface_observation_matrix(self.space, dots, components=(0, 2)).tocsr()
        self.CF = np.asarray(self.C @ rom.F.T)  # (2n, n_modes): observation of every mode
        if nuisance not in ("none", "offset", "rigid", "pose"):
            raise ConfigError(f"nuisance must be none, offset, rigid or pose, got {nuisance!r}")
        self._board = self.obj.board()
        self._pose_centre = self._board.corners.reshape(-1, 3).mean(0)
        self.min_dots, self.nuisance = min_dots, nuisance
        self._dots_ref = dots
        self.rotation_sigma, self.dot_sigma_px = np.radians(rotation_sigma_deg), dot_sigma_px
        self._depth = None
        self._sigma_w = self.rotation_sigma
        self.smoothing, self.jump_sigma = smoothing, jump_sigma
        if filter not in ("alpha-beta", "imm"):
            raise ConfigError(f"filter must be alpha-beta or imm, got {filter!r}")
        if not dwell_sigma >= 0:
            raise ConfigError(f"dwell_sigma must be >= 0, got {dwell_sigma!r}")
        if not motion_accel > 0:
            raise ConfigError(f"motion_accel must be > 0, got {motion_accel!r}")
        if len(switch) != 2 or not all(0 < p < 1 for p in switch):
            raise ConfigError(f"switch must be two probabilities in (0, 1), got {switch!r}")
        self.filter, self.dwell_sigma, self.motion_accel, self.switch = filter, dwell_sigma, motion_accel, switch
        self._imm = IMMFilter(self._lo, self._hi, dwell_sigma, motion_accel, switch, jump_sigma)
        if joint_pose not in (True, False, "weak", "gated"):
            raise ConfigError(f"joint_pose must be True, False, 'weak' or 'gated', got {joint_pose!r}")
        if not joint_gate > 0:
            raise ConfigError(f"joint_gate must be > 0, got {joint_gate!r}")
        self.joint_pose, self.joint_gate = joint_pose, joint_gate
        self._fresh = True  # next measurement (re)initialises the temporal filter
        self.overlay = BeamOverlay(self.space, rom, self.obj, field=field, exaggeration=exaggeration) if overlay \
            else None
        self.mu = (self._lo + self._hi) / 2
        self.std = np.full(self._lo.size, np.nan)
        self._mask = None
        self._proj = None
        self._initialised = False
        self._res_hist = []

    def _dot_radius_px(self, dots):
        d = self.obj.height / 3  # dot diameter assumed <= H/3 when not known
        spacing = np.min(np.diff(dots[:, 0])) if len(dots) > 1 else d
        dist = 0.55
        return 0.5 * min(d, 0.6 * spacing) * self.camera.fx / dist

    # -- estimation ---------------------------------------------------------------------------------------
    def _pose_weighting(self, world, valid, pe):
        """Whitening W (2m, 2m) of the m seen dots' displacements (x, z) for nuisance "pose": the noise
        covariance sigma_d² I + G Σ_pose G^T + sigma_w0² a a^T (dot centroid noise, the camera pose's error
        seen through the back-projection, the in-plane rotation floor ``rotation_sigma_deg``) is whitened by
        its Cholesky factor and the (whitened) uniform offsets are projected out (generalised least squares
        with the offsets as free nuisance parameters), scaled so that W = P for Σ = sigma_d² I."""
        m = int(valid.sum())
        sd = self.dot_sigma_px * (self._depth or 1.0) / self.camera.fx
        S = np.eye(2 * m)
        cov = self._pose_cov(pe)
        if cov is not None:
            G = self._pose_sensitivity(world[valid], pe.pose)
            S += G @ cov @ G.T / sd ** 2
        ref = self._dots_ref[valid]
        a = np.zeros(2 * m)
        a[0::2], a[1::2] = ref[:, 2] - ref[:, 2].mean(), -(ref[:, 0] - ref[:, 0].mean())
        S += np.outer(a, a) * (self.rotation_sigma / sd) ** 2
        Linv = np.linalg.inv(np.linalg.cholesky(S))
        A = np.zeros((2 * m, 2))
        A[0::2, 0] = 1.0  # u_x offset
        A[1::2, 1] = 1.0  # u_z offset
        Q = np.linalg.qr(Linv @ A)[0]
        return Linv - Q @ (Q.T @ Linv)

    def _pose_cov(self, pe):
        """Covariance (6, 6) of the pose error that PnP on the seen marker corners leaves, sigma² (J^T J)^-1
        with sigma = max(reprojection rms, the tracker's corner noise). The error is parametrised as a small
        world motion applied before the pose, X -> c + exp(δθ)(X - c) + δt (c: the board's centre), as in
        :func:`physar.vision.markers.rotation_std`; J by central differences of the projection. None without
        marker corners."""
        X = self._seen_corners(pe)
        if X is None:
            return None
        h = 1e-6
        dirs = self._motion_basis(X)                              # (6, n, 3)
        Xs = X[None, None] + h * np.array([1.0, -1.0])[None, :, None, None] * dirs[:, None]
        p = self.camera.project(Xs.reshape(-1, 3), pe.pose).reshape(6, 2, -1)
        J = ((p[:, 0] - p[:, 1]) / (2 * h)).T                    # (2n, 6)
        try:
            return np.linalg.inv(J.T @ J) * self._corner_sigma(pe) ** 2
        except np.linalg.LinAlgError:
            return None

    def _seen_corners(self, pe):
        """World corners (4k, 3) of the board markers seen in the frame (in the order of ``pe.ids``), or None
        without markers or pose."""
        idx = [k for k in (self._board.index(i) for i in pe.ids) if k is not None]
        if not idx or pe.pose is None:
            return None
        return self._board.corners[idx].reshape(-1, 3)

    def _corner_sigma(self, pe) -> float:
        """Pixel noise of the marker corners: the larger of the frame's reprojection rms and the tracker's."""
        return max(float(np.nan_to_num(pe.reprojection_px, nan=0.0)), self.markers.noise_px)

    def _motion_basis(self, X):
        """(6, n, 3): displacement of the points X per unit small world rotation about the board centre
        (δθ_j e_j x (X - c)) and per unit translation (e_j)."""
        D = X - self._pose_centre
        z = np.zeros(len(X))
        rot = [np.stack(v, 1) for v in ((z, -D[:, 2], D[:, 1]), (D[:, 2], z, -D[:, 0]), (-D[:, 1], D[:, 0], z))]
        return np.stack(rot + [np.tile(np.eye(3)[j], (len(X), 1)) for j in range(3)])

    def _pose_sensitivity(self, world, pose):
        """G (2m, 6): change of the back-projected dots' (x, z) per unit pose error parameter. A pose error
        (world motion g = δθ x (w - c) + δt before the pose) moves the point seen along the ray of a dot
        (direction d from the camera centre) to w' with T(w') on the ray and w'_y = 0, to first order
        δw = d g_y / d_y - g."""
        d = world - pose.center
        B = self._motion_basis(world)                             # (6, m, 3): g per parameter
        dw = d[None] * (B[:, :, 1] / d[None, :, 1])[:, :, None] - B
        return dw[:, :, [0, 2]].reshape(6, -1).T

    def _assimilate(self, disp: np.ndarray, valid: np.ndarray, sigma_w: float | None = None, world=None, pe=None):
        rows = np.flatnonzero(np.repeat(valid, 2))
        if self.nuisance == "pose":
            W = self._pose_weighting(world, valid, pe)
            self._proj, self._mask = W, None
            self.rom.set_observation(matrix=_Projected(W, self.C[rows]))
            return self._solve(W @ disp[valid][:, [0, 2]].ravel())
        sigma_w = max(self.rotation_sigma, sigma_w or 0.0)
        key = (valid.tobytes(), round(2 * np.log2(sigma_w)))  # re-weight when sigma_w changes by > 41 %
        if key != self._mask:
            self._sigma_w = sigma_w
        y = disp[valid][:, [0, 2]].ravel()
        if key != self._mask:
            Cv = self.C[rows]
            self._proj = None
            if self.nuisance != "none":
                m = int(valid.sum())
                A = np.zeros((2 * m, 2))
                A[0::2, 0] = 1.0  # u_x offset
                A[1::2, 1] = 1.0  # u_z offset
                Q = np.linalg.qr(A)[0]
                W = np.eye(2 * m) - Q @ Q.T
                if self.nuisance == "rigid":  # small in-plane rotation w about y
                    ref = self._dots_ref[valid]
                    a = np.zeros(2 * m)
                    a[0::2], a[1::2] = ref[:, 2] - ref[:, 2].mean(), -(ref[:, 0] - ref[:, 0].mean())
                    a = W @ a
                    na = float(np.linalg.norm(a))
                    if na > 0:
                        sd = self.dot_sigma_px * (self._depth or 1.0) / self.camera.fx
                        f = 1 - sd / np.hypot(sd, self._sigma_w * na)
                        W = W - f * np.outer(a / na, a / na)
                self._proj = W
                Cv = _Projected(W, Cv)
            self.rom.set_observation(matrix=Cv)
            self._mask = key
        if self._proj is not None:
            y = self._proj @ y
        return self._solve(y)

    def _solve(self, y):
        from physar.assimilation import assimilate

        if not self._initialised:
            res = assimilate(self.rom, y, restart_residual=0.0, n_starts=9, max_iter=30)
            self._initialised = True
        else:
            res = assimilate(self.rom, y, mu0=self.mu, max_iter=15, tol=1e-7)
            med = np.median(self._res_hist[-30:]) if self._res_hist else np.inf
            if res.residual > 3 * med:  # warm start stuck (or the load jumped): global search
                res2 = assimilate(self.rom, y, restart_residual=0.0, n_starts=9, max_iter=30)
                if res2.residual < res.residual:
                    res = res2
        self._res_hist.append(res.residual)
        return res

    def _joint_refine(self, pe, pixels, valid, mu0, iters: int = 8):
        """Camera pose and reduced parameters refined together from the image (when ``joint_pose`` asks for it:
        with fewer than three markers seen, PnP alone is weak in a yaw + depth direction): Gauss-Newton on
        theta = (6 small world-motion pose parameters as in :meth:`_pose_cov`, mu) minimising
        ||(p(corners; pose) - corners*)/sigma_c||² + ||(p(ref + C u(mu); pose) - dots*)/sigma_px||², with
        sigma_c = max(reprojection rms, the tracker's corner noise) and sigma_px = ``dot_sigma_px`` (p: the
        projection, corners* and dots*: the measured pixels). The dots along the beam, whose positions the
        reduced model predicts, pin the yaw that two stacked markers leave loose. It starts from the frame's
        pose and the assimilation's mu0. Returns (mu, std of mu, pose) with the covariance sigma² (J^T J)^-1 (sigma² = chi²/dof, as the assimilation's), or None when
        the corners or dots are missing or the normal matrix is singular."""
        from physar.vision.camera import Pose

        X = self._seen_corners(pe)
        if X is None or pe.image_corners is None or valid.sum() < 3:
            return None
        img = np.asarray(pe.image_corners, float).reshape(-1, 2)
        if img.shape[0] != X.shape[0]:
            return None
        sc, sd = self._corner_sigma(pe), self.dot_sigma_px
        ref, px = self._dots_ref[valid], pixels[valid]
        lo, hi = self._lo, self._hi
        p = lo.size
        R0, t0, c = pe.pose.R, pe.pose.t, self._pose_centre

        def pose_of(th):
            E = cv2.Rodrigues(th[:3].reshape(3, 1))[0]
            return Pose(R0 @ E, R0 @ (c - E @ c + th[3:6]) + t0)

        def resid(th):
            pose = pose_of(th)
            u = (self.CF @ self.rom._coeffs(th[6:6 + p].tolist())[0]).reshape(-1, 2)[valid]
            w = ref.copy()
            w[:, 0] += u[:, 0]
            w[:, 2] += u[:, 1]
            q = self.camera.project(np.vstack([X, w]), pose)
            return np.concatenate([((q[:len(X)] - img) / sc).ravel(), ((q[len(X):] - px) / sd).ravel()])

        th = np.zeros(6 + p)
        th[6:6 + p] = np.clip(mu0, lo, hi)
        steps = np.r_[np.full(3, 1e-6), np.full(3, 1e-6), 1e-6 * (hi - lo)]

        def jac(th, r):  # forward differences from the residual r at th (half the cost of central ones)
            E = np.diag(steps)
            return np.stack([(resid(th + e) - r) / h for e, h in zip(E, steps)], 1)

        r = resid(th)
        cost = r @ r
        for _ in range(iters):
            J = jac(th, r)
            A = J.T @ J
            try:
                dx = -np.linalg.solve(A, J.T @ r)
            except np.linalg.LinAlgError:
                return None
            lam = 1.0
            while lam > 1e-3:
                tn = th + lam * dx
                tn[6:6 + p] = np.clip(tn[6:6 + p], lo, hi)
                rn = resid(tn)
                if rn @ rn < cost:
                    break
                lam *= 0.5
            else:
                break
            done = np.all(np.abs(tn - th) < steps)  # steps below 1e-6 rad, 1e-6 m, 1e-6 of the range
            th, r, cost = tn, rn, rn @ rn
            if done:
                break
        J = jac(th, r)
        try:
            cov = np.linalg.inv(J.T @ J) * cost / max(r.size - th.size, 1)
        except np.linalg.LinAlgError:
            return None
        std = np.sqrt(np.abs(np.diag(cov)[6:6 + p]))
        return th[6:6 + p].copy(), std, pose_of(th)

    def _predict_unseen(self, valid):
        """Give the dot tracker the reduced model's displacement at the estimate for the dots it did not see,
        so that it searches for them where the deformed beam puts them (a dot displaced by more than the
        tracker's search radius from its last known position, e.g. near the tip of a heavily loaded beam,
        is otherwise never found again)."""
        if valid.all():
            return
        u = (self.CF @ self.rom.coefficients(self.mu)[0]).reshape(-1, 2)
        lost = ~valid
        self.dots.displacement[lost, 0] = u[lost, 0]
        self.dots.displacement[lost, 1] = 0.0
        self.dots.displacement[lost, 2] = u[lost, 1]

    def _surprising(self, mu, std) -> bool:
        """Is the frame's estimate more than ``joint_gate`` combined standard deviations from the filtered one
        (the start of a move, or a pose error the frame's own std does not cover)?"""
        if self._fresh:
            return False
        d = np.abs(mu - self.mu) / np.sqrt(np.nan_to_num(std, nan=np.inf) ** 2 + self.std ** 2)
        return bool(np.any(d > self.joint_gate))

    def _filter(self, mu, std):
        if self.filter == "imm":
            return self._filter_imm(mu, std)
        return self._filter_ab(mu, std)

    def _filter_imm(self, z, std):
        """The interacting multiple model filter (:class:`physar.assimilation.filters.IMMFilter`) with this
        pipeline's ``dwell_sigma``, ``motion_accel``, ``switch`` and ``jump_sigma``; restarted when
        ``self._fresh`` is set (a lost pose)."""
        if self._fresh:
            self._imm.reset()
            self._fresh = False
        self.mu, self.std = self._imm.update(z, std)

    def _filter_ab(self, mu, std):
        """Alpha-beta (constant-velocity) filter on the estimate, with a jump detector: prediction
        m = mu + v; innovation e = z - m; mu <- m + a e, v <- v + b e with a = smoothing and b = a²/(2 - a)
        (critically damped), so a load moving at constant speed is followed without lag; when
        |e| > jump_sigma * max(std, 0.2 % of the range) the measurement passes unfiltered (a = 1, v = 0)."""
        lo, hi = self._lo, self._hi
        if self._fresh or self.smoothing >= 1:
            self.mu, self.std = mu.copy(), std.copy()
            self._vel = np.zeros_like(mu)
            self._fresh = False
            return
        scale = np.maximum(np.nan_to_num(std, nan=0.0), 2e-3 * (hi - lo))
        pred = np.clip(self.mu + self._vel, lo, hi)
        e = mu - pred
        jump = np.abs(e) > self.jump_sigma * scale
        a = np.where(jump, 1.0, self.smoothing)
        b = np.where(jump, 0.0, a * a / (2 - a))
        self.mu = pred + a * e
        self._vel = np.where(jump, 0.0, self._vel + b * e)
        # variance of the alpha-beta estimate for white measurement noise (steady state):
        # (2a² + 2b - 3ab) / (a (4 - 2a - b)) of the measurement's (Kalata 1984)
        g = np.where(jump, 1.0, (2 * a * a + 2 * b - 3 * a * b) / (a * (4 - 2 * a - b)))
        self.std = np.sqrt(np.clip(g, 0, 1)) * std

    def process(self, frame: np.ndarray, index: int, draw: bool = True,
                gray: np.ndarray | None = None) -> tuple[np.ndarray, FrameResult]:
        """One BGR frame; ``gray``: its grey image when the caller has one (the decoder's luma plane), else
        it is converted here."""
        t0, c0 = time.perf_counter(), time.thread_time()
        st = {}
        if gray is None:
            gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        pe = self.markers.update(gray)
        t1 = time.perf_counter()
        st["markers_pose"] = (t1 - t0) * 1e3
        status, resid, n_dots = "lost", float("nan"), 0
        draw_pose = pe.pose  # the overlay's camera pose: the joint refinement's where it ran (the tracker keeps its own)
        if pe.status == "measured":
            obs = self.dots.update(frame, gray, pe.pose)
            n_dots = int(obs.valid.sum())
            t2 = time.perf_counter()
            st["dots"] = (t2 - t1) * 1e3
            if n_dots >= max(2, self.min_dots * len(obs.valid)):
                depth = float(pe.pose.apply(self._dots_ref.mean(0, keepdims=True))[0, 2])
                if self._depth is None or abs(depth / self._depth - 1) > 0.05:  # re-weight on 5 % depth change
                    self._depth, self._mask = depth, None
                sw = None if pe.rotation_std is None else float(pe.rotation_std[1])  # about the face normal y
                res = self._assimilate(obs.displacement, obs.valid, sw, obs.world, pe)
                mu, std = res.params, res.std
                if self.joint_pose and self.nuisance == "pose" and pe.n_markers > 0 \
                        and (self.joint_pose is True or pe.n_markers < 3 or (self.joint_pose == "gated"
                                                                             and self._surprising(mu, std))):
                    joint = self._joint_refine(pe, obs.pixels, obs.valid, mu)
                    if joint is not None:
                        mu, std, draw_pose = joint
                self._filter(mu, std)
                self._predict_unseen(obs.valid)
                resid = res.residual * 1e3
                status = "tracking"
            else:
                status = "hold"
            t3 = time.perf_counter()
            st["assimilate"] = (t3 - t2) * 1e3
        else:
            self.dots.reset()
            self._fresh = True
            status = "hold" if pe.status == "predicted" else "lost"
            t3 = time.perf_counter()
            st["dots"] = st["assimilate"] = 0.0
        t3 = time.perf_counter()
        state = None
        if self.overlay is not None:
            state = {"pose": draw_pose, "c": self.rom.coefficients(self.mu)[0], "mu": self.mu.copy(),
                     "std": self.std.copy(), "status": status if pe.pose is not None else "lost",
                     "info": {"markers": pe.n_markers, "dots": n_dots, "dots_total": len(self.obj.dots),
                              "frame": index, "latency_ms": (t3 - t0) * 1e3}}
        out = self.render(frame, state) if draw and state is not None else frame
        t4 = time.perf_counter()
        st["overlay"] = (t4 - t3) * 1e3
        r = FrameResult(index, status, self.mu.copy(), self.std.copy(), resid, pe.n_markers, n_dots,
                        (t4 - t0) * 1e3, st, (time.thread_time() - c0) * 1e3)
        r._draw = state
        return out, r

    def render(self, frame: np.ndarray, state: dict) -> np.ndarray:
        """Draw the overlay of one frame's estimate ``state`` (made by :meth:`process`) onto ``frame`` (in
        place). Thread-safe with respect to the estimation: it reads only the overlay's own data and the
        state's copies, so it can run in the encoder thread while the next frame is being estimated."""
        c = state["c"]
        vals = self.overlay.values(c)
        u_tip = float(np.tensordot(c, self.overlay.Fg, 1)[len(self.overlay.zs) // 2, -1, 2]) * -1e3
        info = dict(state["info"], field_max=float(vals.max()), tip_mm=u_tip)
        return self.overlay.draw(frame, self.camera, state["pose"], c, state["mu"], state["std"], state["status"],
                                 info, values=vals)

    # -- whole videos -------------------------------------------------------------------------------------
    def run(self, source, out_video=None, out_csv=None, fps: float | None = None, crf: int = 20,
            preset: str = "ultrafast", progress: Callable[[int, int], None] | None = None,
            max_frames: int | None = None, snapshots: dict | None = None, overlay_thread: bool = False,
            use_luma: bool = True, encoder_threads: int | None = None, convert: str = "opencv",
            cv_threads: int | None = 1) -> dict:
        """Process a video file path or a frame source (VideoReader / CameraSource / iterable of frames).

        Three threads overlap: the decoder (PyAV, reading ahead), the estimation and overlay (this thread)
        and the encoder. ``overlay_thread``: draw the overlay in the encoder thread instead (:meth:`render`);
        measured slower on 2 cores (the overlay's Python/numpy steps and the estimation's then contend for
        the GIL: 109 vs 161 fps end to end, 12.7 vs 11.0 ms CPU per frame, benchmarks/bench_ar.py). ``use_luma``: take the grey image from the decoder's luma plane
        (else convert BGR to grey here). ``encoder_threads``: libx264 threads (0: its default, 1.5 per core;
        None: the cores left by the decoder and the estimation, at least 1). ``cv_threads``: OpenCV's thread
        pool size while the video runs (restored afterwards; None: unchanged): the stages already run in
        parallel threads, and OpenCV's own workers only contend with them on few cores. ``preset``: libx264
        preset; "ultrafast" encodes a 720p frame in about a third of "veryfast"'s CPU time at equal PSNR
        (CRF) and about 2.5x its bit rate (benchmarks/bench_ar.py). ``convert``:
        yuv420p <-> BGR conversion of the reader (for a path source) and the writer, "opencv" or "ffmpeg"
        (see :class:`physar.ar.video.VideoWriter`).

        Outputs are written atomically (temporary file renamed at the end). ``snapshots``: {frame index:
        PNG path} of augmented frames to save. Returns a summary with fps and per-stage latency statistics
        ("overlay" is measured in the thread that draws it; "cpu_ms_median": CPU time of the estimation
        thread per frame, overlay included when it is drawn there).
        """
        if encoder_threads is None:
            encoder_threads = max(1, (os.cpu_count() or 1) - 2)
        if cv_threads is not None:
            cv_prev = cv2.getNumThreads()
            cv2.setNumThreads(int(cv_threads))
        try:
            return self._run(source, out_video, out_csv, fps, crf, preset, progress, max_frames, snapshots,
                             overlay_thread, use_luma, encoder_threads, convert)
        finally:
            if cv_threads is not None:
                cv2.setNumThreads(cv_prev)

    def _run(self, source, out_video, out_csv, fps, crf, preset, progress, max_frames, snapshots, overlay_thread,
             use_luma, encoder_threads, convert) -> dict:
        names = self.rom.names
        header = [f"{n}_est" for n in names] + [f"{n}_std" for n in names] + ["residual_mm", "markers", "dots",
                                                                              "latency_ms"]
        deferred = bool(out_video) and overlay_thread and self.overlay is not None
        draw = bool(out_video) and not deferred

        def step(k, item, _used):
            frame, luma = item
            out, r = self.process(frame, k, draw=draw, gray=luma)
            return (self._render_job(frame, r) if deferred else out), r

        def frames(reader):
            if use_luma and hasattr(reader, "frames_with_luma"):
                return reader.frames_with_luma()
            return ((f, None) for f in reader)

        s = run_video(step, self.camera, source, out_video, out_csv, fps, crf, header, _estimates_row, progress,
                      snapshots, max_frames, STAGES, preset=preset, encoder_threads=encoder_threads, convert=convert,
                      frames=frames, time_io=True, cpu=True)
        results = s.pop("results")
        for r in results:
            r.__dict__.pop("_draw", None)
        cpu = s.pop("process_cpu_ms_per_frame")  # all threads: decode, estimate, draw, encode
        s["stages_ms_mean"] = {st: float(np.mean([r.stages_ms.get(st, 0.0) for r in results])) for st in STAGES}
        s["cpu_ms_median"] = float(np.median([r.cpu_ms for r in results]))
        return {**s, "process_cpu_ms_per_frame": cpu, "results": results}

    def _render_job(self, frame, r: FrameResult):
        """A callable for the encoder thread: draws frame r's overlay (timed into r.stages_ms["overlay"]) and
        returns the image to encode."""
        state = r._draw

        def job():
            t = time.perf_counter()
            out = self.render(frame, state) if state is not None else frame
            r.stages_ms["overlay"] = (time.perf_counter() - t) * 1e3
            return out
        return job


def _estimates_row(r: FrameResult) -> list:
    """The columns of estimates.csv after frame, time_s, status."""
    return ([f"{v:.6f}" for v in r.mu] + [f"{v:.6f}" for v in r.std] +
            [f"{r.residual_mm:.5f}", r.n_markers, r.n_dots, f"{r.latency_ms:.3f}"])


def read_estimates(path) -> dict:
    """Columns of an estimates.csv as numpy arrays (status as str)."""
    from physar.ar.scene import read_csv_columns

    cols = read_csv_columns(path, "estimates file")
    if "status" in cols:
        cols["status"] = cols["status"].astype(str)
    return cols
