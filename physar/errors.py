"""User-facing errors.

Every error that a user can cause (bad file, bad config value, bad mesh, ill-posed problem) is raised
as a :class:`PhysarError` with a one-line message naming the problem; the CLI prints that line and exits
with code 2. Anything else is a bug.
"""


class PhysarError(Exception):
    """An error caused by the input (file, field, value), with a message a user can act on."""


class ConfigError(PhysarError, ValueError):
    """A configuration file or value is invalid."""


class MeshError(PhysarError, ValueError):
    """A mesh is invalid (NaN coordinates, degenerate or inverted elements, bad connectivity)."""


class SolverError(PhysarError, RuntimeError):
    """A solve failed for a reason the user can fix (singular system, divergence)."""
