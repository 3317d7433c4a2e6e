"""physar: physics-based visual computing.

Layers (data flows one way): geometry -> fem -> (integrators | rom) -> assimilation -> vision/ar,
and geometry -> mpm -> gaussians/skinning -> recon (tests/test_architecture.py checks the imports).

The public API is what each package's ``__all__`` names (here: the errors every layer raises); the rest is
private (docs: "Public API and stability").
"""

from importlib.metadata import PackageNotFoundError, version

from physar.errors import ConfigError, MeshError, PhysarError, PhysarWarning, SolverError

try:
    __version__ = version("physar")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["ConfigError", "MeshError", "PhysarError", "PhysarWarning", "SolverError", "__version__"]
