"""New-user review leftovers in :mod:`physar.geometry`:

* ``repr(MeshTags)`` printed the whole tag arrays (a notebook page for a real mesh); it is now one line with the
  tagged counts, the distinct ids and the names (at most 6 of each);
* :func:`physar.geometry.pointcloud.read_ply` dropped the vertex colours of a PLY; ``read_ply(path,
  colors=True)`` now also returns them as (n, 3) float64 in [0, 1] (uchar / 255, ushort / 65535, floats kept),
  ``read_ply(path)`` still returns (points, faces); ``write_ply(path, points, colors)`` writes uchar colours.

The PLY files are written here byte by byte (ASCII text, or a NumPy structured array behind a hand-written
header), and the files physar writes are parsed here by hand, so neither side is checked against physar itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from physar.errors import PhysarError
from physar.geometry.pointcloud import read_ply, write_ply
from physar.geometry.regions import MeshTags


# ----------------------------------------------------------------------------------------------- MeshTags repr
def test_meshtags_repr_small_exact():
    tags = MeshTags(np.array([1, 1, 2]), np.array([[0, 1, 2]]), np.array([7]), {"top": (7, 2), "body": (1, 3)})
    assert repr(tags) == "MeshTags(3 tetrahedra tagged (ids 1, 2), 1 triangle tagged (ids 7), names body=1, top=7)"
    assert repr(MeshTags()) == "MeshTags(no tetrahedron tags, 0 triangles tagged)"


def test_meshtags_repr_big_is_one_short_line_with_counts():
    rng = np.random.default_rng(0)
    cells = rng.integers(1, 41, 200_000)                     # 40 distinct ids
    faces = rng.integers(0, 1000, (5000, 3))
    names = {f"region_{i}": (i, 3) for i in range(50)}
    text = repr(MeshTags(cells, faces, np.arange(5000) % 3 + 100, names))
    assert "\n" not in text and len(text) < 200, text
    assert text.startswith("MeshTags(200000 tetrahedra tagged (ids 1, 2, 3, 4, ... (40 in all)), "
                           "5000 triangles tagged (ids 100, 101, 102), names region_0=0, ")
    assert text.endswith("... (50 in all))")


# ----------------------------------------------------------------------------------------------- PLY colours
def _binary_ply(path, columns: dict, order: str = "<", faces=None):
    """A binary PLY of the vertex ``columns`` {name: array} (their NumPy types give the PLY types), and optional
    triangle ``faces``, written with a hand-made header and ``ndarray.tobytes``."""
    ply_type = {"f4": "float", "f8": "double", "u1": "uchar", "u2": "ushort", "i4": "int", "i1": "char"}
    n = len(next(iter(columns.values())))
    dt = np.dtype([(k, order + np.asarray(v).dtype.str[1:]) for k, v in columns.items()])
    rec = np.empty(n, dt)
    for k, v in columns.items():
        rec[k] = v
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    head = [f"ply\nformat {fmt} 1.0\nelement vertex {n}\n"]
    head += [f"property {ply_type[np.asarray(v).dtype.str[1:]]} {k}\n" for k, v in columns.items()]
    body = rec.tobytes()
    if faces is not None:
        head.append(f"element face {len(faces)}\nproperty list uchar int vertex_indices\n")
        fr = np.empty(len(faces), np.dtype([("c", "u1"), ("v", order + "i4", (3,))]))
        fr["c"], fr["v"] = 3, faces
        body += fr.tobytes()
    path.write_bytes(("".join(head) + "end_header\n").encode() + body)
    return path


XYZ = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
RGB8 = np.array([[255, 0, 10], [0, 128, 20], [1, 2, 3], [254, 253, 252]], np.uint8)


def _xyz_rgb(rgb, names=("red", "green", "blue"), **extra):
    cols = {k: XYZ[:, j].astype(np.float32) for j, k in enumerate("xyz")}
    cols.update({k: rgb[:, j] for j, k in enumerate(names)})
    cols.update(extra)
    return cols


def test_read_ascii_uchar_colours(tmp_path):
    rows = "".join(f"{x:g} {y:g} {z:g} {r} {g} {b}\n" for (x, y, z), (r, g, b) in zip(XYZ, RGB8.tolist()))
    path = tmp_path / "a.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                    "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
                    + rows)
    pts, faces, rgb = read_ply(path, colors=True)
    np.testing.assert_array_equal(pts, XYZ)
    assert faces is None
    assert rgb.dtype == np.float64 and rgb.shape == (4, 3)
    np.testing.assert_array_equal(rgb, RGB8 / 255.0)     # 255 -> 1, 128 -> 128 / 255, exactly


def test_read_binary_uchar_colours_with_alpha_and_default_arity(tmp_path):
    path = _binary_ply(tmp_path / "b.ply", _xyz_rgb(RGB8, alpha=np.full(4, 7, np.uint8)))
    out = read_ply(path)
    assert len(out) == 2 and out[1] is None                 # existing callers: pts, faces = read_ply(path)
    pts, faces, rgb = read_ply(path, colors=True)
    np.testing.assert_array_equal(pts, XYZ)
    assert faces is None
    np.testing.assert_array_equal(rgb, RGB8 / 255.0)      # alpha is not read


def test_read_big_endian_ushort_and_diffuse_names(tmp_path):
    rgb16 = np.array([[65535, 0, 1], [32768, 2, 3], [4, 5, 6], [7, 8, 65534]], np.uint16)
    path = _binary_ply(tmp_path / "c.ply", _xyz_rgb(rgb16, ("diffuse_red", "diffuse_green", "diffuse_blue")),
                       order=">")
    _, _, rgb = read_ply(path, colors=True)
    np.testing.assert_array_equal(rgb, rgb16 / 65535.0)


def test_read_float_colours_kept_and_mesh_colours(tmp_path):
    rgbf = np.array([[0.0, 0.25, 1.0], [0.5, 0.75, 0.125], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    pts, f, rgb = read_ply(_binary_ply(tmp_path / "m.ply", _xyz_rgb(rgbf), faces=faces), colors=True)
    np.testing.assert_array_equal(pts, XYZ)
    np.testing.assert_array_equal(f, faces)
    np.testing.assert_array_equal(rgb, rgbf.astype(float))


def test_read_without_colours_gives_none(tmp_path):
    _, _, rgb = read_ply(_binary_ply(tmp_path / "n.ply", {k: XYZ[:, j].astype(np.float32)
                                                          for j, k in enumerate("xyz")}), colors=True)
    assert rgb is None


@pytest.mark.parametrize("cols, words", [
    (_xyz_rgb(np.array([[200.0, 0, 0]] * 4, np.float32)), "red = 200 is a float colour outside"),
    ({k: XYZ[:, j].astype(np.float32) for j, k in enumerate("xyz")} | {"red": RGB8[:, 0], "green": RGB8[:, 1]},
     "colours need red, green, blue; the file has only red, green"),
    (_xyz_rgb(RGB8.astype(np.int32)), "red is int32; colours must be uchar"),
])
def test_read_refuses_bad_colours(tmp_path, cols, words):
    path = _binary_ply(tmp_path / "bad.ply", cols)
    with pytest.raises(PhysarError, match=words) as e:
        read_ply(path, colors=True)
    assert "\n" not in str(e.value) and "bad.ply" in str(e.value)
    pts, _ = read_ply(path)                                    # the points still read without colours=True
    np.testing.assert_array_equal(pts, XYZ)


def _parse_binary_ply(data: bytes) -> np.ndarray:
    """The vertex records of a binary little-endian PLY (scalar properties only), parsed from its header."""
    head, body = data.split(b"end_header\n", 1)
    lines = head.decode().splitlines()
    assert lines[1] == "format binary_little_endian 1.0"
    n = next(int(s.split()[2]) for s in lines if s.startswith("element vertex"))
    np_type = {"float": "<f4", "double": "<f8", "uchar": "u1", "float32": "<f4", "uint8": "u1"}
    dt = np.dtype([(s.split()[2], np_type[s.split()[1]]) for s in lines if s.startswith("property")])
    return np.frombuffer(body, dt, count=n)


def test_write_colours_as_uchar_rounded(tmp_path):
    rgb = np.array([[0.0, 1.0, 0.999], [0.5, 0.2, 0.001], [0.1, 0.9, 0.4], [1.0, 0.0, 0.0]])
    path = write_ply(tmp_path / "w.ply", XYZ, rgb)
    rec = _parse_binary_ply(path.read_bytes())
    np.testing.assert_array_equal(np.c_[rec["x"], rec["y"], rec["z"]], XYZ)
    # by hand: 0.999 * 255 = 254.7 -> 255; 0.5 * 255 = 127.5 -> 128; 0.001 * 255 = 0.26 -> 0
    want = [[0, 255, 255], [128, 51, 0], [26, 230, 102], [255, 0, 0]]
    np.testing.assert_array_equal(np.c_[rec["red"], rec["green"], rec["blue"]], want)
    assert rec["red"].dtype == np.uint8
    _, _, back = read_ply(path, colors=True)
    np.testing.assert_allclose(back, rgb, atol=0.5 / 255)
    plain = _parse_binary_ply(write_ply(tmp_path / "p.ply", XYZ).read_bytes())
    assert plain.dtype.names == ("x", "y", "z")               # no colours given: none written


def test_write_uint8_colours_kept(tmp_path):
    rec = _parse_binary_ply(write_ply(tmp_path / "u.ply", XYZ, RGB8).read_bytes())
    np.testing.assert_array_equal(np.c_[rec["red"], rec["green"], rec["blue"]], RGB8)


@pytest.mark.parametrize("rgb, words", [
    (np.full((4, 3), 255.0), r"colours\[0\] = \[255.0, 255.0, 255.0\] must lie in \[0, 1\]"),
    (np.array([[0.5, 0.5, 0.5]] * 3 + [[0.5, np.nan, 0.5]]), r"colours\[3\] = \[0.5, nan, 0.5\]"),
    (np.zeros((3, 3)), r"point colours must have shape \(4, 3\)"),
])
def test_write_refuses_bad_colours(tmp_path, rgb, words):
    with pytest.raises(PhysarError, match=words):
        write_ply(tmp_path / "bad.ply", XYZ, rgb)
    assert not (tmp_path / "bad.ply").exists()
