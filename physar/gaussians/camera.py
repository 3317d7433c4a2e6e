r"""Pinhole camera for the Gaussian rasteriser (OpenCV convention: x right, y down, z forward, unit m).

A world point :math:`X` maps to camera coordinates :math:`p = R X + t` and to the pixel
:math:`(u, v) = (f_x p_x / p_z + c_x,\ f_y p_y / p_z + c_y)`, in pixel units with the centre of pixel
:math:`(i, j)` (column :math:`i`, row :math:`j`) at :math:`(i + 0.5, j + 0.5)` (the convention of gsplat and of
the 3DGS CUDA rasteriser).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from physar.errors import PhysarError

#: largest :math:`\max |R^\top R - I|` accepted for a camera rotation (float32 poses rounded in a JSON file pass;
#: a scaled matrix or a shear does not).
ROTATION_TOL = 1e-3


def _number(value) -> float:
    """``value`` as a float (a Python, NumPy or 0-d torch number), NaN when it is not one (a bool, a string)."""
    if isinstance(value, (bool, str, bytes)):
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError, RuntimeError):
        return math.nan


def _real(value, name: str) -> float:
    """``value`` as a finite float, else a PhysarError naming ``name``."""
    v = _number(value)
    if not math.isfinite(v):
        raise PhysarError(f"Camera: {name} must be a finite number (px), got {value!r}")
    return v


def _size(value, name: str) -> int:
    """``value`` as a positive int (an integral float such as 64.0 passes), else a PhysarError naming ``name``."""
    v = _number(value)
    if not math.isfinite(v) or v != int(v) or v <= 0:
        raise PhysarError(f"Camera: {name} must be a positive whole number of pixels, got {value!r}")
    return int(v)


def _pose_tensor(value, shape: tuple, name: str) -> torch.Tensor:
    """``value`` as a finite floating tensor of ``shape`` (NumPy arrays and lists are converted)."""
    try:
        t = value if isinstance(value, torch.Tensor) else torch.as_tensor(value)
    except (TypeError, ValueError, RuntimeError):
        raise PhysarError(f"Camera: {name} must be a tensor of shape {shape}, got {type(value).__name__}") from None
    if not t.is_floating_point():
        t = t.to(torch.get_default_dtype())
    if tuple(t.shape) != shape:
        raise PhysarError(f"Camera: {name} must have shape {shape}, got {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise PhysarError(f"Camera: {name} contains NaN or infinite values: {t.tolist()}")
    return t


@dataclass(frozen=True)
class Camera:
    """Pinhole camera: intrinsics fx, fy, cx, cy (px), image size, world-to-camera rotation R and t (m).

    Pixel convention: pixel (i, j) covers [i, i + 1) x [j, j + 1), its centre at (i + 0.5, j + 0.5) (gsplat's
    and OpenGL's), so an image's centre is (width / 2, height / 2). OpenCV (and :class:`physar.vision.Camera`,
    ``physar calibrate``) puts pixel centres at integers: from an OpenCV K use ``cx = cx_cv + 0.5``,
    ``cy = cy_cv + 0.5`` (``physar recon import`` does so).

    Checked on construction: fx, fy finite and > 0, cx, cy finite, width and height positive whole numbers,
    R a (3, 3) rotation (orthonormal within :data:`ROTATION_TOL`, det +1) and t a finite (3,) vector of R's
    dtype; NumPy arrays for R and t are converted to tensors."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    R: torch.Tensor  # (3, 3) world -> camera rotation
    t: torch.Tensor  # (3,) m

    def __post_init__(self) -> None:
        fx, fy = _real(self.fx, "fx"), _real(self.fy, "fy")
        if fx <= 0 or fy <= 0:
            raise PhysarError(f"Camera: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        w, h = _size(self.width, "width"), _size(self.height, "height")
        values = {"fx": fx, "fy": fy, "cx": _real(self.cx, "cx"), "cy": _real(self.cy, "cy"), "width": w,
                  "height": h, "R": _pose_tensor(self.R, (3, 3), "R"), "t": _pose_tensor(self.t, (3,), "t")}
        R = values["R"]
        if values["t"].dtype != R.dtype:
            raise PhysarError(f"Camera: R ({R.dtype}) and t ({values['t'].dtype}) must have the same dtype; "
                              "convert one with .to()")
        Rd = R.detach().double().cpu()
        err = float((Rd.T @ Rd - torch.eye(3, dtype=torch.float64)).abs().max())
        det = float(torch.linalg.det(Rd))
        if err > ROTATION_TOL or det < 0:
            raise PhysarError(f"Camera: R is not a rotation matrix (|R^T R - I| = {err:.3g}, det {det:.3g}; "
                              f"expected orthonormal with det +1), got {[[round(v, 6) for v in r] for r in Rd.tolist()]}")
        for k, v in values.items():
            object.__setattr__(self, k, v)

    @classmethod
    def look_at(cls, eye, target, up=(0.0, -1.0, 0.0), fov_y_deg: float = 45.0, width: int = 128,
                height: int = 128, dtype: torch.dtype = torch.float32) -> Camera:
        """Camera at ``eye`` (m) looking at ``target``, image y axis along -``up`` projected; vertical
        field of view ``fov_y_deg`` (degrees, in (0, 180)); principal point at the image centre. ``eye``,
        ``target`` and ``up`` are finite 3-vectors, ``dtype`` a floating dtype."""
        if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
            raise PhysarError(f"Camera.look_at: dtype must be a floating torch dtype, got {dtype}")
        if not 0 < _number(fov_y_deg) < 180:
            raise PhysarError(f"Camera.look_at: fov_y_deg must be a number of degrees in (0, 180), got {fov_y_deg!r}")
        for name, v in (("eye", eye), ("target", target), ("up", up)):
            try:
                ok = torch.as_tensor(v, dtype=torch.float64)
                ok = tuple(ok.shape) == (3,) and bool(torch.isfinite(ok).all())
            except (TypeError, ValueError, RuntimeError):
                ok = False
            if not ok:
                raise PhysarError(f"Camera.look_at: {name} must be 3 finite numbers (m), got {v!r}")
        eye = torch.as_tensor(eye, dtype=dtype)
        z = torch.as_tensor(target, dtype=dtype) - eye
        if torch.linalg.vector_norm(z) == 0:
            raise PhysarError("Camera.look_at: eye and target coincide")
        z = z / torch.linalg.vector_norm(z)
        up_t = torch.as_tensor(up, dtype=dtype)
        x = torch.linalg.cross(-up_t, z)
        if torch.linalg.vector_norm(x) < 1e-9:
            raise PhysarError("Camera.look_at: the up vector is parallel to the viewing direction")
        x = x / torch.linalg.vector_norm(x)
        y = torch.linalg.cross(z, x)
        R = torch.stack([x, y, z])
        f = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2)
        return cls(f, f, width / 2, height / 2, width, height, R, -R @ eye)

    def to(self, dtype: torch.dtype) -> Camera:
        return Camera(self.fx, self.fy, self.cx, self.cy, self.width, self.height, self.R.to(dtype),
                      self.t.to(dtype))

    @property
    def center(self) -> torch.Tensor:
        r"""Camera centre in world coordinates, m: :math:`C = -R^\top t`."""
        return -self.R.T @ self.t

    @property
    def K(self) -> torch.Tensor:
        return torch.tensor([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]], dtype=self.R.dtype)

    @property
    def viewmat(self) -> torch.Tensor:
        r"""(4, 4) world-to-camera matrix :math:`\begin{bmatrix} R & t \\ 0 & 1 \end{bmatrix}`."""
        m = torch.eye(4, dtype=self.R.dtype)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m
