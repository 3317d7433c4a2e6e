"""Differentiable MLS-MPM (seed 002, §3.2, §4.2-4.3): Warp kernels, expert and neural-residual laws.

``MPMModel`` (constants) + ``MPMState`` (x, v, C, F) + ``MPMSolver.step(state_in, state_out, control, dt)``
for forward runs; :mod:`physar.mpm.torch_bridge` for gradients through PyTorch.
"""

from physar.mpm.model import Control, MPMModel, MPMSolver, MPMState, diagnostics
from physar.mpm.scene import build_model, load_scene, parse_scene

__all__ = ["Control", "MPMModel", "MPMSolver", "MPMState", "Params", "build_model", "diagnostics", "load_scene",
           "parse_scene", "simulate"]  # identification: physar.mpm.identify.identify (a submodule of that name)

def __getattr__(name: str):
    """``simulate`` and ``Params`` need PyTorch: imported on first use, not with the package."""
    if name in ("Params", "simulate"):
        from physar.mpm import torch_bridge

        return getattr(torch_bridge, name)
    raise AttributeError(f"module 'physar.mpm' has no attribute {name!r}")
