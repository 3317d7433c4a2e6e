"""physar: physics-based visual computing.

Layers (data flows one way): geometry -> fem -> (integrators | rom) -> assimilation -> vision/ar,
and geometry -> mpm -> gaussians/skinning -> recon. See ARCHITECTURE.md.
"""

from importlib.metadata import PackageNotFoundError, version

from physar.errors import PhysarError

try:
    __version__ = version("physar")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["PhysarError", "__version__"]
