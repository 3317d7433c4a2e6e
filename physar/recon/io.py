"""Small I/O helpers of the reconstruction pipeline: MP4 writing (PyAV) and PNG sequences (files are written
through :mod:`physar.output`)."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from physar.errors import ConfigError
from physar.mpm.io import mp4_encoder
from physar.output import atomic_path


def write_mp4(path: str | Path, frames, fps: float = 30.0) -> bool:
    """Write RGB uint8 frames (H, W, 3) as an H.264 (or MPEG-4) MP4; False (nothing written) when PyAV has
    no MP4 encoder or there is no frame. Any other failure raises and leaves no file behind.

    Odd sizes are padded to even (yuv420p); the file appears only when complete (:func:`physar.output.
    atomic_path`)."""
    import av

    frames = [np.asarray(f, dtype=np.uint8) for f in frames]
    codec = mp4_encoder()
    if not frames or codec is None:
        return False
    h, w = frames[0].shape[:2]
    H, W = h + h % 2, w + w % 2
    with atomic_path(path) as tmp, av.open(str(tmp), mode="w", format="mp4") as container:
        stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
        for f in frames:
            pad = np.zeros((H, W, 3), np.uint8)
            pad[:h, :w] = f
            for packet in stream.encode(av.VideoFrame.from_ndarray(pad, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return True


def imread(path: Path, flags: int) -> np.ndarray | None:
    """``cv2.imread`` (None when OpenCV cannot decode the file) with OpenCV's own refusals (a header announcing
    more than 2**30 pixels, a "decompression bomb") turned into one ConfigError line naming the file."""
    try:
        return cv2.imread(str(path), flags)
    except cv2.error as e:
        why = "its header announces more than 2**30 pixels" if "MAX_IMAGE" in str(e) else "a damaged header"
        raise ConfigError(f"'{path}': not an image OpenCV reads ({why})") from None


def _header_size(path: Path) -> tuple[int, int] | None:
    """(W, H) of a PNG from its IHDR chunk (bytes 16-24: big-endian width, height), read without decoding; None
    when the file is not a PNG."""
    with open(path, "rb") as fh:
        head = fh.read(24)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def read_pngs(folder: Path, n: int, gray: bool = False, size: tuple[int, int] | None = None) -> np.ndarray:
    """Frames 0000.png .. (n-1).png of a folder as float32 in [0, 1]: (n, H, W, 3) or (n, H, W). Every frame
    must be ``size`` = (W, H) px when given, else the first frame's size (ConfigError naming the PNG)."""
    out = []
    for f in range(n):
        p = folder / f"{f:04d}.png"
        if not p.exists():
            raise ConfigError(f"missing frame '{p}'")
        want = size if size is not None else ((out[0].shape[1], out[0].shape[0]) if out else None)
        got = _header_size(p) if want is not None else None  # judged before decoding (a header can lie big)
        if got is None or tuple(got) == tuple(want):
            img = imread(p, cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR)
            if img is None:
                raise ConfigError(f"'{p}' is not a readable image")
            got = (img.shape[1], img.shape[0])
        if want is not None and tuple(got) != tuple(want):
            raise ConfigError(f"'{p}' is {got[0]}x{got[1]} px, expected {want[0]}x{want[1]} px"
                              + (" (the camera's size in scene.json)" if size else f" (as {folder / '0000.png'})"))
        out.append(img if gray else cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    return np.stack(out).astype(np.float32) / 255.0


__all__ = ["imread", "read_pngs", "write_mp4"]
