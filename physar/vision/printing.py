r"""Printable sheets at true scale: a ChArUco calibration board and ArUco markers.

The sheet is drawn as a white raster at ``dpi`` (each marker or board drawn by OpenCV at its physical size
rounded to whole pixels, so sizes are true within half a pixel) and written as

* PNG, with the resolution stored in the pHYs chunk (Pillow's ``dpi=``), so printing at 100 % gives the true
  size (``cv2.imwrite`` would store none);
* PDF (matplotlib's PDF backend): one page whose size in points is the sheet's physical size (72 pt per inch),
  the raster embedded losslessly at ``dpi`` filling it.

Each marker is labelled under it with its dictionary, id and side length in mm; the board with its squares,
square and marker sides and dictionary. ``paper`` ("A4", "A3", "letter" or (width, height) in m, portrait)
fixes the page size (portrait, or landscape when only that fits; contents centred; ConfigError when they do
not fit); else the sheet fits the contents with a 10 mm margin. Sheets larger than A0
(:math:`841 \times 1189` mm, either orientation) are refused.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from physar.errors import ConfigError
from physar.vision.calibration import CharucoSpec, aruco_dictionary

MM = 1e-3
PAPERS = {"A4": (0.210, 0.297), "A3": (0.297, 0.420), "A2": (0.420, 0.594), "A1": (0.594, 0.841),
          "A0": (0.841, 1.189), "LETTER": (0.2159, 0.2794)}
MARGIN, GAP, LABEL = 10 * MM, 8 * MM, 6 * MM  # page margin, space between markers, label band under each


def _px(m: float, dpi: float) -> int:
    return round(m / 0.0254 * dpi)


def _check_dpi(dpi) -> float:
    if not 72 <= float(dpi) <= 1200:
        raise ConfigError(f"dpi must be within 72..1200, got {dpi}")
    return float(dpi)


def _suffix(path) -> str:
    suf = Path(path).suffix.lower()
    if suf not in (".png", ".pdf"):
        raise ConfigError(f"{path}: unknown sheet suffix {suf or '(none)'!r}; use .png or .pdf")
    return suf


def _page(paper, content_w: float, content_h: float) -> tuple[float, float]:
    r"""Page size (m) for contents of :math:`\mathtt{content\_w} \times \mathtt{content\_h}` m (margins
    included in neither)."""
    if paper is None:
        w, h = content_w + 2 * MARGIN, content_h + 2 * MARGIN
    else:
        if isinstance(paper, str):
            if paper.upper() not in PAPERS:
                raise ConfigError(f"unknown paper {paper!r}; use one of {', '.join(PAPERS)} or (width, height) in m")
            w, h = PAPERS[paper.upper()]
        else:
            w, h = (float(v) for v in paper)
        fits = lambda a, b: content_w + 2 * MARGIN <= a + 1e-9 and content_h + 2 * MARGIN <= b + 1e-9
        if not fits(w, h) and fits(h, w):
            w, h = h, w  # landscape
        if not fits(w, h):
            raise ConfigError(f"the sheet contents ({content_w / MM:.0f} x {content_h / MM:.0f} mm plus 10 mm "
                              f"margins) do not fit on paper {paper!r} in either orientation ({w / MM:.0f} x {h / MM:.0f} mm)")
    if max(w, h) > 1.189 + 1e-9 or min(w, h) > 0.841 + 1e-9:
        raise ConfigError(f"the sheet would be {w / MM:.0f} x {h / MM:.0f} mm, larger than A0 (841 x 1189 mm)")
    return w, h


def _label(img: np.ndarray, text: str, x: int, y: int, height_px: int, max_w: int) -> None:
    """Black text with its top-left at (x, y), about height_px tall, shrunk to fit max_w pixels."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = height_px / 22.0  # Hershey simplex capitals are about 22 px tall at scale 1
    (tw, _), _ = cv2.getTextSize(text, font, scale, 1)
    if tw > max_w:
        scale *= max_w / tw
    thick = max(1, round(scale * 1.5))
    (_, th), _ = cv2.getTextSize(text, font, scale, thick)
    cv2.putText(img, text, (x, y + th), font, scale, 0, thick, cv2.LINE_AA)


def _write(img: np.ndarray, path, dpi: float, size_m: tuple[float, float]) -> dict:
    from physar.output import atomic_path

    suf = _suffix(path)
    with atomic_path(path) as tmp:
        if suf == ".png":
            from PIL import Image

            Image.fromarray(img).save(tmp, format="PNG", dpi=(dpi, dpi))
        else:
            from matplotlib.figure import Figure

            fig = Figure(figsize=(size_m[0] / 0.0254, size_m[1] / 0.0254), dpi=dpi)  # the page: physical size
            ax = fig.add_axes((0, 0, 1, 1))  # the raster spans the page (within a pixel of its own size)
            ax.set_axis_off()
            ax.imshow(img, cmap="gray", vmin=0, vmax=255, interpolation="none", aspect="auto")  # embedded as is
            fig.savefig(tmp, format="pdf", dpi=dpi)
    return {"path": str(path), "dpi": dpi, "pixels": (img.shape[1], img.shape[0]),
            "width_mm": img.shape[1] / dpi * 25.4, "height_mm": img.shape[0] / dpi * 25.4,
            "page_mm": (size_m[0] / MM, size_m[1] / MM)}


def write_board_sheet(spec: CharucoSpec, path, dpi: float = 300, paper=None) -> dict:
    r"""Write the ChArUco board ``spec`` at true scale to ``path`` (.png or .pdf) with a label under it.

    Returns path, dpi, pixels (w, h), width_mm/height_mm (the raster: :math:`\mathrm{pixels} / \mathrm{dpi}`,
    within a pixel of the page) and page_mm (the page; a PDF's page size exactly). Raises ConfigError for a bad
    dpi, suffix or paper, or a sheet larger than A0."""
    dpi = _check_dpi(dpi)
    _suffix(path)
    bw, bh = spec.squares_x * spec.square, spec.squares_y * spec.square
    pw, ph = _page(paper, bw, bh + LABEL)
    W, H = _px(pw, dpi), _px(ph, dpi)
    img = np.full((H, W), 255, np.uint8)
    sq = _px(spec.square, dpi)                      # whole pixels per square: every square the same size
    bwp, bhp = sq * spec.squares_x, sq * spec.squares_y
    board = spec.board().generateImage((bwp, bhp), marginSize=0, borderBits=1)
    if board.shape != (bhp, bwp):
        board = cv2.resize(board, (bwp, bhp), interpolation=cv2.INTER_NEAREST)
    x0, y0 = (W - bwp) // 2, (H - bhp - _px(LABEL, dpi)) // 2
    img[y0:y0 + bhp, x0:x0 + bwp] = board
    _label(img, f"ChArUco {spec.squares_x}x{spec.squares_y}  square {spec.square / MM:g} mm  marker "
                f"{spec.marker / MM:g} mm  {spec.dictionary}  (print at 100 %)",
           x0, y0 + bhp + _px(1.5 * MM, dpi), _px(3 * MM, dpi), bwp)
    return _write(img, path, dpi, (pw, ph))


def write_marker_sheet(markers, path, dpi: float = 300, paper=None) -> dict:
    r"""Write ArUco markers at true scale to ``path`` (.png or .pdf): ``markers`` is a list of (dictionary name,
    id, side in m), laid out left to right in rows (a new row when the next one would pass 1189 mm or the
    paper's width), each labelled under it ("DICT_4X4_50 id 3, 30 mm").

    Returns as :func:`write_board_sheet`, plus ``markers``: the top-left pixel and side in pixels of each.
    Raises ConfigError for an unknown dictionary, an id outside the dictionary's range, a side :math:`\le 0`, an
    empty list, or a sheet larger than A0 / the paper."""
    dpi = _check_dpi(dpi)
    _suffix(path)
    if not markers:
        raise ConfigError("no markers to print")
    items = []
    for m in markers:
        try:
            name, mid, side = m
        except (TypeError, ValueError):
            raise ConfigError(f"marker must be (dictionary, id, side_m), got {m!r}") from None
        d = aruco_dictionary(str(name))
        n = d.bytesList.shape[0]
        if not (isinstance(mid, (int, np.integer)) and 0 <= int(mid) < n):
            raise ConfigError(f"marker id {mid!r} is outside {name}'s range 0..{n - 1}")
        if not float(side) > 0:
            raise ConfigError(f"marker {name} id {mid}: side must be > 0 m, got {side}")
        items.append((str(name), d, int(mid), float(side)))
    max_w = (PAPERS[paper.upper()][0] if isinstance(paper, str) and paper.upper() in PAPERS
             else float(paper[0]) if paper is not None and not isinstance(paper, str) else 1.189) - 2 * MARGIN
    rows, row, x = [], [], 0.0  # layout in m
    for it in items:
        cell = max(it[3], 0.03)  # room for the label under small markers
        start = x + GAP if row else 0.0
        if row and start + cell > max_w:
            rows.append(row)
            row, start = [], 0.0
        row.append((start, it))
        x = start + cell
    rows.append(row)
    width = max(r[-1][0] + max(r[-1][1][3], 0.03) for r in rows)
    heights = [max(it[3] for _, it in r) + LABEL for r in rows]
    height = sum(heights) + GAP * (len(rows) - 1)
    pw, ph = _page(paper, width, height)
    W, H = _px(pw, dpi), _px(ph, dpi)
    img = np.full((H, W), 255, np.uint8)
    ox, oy = (pw - width) / 2, (ph - height) / 2
    placed, y = [], oy
    for r, rh in zip(rows, heights, strict=True):
        for x, (name, d, mid, side) in r:
            s = _px(side, dpi)
            px, py = _px(ox + x, dpi), _px(y, dpi)
            img[py:py + s, px:px + s] = cv2.aruco.generateImageMarker(d, mid, s, borderBits=1)
            _label(img, f"{name} id {mid}, {side / MM:g} mm", px, py + s + _px(1.5 * MM, dpi), _px(2.5 * MM, dpi),
                   max(s, _px(0.03, dpi)))
            placed.append({"dictionary": name, "id": mid, "side_m": side, "xy_px": (px, py), "side_px": s})
        y += rh + GAP
    return {**_write(img, path, dpi, (pw, ph)), "markers": placed}
