"""`physar denoise` of a coloured PLY point cloud keeps each point's colour, in the input's order.

The input PLY is written here by hand (header + numpy structured array, no physar code); the output is read
back with a hand PLY parser (header -> numpy dtype), independent of physar's trimesh-based reader. Each
point's colour is a function of its clean position on the unit sphere, so a colour moved to another point
shows as a mismatch against the colour written for that index.
"""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from physar.cli.main import app

runner = CliRunner()
_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
              "float": "f4", "double": "f8"}


def _write_ply(path, columns: dict, ascii: bool = False) -> None:
    """A PLY point cloud (vertex element only) with the given {name: (n,) array} columns, in dict order."""
    n = len(next(iter(columns.values())))
    names = {v: k for k, v in _PLY_TYPES.items()}
    props = "".join(f"property {names[np.dtype(c.dtype).str[1:]]} {k}\n" for k, c in columns.items())
    fmt = "ascii" if ascii else "binary_little_endian"
    header = f"ply\nformat {fmt} 1.0\nelement vertex {n}\n{props}end_header\n".encode()
    if ascii:
        body = "".join(" ".join(repr(c[i].item()) for c in columns.values()) + "\n" for i in range(n)).encode()
    else:
        a = np.empty(n, [(k, "<" + np.dtype(c.dtype).str[1:]) for k, c in columns.items()])
        for k, c in columns.items():
            a[k] = c
        body = a.tobytes()
    path.write_bytes(header + body)


def _read_ply(path) -> dict:
    """{name: column} of the vertex element of a binary little-endian PLY (hand parser)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode().splitlines()
    assert "format binary_little_endian 1.0" in lines
    n, fields, element = 0, [], None
    for ln in lines:
        w = ln.split()
        if w[0] == "element":
            element = w[1]
            n = int(w[2]) if element == "vertex" else n
        elif w[0] == "property" and element == "vertex":
            fields.append((w[2], "<" + _PLY_TYPES[w[1]]))
    data = np.frombuffer(raw, dtype=fields, count=n, offset=end)
    return {k: data[k] for k in data.dtype.names}


def _coloured_noisy_sphere(n=800, seed=4):
    """(clean unit-sphere points, noisy points, uint8 colours); colour = (clean position + 1) / 2 * 255."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    col = np.round((u + 1) / 2 * 255).astype(np.uint8)
    noisy = u * (1 + 0.02 * rng.standard_normal((n, 1)))
    return u, noisy, col


def _denoise(src, out, *extra):
    return runner.invoke(app, ["denoise", str(src), "--out", str(out), "--no-render", "--k", "12", *extra])


def _radius_error(p):
    return np.abs(np.linalg.norm(p, axis=1) - 1).mean()


# mutants caught: colours dropped (write_ply without colors: no red/green/blue in the output), colours reordered
# (rgb[::-1], or rgb sorted by red); the points left in place (no denoising) fails the radius check
def test_denoise_cloud_keeps_colours_in_order(tmp_path):
    _, noisy, col = _coloured_noisy_sphere()
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.ply"
    _write_ply(src, {"x": noisy[:, 0].astype(np.float32), "y": noisy[:, 1].astype(np.float32),
                     "z": noisy[:, 2].astype(np.float32), "red": col[:, 0], "green": col[:, 1], "blue": col[:, 2]})
    r = _denoise(src, out)
    assert r.exit_code == 0, r.output
    back = _read_ply(out)
    assert len(back["x"]) == len(noisy)
    for j, k in enumerate(("red", "green", "blue")):
        assert back[k].dtype == np.uint8
        np.testing.assert_array_equal(back[k], col[:, j])
    assert (back["alpha"] == 255).all()
    p = np.c_[back["x"], back["y"], back["z"]].astype(float)
    assert _radius_error(p) < 0.7 * _radius_error(noisy.astype(np.float32))  # moved towards the sphere
    assert np.linalg.norm(p - noisy, axis=1).max() < 0.1  # each point stayed near its own input position


# mutant caught: float colours in [0, 1] written as 0/1 bytes (not times 255) or truncated (not rounded);
# colours of an ASCII input dropped
def test_ascii_float_colours_rounded_to_bytes(tmp_path):
    _, noisy, col = _coloured_noisy_sphere(seed=5)
    f = ((col + 0.6) / 255.0).clip(0, 1)  # 0.6 byte above col: rounding gives col + 1, truncation col
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.ply"
    _write_ply(src, {"x": noisy[:, 0], "y": noisy[:, 1], "z": noisy[:, 2], "red": f[:, 0], "green": f[:, 1],
                     "blue": f[:, 2]}, ascii=True)
    r = _denoise(src, out, "--method", "al", "--iterations", "3")
    assert r.exit_code == 0, r.output
    back = _read_ply(out)
    for j, k in enumerate(("red", "green", "blue")):
        np.testing.assert_array_equal(back[k], np.minimum(col[:, j].astype(int) + 1, 255))


# mutants caught: other vertex properties dropped without a warning; an opaque alpha (all 255) warned about
def test_properties_a_cloud_cannot_keep_are_named(tmp_path):
    _, noisy, col = _coloured_noisy_sphere(seed=6)
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.ply"
    cols = {"x": noisy[:, 0].astype(np.float32), "y": noisy[:, 1].astype(np.float32),
            "z": noisy[:, 2].astype(np.float32), "red": col[:, 0], "green": col[:, 1], "blue": col[:, 2],
            "alpha": np.full(len(col), 255, np.uint8), "intensity": np.linspace(0, 1, len(col)).astype(np.float32)}
    _write_ply(src, cols)
    r = _denoise(src, out)
    assert r.exit_code == 0, r.output
    warned = [ln for ln in r.output.splitlines() if "not carried" in ln]
    assert len(warned) == 1 and "intensity" in warned[0] and "alpha" not in warned[0], r.output
    np.testing.assert_array_equal(_read_ply(out)["green"], col[:, 1])


# mutant caught: an out-of-range float colour clipped silently or a traceback; the output written anyway
def test_float_colour_out_of_range_is_one_line(tmp_path):
    _, noisy, col = _coloured_noisy_sphere(seed=7)
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.ply"
    red = (col[:, 0] / 255.0).astype(np.float32)
    red[10] = 200.0
    _write_ply(src, {"x": noisy[:, 0], "y": noisy[:, 1], "z": noisy[:, 2], "red": red,
                     "green": col[:, 1] / 255.0, "blue": col[:, 2] / 255.0})
    r = _denoise(src, out)
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    errors = [ln for ln in r.output.splitlines() if "red = 200" in ln]
    assert len(errors) == 1 and str(src.name) in errors[0], r.output
    assert not out.exists()


# mutant caught: colour properties invented for a cloud that has none
def test_cloud_without_colours_stays_without(tmp_path):
    _, noisy, _ = _coloured_noisy_sphere(seed=8)
    src, out = tmp_path / "noisy.ply", tmp_path / "clean.ply"
    _write_ply(src, {"x": noisy[:, 0].astype(np.float32), "y": noisy[:, 1].astype(np.float32),
                     "z": noisy[:, 2].astype(np.float32)})
    r = _denoise(src, out)
    assert r.exit_code == 0, r.output
    assert set(_read_ply(out)) == {"x", "y", "z"}
