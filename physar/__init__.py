"""physar: physics-based visual computing.

Layers (data flows one way): geometry -> fem -> (integrators | rom) -> assimilation -> vision/ar,
and geometry -> mpm -> gaussians/skinning -> recon (tests/test_architecture.py checks the imports).

The public API is what each package's ``__all__`` names (here: the errors every layer raises); the rest is
private (docs: "Public API and stability").
"""

import os as _os
import sys as _sys
from importlib.metadata import PackageNotFoundError as _PackageNotFoundError
from importlib.metadata import version as _version

# OpenMP threads that sleep when idle (libgomp's default spins): measured on 2 shared cores at load 6-8, a
# 256 px Gaussian render took 3.4 s with spinning threads and 0.28 s with passive ones (about 15 % slower on a
# quiet machine). Only read when torch first loads its OpenMP runtime; a user's own setting is kept.
if "torch" not in _sys.modules:
    _os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from physar.errors import ConfigError, MeshError, PhysarError, PhysarWarning, SolverError

try:
    __version__ = _version("physar")
except _PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["ConfigError", "MeshError", "PhysarError", "PhysarWarning", "SolverError", "__version__"]
