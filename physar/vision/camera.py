r"""Pinhole camera with lens distortion, rigid poses, plane back-projection (seed 000 §2.1).

The projection is :math:`p = \Pi(x) = K\, [R \mid t]\, x` (seed 000 §2.1, Eq. of the camera operator),
followed by the
OpenCV radial/tangential distortion model (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4]]]). A :class:`Pose`
maps world points to camera coordinates, :math:`x_c = R x_w + t` (OpenCV convention: x right, y down, z forward).
Lengths in m, pixels in px.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from physar.errors import ConfigError, PhysarError
from physar.output import atomic_write_text, check_destination

_DIST_SIZES = (0, 4, 5, 8, 12, 14)


def mat3(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """X @ M.T for X (n, 3), M (3, 3) without BLAS (tall-skinny products are slow and contended there)."""
    X = np.asarray(X, float)
    return X[:, :1] * M[:, 0] + X[:, 1:2] * M[:, 1] + X[:, 2:3] * M[:, 2]


ROTATION_TOL = 1e-5
r"""Largest :math:`\max |R^\top R - I|` a :class:`Pose` accepts: float32 rotations (round-off ~1e-7) pass, a
scaled matrix does not (a scale of 1 + e moves a pixel 700 px from the principal point by ~350 e px). Vision is
below recon in the layers, so ``physar.recon.scene.ROTATION_TOL`` (1e-2, for float32 skeleton poses) could
import this name, or keep its own more lenient value."""


def _finite_vector(v, n: int, name: str) -> np.ndarray:
    """``v`` as a float array of ``n`` finite values, or ConfigError naming ``name`` and the value."""
    try:
        a = np.asarray(v, float)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be {n} numbers, got {v!r}") from None
    if a.size != n:
        raise ConfigError(f"{name} must have {n} values, got shape {a.shape}")
    a = a.reshape(n)
    if not math.isfinite(sum(a.tolist())):  # NaN or inf in any value (Python floats: cheap for n <= 9)
        raise ConfigError(f"{name} must be finite, got {a.tolist()}")
    return a


def _rotation_error(R: np.ndarray) -> tuple[float, float]:
    r""":math:`\max |R^\top R - I|` and :math:`\det R` of one (3, 3) matrix (a rotation: 0 and +1); scalar
    arithmetic, as a Pose is built in inner loops where NumPy's per-call overhead would dominate."""
    a, b, c, d, e, f, g, h, i = R.ravel().tolist()
    cols = ((a, d, g), (b, e, h), (c, f, i))
    err = max(abs(sum(u * v for u, v in zip(cols[j], cols[k])) - (j == k)) for j in range(3) for k in range(j, 3))
    return err, a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


@dataclass(frozen=True, repr=False)
class Pose:
    """Rigid transform world -> camera: :math:`x_c = R x_w + t` (R (3, 3) rotation, t (3,) in m).

    R must be orthonormal with det +1 (:data:`ROTATION_TOL`) and both finite; anything else (a scaled
    matrix, a reflection, NaN) is refused with a ConfigError naming the field."""

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self):
        R = _finite_vector(self.R, 9, "Pose: R").reshape(3, 3)
        t = _finite_vector(self.t, 3, "Pose: t")
        err, det = _rotation_error(R)
        if err > ROTATION_TOL or det < 0:
            raise ConfigError(f"Pose: R is not a rotation matrix (|R^T R - I| = {err:.3g}, det {det:.3g}; "
                              f"expected orthonormal with det +1), got {np.round(R, 6).tolist()}")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    @classmethod
    def from_rvec(cls, rvec, tvec) -> Pose:
        """Pose of an OpenCV rotation vector (axis * angle, rad) and translation (m)."""
        R, _ = cv2.Rodrigues(_finite_vector(rvec, 3, "Pose.from_rvec: rvec").reshape(3, 1))
        return cls(R, _finite_vector(tvec, 3, "Pose.from_rvec: tvec"))

    @classmethod
    def look_at(cls, eye, target, up=(0.0, 0.0, 1.0)) -> Pose:
        """Camera at `eye` looking at `target` with world `up` pointing up in the image; refuses eye == target
        and an `up` parallel to the viewing direction (no unique pose)."""
        eye, target, up = (_finite_vector(v, 3, f"Pose.look_at: {n}")
                           for v, n in ((eye, "eye"), (target, "target"), (up, "up")))
        z = target - eye
        if np.linalg.norm(z) == 0:
            raise ConfigError(f"Pose.look_at: eye and target coincide ({eye.tolist()}): no viewing direction")
        if np.linalg.norm(up) == 0:
            raise ConfigError("Pose.look_at: up must be a non-zero vector, got [0, 0, 0]")
        z /= np.linalg.norm(z)
        x = np.cross(z, up / np.linalg.norm(up))
        if np.linalg.norm(x) < 1e-12:
            raise ConfigError(f"Pose.look_at: viewing direction {np.round(z, 6).tolist()} is parallel to up "
                              f"{up.tolist()}: choose another up")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        return cls(R, -R @ eye)

    @property
    def rvec(self) -> np.ndarray:
        return cv2.Rodrigues(self.R)[0].ravel()

    @property
    def center(self) -> np.ndarray:
        r"""Camera centre in world coordinates, :math:`c = -R^\top t` (m)."""
        return -self.R.T @ self.t

    def inverse(self) -> Pose:
        return Pose(self.R.T, -self.R.T @ self.t)

    def compose(self, other: Pose) -> Pose:
        r""":math:`\mathrm{self} \circ \mathrm{other}`: first `other`, then `self`."""
        return Pose(self.R @ other.R, self.R @ other.t + self.t)

    def apply(self, X) -> np.ndarray:
        return mat3(np.asarray(X, float).reshape(-1, 3), self.R) + self.t

    def angle_to(self, other: Pose) -> float:
        r"""Rotation angle of :math:`Q = R_\text{self}^\top R_\text{other}` in degrees:
        :math:`\operatorname{atan2}(\sin, \cos)` with
        :math:`\sin = \lvert \operatorname{vee}(Q - Q^\top) \rvert / 2` and
        :math:`\cos = (\operatorname{tr} Q - 1) / 2` (accurate near 0 and near 180 degrees, unlike acos of the
        trace alone)."""
        Q = self.R.T @ other.R
        s = 0.5 * math.sqrt((Q[2, 1] - Q[1, 2]) ** 2 + (Q[0, 2] - Q[2, 0]) ** 2 + (Q[1, 0] - Q[0, 1]) ** 2)
        return math.degrees(math.atan2(s, (np.trace(Q) - 1.0) / 2.0))

    def matrix(self) -> np.ndarray:
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = self.R, self.t
        return M

    def __repr__(self) -> str:
        """One line: the rotation as an angle [deg] about a unit axis (of :attr:`rvec`) and t [m]."""
        rvec = self.rvec
        angle = float(np.linalg.norm(rvec))
        t = ", ".join(f"{v + 0.0:.4g}" for v in self.t.tolist())  # + 0.0: no "-0"
        if angle == 0.0:
            return f"Pose(rotation 0 deg, t=[{t}] m)"
        axis = ", ".join(f"{(v if abs(v) > 1e-12 else 0.0) + 0.0:.4g}" for v in (rvec / angle).tolist())
        return f"Pose(rotation {math.degrees(angle):.4g} deg about [{axis}], t=[{t}] m)"


@dataclass(frozen=True, repr=False)
class Camera:
    """Intrinsics K (3, 3) [px] = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (OpenCV's model: no skew), distortion
    coefficients (OpenCV order), image size (width, height) [px]."""

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 1280
    height: int = 720

    def __post_init__(self):
        K = np.asarray(self.K, float)
        if K.shape != (3, 3):
            raise ConfigError(f"camera matrix must be 3x3, got shape {K.shape}")
        d = np.asarray(self.dist, float).ravel()
        if d.size not in _DIST_SIZES:
            raise ConfigError(f"distortion must have 0, 4, 5, 8, 12 or 14 coefficients, got {d.size}")
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(d))):
            raise ConfigError("camera matrix/distortion contain NaN or inf")
        # zeros up to rounding (a K from cv2.decomposeProjectionMatrix has a skew of 7e-15): 1e-9 of the focal
        tol = 1e-9 * max(abs(K[0, 0]), abs(K[1, 1]), 1.0)
        if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1) > 1e-9 or np.any(np.abs(K[1:, 0]) > tol) \
                or abs(K[2, 1]) > tol:
            raise ConfigError(f"camera matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, "
                              f"got {K.tolist()}")
        if abs(K[0, 1]) > tol:  # cv2.projectPoints/solvePnP/undistortPoints would silently drop it
            raise ConfigError(f"camera matrix skew K[0, 1] must be 0 (OpenCV's camera model, which projection, "
                              f"pose estimation and undistortion use, has none), got {float(K[0, 1])!r}")
        K = K.copy()
        K[1:, 0] = K[2, 1] = K[0, 1] = 0.0
        K[2, 2] = 1.0
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not np.isfinite(v) \
                    or v <= 0 or v != int(v):
                raise ConfigError(f"image {name} must be a positive whole number of pixels, got {v!r}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", d if d.size else np.zeros(5))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # --- construction / conversion ---------------------------------------------------------------
    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, dist=None) -> Camera:
        r"""Camera of horizontal field of view ``hfov_deg`` in (0, 180) degrees, square pixels, principal point at
        the image centre: :math:`f = (w / 2) / \tan(\mathrm{hfov} / 2)` px."""
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not np.isfinite(v) or v <= 0 \
                    or v != int(v):
                raise ConfigError(f"Camera.from_fov: {name} must be a positive whole number of pixels, got {v!r}")
        width, height = int(width), int(height)
        if isinstance(hfov_deg, bool) or not isinstance(hfov_deg, (int, float, np.number)) \
                or not 0 < hfov_deg < 180:
            raise ConfigError(f"Camera.from_fov: hfov_deg must be in (0, 180) degrees, got {hfov_deg!r}")
        f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
        K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
        return cls(K, np.zeros(5) if dist is None else dist, width, height)

    def to_opencv(self) -> tuple[np.ndarray, np.ndarray]:
        """(cameraMatrix (3, 3), distCoeffs (1, n)) as OpenCV expects them."""
        return self.K.copy(), self.dist.reshape(1, -1).copy()

    @classmethod
    def from_opencv(cls, camera_matrix, dist_coeffs, image_size) -> Camera:
        w, h = image_size
        return cls(np.asarray(camera_matrix, float), np.asarray(dist_coeffs, float).ravel(), int(w), int(h))

    def scaled(self, factor: float) -> Camera:
        """The same camera with an image `factor` times larger (pixel-centre convention)."""
        K = self.K.copy()
        K[:2, :2] *= factor
        K[:2, 2] = (K[:2, 2] + 0.5) * factor - 0.5
        return Camera(K, self.dist, round(self.width * factor), round(self.height * factor))

    def size_hint(self, width: int, height: int) -> str:
        """What to do about frames of ``width`` x ``height`` px for this camera of another size: ``; ...`` text
        (a video of the same aspect ratio is often the calibrated mode resized: :meth:`scaled` gives its camera,
        or a calibration at that size does; another aspect ratio is another crop of the sensor)."""
        if (width, height) == self.size:
            return ""
        if abs(width / height - self.height / self.width) <= 0.01 * width / height and \
                (width > height) != (self.width > self.height):
            return ("; the video is turned 90 deg against the calibration (portrait vs landscape): calibrate with "
                    "the camera held as it was for this video")
        f = width / self.width
        if abs(height - self.height * f) <= 1:
            return (f"; calibrate at {width}x{height} (`physar calibrate` on frames of this video mode), or, if "
                    f"this video is the calibrated mode resized (same field of view), scale the camera by {f:g} "
                    f"(an AR project's [camera] scale = {f:g})")
        return (f"; the aspect ratio differs ({width / height:.3f} vs {self.width / self.height:.3f}: another crop of "
                f"the sensor): calibrate at {width}x{height} (`physar calibrate` on frames of this video mode)")

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    def __repr__(self) -> str:
        """One line: image size, focal lengths and principal point [px], distortion (``none`` when all zero)."""
        dist = ", ".join(f"{v:.4g}" for v in self.dist.tolist()) if np.any(self.dist) else None
        return (f"Camera({self.width}x{self.height}, fx={self.fx:.1f}, fy={self.fy:.1f}, cx={self.K[0, 2]:.1f}, "
                f"cy={self.K[1, 2]:.1f}, dist={'none' if dist is None else '[' + dist + ']'})")

    def intrinsics_problem(self, max_aspect: float = 4.0) -> str | None:
        """Why these intrinsics cannot be a calibration of a camera of this image size (None: they can): the
        principal point outside the image (pixel centres at 0 .. W - 1, so cx in [-0.5, W - 0.5], cy likewise),
        or pixels more than ``max_aspect`` times taller than wide or wider than tall (fx / fy; anamorphic lenses
        squeeze up to 2)."""
        cx, cy = float(self.K[0, 2]), float(self.K[1, 2])
        for name, c, n in (("cx", cx, self.width), ("cy", cy, self.height)):
            if not -0.5 <= c <= n - 0.5:
                return (f"principal point {name} = {c:g} px lies outside the {self.width}x{self.height} image "
                        f"(0 .. {n - 1} px)")
        r = self.fx / self.fy
        if not 1 / max_aspect <= r <= max_aspect:
            return f"fx = {self.fx:g} px and fy = {self.fy:g} px differ {max(r, 1 / r):.3g}-fold (pixels are about square)"
        return None

    def distortion_problem(self, min_inside: float = 0.5, n: int = 200) -> str | None:
        r"""Why the distortion cannot describe a lens over this image, or None.

        Two checks on :math:`p = K\,\operatorname{distort}(x)` of undistorted normalised points :math:`x`
        (``cv2.projectPoints``, so every OpenCV coefficient counts): along the rays from the principal point to
        the four edge midpoints the distorted radius must grow (a radius that stops growing folds the image:
        two scene directions land on one pixel; a ray shorter than 1 px, a principal point on an edge, is
        skipped); and at least ``min_inside`` of the undistorted frame (sampled on a grid of at most
        ``n`` x ``n`` pixels: the undistortion map with the same K, as ``cv2.initUndistortRectifyMap`` builds it)
        must come from inside the image. Calibrations of real lenses pass both; coefficients from another camera,
        another unit or a typing slip fail them. :meth:`load` refuses such a file;
        ``calibration.calibration_warnings`` warns about a fresh calibration with this and stricter rules."""
        if not np.any(self.dist):
            return None
        K, d, W, H = self.K, self.dist, self.width, self.height
        cx, cy = K[0, 2], K[1, 2]

        def distort(u, v):  # pixels of the undistorted image -> pixels of the distorted image
            xy = np.linalg.solve(K, np.stack([u, v, np.ones_like(u)]))[:2].T
            p, _ = cv2.projectPoints(np.column_stack([xy, np.ones(len(xy))]), np.zeros(3), np.zeros(3), K, d)
            return p.reshape(-1, 2)

        s = np.linspace(0.0, 1.0, n + 1)[1:]
        for ex, ey, name in ((0.0, cy, "left"), (W - 1.0, cy, "right"), (cx, 0.0, "top"), (cx, H - 1.0, "bottom")):
            if math.hypot(ex - cx, ey - cy) < 1.0:
                continue
            r = np.hypot(*(distort(cx + s * (ex - cx), cy + s * (ey - cy)) - K[:2, 2]).T)
            grows = np.isfinite(r[1:]) & (np.diff(r) > 0)
            if not (np.isfinite(r[0]) and grows.all()):
                k = int(np.argmin(grows)) if np.isfinite(r[0]) else 0
                return (f"distortion {np.round(d, 6).tolist()} folds the image: the distorted radius stops growing "
                        f"{s[k]:.0%} of the way to the {name} edge")
        u, v = np.meshgrid(np.linspace(0, W - 1, min(W, n)), np.linspace(0, H - 1, min(H, n)))
        p = distort(u.ravel(), v.ravel())
        inside = float(np.mean((p[:, 0] >= -0.5) & (p[:, 0] <= W - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] <= H - 0.5)))
        if inside < min_inside:
            return (f"distortion {np.round(d, 6).tolist()} maps only {inside:.0%} of the undistorted {W}x{H} image "
                    f"inside the image (a lens keeps most of it)")
        return None

    # --- geometry ---------------------------------------------------------------------------------
    def project(self, X, pose: Pose) -> np.ndarray:
        r"""Pixels (n, 2) of world points X (..., 3): :math:`p = \operatorname{distort}(K [R|t] X)`.

        The last axis of X must be 3 (one point per row; a transposed (3, n) array is refused). A point at depth
        :math:`z_c \le 0` (behind the camera or in its centre plane) has no image: its row is NaN, where
        ``cv2.projectPoints`` would return a mirrored pixel that may well lie inside the image. Test
        ``np.isfinite(p).all(1)`` before drawing or fitting with the result."""
        X = np.asarray(X, float)
        if X.ndim == 0 or X.shape[-1] != 3:
            raise ConfigError(f"project: X must have shape (n, 3) (points in rows), got shape {X.shape}")
        if not isinstance(pose, Pose):
            raise ConfigError(f"project: pose must be a Pose, got {type(pose).__name__}")
        X = X.reshape(-1, 3)
        if not np.any(self.dist):
            Xc = mat3(X, pose.R) + pose.t
            uv = Xc[:, :2] / np.where(Xc[:, 2:3] > 0, Xc[:, 2:3], np.nan)  # NaN behind, no warning
            return uv[:, :1] * self.K[:2, 0] + uv[:, 1:] * self.K[:2, 1] + self.K[:2, 2]
        if not len(X):
            return np.zeros((0, 2))
        p, _ = cv2.projectPoints(X, pose.rvec, pose.t, self.K, self.dist)
        p = p.reshape(-1, 2)
        p[X @ pose.R[2] + pose.t[2] <= 0] = np.nan
        return p

    def normalized(self, pixels) -> np.ndarray:
        """Undistorted normalised image coordinates (n, 2) of pixels (n, 2)."""
        px = np.asarray(pixels, float).reshape(-1, 1, 2)
        if not np.any(self.dist):
            Ki = np.linalg.inv(self.K[:2, :2])
            q = px.reshape(-1, 2) - self.K[:2, 2]
            return q[:, :1] * Ki[:, 0] + q[:, 1:] * Ki[:, 1]
        return cv2.undistortPoints(px, self.K, self.dist, None, None, None,
                                       (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-10)).reshape(-1, 2)

    def backproject_to_plane(self, pixels, pose: Pose, point, normal) -> np.ndarray:
        r"""World points (n, 3) where the rays of `pixels` meet the plane :math:`n \cdot (x - x_0) = 0` (m).

        .. math::

            x = c + \lambda d \quad \text{with} \quad c = -R^\top t, \quad d = R^\top [x_n, y_n, 1], \quad
            \lambda = \frac{n \cdot (x_0 - c)}{n \cdot d}.
        """
        xn = self.normalized(pixels)
        d = mat3(np.column_stack([xn, np.ones(len(xn))]), pose.R.T)  # R^T d_c, row-wise
        c = pose.center
        n = np.asarray(normal, float)
        lam = (n @ (np.asarray(point, float) - c)) / (d @ n)
        return c + lam[:, None] * d

    # --- files ------------------------------------------------------------------------------------
    def save(self, path, rms_px: float | None = None) -> None:
        """Write the camera as TOML ([camera] width, height, matrix, distortion) atomically; ``path`` must end
        in .toml (so that an image given by mistake, ``-o board_0.png``, is refused, never overwritten)."""
        lines = ["# physar camera (pinhole + OpenCV distortion k1, k2, p1, p2, k3, ...)", "[camera]",
                 f"width = {self.width}", f"height = {self.height}",
                 "matrix = [" + ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in self.K) + "]",
                 "distortion = [" + ", ".join(repr(float(v)) for v in self.dist) + "]"]
        if rms_px is not None:
            lines.append(f"rms_px = {float(rms_px)!r}")
        check_destination(path, suffixes=[".toml"], kind="camera file")
        atomic_write_text(path, "\n".join(lines) + "\n")

    @classmethod
    def load(cls, path) -> Camera:
        """Read a camera TOML written by :meth:`save` (or by hand), or a JSON of intrinsics as other tools write
        them (:func:`camera_from_json`); errors name the file and field."""
        path = Path(path)
        try:
            text = path.read_text()
            data = {"camera": camera_from_json(path, text)} if path.suffix.lower() == ".json" else tomllib.loads(text)
        except FileNotFoundError:
            raise ConfigError(f"{path}: camera file not found") from None
        except (OSError, UnicodeDecodeError) as e:
            raise ConfigError(f"{path}: cannot read camera file ({e})") from None
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{path}: not valid TOML ({e})") from None
        cam = data.get("camera")
        if not isinstance(cam, dict):
            raise ConfigError(f"{path}: missing [camera] table")
        unknown = set(cam) - {"width", "height", "matrix", "distortion", "rms_px"}
        if unknown:
            raise ConfigError(f"{path}: [camera] has unknown key(s) {sorted(unknown)}")
        for key in ("width", "height", "matrix"):
            if key not in cam:
                raise ConfigError(f"{path}: [camera] needs {key}")
        for key in ("width", "height"):
            if not isinstance(cam[key], int) or cam[key] <= 0:
                raise ConfigError(f"{path}: [camera] {key} must be a positive integer, got {cam[key]!r}")
        try:
            K = np.array(cam["matrix"], dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(f"{path}: [camera] matrix must be a 3x3 array of numbers "
                              f"[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]") from None
        if K.shape != (3, 3):
            raise ConfigError(f"{path}: [camera] matrix must be 3x3 [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "
                              f"got shape {K.shape}")
        try:
            d = np.array(cam.get("distortion", []), dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(f"{path}: [camera] distortion must be a list of numbers") from None
        if d.ndim != 1 or d.size not in _DIST_SIZES:
            raise ConfigError(f"{path}: [camera] distortion must be a flat list of 0, 4, 5, 8, 12 or 14 "
                              f"numbers (k1, k2, p1, p2, k3, ...), got shape {d.shape}")
        try:
            c = cls(K, d, cam["width"], cam["height"])
        except ConfigError as e:
            raise ConfigError(f"{path}: {e}") from None
        why = c.intrinsics_problem() or c.distortion_problem()
        if why:
            raise ConfigError(f"{path}: [camera] {why}: is it the calibration of this camera?")
        return c


def camera_from_json(path: Path, text: str) -> dict:
    r"""The ``[camera]`` table (width, height, matrix, distortion) of a JSON file of intrinsics, in one of the
    layouts other tools write:

    * ``fx``, ``fy``, ``cx``, ``cy``, ``width``, ``height`` (optional ``distortion``: OpenCV's k1, k2, p1, p2,
      k3 ...): OpenCV's convention (pixel centres at integers), as physar's TOML;
    * ``K`` / ``camera_matrix`` / ``matrix`` (3x3, or OpenCV FileStorage's ``{"rows": 3, "cols": 3, "data":
      [...]}``) with ``width``/``height`` (or ``image_width``/``image_height``) and optional ``distortion`` /
      ``dist_coeffs`` / ``distortion_coefficients``: OpenCV's convention;
    * nerfstudio's ``transforms.json`` (phone capture apps, COLMAP exports): ``fl_x``, ``fl_y``, ``cx``, ``cy``,
      ``w``, ``h``, optional ``k1``, ``k2``, ``k3``, ``p1``, ``p2``, in COLMAP's convention (the first pixel's
      centre at (0.5, 0.5)): :math:`c_{\mathrm{OpenCV}} = c - 1/2`."""
    import json

    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise ConfigError(f"{path}: not valid JSON ({' '.join(str(e).split())[:100]})") from None
    if not isinstance(d, dict):
        raise ConfigError(f"{path}: a camera JSON must be an object of intrinsics")

    def num(*keys):
        for k in keys:
            if k in d:
                v = d[k]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ConfigError(f"{path}: field '{k}' must be a number, got {v!r}")
                return v
        return None

    def size(*keys):
        v = num(*keys)
        if v is None or v != int(v) or v <= 0:
            raise ConfigError(f"{path}: field '{keys[0]}' must be the image {keys[0]} in px (a positive integer), "
                              f"got {v!r}")
        return int(v)

    if "fl_x" in d:   # nerfstudio / COLMAP: pixel-corner convention
        fx, fy, cx, cy = num("fl_x"), num("fl_y", "fl_x"), num("cx"), num("cy")
        if cx is None or cy is None:
            raise ConfigError(f"{path}: nerfstudio intrinsics need cx and cy")
        dist = [num(k) or 0.0 for k in ("k1", "k2", "p1", "p2")] + ([num("k3")] if "k3" in d else [])
        return {"width": size("w"), "height": size("h"), "matrix": [[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5],
                                                                   [0.0, 0.0, 1.0]],
                "distortion": dist if any(dist) else []}
    width, height = size("width", "image_width"), size("height", "image_height")
    dist = next((d[k] for k in ("distortion", "dist_coeffs", "distortion_coefficients", "dist") if k in d), [])
    if isinstance(dist, dict):
        dist = dist.get("data", [])
    dist = np.asarray(dist, dtype=object).ravel().tolist()
    mk = next((k for k in ("K", "camera_matrix", "matrix", "intrinsics") if k in d), None)
    if mk is not None:
        K = d[mk]
        if isinstance(K, dict):
            K = K.get("data")
        try:
            K = np.asarray(K, dtype=float).reshape(3, 3).tolist()
        except (TypeError, ValueError):
            raise ConfigError(f"{path}: field '{mk}' must be a 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]") from None
        return {"width": width, "height": height, "matrix": K, "distortion": dist}
    fx, fy, cx, cy = num("fx"), num("fy", "fx"), num("cx"), num("cy")
    if None in (fx, cx, cy):
        raise ConfigError(f"{path}: no intrinsics found: give fx, fy, cx, cy, width, height (OpenCV convention), "
                          "K with width/height, or nerfstudio's fl_x, fl_y, cx, cy, w, h")
    return {"width": width, "height": height, "matrix": [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]],
            "distortion": dist}


_atomic_write_text = atomic_write_text  # the name physar.cli.ar imports


def rotation_x(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def rotation_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def rotation_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def check_image(img, name="image") -> np.ndarray:
    if not isinstance(img, np.ndarray) or img.ndim not in (2, 3) or img.size == 0:
        raise PhysarError(f"{name}: expected an image array (h, w[, 3]), got {getattr(img, 'shape', type(img))}")
    return img
