"""3-D Gaussians (seed 002, §3.1, §4.1): parameter set, physics-aware covariance (Eq. 3), 3DGS PLY I/O and
a differentiable CPU rasteriser (vectorised PyTorch; gsplat on CUDA)."""

from physar.gaussians.camera import Camera
from physar.gaussians.model import Gaussians, covariance, quat_to_rotmat, rgb_to_sh0, rotmat_to_quat
from physar.gaussians.ply import load_ply, save_ply
from physar.gaussians.rasterize import RenderResult, project, rasterize_dense, rasterize_tiles, render
from physar.gaussians.sh import eval_sh

__all__ = ["Camera", "Gaussians", "RenderResult", "covariance", "eval_sh", "load_ply", "project",
           "quat_to_rotmat", "rasterize_dense", "rasterize_tiles", "render", "rgb_to_sh0", "rotmat_to_quat",
           "save_ply"]
