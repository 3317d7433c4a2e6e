"""Small I/O helpers of the reconstruction pipeline: MP4 writing (PyAV), PNG sequences, atomic npz/json."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np

from physar.errors import ConfigError


def write_mp4(path: str | Path, frames, fps: float = 30.0) -> bool:
    """Write RGB uint8 frames (H, W, 3) as an H.264 (or MPEG-4) MP4; False when no encoder works.

    Odd sizes are padded to even (yuv420p); the file appears only when complete (temp + os.replace)."""
    import av

    path = Path(path)
    frames = [np.asarray(f, dtype=np.uint8) for f in frames]
    if not frames:
        return False
    h, w = frames[0].shape[:2]
    H, W = h + h % 2, w + w % 2
    tmp = path.with_name("tmp_" + path.name)
    try:
        with av.open(str(tmp), mode="w", format="mp4") as container:
            stream = container.add_stream("libx264" if "libx264" in av.codecs_available else "mpeg4",
                                          rate=max(1, round(fps)))
            stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
            for f in frames:
                pad = np.zeros((H, W, 3), np.uint8)
                pad[:h, :w] = f
                for packet in stream.encode(av.VideoFrame.from_ndarray(pad, format="rgb24")):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)
    except Exception:  # noqa: BLE001 - video output is optional
        tmp.unlink(missing_ok=True)
        return False
    os.replace(tmp, path)
    return True


def read_pngs(folder: Path, n: int, gray: bool = False) -> np.ndarray:
    """Frames 0000.png .. (n-1).png of a folder as float32 in [0, 1]: (n, H, W, 3) or (n, H, W)."""
    out = []
    for f in range(n):
        p = folder / f"{f:04d}.png"
        if not p.exists():
            raise ConfigError(f"missing frame '{p}'")
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR)
        if img is None:
            raise ConfigError(f"'{p}' is not a readable image")
        out.append(img if gray else cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    return np.stack(out).astype(np.float32) / 255.0


def save_npz_atomic(path: str | Path, **arrays) -> None:
    path = Path(path)
    tmp = path.with_name("tmp_" + path.name)
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp, path)


def save_json_atomic(path: str | Path, obj) -> None:
    path = Path(path)
    tmp = path.with_name("tmp_" + path.name)
    tmp.write_text(json.dumps(obj, indent=1))
    os.replace(tmp, path)
