"""Video of a trajectory: the deformed boundary surface, flat shaded, painter's algorithm, one fixed
oblique camera; frames drawn with matplotlib (Agg) and encoded as H.264 MP4 (PyAV, yuv420p)."""

from __future__ import annotations

import math
import os
from fractions import Fraction
from pathlib import Path

import numpy as np

from physar.errors import ConfigError, PhysarError
from physar.output import atomic_path

MAX_FPS = 1000.0  # frames per second; H.264 levels end at 300 fps, a larger request is a typo


def check_fps(fps: float, name: str = "video frame rate") -> Fraction:
    """``fps`` as the exact rational rate the MP4 gets (29.97 -> 2997/100); ConfigError unless it is a finite
    number in (0, MAX_FPS] frames per second (no silent rounding: 0 does not become 1)."""
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not math.isfinite(fps) or \
            not 0 < fps <= MAX_FPS:
        raise ConfigError(f"{name} must be a number of frames per second in (0, {MAX_FPS:g}], got {fps}")
    return Fraction(fps).limit_denominator(1001)


def _camera(azim: float, elev: float) -> np.ndarray:
    a, e = np.radians(azim), np.radians(elev)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    # columns: screen x, screen y (up), depth (towards the viewer)
    P = Rx @ Rz
    return P[[0, 2, 1]]


def write_video(path: str | os.PathLike, points: np.ndarray, faces: np.ndarray, frames_u: list,
                times: list, fps: float = 30.0, size: tuple[int, int] = (640, 360), azim: float = -30.0,
                elev: float = 20.0, title: str = "") -> Path:
    """Render the surface (points (n,3), faces (f,3)) displaced by each frame of `frames_u` into an MP4."""
    import av
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise PhysarError(f"video output must end in .mp4, got {path.name}")
    rate = check_fps(fps)
    if "libx264" not in av.codecs_available:
        raise PhysarError("PyAV has no libx264 encoder; install a PyAV wheel with H.264 support")
    P = _camera(azim, elev)
    allx = np.concatenate([(points + u) @ P.T for u in frames_u[:: max(1, len(frames_u) // 50)] + [frames_u[-1]]])
    lo, hi = allx.min(axis=0), allx.max(axis=0)
    span = max(hi[0] - lo[0], (hi[1] - lo[1]) * size[0] / size[1]) * 1.08 + 1e-12
    cx, cy = (lo[:2] + hi[:2]) / 2
    w, h = size
    light = np.array([0.3, 0.8, 0.6])
    light /= np.linalg.norm(light)
    fig = plt.figure(figsize=(w / 100, h / 100), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    try:
        with atomic_path(path) as tmp, av.open(str(tmp), mode="w", format="mp4") as container:
            stream = container.add_stream("libx264", rate=rate)
            stream.width, stream.height = w - w % 2, h - h % 2
            stream.pix_fmt = "yuv420p"
            for u, t in zip(frames_u, times):
                x = (points + u) @ P.T
                tri = x[faces]
                n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
                n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-300
                shade = 0.35 + 0.65 * np.abs(n @ light)
                order = np.argsort(tri[:, :, 2].mean(axis=1))
                ax.clear()
                ax.set_xlim(cx - span / 2, cx + span / 2)
                ax.set_ylim(cy - span * h / w / 2, cy + span * h / w / 2)
                ax.set_axis_off()
                col = np.column_stack([0.25 * shade, 0.5 * shade, 0.85 * shade, np.ones_like(shade)])
                ax.add_collection(PolyCollection(tri[order, :, :2], facecolors=col[order], edgecolors="none"))
                ax.text(0.02, 0.95, f"{title}  t = {t:.3f} s", transform=ax.transAxes, fontsize=9, va="top")
                fig.canvas.draw()
                img = np.asarray(fig.canvas.buffer_rgba())[: stream.height, : stream.width, :3]
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
                for packet in stream.encode(frame):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)
    finally:
        plt.close(fig)
    return path
