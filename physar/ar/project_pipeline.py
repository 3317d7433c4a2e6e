r"""The frame loop of any AR project (seed 000 §2.1, §4, §5): markers -> camera pose -> printed dots ->
parameters :math:`\mu^*` of the reduced model by Levenberg-Marquardt on the image -> overlay -> encode.

Nothing here knows the object's shape: the project gives the reduced model (its mesh and modes), the
markers' corners and the dots' positions in the object's frame. Each frame:

1. the markers give the camera pose (ArUco, tracked corners, filtered: :class:`physar.vision.markers.MarkerTracker`);
2. each dot is searched near its predicted pixel, the projection of its reference position moved by the
   reduced model at the previous estimate, dots on faces turned away from the camera are skipped, and the
   search is brightness-invariant (:func:`physar.vision.blobs.find_dots`);
3. the parameters and the camera pose are refined together (Gauss-Newton with step halving, bounds by
   clipping) on :math:`\theta` = (6 small world-motion pose parameters, :math:`\mu`):

   .. math::

       \lVert (P(X_c; \mathrm{pose}) - c^*) / \sigma_c \rVert^2
       + \lVert (P(x_i + u_i(\mu); \mathrm{pose}) - d^*_i) / \sigma_d \rVert^2,

   with :math:`X_c` the seen marker corners, :math:`c^*` their pixels, :math:`x_i` the dots' reference
   positions (and, with ``[features] mode = "points"``, the texture features' material points,
   :mod:`physar.ar.surface_points`, as more rows with their own :math:`\sigma_f`, set from the features'
   residuals relative to the dots'), :math:`u_i(\mu) = \sum_m c_m(\mu)\, C_i F_m` the reduced model at the dots (:math:`C`: the
   surface observation operator), :math:`d^*_i` the dots' pixels; a pose error moves the points as
   :math:`X \to c + \exp(\delta\theta)(X - c) + \delta t` before the pose (:math:`c`: the markers' centre).
   The covariance of :math:`\mu` is the inverse Gauss-Newton matrix scaled by
   :math:`\max(1, \chi^2/\mathrm{dof})`. On a fresh start (first frame, after a loss) or when the residual is
   far above the recent ones, the parameter box is searched on a grid first (the cost is not convex in a load
   position); after a fresh start the dots are searched again, with the normal radius, where the estimate
   puts them, and solved again while the residual falls (at most 3 times: the wide first search can take a
   neighbouring dot for a dot);
4. an interacting multiple model filter (:class:`physar.assimilation.filters.IMMFilter`) smooths the
   estimate with each frame's std;
5. the overlay (:class:`physar.ar.surface.SurfaceOverlay`) draws the deformed surface coloured by the field.
"""
from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from physar.ar.runner import run_video
from physar.assimilation.filters import IMMFilter
from physar.errors import ConfigError, PhysarError, PhysarWarning
from physar.vision.blobs import find_dots
from physar.vision.camera import Pose
from physar.vision.observation import closest_on_triangles, surface_observation_matrix
from physar.vision.occlusion import hidden_points

STAGES = ("decode", "markers_pose", "dots", "assimilate", "overlay", "encode")


BOUND_TOL = 0.005
"""An estimate within this fraction of its range's width from a bound is "at the bound" (the ``at_bound``
column of :meth:`ProjectPipeline.run`'s CSV): the solve clips the parameters to the model's box, so an
estimate that stays there says the true value is probably outside the box (or in other units)."""

PINNED_FRACTION = 0.25
"""Fraction of the tracked frames at one bound of a parameter from which :meth:`ProjectPipeline.run` warns
(once, at the end of the run). A value that truly dwells at a range end a quarter of the time also warns."""
#: a parameter whose standard deviation averages more than this fraction of its range over the tracked frames
#: is reported as poorly observed (2 sd then span 5 x the 1 % tolerance `physar synth score` judges by)
WEAK_STD_FRACTION = 0.025


LOW_BITS_PER_PIXEL = 0.15
"""Bits per pixel and frame below which :meth:`ProjectPipeline.run` warns that texture features suffer from the
codec: the bracket example's clips at 0.09 (2.4 Mbit/s, 1280x720, 30 fps) made the dots + features project worse
than the dots alone, at 0.6 (17 Mbit/s) better; a phone's 1080p at 17 Mbit/s is about 0.27."""


RIM_FRACTION = 1.15
"""Radius of the ring of points tested for occlusion around each dot, as a fraction of the dot's radius (the
blob's centroid window reaches past the printed edge)."""


def _rim_offsets(normals: np.ndarray, radius: float, n: int = 8) -> np.ndarray:
    """(d, n + 1, 3): the centre (zero) and ``n`` points on a circle of ``radius`` [m] in each dot's tangent plane
    (normals (d, 3)), as offsets from the dot's centre."""
    N = np.asarray(normals, float)
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    a = np.where(np.abs(N[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    e1 = np.cross(N, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(N, e1)
    th = 2 * np.pi * np.arange(n) / n
    ring = radius * (np.cos(th)[None, :, None] * e1[:, None] + np.sin(th)[None, :, None] * e2[:, None])
    return np.concatenate([np.zeros((len(N), 1, 3)), ring], 1)


def _rotations(w: np.ndarray) -> np.ndarray:
    r"""Rotation matrices (k, 3, 3) of rotation vectors w (k, 3) (Rodrigues, as ``cv2.Rodrigues`` one by one):
    :math:`R = I + a W + b W^2`, :math:`W = [w]_\times`, :math:`a = \sin\theta / \theta`,
    :math:`b = (1 - \cos\theta) / \theta^2`, :math:`\theta = |w|` (their series below 1e-4)."""
    w = np.asarray(w, float).reshape(-1, 3)
    th2 = np.einsum("ki,ki->k", w, w)
    th = np.sqrt(th2)
    small = th < 1e-4
    ts = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ts)) / (ts * ts))
    W = np.zeros((len(w), 3, 3))
    W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    W[:, 1, 0], W[:, 2, 0], W[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return np.eye(3) + a[:, None, None] * W + b[:, None, None] * (W @ W)


@dataclass
class ProjectFrame:
    """What :meth:`ProjectPipeline.process` reports for one frame (a CSV row of :meth:`ProjectPipeline.run`).

    Attributes:
        frame: index of the frame.
        status: "tracking" (parameters updated), "hold" (pose known, parameters held), "lost" (no pose), or,
            with markerless features, "reference" (the reference view being taken) and "rest".
        mu: (p,) current estimate of the project's parameters, in their units: the frame's ("tracking") or the
            last one held ("hold", "rest"); NaN in a "lost" frame and in every frame before the first estimate
            (since the start, a :meth:`ProjectPipeline.reset` or a "lost" frame: the starting value, or an estimate
            from before the object was lost from sight, is no estimate).
        std: (p,) its standard deviation (NaN where ``mu`` is).
        at_bound: (name, "lower" | "upper") of each parameter whose ``mu`` is within :data:`BOUND_TOL` of the
            range's width from a bound of the model's range.
        residual_px: RMS reprojection residual of the frame's fit (nan where none was made).
        n_markers: markers found.
        n_dots: observations used: dots (or tracked feature points) and directly measured levers.
        n_features: texture features used beside the dots (``[features] mode = "points"``).
        latency_ms: wall time of the frame, ms.
        stages_ms: wall time per stage (``markers_pose``, ``dots``, ``assimilate``, ``overlay``), ms.
        cpu_ms: CPU time of the processing thread, ms.
    """

    frame: int
    status: str            # tracking | hold | lost
    mu: np.ndarray
    std: np.ndarray
    residual_px: float
    n_markers: int
    n_dots: int
    latency_ms: float
    stages_ms: dict = field(default_factory=dict)
    cpu_ms: float = float("nan")
    n_features: int = 0
    at_bound: tuple = ()


def _grey_levels_only(path, max_frames: int = 60) -> bool | None:
    """Whether a video file holds grey levels only: a grey pixel format, or (a monochrome camera's H.264) colour
    planes within 3 levels of neutral (128) all over its first frame with texture (luma standard deviation of 4
    levels or more; a black, white or faded-in start has neutral colour planes in any video); None when it cannot
    be read here or no frame of the first ``max_frames`` has texture."""
    import av

    try:
        with av.open(str(path)) as c:
            s = c.streams.video[0]
            if (s.codec_context.pix_fmt or "").startswith("gray"):
                return True
            for i, f in enumerate(c.decode(s)):
                if f.format.name not in ("yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p"):
                    return False
                pl = [np.frombuffer(p, np.uint8).reshape(p.height, p.line_size)[:, :p.width] for p in f.planes[:3]]
                if pl[0].std() >= 4.0:
                    return all(int(np.abs(x.astype(np.int16) - 128).max()) <= 3 for x in pl[1:])
                if i + 1 >= max_frames:
                    break
            return None
    except (av.FFmpegError, OSError, ValueError, IndexError, AttributeError):
        return None  # the reader names what is wrong with the file


class ProjectPipeline:
    """The frame loop on an :class:`physar.ar.project.ARProject` (see the module doc). ``overlay``: draw the
    augmented frames (False: estimation only)."""

    def __init__(self, project, overlay: bool = True):
        from physar.ar.bars import BarObserver
        from physar.ar.features import FeatureObserver
        from physar.ar.registration import Registration
        from physar.ar.surface import SurfaceOverlay

        self.project = project
        cfg = project.config
        rom, cam = project.rom, project.camera
        self.rom, self.camera = rom, cam
        trk = project.tracking
        self.names, self.units = list(rom.names), list(rom.units)
        self.lo, self.hi = (np.array(b, float) for b in zip(*rom.ranges))
        space = rom.space()
        pts = space.mesh.points
        self.registration = Registration(project, bounds=np.array([pts.min(0), pts.max(0)]))
        self.markers = self.registration.markers
        self.board = project.board
        self.centre = (self.board.corners.reshape(-1, 3).mean(0) if self.board is not None else pts.mean(0))
        params = project.parameters()
        self.bars = [BarObserver(b, params[self.names.index(b.parameter)], self.names.index(b.parameter), cam)
                     for b in cfg.bar]
        self.dots, self.normals = project.dots, project.dot_normals
        self.use_dots = cfg.dots is not None and len(self.dots) > 0
        # texture features: as image points beside the dots (mode "points"), or alone in the face's rectified
        # view (mode "plane")
        points_mode = cfg.features is not None and (cfg.features.mode == "points" or (
            cfg.features.mode == "auto" and self.use_dots))
        self.features = FeatureObserver(project) if cfg.features is not None and not points_mode else None
        self.points = self._fsig = None
        self._ref_wait = 0
        if points_mode:
            from physar.ar.surface_points import GroupSigma, SurfacePoints

            try:
                self.points = SurfacePoints(project)
            except PhysarError as e:
                raise ConfigError(f"{project.source}: {e}") from None
            self._fsig = GroupSigma(start=3 * trk.dot_sigma_px)
        if self.use_dots:
            C = surface_observation_matrix(space, self.dots, components=(0, 1, 2),
                                           tol=cfg.dots.tol or cfg.dots.diameter / 4)
            self.Fd = np.asarray(C @ rom.F.T).T.reshape(rom.n_modes, -1, 3)   # (modes, n dots, 3)
            self.radius_m = cfg.dots.diameter / 2
            # the model's surface, for the dots it hides (a flange over a web): its vertices and their modes
            surf = space.mesh.boundary()
            self._occ_faces = surf.mesh.faces
            self._occ_X0 = surf.mesh.points
            self._occ_U = np.ascontiguousarray(rom.F.reshape(rom.n_modes, -1, 3)[:, surf.node_map])
            # the test points: centre and rim on the surface (a dot the file places up to [dots] tol inside it
            # would be hidden by its own face), moving with the dot
            tri = surf.mesh.points[surf.mesh.faces]
            f_near, lam, _ = closest_on_triangles(self.dots, tri)
            snap = np.einsum("ij,ijk->ik", lam, tri[f_near]) - self.dots
            self._rim = snap[:, None] + _rim_offsets(self.normals, RIM_FRACTION * self.radius_m)   # (n dots, 9, 3)
            self._n_hidden = 0      # frames with too few dots because the object hid them (statistics)
            self._facing = 0        # dots turned towards the camera in the last _expected
            self.colour = cfg.dots.colour
            # the largest dot displacement over the parameter box bounds the search after a fresh start
            corners = np.stack(np.meshgrid(*[np.linspace(a, b, 5) for a, b in rom.ranges], indexing="ij"),
                               -1).reshape(-1, rom.n_params)
            self._umax = max(float(np.abs(np.tensordot(rom.coefficients(m)[0], self.Fd, 1)).max())
                             for m in corners)
        self.filter = IMMFilter(self.lo, self.hi) if trk.filter == "imm" else None
        self.mu = (self.lo + self.hi) / 2
        self.std = np.full(self.lo.size, np.nan)
        self.at_rest = self.features is not None      # texture features: the first frames show the object at rest
        self._fresh = True
        self._estimated = False                       # a frame has been tracked since the start / reset
        self._res_hist: list[float] = []
        self.overlay = None
        self.last_pose, self.last_status = None, "lost"
        if overlay:
            pos = next((j for j, p in enumerate(params) if p.get("kind") == "load_position"), None)
            mat = rom.metadata.get("material_params") or {}
            ov = project.overlay
            material = (float(mat["E"]), float(mat["nu"])) if "E" in mat and "nu" in mat else None
            table = None
            linear_modes = mat.get("model", "linear") == "linear" and not any(
                p.get("kind") == "youngs_modulus" for p in params)
            if ov.field == "von_mises" and not linear_modes:
                table = self._stress_table()
            fld = ov.field if (ov.field != "von_mises" or material is not None or table is not None) else "u"
            show = None if ov.show is None else [self.names.index(s) for s in ov.show]
            self.overlay = SurfaceOverlay(rom, fld, ov.range, ov.exaggeration, ov.alpha, material,
                                          None if pos is None else params[pos].get("path"), pos,
                                          None if pos is None else params[pos].get("load"), show,
                                          stress_table=table, max_faces=ov.faces)

    def reset(self) -> None:
        """Forget the history (a new camera stream): the pose tracker, the filter, the tracked texture points'
        flow, the estimate (back to the box centre, std unknown); the next frame starts fresh (grid search).
        The texture reference (the object at rest, in its own frame) is kept."""
        self.registration.reset()
        if self.filter is not None:
            self.filter.reset()
        if self.features is not None:
            self.features.reset()
        if self.points is not None:
            self.points.reset()
            self._fsig.reset()
        self._ref_wait = 0
        self.mu = (self.lo + self.hi) / 2
        self.std = np.full(self.lo.size, np.nan)
        self.at_rest = self.features is not None
        self._fresh = True
        self._estimated = False
        self._res_hist = []

    @property
    def has_estimate(self) -> bool:
        """Whether a frame was tracked since the start, a :meth:`reset` or the last "lost" frame: the rows and
        the overlay show an estimate only then."""
        return self._estimated

    def view_coefficients(self) -> np.ndarray:
        """The mode coefficients the overlay draws: the estimate's, or zero while the object is at rest."""
        return np.zeros(self.rom.n_modes) if self.at_rest else self.rom.coefficients(self.mu)[0]

    def _stress_table(self):
        """Nodal von Mises stress at the surface vertices sampled over the parameter box with the model's own
        material (nonlinear, or a Young's modulus region): see :func:`physar.ar.surface.sampled_stress`.
        Needs the project's ``[model] config`` (the material and regions); None without it."""
        from physar.ar.project import _file
        from physar.ar.surface import sampled_stress
        from physar.rom.config import build_parametric_problem, build_problem, load_rom_config

        cfg = self.project.config
        if cfg.model.config is None:
            return None
        conf = _file(cfg._base_dir, cfg.model.config)
        rcfg = load_rom_config(conf)
        problem = build_problem(rcfg)
        if problem.space.n_dofs != self.rom.F.shape[1]:
            return None
        pp = build_parametric_problem(rcfg, problem, str(conf))
        nodes = problem.space.mesh.boundary().node_map
        has_e = any(k == "youngs_modulus" for k in pp.kinds)
        return sampled_stress(self.rom, problem.model, nodes, pp.cell_scale if has_e else None)

    @property
    def pose_from(self) -> str:
        """What gives the pose now (for the overlay's status line)."""
        if self.registration.method == "markers" or self.registration.map is None:
            return "markers"
        return "plane features"

    def _observed(self, n_obs: int, n_bars: int, n_feat: int = 0) -> str:
        parts = []
        if self.use_dots:
            parts.append(f"{n_obs}/{len(self.dots)} dots")
        if self.points is not None and self.points.ready:
            parts.append(f"{n_feat}/{len(self.points.points)} features")
        elif self.features is not None:
            total = len(self.features.points) if self.features.ready else 0
            parts.append(f"{n_obs}/{total} features" if total else "collecting the reference")
        if self.bars:
            parts.append(f"{n_bars}/{len(self.bars)} bars")
        return ", ".join(parts)

    # -- geometry ------------------------------------------------------------------------------------------
    def dot_positions(self, mu) -> np.ndarray:
        """Deformed dot positions (n, 3) [m] for the parameters mu."""
        return self._dots_at(mu)[0]

    def _dots_at(self, mu) -> tuple[np.ndarray, np.ndarray]:
        """(deformed dot positions (n, 3) [m], mode coefficients (modes,)) for the parameters mu."""
        c = self.rom.coefficients(mu)[0]
        return self.dots + np.tensordot(c, self.Fd, 1), c

    def _expected(self, pose: Pose, X, c=None):
        """Visibility, expected image radius [px] of the dots at X. A dot is visible when its face is turned
        towards the camera and, given the mode coefficients ``c`` of X, no part of the model's deformed surface
        hides any of its centre and rim (8 points at :data:`RIM_FRACTION` of its radius;
        :func:`physar.vision.occlusion.hidden_points`): a dot the object half hides (under a flange) is not
        measured, as its blob's centroid is off by the hidden part (1.2-1.8 px on a T-beam's web)."""
        Xc = X @ pose.R.T + pose.t
        nc = self.normals @ pose.R.T
        view = Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
        cos = -np.einsum("ij,ij->i", nc, view)
        r = self.camera.fx * self.radius_m / np.maximum(Xc[:, 2], 1e-9) * np.sqrt(np.clip(cos, 0.05, 1))
        vis = (cos > 0.15) & (Xc[:, 2] > 0)
        self._facing = int(vis.sum())
        if c is not None and vis.any():
            S = self._occ_X0 + np.tensordot(c, self._occ_U, 1)
            rim = (X[vis][:, None] + self._rim[vis]).reshape(-1, 3) @ pose.R.T + pose.t
            hid = hidden_points(rim, S @ pose.R.T + pose.t, self._occ_faces, 0.25 * self.radius_m, closed=True)
            vis[np.flatnonzero(vis)[hid.reshape(-1, self._rim.shape[1]).any(1)]] = False
        return vis, r

    # -- estimation ----------------------------------------------------------------------------------------
    def _pose_of(self, pose: Pose, th):
        E = cv2.Rodrigues(np.asarray(th[:3], float).reshape(3, 1))[0]
        c = self.centre
        return Pose(pose.R @ E, pose.R @ (c - E @ c + th[3:6]) + pose.t)

    def _residuals(self, pose, TH, Xc, img_c, P, Fp, tgt, sc, sig) -> np.ndarray:
        """Weighted residuals (k, m) of k vectors TH (k, 6 + p) = (pose increment, mu) at once (the frame's
        residual and the finite-difference Jacobian's columns in one pass): marker corners / sc, then the
        observed surface points (dots, then features) / sig, pixels of their deformed positions P + c(mu) Fp
        under the increment's pose (:meth:`_pose_of`) minus their detected pixels tgt. A point behind the camera
        gives NaN (with or without lens distortion), so that the step leading there is rejected."""
        TH = np.atleast_2d(TH)
        p = self.lo.size
        E = _rotations(TH[:, :3])                                                               # (k, 3, 3)
        R = pose.R @ E
        c0 = self.centre
        t = (c0 - E @ c0 + TH[:, 3:6]) @ pose.R.T + pose.t                                     # (k, 3)
        coeffs: dict = {}                   # the pose columns share the frame's mu: c(mu) once per distinct mu
        C = np.array([coeffs[m] if m in coeffs else coeffs.setdefault(m, self.rom._coeffs(list(m))[0])
                      for m in map(tuple, np.clip(TH[:, 6:6 + p], self.lo, self.hi).tolist())])   # (k, modes)
        W = P[None] + np.einsum("km,mnd->knd", C, Fp)
        if Xc is not None:
            W = np.concatenate([np.broadcast_to(Xc, (len(TH),) + Xc.shape), W], 1)
        if np.any(self.camera.dist):
            q = np.array([self.camera.project(Wi, Pose(Ri, ti)) for Wi, Ri, ti in zip(W, R, t)])
        else:
            Xcam = np.einsum("kij,knj->kni", R, W) + t[:, None]
            z = np.where(Xcam[..., 2:3] > 0, Xcam[..., 2:3], np.nan)  # behind the camera: NaN, as Camera.project
            uv = Xcam[..., :2] / z
            K = self.camera.K
            q = uv[..., :1] * K[:2, 0] + uv[..., 1:] * K[:2, 1] + K[:2, 2]
        nc = 0 if Xc is None else len(Xc)
        rd = ((q[:, nc:] - tgt) / np.reshape(sig, (-1, 1))).reshape(len(TH), -1)
        if Xc is None:
            return rd
        return np.concatenate([((q[:, :nc] - img_c) / sc).reshape(len(TH), -1), rd], 1)

    def _grid_start(self, pose, px, valid) -> np.ndarray:
        """The grid point of the parameter box with the smallest dot reprojection error (pose fixed)."""
        g = 9 if self.lo.size < 3 else 6
        mus = np.stack(np.meshgrid(*[np.linspace(a, b, g) for a, b in zip(self.lo, self.hi)], indexing="ij"),
                       -1).reshape(-1, self.lo.size)
        cs = np.array([self.rom._coeffs(m.tolist())[0] for m in mus])            # (G, modes)
        W = self.dots[valid][None] + np.einsum("gm,mnk->gnk", cs, self.Fd[:, valid])
        q = self.camera.project(W.reshape(-1, 3), pose).reshape(len(mus), -1, 2)
        cost = np.sum((q - px[valid][None]) ** 2, (1, 2))
        return mus[int(np.argmin(np.where(np.isfinite(cost), cost, np.inf)))]  # NaN: a dot behind the camera

    def _inliers(self, pose, mu, px, valid) -> np.ndarray:
        """Dots whose reprojection error is below max(1 px, 4 x 1.4826 MAD of the errors): a detection
        farther than that from the fitted model is another blob (texture, a reflection), not the dot."""
        q = self.camera.project(self.dot_positions(mu)[valid], pose)
        e = np.linalg.norm(q - px[valid], axis=1)
        lim = max(1.0, 4 * 1.4826 * float(np.median(np.abs(e - np.median(e)))) + float(np.median(e)))
        out = valid.copy()
        out[np.flatnonzero(valid)[e > lim]] = False
        return out

    def _solve(self, pe, px, valid, mu0, iters: int = 10, feat=None):
        """Joint Gauss-Newton on (pose, mu) from the frame's pose and mu0 on the dots ``px[valid]`` and, with
        ``feat`` = (pixels, valid, sigma), the features' rows; returns (mu, std, pose, rms px of the dots,
        rms px of the features)."""
        trk = self.project.tracking
        sd = trk.dot_sigma_px
        P, Fp, tgt = self.dots[valid], self.Fd[:, valid], px[valid]
        sig = np.full(len(P), sd)
        n_f = 0
        if feat is not None:
            fpx, fvalid, fsig = feat
            n_f = int(fvalid.sum())
            P = np.concatenate([P, self.points.points[fvalid]])
            Fp = np.concatenate([Fp, self.points.Fp[:, fvalid]], 1)
            tgt = np.concatenate([tgt, fpx[fvalid]])
            sig = np.r_[sig, np.full(n_f, fsig)]
        Xc = img_c = Xc_all = img_all = None
        sc = max(float(np.nan_to_num(pe.reprojection_px, nan=0.0)), trk.corner_sigma_px)
        npose = 0
        if pe.image_corners is not None and pe.ids:
            idx = [k for k in (self.board.index(i) for i in pe.ids) if k is not None]
            img_all = np.asarray(pe.image_corners, float).reshape(-1, 2)
            if idx and img_all.shape[0] == 4 * len(idx):
                Xc_all = self.board.corners[idx].reshape(-1, 3)
            else:
                img_all = None
        if trk.joint_pose and Xc_all is not None:
            Xc, img_c, npose = Xc_all, img_all, 6
        p = self.lo.size
        rng = self.hi - self.lo
        th = np.zeros(6 + p)
        th[6:] = np.clip(mu0, self.lo, self.hi)
        free = np.r_[np.arange(6) if npose else np.array([], int), 6 + np.arange(p)]
        steps = np.r_[np.full(6, 1e-6), 1e-6 * rng]

        def res(t):
            return self._residuals(pe.pose, t, Xc, img_c, P, Fp, tgt, sc, sig)[0]

        def jac(t, r):
            h = steps[free].copy()
            upper = (free >= 6) & (t[free] + h > np.r_[np.full(6, np.inf), self.hi][free])
            h[upper] = -h[upper]          # at the upper bound: a backward difference (a forward one would be
            E = np.tile(t, (free.size, 1))  # clipped to zero and freeze the parameter there)
            E[np.arange(free.size), free] += h
            return ((self._residuals(pe.pose, E, Xc, img_c, P, Fp, tgt, sc, sig) - r) / h[:, None]).T

        r = res(th)
        cost = r @ r
        lam = 1e-3
        for _ in range(iters):
            J = jac(th, r)
            A = J.T @ J
            g = J.T @ r
            improved = False
            for _ in range(8):
                try:
                    dx = -np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), g)
                except np.linalg.LinAlgError:
                    lam *= 10
                    continue
                tn = th.copy()
                tn[free] += dx
                tn[6:] = np.clip(tn[6:], self.lo, self.hi)
                rn = res(tn)
                if rn @ rn < cost:
                    improved = True
                    lam = max(lam / 3, 1e-7)
                    break
                lam *= 10
            if not improved:
                break
            done = np.all(np.abs(tn - th) <= steps)
            th, r, cost = tn, rn, rn @ rn
            if done:
                break
        if npose == 0 and Xc_all is not None:
            # the pose held at the markers' (joint_pose = false): its uncertainty, from the same corners, still
            # enters mu's std, so the covariance is the joint one (the pose's increments about the markers' pose)
            Xc, img_c = Xc_all, img_all
            free = np.r_[np.arange(6), 6 + np.arange(p)]
            r = res(th)
            cost = r @ r
        J = jac(th, r)
        dof = max(r.size - free.size, 1)
        try:
            cov = np.linalg.pinv(J.T @ J) * max(1.0, cost / dof)
        except np.linalg.LinAlgError:
            cov = np.full((free.size, free.size), np.inf)
        std = np.sqrt(np.abs(np.diag(cov)[-p:]))
        n_d = int(valid.sum())
        rp = (r[r.size - 2 * (n_d + n_f):] * np.repeat(sig, 2)).reshape(-1, 2)      # pixels: dots, features
        rms = float(np.sqrt(np.mean(rp[:n_d] ** 2))) if n_d else float("nan")
        rms_f = float(np.sqrt(np.mean(rp[n_d:] ** 2))) if n_f else float("nan")
        return th[6:].copy(), std, self._pose_of(pe.pose, th), rms, rms_f

    def _feature_inliers(self, pose, mu, fpx, fvalid) -> np.ndarray:
        """Features whose reprojection error is below max(1 px, median + 4 x 1.4826 MAD): LK locked onto
        another patch (or a feature occluded since the reference) is dropped, as for the dots."""
        q = self.camera.project(self.points.positions(self.rom.coefficients(mu)[0])[fvalid], pose)
        e = np.linalg.norm(q - fpx[fvalid], axis=1)
        lim = max(1.0, 4 * 1.4826 * float(np.median(np.abs(e - np.median(e)))) + float(np.median(e)))
        out = fvalid.copy()
        out[np.flatnonzero(fvalid)[e > lim]] = False
        return out

    def _dots(self, frame, gray, pe, st, t1):
        """Dots stage: search, features tracked (points mode), joint (pose, mu) solve, outlier dots and
        features, re-search of the box on a jump. -> ((mu, std, pose, rms px, features used) or None when
        too few dots, dots used)."""
        trk = self.project.tracking
        X, c0 = self._dots_at(self.mu)
        vis, r_px = self._expected(pe.pose, X, c0)
        pred = self.camera.project(X, pe.pose)
        pred[~vis] = np.nan
        extra = trk.search_px
        if self._fresh:   # the load may be anywhere: search as far as the model can move a dot
            extra = max(extra, self.camera.fx * self._umax / max(float(np.median(
                (X @ pe.pose.R.T + pe.pose.t)[:, 2])), 1e-9))
        search = np.maximum(2.5 * r_px, 4.0) + extra
        px, valid = find_dots(frame, gray, pred, r_px, self.colour, search)
        n_dots = int(valid.sum())
        feat = None
        if self.points is not None and self.points.ready and not self._fresh:
            fpx, fvalid = self.points.track(gray, pe.pose, c0)
            if fvalid.sum() >= 3:
                feat = (fpx, fvalid, self._fsig.sigma(trk.dot_sigma_px))
        t2 = time.perf_counter()
        st["dots"] = (t2 - t1) * 1e3
        if n_dots < trk.min_dots:
            if self._facing >= trk.min_dots > int(vis.sum()):
                self._n_hidden += 1         # the dots turned towards the camera, but the object hides them
            return None, n_dots
        start = self.mu
        if self._fresh:
            start = self._grid_start(pe.pose, px, valid)
        mu, std, pose, rms, rms_f = self._solve(pe, px, valid, start, feat=feat)
        valid2 = self._inliers(pose, mu, px, valid)
        fvalid2 = None if feat is None else self._feature_inliers(pose, mu, feat[0], feat[1])
        drop_d = valid2.sum() < valid.sum() and valid2.sum() >= trk.min_dots
        drop_f = feat is not None and fvalid2.sum() < feat[1].sum() and fvalid2.sum() >= 3
        if drop_d or drop_f:                # a wrong blob taken for a dot, a feature lost: solve without it
            if drop_d:
                valid = valid2
                n_dots = int(valid.sum())
            if drop_f:
                feat = (feat[0], fvalid2, feat[2])
            mu, std, pose, rms, rms_f = self._solve(pe, px, valid, mu, feat=feat)
        for _ in range(3 if self._fresh else 0):
            # the wide search may have taken a neighbour for a dot: search again where the estimate puts them
            X2, c2 = self._dots_at(mu)
            vis2, r2 = self._expected(pose, X2, c2)
            pred2 = self.camera.project(X2, pose)
            pred2[~vis2] = np.nan
            px2, valid2 = find_dots(frame, gray, pred2, r2, self.colour, np.maximum(2.5 * r2, 4.0) + trk.search_px)
            if valid2.sum() < trk.min_dots:
                break
            out2 = self._solve(pe, px2, valid2, mu)
            if not out2[3] < 0.9 * rms:
                break
            (mu, std, pose, rms, rms_f), n_dots = out2, int(valid2.sum())
        med = np.median(self._res_hist[-30:]) if len(self._res_hist) >= 5 else np.inf
        if not self._fresh and rms > 4 * med:       # stuck in a local minimum, or a jump: search again
            out2 = self._solve(pe, px, valid, self._grid_start(pe.pose, px, valid), feat=feat)
            if out2[3] < rms:
                mu, std, pose, rms, rms_f = out2
        self._res_hist.append(rms)
        del self._res_hist[:-60]
        n_feat = 0
        if feat is not None:
            n_feat = int(feat[1].sum())
            self._fsig.add(rms_f, rms)
            self.points.refine(pose, self.rom.coefficients(mu)[0], feat[0], feat[1])
        if self._ref_wait > 0:
            self._ref_wait -= 1
        elif self.points is not None and not self._fresh and (not self.points.ready
                                                               or self.points.valid_fraction < 0.5):
            # choose the features in this frame (placed on the surface the dots' estimate gives), or again
            # when fewer than half of them are still tracked (the view has changed); a face not seen well
            # enough is tried again 30 frames later
            X3, c3 = self._dots_at(mu)
            vis3, r3 = self._expected(pose, X3, c3)
            q3 = self.camera.project(X3, pose)
            if self.points.set_reference(gray, pose, c3, q3[vis3], r3[vis3]) == 0:
                self._ref_wait = 30
            self._fsig.reset()
        return (mu, std, pose, rms, n_feat), n_dots

    def process(self, frame: np.ndarray, index: int, draw: bool = True, gray: np.ndarray | None = None):
        """One BGR frame -> (image, :class:`ProjectFrame`)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        st = {}
        if gray is None:
            gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        pe = self.registration.update(gray)
        t1 = time.perf_counter()
        st["markers_pose"] = (t1 - t0) * 1e3
        status, rms, n_obs, n_bars, n_feat, draw_pose = "lost", float("nan"), 0, 0, 0, pe.pose
        st["dots"] = st["assimilate"] = 0.0
        if pe.status == "measured":
            p = self.lo.size
            mu, std = np.full(p, np.nan), np.full(p, np.nan)
            status = "hold"
            if self.use_dots:
                out, n_obs = self._dots(frame, gray, pe, st, t1)
                if out is not None:
                    mu, std, draw_pose, rms, n_feat = out
            elif self.features is not None:
                if not self.features.ready:
                    self.features.add_reference(frame, gray, pe.pose)
                    status = "reference"
                else:
                    fs, fmu, fstd, res, n_obs = self.features.update(gray, pe.pose)
                    if fs == "rest":
                        status, self.at_rest, self._fresh = "rest", True, True
                    elif fs == "tracking":
                        mu, std, rms = fmu, fstd, res * 1e3
                st["dots"] = (time.perf_counter() - t1) * 1e3
            t2 = time.perf_counter()
            for b in self.bars:                      # a lever measured directly
                a, _npx = b.measure(frame, pe.pose)
                if np.isfinite(a):
                    mu[b.index], std[b.index] = a, b.bar.sigma
                    n_bars += 1
            if np.all(np.isfinite(mu)):
                if self.filter is not None:
                    if self._fresh:
                        self.filter.reset()
                    # a parameter the frame does not constrain (flat cost: std NaN) enters with the range as
                    # its std, not as a certain measurement (IMMFilter refuses NaN)
                    std = np.where(np.isfinite(std), std, self.hi - self.lo)
                    self.mu, self.std = self.filter.update(mu, std)
                else:
                    self.mu, self.std = mu, std
                self._fresh = False
                self.at_rest = False
                self._estimated = True
                status = "tracking"
            st["assimilate"] = (time.perf_counter() - t2) * 1e3
        else:
            self._fresh = True
            if self.features is not None:
                self.features.reset()
            status = "hold" if pe.status == "predicted" else "lost"
            if status == "lost":   # the object was out of sight for longer than the hold: its estimate is stale
                self._estimated = False
        t3 = time.perf_counter()
        if status == "lost" or not self._estimated:   # no estimate: not the held or the starting value
            mu_out, std_out = np.full(self.lo.size, np.nan), np.full(self.lo.size, np.nan)
        else:
            mu_out, std_out = self.mu.copy(), self.std.copy()
        out = frame
        self.last_pose, self.last_status = draw_pose, status      # what the frame's overlay is drawn with
        if draw and self.overlay is not None:   # the overlay shows what the CSV row says (no estimate: none drawn)
            info = {"markers": pe.n_markers, "pose_from": self.pose_from, "observed": self._observed(n_obs, n_bars, n_feat)}
            c = self.view_coefficients()
            out = self.overlay.draw(frame, self.camera, draw_pose, c, mu_out, std_out,
                                    status if draw_pose is not None else "lost", info, self.names, self.units)
        t4 = time.perf_counter()
        st["overlay"] = (t4 - t3) * 1e3
        return out, ProjectFrame(index, status, mu_out, std_out, rms, pe.n_markers, n_obs + n_bars,
                                 (t4 - t0) * 1e3, st, (time.thread_time() - c0) * 1e3, n_feat,
                                 self.bounds_reached(mu_out))

    def bounds_reached(self, mu) -> tuple:
        """(name, "lower" | "upper") of each parameter of ``mu`` within :data:`BOUND_TOL` of its range's width
        from a bound of the model's range (beyond it too; NaN: none)."""
        mu = np.asarray(mu, float)
        tol = BOUND_TOL * (self.hi - self.lo)
        out = []
        for j, name in enumerate(self.names):
            if mu[j] <= self.lo[j] + tol[j]:
                out.append((name, "lower"))
            elif mu[j] >= self.hi[j] - tol[j]:
                out.append((name, "upper"))
        return tuple(out)

    # -- whole videos --------------------------------------------------------------------------------------
    def csv_header(self) -> list[str]:
        """The CSV columns after frame, time_s, status: ``{name}_est`` and ``{name}_std`` of each parameter
        ("nan" in a lost frame and before the first estimate), residual_px, markers, dots, features (with
        ``[features] mode = "points"``), latency_ms, and at_bound: ``name:lower`` / ``name:upper`` of each
        estimate at a bound of the model's range (:data:`BOUND_TOL`), ";"-separated, empty when none."""
        return ([f"{n}_est" for n in self.names] + [f"{n}_std" for n in self.names]
                + ["residual_px", "markers", "dots"] + (["features"] if self.points is not None else [])
                + ["latency_ms", "at_bound"])

    def csv_row(self, r: ProjectFrame) -> list:
        return ([f"{v:.6g}" for v in r.mu] + [f"{v:.6g}" for v in r.std]
                + [f"{r.residual_px:.4f}", r.n_markers, r.n_dots]
                + ([r.n_features] if self.points is not None else []) + [f"{r.latency_ms:.3f}"]
                + [";".join(f"{n}:{side}" for n, side in r.at_bound)])

    def _warn_bitrate(self, source) -> None:
        """One warning when texture features are tracked in a video file (a path or an opened
        :class:`physar.ar.video.VideoReader`) below :data:`LOW_BITS_PER_PIXEL`."""
        from pathlib import Path

        from physar.ar.sources import is_url
        from physar.ar.video import bits_per_pixel

        if self.points is None:
            return
        if not isinstance(source, (str, Path)):
            source = getattr(source, "path", None)          # an opened VideoReader
        if not isinstance(source, (str, Path)) or is_url(str(source)) or not Path(source).is_file():
            return
        q = bits_per_pixel(source)
        if q is not None and q[0] < LOW_BITS_PER_PIXEL:
            bpp, rate, w, h, fps = q
            warnings.warn(PhysarWarning(
                f"{source}: {rate / 1e6:.1f} Mbit/s for {w}x{h} at {fps:g} fps ({bpp:.2f} bit per pixel): at so low "
                "a bitrate H.264 moves a fine texture by a tenth of a pixel, and the [features] may make the "
                "estimates worse than the dots alone (measured on examples/ar/bracket: benchmarks/RESULTS.md, "
                "\"H.264 bitrate\")"), stacklevel=3)

    def _warn_grey(self, source) -> None:
        """One warning when coloured dots are to be found in a video of grey levels only (a file whose stream
        is a grey pixel format or whose first frame has neutral colour planes, or an opened reader with
        ``grey``): their colour is not in the frames, so the dot score sees only luma contrast and a dark blue
        dot looks like any dark texture."""
        from pathlib import Path

        from physar.ar.sources import is_url

        if not self.use_dots or np.ptp(np.asarray(self.colour, float)) < 40:  # grey-ish dots: luma is enough
            return
        grey = getattr(source, "grey", None)
        path = source if isinstance(source, (str, Path)) else getattr(source, "path", None)
        if not grey and isinstance(path, (str, Path)) and not is_url(str(path)) and Path(path).is_file():
            grey = _grey_levels_only(path)
        if grey:
            name = getattr(source, "path", source)
            warnings.warn(PhysarWarning(
                f"{name}: the video holds grey levels only but the [dots] colour is {list(self.colour)} (RGB): "
                "coloured dots cannot be told from dark or bright texture in it; record in colour, or print "
                "black or white dots and set [dots] colour to match"), stacklevel=3)

    def run(self, source, out_video=None, out_csv=None, fps: float | None = None, crf: int = 20,
            preset: str = "ultrafast", progress: Callable[[int, int], None] | None = None,
            max_frames: int | None = None, snapshots: dict | None = None, **kw) -> dict:
        """Process a source (path, or a frame source from :mod:`physar.ar.sources`); outputs as in
        :func:`physar.ar.runner.run_video` (the CSV's columns: :meth:`csv_header`). Returns its summary, with
        also ``marker_frames`` (frames where at least one of the project's markers was found; with a learned
        ``[registration] method = "plane"``, frames with plane-feature inliers) and ``at_bound``
        ({name: {"bound": "lower" | "upper", "value", "frames", "tracked", "fraction"}}: each parameter whose
        estimate was at a bound of the model's range in a tracked frame, the bound it was at most often, in how
        many of the tracked frames). A parameter at one bound in at least :data:`PINNED_FRACTION` of the
        tracked frames gives one PhysarWarning at the end (all such parameters in one line)."""
        if self.use_dots:
            self._n_hidden = 0
        tally = {"tracked": 0, "markers": 0, "bounds": {}, "std_sum": np.zeros(len(self.names)),
                 "std_n": np.zeros(len(self.names))}

        def step(k, item, draw):
            frame, luma = item
            img, r = self.process(frame, k, draw=draw and self.overlay is not None, gray=luma)
            tally["markers"] += r.n_markers > 0
            if r.status == "tracking":
                tally["tracked"] += 1
                for key in r.at_bound:
                    tally["bounds"][key] = tally["bounds"].get(key, 0) + 1
                sd = np.asarray(r.std, float)
                ok = np.isfinite(sd)
                tally["std_sum"][ok] += sd[ok]
                tally["std_n"] += ok
            return img, r

        def frames(reader):
            if hasattr(reader, "frames_with_luma"):
                return reader.frames_with_luma()
            return ((f, None) for f in reader)

        self._warn_bitrate(source)
        self._warn_grey(source)
        prev = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            summary = run_video(step, self.camera, source, out_video, out_csv, fps, crf, self.csv_header(),
                                self.csv_row, progress, snapshots, max_frames, STAGES, preset=preset,
                                convert="opencv", frames=frames, time_io=True, cpu=True, **kw)
        finally:
            cv2.setNumThreads(prev)
        summary["marker_frames"] = tally["markers"]
        summary["hidden_frames"] = self._n_hidden if self.use_dots else 0
        if summary["hidden_frames"]:
            warnings.warn(PhysarWarning(
                f"{self.project.source}: in {summary['hidden_frames']} of {summary['frames']} frames the object "
                f"itself hid the dots (fewer than [tracking] min_dots = {self.project.tracking.min_dots} seen "
                "whole): those frames hold the last estimate; film from a side where the dots are in view, or put "
                "dots on the faces the camera sees"), stacklevel=2)
        summary["at_bound"] = self._pinned(tally["tracked"], tally["bounds"])
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_std = tally["std_sum"] / tally["std_n"]
        summary["std_mean"] = {n: float(v) for n, v in zip(self.names, mean_std)}
        weak = self._weak(mean_std)
        self._warn_pinned(summary["at_bound"], weak)
        self._warn_weak(weak)
        return summary

    def _weak(self, mean_std: np.ndarray) -> dict:
        """{name: mean std / range width} of each parameter whose standard deviation averages more than
        :data:`WEAK_STD_FRACTION` of its range over the tracked frames."""
        width = np.asarray(self.hi, float) - np.asarray(self.lo, float)
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = mean_std / width
        return {n: float(f) for n, f in zip(self.names, frac) if np.isfinite(f) and f > WEAK_STD_FRACTION}

    def _warn_weak(self, weak: dict) -> None:
        """One PhysarWarning naming each poorly observed parameter (:meth:`_weak`) and what makes it observable."""
        if not weak:
            return
        params = {p["name"]: p for p in self.project.parameters()}
        parts = []
        for name, f in weak.items():
            j = self.names.index(name)
            unit = params.get(name, {}).get("unit") or ""
            parts.append(f"{name} is poorly observed: its standard deviation averages {f * (self.hi[j] - self.lo[j]):.3g}"
                         f"{' ' + unit if unit else ''}, {100 * f:.1f} % of its range, over the tracked frames")
        warnings.warn(PhysarWarning(
            f"{self.project.source}: " + "; ".join(parts) + ": the dots move too few pixels for it to be told "
            "apart (estimates near a bound, wide swings); bring the camera closer or record at a higher "
            "resolution, put dots where the object moves most, or use a larger load"), stacklevel=3)

    def _pinned(self, tracked: int, bounds: dict) -> dict:
        """The summary's ``at_bound`` entry from the tracked frames' count and {(name, side): frames}."""
        out = {}
        for j, name in enumerate(self.names):
            k, side = max((bounds.get((name, sd), 0), sd) for sd in ("upper", "lower"))
            if k:
                out[name] = {"bound": side, "value": float(self.hi[j] if side == "upper" else self.lo[j]),
                             "frames": int(k), "tracked": int(tracked), "fraction": k / tracked}
        return out

    def _warn_pinned(self, at_bound: dict, weak: dict | None = None) -> None:
        """One PhysarWarning naming each parameter at one bound in at least :data:`PINNED_FRACTION` of the tracked
        frames, the bound, the fraction and the model file's field that sets the range; for a poorly observed
        one (``weak``, :meth:`_weak`) that as the first cause."""
        params = {p["name"]: p for p in self.project.parameters()}
        cfg = self.project.config
        where = cfg.model.config or cfg.model.file or "the model"
        parts = []
        for name, b in at_bound.items():
            if b["fraction"] < PINNED_FRACTION:
                continue
            p = params.get(name, {})
            unit = p.get("unit") or ""
            lo, hi = self.lo[self.names.index(name)], self.hi[self.names.index(name)]
            field = (f"`path`, {hi - lo:g} {unit} long".rstrip() if p.get("kind") == "load_position"
                     else f"`range` = [{lo:g}, {hi:g}]")
            head = (f"{name} pinned at its {b['bound']} bound {b['value']:g}{' ' + unit if unit else ''} in "
                    f"{100 * b['fraction']:.0f} % of the tracked frames ({b['frames']} of {b['tracked']}): ")
            if name in (weak or {}):
                parts.append(head + f"it is poorly observed ({100 * weak[name]:.1f} % of its range as standard "
                             f"deviation, see below), which pulls estimates to a bound; else the true value may be "
                             f"outside the model's range ({where} [[parameter]] {name} {field}) or in other units")
            else:
                parts.append(head + f"unless the object truly stays there, the true value is probably outside the "
                             f"model's range ({where} [[parameter]] {name} {field}) or in other units")
        if parts:
            warnings.warn(PhysarWarning(f"{self.project.source}: " + "; ".join(parts)), stacklevel=3)


__all__ = ["ProjectFrame", "ProjectPipeline"]
