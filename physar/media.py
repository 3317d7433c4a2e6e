"""Video decoding shared by every layer (``physar.ar`` reads videos, files and streams, ``physar.recon`` imports
them): frames in their displayed orientation, every frame's size checked, truncated files reported.

* **Orientation.** Phones store a portrait clip as landscape pictures plus a display matrix (FFmpeg's
  ``DISPLAYMATRIX`` side data, MP4/MOV ``tkhd`` matrix). PyAV's ``VideoFrame.rotation`` is the angle
  :math:`\\theta` (degrees, multiple of 90 here) by which that matrix turns the stored picture
  *counter-clockwise* for display (the sign of ``VideoStream.set_display_rotation``), so the displayed image
  is ``np.rot90(stored, θ / 90)`` (numpy's ``rot90`` turns counter-clockwise as an image is viewed, row 0 at
  the top). Flips in the matrix are not applied (no phone writes them). Sizes (``width``, ``height``) are
  the displayed ones everywhere.
* **Size changes.** A stream whose pictures change size (concatenated MPEG-TS files, a camera switching
  resolution) raises :class:`VideoChanged` at the first frame of the new size, naming the file, the frame
  index and both sizes; the frames before it were delivered (a frame loop can keep its outputs up to there).
* **Truncation.** :func:`shortfall` compares the decoded time span with the container's duration: FFmpeg's
  threaded decoders end a cut file silently, so the caller warns (``decoded 0.9 s of a 2.0 s video
  (truncated?)``).
"""
from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from physar.errors import PhysarError

#: planar 8-bit YUV formats whose first plane is the luma Y (limited range)
_YUV8 = ("yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p", "nv12")


class VideoChanged(PhysarError):
    """A video's frames change size (or display rotation) mid-stream; the frames before were fine."""


def frame_order(path) -> tuple:
    """Sort key of a frame file of a folder (mask PNGs, particle PLYs): the numbers in its name compared as
    numbers (``frame_2`` before ``frame_10``, as tools that do not pad their numbers write them), the rest as
    text, then the whole name."""
    name = Path(path).name
    return tuple(int(t) if i % 2 else t for i, t in enumerate(re.split(r"(\d+)", name))), name


def rotation_of(frame) -> int:
    """The display rotation of a decoded PyAV frame, degrees counter-clockwise in {0, 90, 180, 270} (the
    display matrix's angle rounded to a quarter turn; 0 without one)."""
    r = getattr(frame, "rotation", 0) or 0
    return round(float(r) / 90.0) % 4 * 90


def upright(img: np.ndarray, rotation: int) -> np.ndarray:
    """``img`` (h, w, ...) as displayed: turned counter-clockwise by ``rotation`` degrees (a multiple of 90);
    the same array for 0, else a contiguous copy."""
    k = int(rotation) // 90 % 4
    return np.ascontiguousarray(np.rot90(img, k)) if k else img


def displayed_size(frame) -> tuple[int, int]:
    """(width, height) px of a decoded frame as displayed (swapped for a quarter turn)."""
    w, h = int(frame.width), int(frame.height)
    return (h, w) if rotation_of(frame) in (90, 270) else (w, h)


def luma(frame) -> np.ndarray | None:
    """The decoded frame's luma plane Y (h, w) uint8 as stored (limited range; a copy, no colour conversion)
    when it is planar 8-bit YUV, else None (grey, RGB, 10-bit streams)."""
    if frame.format.name not in _YUV8:
        return None
    p = frame.planes[0]
    return np.frombuffer(p, np.uint8).reshape(p.height, p.line_size)[:, :frame.width].copy()


def to_bgr(frame, convert: str = "ffmpeg") -> tuple[np.ndarray, np.ndarray | None]:
    """(BGR uint8 (h, w, 3), luma uint8 (h, w) or None) of a decoded frame, both in the displayed orientation.
    ``convert="opencv"`` converts 8-bit yuv420p of even size with ``cv2.cvtColor(COLOR_YUV2BGR_I420)``
    (BT.601, about half the CPU time of FFmpeg's swscale; within 3 grey levels of it), anything else with
    swscale."""
    rot = rotation_of(frame)
    if convert == "opencv" and frame.format.name == "yuv420p" and frame.width % 2 == 0 and frame.height % 2 == 0:
        import cv2

        yuv = frame.to_ndarray()  # (3h/2, w): Y, then U and V
        bgr, y = cv2.cvtColor(yuv, cv2.COLOR_YUV2BGR_I420), yuv[:frame.height]
    else:
        bgr, y = frame.to_ndarray(format="bgr24"), luma(frame)
    return upright(bgr, rot), (upright(y, rot) if y is not None else None)


def to_rgb(frame) -> np.ndarray:
    """RGB uint8 (h, w, 3) of a decoded frame in the displayed orientation."""
    return upright(frame.to_ndarray(format="rgb24"), rotation_of(frame))


class Checked:
    """The decoded frames of ``frames`` (an iterator of PyAV video frames, e.g. ``container.decode(stream)``),
    each checked against the first's displayed size and rotation (:class:`VideoChanged` naming ``name``, the
    frame index and both sizes) and a decoder error turned into a PhysarError naming ``name`` and the frame.

    ``count``: frames delivered; ``first_time``/``last_time``: presentation times (s) of the first and last
    frames delivered (None when the stream has no timestamps); ``size``: (width, height) displayed.
    """

    def __init__(self, frames: Iterable, name: str, what: str = "video", first=None):
        self.name, self.what = str(name), what
        self.count = 0
        self.size: tuple[int, int] | None = None
        self.rotation = 0
        self.first_time = self.last_time = None
        self._it = iter(frames)
        self._first = first

    def _take(self, f):
        size, rot = displayed_size(f), rotation_of(f)
        if self.size is None:
            self.size, self.rotation = size, rot
        elif (size, rot) != (self.size, self.rotation):
            k = self.count
            old = f"{self.size[0]}x{self.size[1]}" + (f" (turned {self.rotation} deg)" if rot != self.rotation else "")
            new = f"{size[0]}x{size[1]}" + (f" (turned {rot} deg)" if rot != self.rotation else "")
            raise VideoChanged(f"{self.name}: frame {k} is {new} px but frames 0-{k - 1} are {old} px (the {self.what} "
                               "changes resolution mid-stream; cut it there or convert it to one size)")
        t = f.time
        if t is not None:
            if self.first_time is None:
                self.first_time = t
            self.last_time = t
        self.count += 1
        return f

    def __iter__(self) -> Iterator:
        import av

        if self._first is not None:
            f, self._first = self._first, None
            yield self._take(f)
        while True:
            try:
                f = next(self._it)
            except StopIteration:
                return
            except (av.FFmpegError, OSError, ValueError) as e:
                raise PhysarError(f"{self.name}: cannot decode frame {self.count} of the {self.what} "
                                  f"({type(e).__name__}: {' '.join(str(e).split())[:100]})") from None
            yield self._take(f)


def duration_of(container, stream) -> float | None:
    """The duration (s) a file's header gives its video: the stream's, else the container's; None if neither."""
    if stream.duration and stream.time_base:
        return float(stream.duration * stream.time_base)
    if container.duration:
        return container.duration / 1e6
    return None


def shortfall(checked: Checked, duration: float | None, fps: float, what: str = "video") -> str | None:
    """A one-line warning when the decoded frames of ``checked`` cover clearly less than ``duration`` (s, the
    header's): both the decoded span :math:`t_\\text{last} - t_\\text{first} + 1/f` and the end time
    :math:`t_\\text{last} + 1/f` (headers differ on whether the duration counts a start offset) fall short by
    more than 2.5 frame periods :math:`1/f`; else None."""
    if not duration or checked.first_time is None or not fps or fps <= 0:
        return None
    dt = 1.0 / fps
    span, end = checked.last_time - checked.first_time + dt, checked.last_time + dt
    tol = 2.5 * dt
    if span < duration - tol and end < duration - tol:
        return (f"{checked.name}: decoded {span:.1f} s ({checked.count} frames) of a {duration:.1f} s {what} "
                "(truncated?)")
    return None


__all__ = ["Checked", "VideoChanged", "displayed_size", "duration_of", "frame_order", "luma", "rotation_of", "shortfall", "to_bgr",
           "to_rgb", "upright"]
