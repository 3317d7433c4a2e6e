"""physar.vision.printing: sheets at true scale, checked by detecting the markers in the written PNG (OpenCV's
ArUco detector), reading the PNG's pHYs chunk with a hand-written chunk parser and the PDF's MediaBox."""
import re
import struct
import zlib

import cv2
import numpy as np
import pytest

from physar.errors import ConfigError
from physar.vision.calibration import CharucoSpec
from physar.vision.printing import write_board_sheet, write_marker_sheet

MARKERS = [("DICT_4X4_50", 3, 0.03), ("DICT_4X4_50", 7, 0.05), ("DICT_5X5_100", 42, 0.04)]


def _phys_dpi(path):
    """Resolution of a PNG from its pHYs chunk (pixels per metre, unit 1), parsed independently of Pillow."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    i = 8
    while i < len(data):
        n, kind = struct.unpack(">I4s", data[i:i + 8])
        body = data[i + 8:i + 8 + n]
        assert zlib.crc32(kind + body) == struct.unpack(">I", data[i + 8 + n:i + 12 + n])[0]
        if kind == b"pHYs":
            x, y, unit = struct.unpack(">IIB", body)
            assert unit == 1
            return x * 0.0254, y * 0.0254
        i += 12 + n
    return None


def _detect(img, dictionary):
    # sub-pixel corners: the intersections of the fitted black/white edges, so the distance between two
    # corners is the marker's printed side (the contour corners would sit on the centres of its outer pixels)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), params)
    corners, ids, _ = det.detectMarkers(img)
    ids = [] if ids is None else ids.ravel().tolist()
    return dict(zip(ids, corners, strict=True))


def _side_px(c):
    c = c.reshape(4, 2)
    return float(np.mean(np.linalg.norm(c - np.roll(c, 1, axis=0), axis=1)))


@pytest.mark.parametrize("dpi", [150, 300])
def test_marker_sheet_png_true_scale(tmp_path, dpi):
    # mutants caught: dpi not stored (cv2.imwrite: no pHYs), markers drawn at a wrong scale (e.g. px per mm
    # instead of per inch), wrong ids or dictionaries
    path = tmp_path / "markers.png"
    info = write_marker_sheet(MARKERS, path, dpi=dpi)
    xdpi, ydpi = _phys_dpi(path)
    assert xdpi == pytest.approx(dpi, abs=0.02) and ydpi == pytest.approx(dpi, abs=0.02)
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img.shape[::-1] == info["pixels"]
    found = {**{("DICT_4X4_50", i): c for i, c in _detect(img, "DICT_4X4_50").items()},
             **{("DICT_5X5_100", i): c for i, c in _detect(img, "DICT_5X5_100").items()}}
    assert set(found) == {(d, i) for d, i, _ in MARKERS}
    for d, i, side in MARKERS:
        # the detector's corners are the outer corners of the black border: its side is the marker's side
        assert _side_px(found[(d, i)]) == pytest.approx(side / 0.0254 * dpi, abs=1.0)
    # the label band under each marker holds text (dark pixels), the page margin none
    for m in info["markers"]:
        (x, y), s = m["xy_px"], m["side_px"]
        band = img[y + s + 2:y + s + int(6e-3 / 0.0254 * dpi), x:x + s]
        assert band.min() < 100
    assert img[: int(5e-3 / 0.0254 * dpi)].min() == 255


def test_board_sheet_png_and_pdf(tmp_path):
    # mutants caught: board drawn at the wrong size; PDF page not the physical size (e.g. pixels as points)
    spec = CharucoSpec(5, 4, 0.03, 0.022, "DICT_4X4_50")
    dpi = 200
    write_board_sheet(spec, tmp_path / "board.png", dpi=dpi)
    assert _phys_dpi(tmp_path / "board.png")[0] == pytest.approx(dpi, abs=0.02)
    img = cv2.imread(str(tmp_path / "board.png"), cv2.IMREAD_GRAYSCALE)
    found = _detect(img, "DICT_4X4_50")
    assert sorted(found) == list(range(spec.squares_x * spec.squares_y // 2))
    for c in found.values():
        assert _side_px(c) == pytest.approx(spec.marker / 0.0254 * dpi, abs=1.0)
    # the sheet: board plus a 6 mm label band, 10 mm margins, at the physical size in points (72 per inch)
    info = write_board_sheet(spec, tmp_path / "board.pdf", dpi=dpi)
    pdf = (tmp_path / "board.pdf").read_bytes()
    (box,) = re.findall(rb"/MediaBox \[ *([\d. ]+)\]", pdf)
    x0, y0, x1, y1 = map(float, box.split())
    w_mm, h_mm = 5 * 30 + 20, 4 * 30 + 6 + 20
    assert (x0, y0) == (0, 0)
    assert x1 == pytest.approx(w_mm / 25.4 * 72, abs=0.01) and y1 == pytest.approx(h_mm / 25.4 * 72, abs=0.01)
    assert f"/Width {info['pixels'][0]} /Height {info['pixels'][1]}".encode() in pdf  # the whole raster, unresampled
    a4 = write_board_sheet(spec, tmp_path / "a4.pdf", dpi=dpi, paper="A4")
    (box,) = re.findall(rb"/MediaBox \[ *([\d. ]+)\]", (tmp_path / "a4.pdf").read_bytes())
    assert [float(v) for v in box.split()[2:]] == pytest.approx([595.276, 841.890], abs=0.01)  # 210 x 297 mm
    assert a4["page_mm"] == pytest.approx((210, 297))


def test_bad_inputs_give_one_line_and_no_file(tmp_path):
    # mutants caught: an out-of-range id reaching cv2 (cv2.error traceback); oversized sheets accepted
    cases = [
        (lambda p: write_marker_sheet([("DICT_4X4_50", 50, 0.03)], p), "marker id 50 is outside DICT_4X4_50's range 0..49"),
        (lambda p: write_marker_sheet([("DICT_4X4_50", -1, 0.03)], p), "outside DICT_4X4_50's range"),
        (lambda p: write_marker_sheet([("DICT_9X9_1", 0, 0.03)], p), "unknown ArUco dictionary"),
        (lambda p: write_marker_sheet([("DICT_4X4_50", 1, 1.5)], p), "larger than A0"),
        (lambda p: write_board_sheet(CharucoSpec(40, 30, 0.04, 0.03, "DICT_5X5_1000"), p), "larger than A0"),
        (lambda p: write_board_sheet(CharucoSpec(), p, paper="A4"), "do not fit on paper 'A4'"),
        (lambda p: write_board_sheet(CharucoSpec(), p, dpi=10), "dpi must be within 72..1200, got 10"),
        (lambda p: write_marker_sheet([], p), "no markers"),
    ]
    for fn, msg in cases:
        with pytest.raises(ConfigError, match=re.escape(msg)) as e:
            fn(tmp_path / "s.png")
        assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match=r"unknown sheet suffix '.jpg'"):
        write_board_sheet(CharucoSpec(), tmp_path / "s.jpg")
    assert list(tmp_path.iterdir()) == []
