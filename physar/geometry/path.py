"""Polylines parametrised by arc length (the path of a moving load).

A path is k >= 2 points [[x, y, z], ...] (m) joined by straight segments; s in [0, path_length(path)]
is the arc length from the first point. :func:`path_point` is piecewise linear in s, so a grid uniform
in s is uniform along the polyline whatever the segment lengths.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from physar.errors import ConfigError


def as_path(path: Sequence[Sequence[float]], what: str = "path") -> np.ndarray:
    """The path as a (k, 3) float array; ConfigError for fewer than 2 points, a non-finite coordinate or
    a zero-length segment (repeated point)."""
    p = np.asarray(path, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
        raise ConfigError(f"{what} must be >= 2 points [[x, y, z], ...], got shape {p.shape}")
    if not np.isfinite(p).all():
        raise ConfigError(f"{what} has a NaN or infinite coordinate")
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if (seg <= 0).any():
        i = int(np.flatnonzero(seg <= 0)[0])
        raise ConfigError(f"{what} segment {i} (points {i} and {i + 1}) has zero length")
    return p


def path_length(path) -> float:
    """Total arc length (m) of the polyline."""
    p = as_path(path)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def path_point(path, s) -> np.ndarray:
    """Point(s) at arc length `s` (m) from the first point: (3,) for a scalar s, (n, 3) for an array.

    s must lie in [0, length] (a round-off of 1e-9 relative is clipped); otherwise ConfigError.
    """
    p = as_path(path)
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    length = cum[-1]
    sa = np.asarray(s, dtype=float)
    eps = 1e-9 * length
    if not np.isfinite(sa).all() or (sa < -eps).any() or (sa > length + eps).any():
        raise ConfigError(f"arc length s = {np.round(sa, 9).tolist()} outside the path [0, {length:.9g}] m")
    sc = np.clip(sa, 0.0, length)
    i = np.clip(np.searchsorted(cum, sc, side="right") - 1, 0, len(seg) - 1)
    x = p[i] + ((sc - cum[i]) / seg[i])[..., None] * (p[i + 1] - p[i])
    return x


def is_straight(path, rel_tol: float = 1e-9) -> bool:
    """True when every point of the path lies on the line through its end points (and in order)."""
    p = as_path(path)
    d = p[-1] - p[0]
    L = np.linalg.norm(d)
    if L == 0:
        return False
    off = np.linalg.norm(np.cross(p - p[0], d / L), axis=1)
    return bool(np.all(off <= rel_tol * L) and np.all(np.diff((p - p[0]) @ d) > 0))


__all__ = ["as_path", "is_straight", "path_length", "path_point"]
