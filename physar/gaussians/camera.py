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


@dataclass(frozen=True)
class Camera:
    """Pinhole camera: intrinsics fx, fy, cx, cy (px), image size, world-to-camera rotation R and t (m).

    Pixel convention: pixel (i, j) covers [i, i + 1) x [j, j + 1), its centre at (i + 0.5, j + 0.5) (gsplat's
    and OpenGL's), so an image's centre is (width / 2, height / 2). OpenCV (and :class:`physar.vision.Camera`,
    ``physar calibrate``) puts pixel centres at integers: from an OpenCV K use ``cx = cx_cv + 0.5``,
    ``cy = cy_cv + 0.5`` (``physar recon import`` does so)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    R: torch.Tensor  # (3, 3) world -> camera rotation
    t: torch.Tensor  # (3,) m

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise PhysarError(f"Camera: image size must be positive, got {self.width}x{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise PhysarError(f"Camera: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if tuple(self.R.shape) != (3, 3) or tuple(self.t.shape) != (3,):
            raise PhysarError("Camera: R must be (3, 3) and t (3,)")

    @classmethod
    def look_at(cls, eye, target, up=(0.0, -1.0, 0.0), fov_y_deg: float = 45.0, width: int = 128,
                height: int = 128, dtype: torch.dtype = torch.float32) -> Camera:
        """Camera at ``eye`` (m) looking at ``target``, image y axis along -``up`` projected; vertical
        field of view ``fov_y_deg`` (degrees); principal point at the image centre."""
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
