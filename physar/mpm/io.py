"""Outputs of MPM runs: per-frame particle PLY (binary little-endian), energy/momentum CSV, MP4 preview.

Every file goes through :mod:`physar.output` (a temporary name in the same folder, renamed when complete), so
no half-written file is left.
"""

from __future__ import annotations

import re
from fractions import Fraction
from pathlib import Path

import numpy as np

from physar.errors import ConfigError
from physar.media import frame_order
from physar.output import atomic_path, write_bytes

_PLY_DTYPE = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("vx", "<f8"), ("vy", "<f8"), ("vz", "<f8"),
                       ("body", "<i4")])


def write_particles_ply(path: str | Path, x: np.ndarray, v: np.ndarray, body: np.ndarray) -> None:
    """Binary PLY point cloud with double x, y, z (m), vx, vy, vz (m/s) and int body per particle."""
    n = len(x)
    rec = np.empty(n, dtype=_PLY_DTYPE)
    for i, k in enumerate(("x", "y", "z")):
        rec[k] = x[:, i]
        rec["v" + k] = v[:, i]
    rec["body"] = body
    header = ("ply\nformat binary_little_endian 1.0\ncomment physar mpm particles\n"
              f"element vertex {n}\n" + "".join(f"property double {k}\n" for k in ("x", "y", "z", "vx", "vy", "vz"))
              + "property int body\nend_header\n")
    write_bytes(Path(path), header.encode("ascii") + rec.tobytes())


def read_particles_ply(path: str | Path) -> dict:
    """Read a PLY written by :func:`write_particles_ply`; returns x (N, 3), v (N, 3), body (N,)."""
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise ConfigError(f"{path}: not a PLY file")
    header = raw[:end].decode("ascii", "replace")
    m = re.search(r"element vertex (\d+)", header)
    props = re.findall(r"property (\w+) (\w+)", header)
    if "binary_little_endian" not in header or m is None or [p[1] for p in props] != list(_PLY_DTYPE.names):
        raise ConfigError(f"{path}: expected a physar particle PLY (binary, x y z vx vy vz body)")
    n = int(m.group(1))
    body = raw[end + len(b"end_header\n"):]
    if len(body) != n * _PLY_DTYPE.itemsize:
        raise ConfigError(f"{path}: truncated particle data ({len(body)} bytes for {n} particles)")
    rec = np.frombuffer(body, dtype=_PLY_DTYPE)
    return {"x": np.stack([rec["x"], rec["y"], rec["z"]], 1), "v": np.stack([rec["vx"], rec["vy"], rec["vz"]], 1),
            "body": rec["body"].astype(np.int64)}


def read_trajectory(folder: str | Path) -> list[dict]:
    """All ``frame_*.ply`` of a folder, in frame order (:func:`physar.media.frame_order`: frame_2 before frame_10)."""
    folder = Path(folder)
    files = sorted(folder.glob("frame_*.ply"), key=frame_order)
    if not files:
        raise ConfigError(f"target folder '{folder}' has no frame_*.ply files (write them with `physar mpm run`)")
    return [read_particles_ply(f) for f in files]


CSV_COLUMNS = ["frame", "time", "com_x", "com_y", "com_z", "p_x", "p_y", "p_z", "L_x", "L_y", "L_z",
               "kinetic_energy", "potential_energy", "elastic_energy", "total_energy"]


def write_diagnostics_csv(path: str | Path, times, diags: list[dict]) -> None:
    """One row per frame: time (s), COM (m), momentum (kg m/s), angular momentum (kg m^2/s), energies (J)."""
    rows = [",".join(CSV_COLUMNS)]
    for i, (t, d) in enumerate(zip(times, diags)):
        vals = [i, t, *d["com"], *d["momentum"], *d["angular_momentum"], d["kinetic_energy"],
                d["potential_energy"], d["elastic_energy"], d["total_energy"]]
        rows.append(",".join(repr(float(v)) if j else str(v) for j, v in enumerate(vals)))
    write_bytes(Path(path), ("\n".join(rows) + "\n").encode())


_PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                     [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], np.uint8)


def render_side_view(x: np.ndarray, body: np.ndarray, size: float, pixels: int = 256) -> np.ndarray:
    """(pixels, pixels, 3) uint8 image of the particles seen along +y (x to the right, z up), coloured by body;
    particles nearer the camera (smaller y) are drawn last."""
    img = np.full((pixels, pixels, 3), 255, np.uint8)
    img[-1, :] = img[:, 0] = 0  # ground line and x = 0 wall
    u = np.clip((x[:, 0] / size * pixels).astype(int), 0, pixels - 1)
    w = np.clip(((1.0 - x[:, 2] / size) * pixels).astype(int), 0, pixels - 1)
    order = np.argsort(-x[:, 1])
    col = _PALETTE[np.asarray(body)[order] % len(_PALETTE)]
    for du in (0, 1):
        for dw in (0, 1):
            img[np.clip(w[order] + dw, 0, pixels - 1), np.clip(u[order] + du, 0, pixels - 1)] = col
    return img


def mp4_encoder() -> str | None:
    """The H.264 encoder (or MPEG-4 part 2 as a fallback) PyAV offers, None when it has neither."""
    import av

    for name in ("libx264", "mpeg4"):
        if name in av.codecs_available:
            return name
    return None


def write_preview_mp4(path: str | Path, frames_x: list[np.ndarray], body: np.ndarray, size: float,
                      fps: float = 30.0, pixels: int = 256) -> bool:
    """Side (x-z) view of the particles per frame as an H.264 MP4 (PyAV). Returns False (nothing written) when
    PyAV has no MP4 encoder; any other failure raises, leaving no file behind."""
    import av

    codec = mp4_encoder()
    if codec is None or not frames_x:
        return False
    with atomic_path(path) as tmp, av.open(str(tmp), mode="w", format="mp4") as container:
        stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
        stream.width = stream.height = pixels
        stream.pix_fmt = "yuv420p"
        for x in frames_x:
            frame = av.VideoFrame.from_ndarray(render_side_view(x, body, size, pixels), format="rgb24")
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return True
