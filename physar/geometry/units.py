"""Length units of a mesh: physar reads every coordinate as metres, so a part modelled in millimetres (the
usual CAD export) or microns comes out 1000 or 10^6 times too large, and a solve on it gives displacements
10^3 to 10^6 times too small with no error. :func:`check_length_units` warns once when a mesh's largest
bounding-box extent lies outside [:data:`MIN_EXTENT_M`, :data:`MAX_EXTENT_M`], and :func:`bounds_text`
states a mesh's bounding box for messages about a selector that misses it.
"""

from __future__ import annotations

import warnings

import numpy as np

from physar.errors import PhysarWarning
from physar.geometry.mesh import _bounds_text

MAX_EXTENT_M = 20.0  # m: larger than any part physar models here (a bridge girder is not a handheld object)
MIN_EXTENT_M = 1e-3  # m: a part under 1 mm is a mesh in other units (or not a mechanical part)


def largest_extent(points) -> float:
    """The largest side [m] of the axis-aligned bounding box of ``points`` (n, 3); 0 for no point."""
    X = np.asarray(points, dtype=float).reshape(-1, 3)
    return float(np.ptp(X, axis=0).max()) if len(X) else 0.0


def units_hint(extent: float) -> str:
    """What a largest extent [m] outside [MIN_EXTENT_M, MAX_EXTENT_M] suggests ("" inside or not finite): a
    model in millimetres (microns above 1000 x MAX_EXTENT_M) read as metres, or one scaled to metres twice."""
    if not np.isfinite(extent):
        return ""
    if extent > MAX_EXTENT_M:
        unit, factor = ("microns", 1e-6) if extent > 1000 * MAX_EXTENT_M else ("millimetres", 1e-3)
        return f"it looks like {unit} ({extent * factor:.4g} m if so): scale it to metres"
    if 0 < extent < MIN_EXTENT_M:
        return ("it is smaller than 1 mm: were the coordinates divided by 1000 twice (or given in km)? "
                "scale it to metres")
    return ""


def check_length_units(points, source: str, scale_hint: str = "") -> bool:
    """Warn once (:class:`physar.errors.PhysarWarning`) when the mesh ``points`` (n, 3), read as metres, have
    a largest bounding-box extent above :data:`MAX_EXTENT_M` (20 m: a model in millimetres or microns) or
    below :data:`MIN_EXTENT_M` (1 mm). ``source`` names the mesh (e.g. "[mesh] file part.stl"); ``scale_hint``
    is appended (how to scale it in the caller's tool). The same message is given once per process (a command
    that reads the mesh twice warns once). Returns whether it warned. Nothing is refused: a
    20 m structure or a 0.5 mm specimen is possible, the warning only says what the numbers look like."""
    extent = largest_extent(points)
    hint = units_hint(extent)
    if not hint:
        return False
    message = (f"{source}: the mesh's largest extent is {extent:.4g} m (coordinates are read as metres): "
               f"{hint}{scale_hint} (if the part really is this size, nothing is wrong)")
    if message in _WARNED:  # a command that reads the same mesh twice (a check solve, a rebuilt model) warns once
        return False
    _WARNED.add(message)
    warnings.warn(message, PhysarWarning, stacklevel=3)
    return True


_WARNED: set[str] = set()  # the messages given in this process


def bounds_text(points) -> str:
    """The bounding box of ``points`` (n, 3) for a message: "[x0, x1] x [y0, y1] x [z0, z1] m (largest extent
    L m)", followed by the hint of :func:`units_hint` when the extent looks like another unit."""
    X = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(X) == 0:
        return "empty (no point)"
    extent = largest_extent(X)
    hint = units_hint(extent)
    return f"{_bounds_text(X)} (largest extent {extent:.4g} m{'; ' + hint if hint else ''})"


__all__ = ["MAX_EXTENT_M", "MIN_EXTENT_M", "bounds_text", "check_length_units", "largest_extent", "units_hint"]
