"""`physar calibrate` refuses, in one `error:` line with exit 2, an image whose header declares more pixels
than OpenCV decodes (a few-byte "decompression bomb" PNG; cv2.error escaped as exit 1) and board sides no
printed board can have (1e40 m squares: OpenCV's CharucoBoard raised SystemError; a 1e-300 m marker is 0 in
float32 and failed the same way).

References: the PNG is built by hand (struct + zlib, the IHDR of the PNG specification); the side limits are
stated in the test (1 mm .. 1 m squares; a 5x5-bit marker's 7 cells at one dot each of 1200 dpi = 0.148 mm).
"""
import struct
import subprocess
import sys
import zlib

import cv2
import numpy as np
import pytest

from physar.errors import ConfigError, PhysarError
from physar.vision.calibration import CharucoSpec, calibrate_charuco


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _bomb(path, w=60000, h=60000):
    """A PNG whose IHDR declares w x h 8-bit grey pixels, with a tiny IDAT (a few hundred bytes in all)."""
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(b"\0" * 10))
                     + _chunk(b"IEND", b""))
    return path


def _run(*args, cwd):
    return subprocess.run([sys.executable, "-m", "physar.cli.main", *map(str, args)], capture_output=True,
                          text=True, check=False, cwd=cwd)


def test_decompression_bomb_png_is_one_line(tmp_path):
    """Mutant caught: cv2.imread called without catching cv2.error (exit 1, a traceback naming
    CV_IO_MAX_IMAGE_PIXELS)."""
    bomb = _bomb(tmp_path / "bomb.png")
    assert bomb.stat().st_size < 200
    with pytest.raises(PhysarError, match=r"bomb\.png: image too large \(60000 x 60000 pixels"):
        calibrate_charuco([bomb])
    r = _run("calibrate", "bomb.png", "-o", "c.toml", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[-1].startswith("error: bomb.png: image too large") and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "c.toml").exists()


@pytest.mark.parametrize("square,marker,needle", [
    ("1e40", "1e39", "square side (--square) 1e+40 m is outside 0.001..1 m"),
    ("1e300", "1e39", "square side (--square) 1e+300 m is outside"),
    ("40", "30", "square side (--square) 40 m is outside"),          # millimetres given as metres
    ("0.0005", "0.0003", "square side (--square) 0.0005 m is outside"),
    ("0.04", "1e-300", "marker side (--marker) 1e-300 m is too small to print"),
])
def test_board_sides_outside_a_printable_range_are_one_line(tmp_path, square, marker, needle):
    """Mutant caught: no range check on the sides (OpenCV's CharucoBoard raises SystemError, exit 1)."""
    cv2.imwrite(str(tmp_path / "blank.png"), np.full((60, 80), 255, np.uint8))
    r = _run("calibrate", "blank.png", "-o", "c.toml", "--square", square, "--marker", marker, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("error: ChArUco "), r.stderr
    assert needle in r.stderr and "Traceback" not in r.stderr and "SystemError" not in r.stderr, r.stderr


def test_board_side_limits():
    """The limits themselves: 1 mm and 1 m squares build a board; just outside is refused; the smallest
    printable 5x5 marker is 7 cells x 25.4 mm / 1200 = 0.148 mm. Mutant caught: a limit off by a factor."""
    for sq, mk in ((1e-3, 0.7e-3), (1.0, 0.75)):
        assert CharucoSpec(7, 5, sq, mk).board() is not None
    for sq, mk in ((0.99e-3, 0.5e-3), (1.01, 0.75)):
        with pytest.raises(ConfigError, match="is outside"):
            CharucoSpec(7, 5, sq, mk)
    smallest = 7 * 0.0254 / 1200
    assert CharucoSpec(7, 5, 0.002, smallest * 1.01).board() is not None
    with pytest.raises(ConfigError, match=r"7 cells need at least 0\.148 mm"):
        CharucoSpec(7, 5, 0.002, smallest * 0.99)


def test_calibration_warns_about_what_loading_will_refuse():
    """A calibration whose tangential terms fold the image passes the radial-factor rule (k1 = k2 = k3 = 0) but
    `Camera.load` refuses the file it is saved to: calibrate must say so at once (mutant: the
    distortion_problem line not added). A real-lens calibration gets no such line."""
    import numpy as np

    from physar.vision.calibration import calibration_warnings
    from physar.vision.camera import Camera

    K = np.array([[620.0, 0, 322.5], [0, 615.0, 238.0], [0, 0, 1]])
    bad = calibration_warnings(Camera(K, [0, 0, 5.0, 5.0, 0], 640, 480), 0.2)
    assert len(bad) == 1 and "folds the image" in bad[0] and "will be refused when loaded" in bad[0], bad
    assert calibration_warnings(Camera(K, [-0.3, 0.1, 0, 0, 0], 640, 480), 0.2) == []
