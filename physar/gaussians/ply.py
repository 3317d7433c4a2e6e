"""3DGS PLY import/export (the layout written by graphdeco-inria/gaussian-splatting's ``save_ply``).

One ``vertex`` element of float32 properties, in this order:
``x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_0 .. f_rest_{3(K-1)-1} opacity scale_0..2 rot_0..3``,
binary little endian. ``f_rest`` is channel-major (all R coefficients of bands >= 1, then G, then B),
``opacity`` is the logit, ``scale_*`` the log standard deviation, ``rot_*`` the quaternion (w, x, y, z).
Normals are written as zeros and ignored on reading. Files are written atomically (temp name + rename).
Reading accepts binary little/big endian and ASCII files with any property order and extra properties,
float or double; missing properties raise a :class:`PhysarError` naming the file and every missing property
(a mesh or point-cloud PLY lacks the 3DGS ones), as do a property declared twice, a binary body shorter
than the header declares or longer by at least one vertex record (a wrong vertex count), and a NaN, an
infinite value or a zero quaternion. An empty file (0 vertices) reads as 0 Gaussians.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from physar.errors import PhysarError
from physar.gaussians.model import Gaussians
from physar.output import atomic_path

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def attribute_names(sh_degree: int) -> list[str]:
    """Property names of the 3DGS PLY layout for SH degree ``sh_degree`` (0..3), in file order."""
    n_rest = 3 * ((sh_degree + 1) ** 2 - 1)
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(n_rest)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def save_ply(path: str | os.PathLike, g: Gaussians) -> Path:
    """Write ``g`` to ``path`` in the standard 3DGS PLY layout (float32, binary little endian).

    Written to a temporary file in the same folder and renamed, so no half-written file is left. Values that
    are NaN, infinite, or beyond the float32 range of the file (they would be written as inf) are refused
    before anything is written.
    """
    path = Path(path)
    if not isinstance(g, Gaussians):
        raise PhysarError(f"{path}: save_ply needs physar.gaussians.Gaussians, got {type(g).__name__}")
    if not path.parent.exists():
        raise PhysarError(f"{path}: folder {path.parent} does not exist")
    t = {k: v.detach().cpu().double().numpy() for k, v in g.tensors().items()}
    n = t["means"].shape[0]
    f32max = float(np.finfo(np.float32).max)
    for k, v in t.items():
        if not np.all(np.isfinite(v)):
            raise PhysarError(f"{path}: Gaussians.{k} contains NaN or infinite values; not written")
        if v.size and np.abs(v).max() > f32max:
            raise PhysarError(f"{path}: Gaussians.{k} has values up to {np.abs(v).max():.3g}, beyond float32 "
                              f"({f32max:.3g}) of the 3DGS PLY layout; not written")
    names = attribute_names(g.sh_degree)
    cols = [t["means"], np.zeros((n, 3)), t["sh"][:, 0, :],
            t["sh"][:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (t["sh"].shape[1] - 1)),
            t["opacity_logits"][:, None], t["log_scales"], t["quats"]]
    data = np.concatenate(cols, axis=1).astype("<f4")
    rec = np.empty(n, dtype=[(name, "<f4") for name in names])
    rec.view("<f4").reshape(n, len(names))[:] = data
    header = ["ply", "format binary_little_endian 1.0", "comment physar 3DGS layout",
              f"element vertex {n}"] + [f"property float {name}" for name in names] + ["end_header"]
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(rec.tobytes())
    return path


def _parse_header(path: Path, f) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]]]:
    first = f.readline()
    if first.strip() != b"ply":
        raise PhysarError(f"{path}: not a PLY file (first line is {first[:20]!r}, expected 'ply')")
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    while True:
        line = f.readline()
        if not line:
            raise PhysarError(f"{path}: PLY header has no 'end_header' line")
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format":
            if len(words) < 2 or words[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise PhysarError(f"{path}: unsupported PLY format line {line.strip()!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PhysarError(f"{path}: malformed PLY element line {line.strip()!r}")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise PhysarError(f"{path}: PLY property before any element: {line.strip()!r}")
            if words[1] == "list":
                raise PhysarError(
                    f"{path}: list property {words[-1]!r} in element {elements[-1][0]!r} is not supported "
                    "in a 3DGS Gaussian file")
            if len(words) != 3 or words[1] not in _PLY_TYPES:
                raise PhysarError(f"{path}: malformed PLY property line {line.strip()!r}")
            if any(name == words[2] for name, _ in elements[-1][2]):
                raise PhysarError(f"{path}: property {words[2]!r} declared twice in element {elements[-1][0]!r}")
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise PhysarError(f"{path}: unknown PLY header keyword {words[0]!r}")
    if fmt is None:
        raise PhysarError(f"{path}: PLY header has no 'format' line")
    return fmt, elements


def load_ply(path: str | os.PathLike, dtype: torch.dtype = torch.float32) -> Gaussians:
    """Read 3DGS Gaussians from a PLY file (see the module docstring for the layout and the checks) as
    tensors of the floating ``dtype``."""
    path = Path(path)
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise PhysarError(f"{path}: load_ply needs a floating dtype, got {dtype}")
    if not path.is_file():
        raise PhysarError(f"{path}: Gaussian PLY file not found")
    with open(path, "rb") as f:
        fmt, elements = _parse_header(path, f)
        if not elements or elements[0][0] != "vertex":
            raise PhysarError(f"{path}: the first PLY element must be 'vertex', got "
                              f"{elements[0][0] if elements else 'none'!r}")
        _, n, props = elements[0]
        extra = 0  # binary bytes after the declared data
        if fmt == "ascii":
            names = [p[0] for p in props]
            try:
                arr = (np.loadtxt(f, dtype=np.float64, max_rows=n, ndmin=2) if n
                       else np.zeros((0, len(names))))
            except ValueError as e:
                raise PhysarError(f"{path}: malformed ASCII PLY body ({e})") from None
            if arr.shape != (n, len(names)):
                raise PhysarError(f"{path}: expected {n} rows of {len(names)} values in the ASCII body, "
                                  f"got {arr.shape}")
            cols = {name: arr[:, i] for i, name in enumerate(names)}
        else:
            endian = "<" if fmt == "binary_little_endian" else ">"
            dt = np.dtype([(name, endian + t) for name, t in props])
            left = os.fstat(f.fileno()).st_size - f.tell()
            if left < dt.itemsize * n:
                raise PhysarError(f"{path}: truncated PLY body: expected {n} vertices of {dt.itemsize} bytes "
                                  f"({dt.itemsize * n} bytes), found {left} bytes")
            rest = sum(m * sum(np.dtype(t).itemsize for _, t in pr) for _, m, pr in elements[1:])
            extra = left - dt.itemsize * n - rest
            raw = f.read(dt.itemsize * n)
            if len(raw) != dt.itemsize * n:
                raise PhysarError(f"{path}: truncated PLY body: expected {n} vertices of {dt.itemsize} bytes "
                                  f"({dt.itemsize * n} bytes), found {len(raw)} bytes")
            rec = np.frombuffer(raw, dtype=dt)
            cols = {name: rec[name].astype(np.float64) for name, _ in props}

    def col(name: str) -> np.ndarray:
        if name not in cols:
            raise PhysarError(f"{path}: missing property {name!r} of the 3DGS layout in element 'vertex'")
        return cols[name]

    missing = [a for a in attribute_names(0) if a not in cols and not a.startswith("n")]
    if missing:
        which = "property" if len(missing) == 1 else "properties"
        raise PhysarError(f"{path}: missing {which} {', '.join(map(repr, missing))} of the 3DGS layout in element "
                          "'vertex' (a mesh or point-cloud PLY? a 3DGS file has x y z f_dc_0..2 opacity "
                          "scale_0..2 rot_0..3)")
    n_rest = sum(1 for k in cols if k.startswith("f_rest_"))
    if n_rest % 3 or (n_rest // 3 + 1) not in (1, 4, 9, 16):
        raise PhysarError(f"{path}: {n_rest} f_rest_* properties; expected 0, 9, 24 or 45 (SH degree 0..3)")
    per = sum(np.dtype(t).itemsize for _, t in props)  # bytes of one binary vertex record
    if extra >= per > 0:
        raise PhysarError(f"{path}: {extra} bytes after the {n} vertices the header declares ({per} bytes each, "
                          f"{extra // per} more whole vertices): the vertex count in the header is wrong")
    k = n_rest // 3 + 1
    means = np.stack([col("x"), col("y"), col("z")], 1)
    dc = np.stack([col(f"f_dc_{i}") for i in range(3)], 1)
    rest = (np.stack([col(f"f_rest_{i}") for i in range(n_rest)], 1).reshape(n, 3, k - 1).transpose(0, 2, 1)
            if n_rest else np.zeros((n, 0, 3)))
    sh = np.concatenate([dc[:, None, :], rest], 1)
    out = {"means": means, "quats": np.stack([col(f"rot_{i}") for i in range(4)], 1),
           "log_scales": np.stack([col(f"scale_{i}") for i in range(3)], 1),
           "opacity_logits": col("opacity"), "sh": sh}
    for name, v in out.items():
        if not np.all(np.isfinite(v)):
            bad = int(np.argwhere(~np.isfinite(v.reshape(n, -1)))[0, 0])
            raise PhysarError(f"{path}: non-finite value in {name} of vertex {bad}")
    if np.any(np.linalg.norm(out["quats"], axis=1) == 0):
        bad = int(np.argmax(np.linalg.norm(out["quats"], axis=1) == 0))
        raise PhysarError(f"{path}: zero quaternion (rot_0..3) at vertex {bad}")
    tensors = {name: torch.from_numpy(np.ascontiguousarray(v)).to(dtype) for name, v in out.items()}
    for name, t in tensors.items():  # finite in float64, beyond the range of dtype (a double property)
        if not bool(torch.isfinite(t).all()):
            bad = int(torch.nonzero(~torch.isfinite(t.reshape(n, -1)))[0, 0])
            raise PhysarError(f"{path}: {name} of vertex {bad} is beyond the range of {dtype} "
                              f"({torch.finfo(dtype).max:.3g}); load with dtype=torch.float64")
    return Gaussians(**tensors)
