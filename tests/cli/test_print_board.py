"""`physar calibrate --print-board`: the ChArUco board a user prints is the one `calibrate` expects, at true
scale (reference: OpenCV's own ChArUco detector on the written raster, and the dpi)."""
import subprocess
import sys

import cv2
import numpy as np


def run(*args):
    return subprocess.run([sys.executable, "-m", "physar.cli.main", *map(str, args)], capture_output=True, text=True, check=False)


def test_print_board_is_detected_at_true_scale(tmp_path):
    """The written PNG holds the 5x4 board whose chessboard corners OpenCV finds, 25 mm apart at 200 dpi
    (196.85 px). Mutants caught: the square size ignored (default 40 mm), squares swapped (4x5), another
    dictionary than --dictionary (no marker decodes)."""
    out = tmp_path / "board.png"
    r = run("calibrate", "--print-board", out, "--squares", "5x4", "--square", "0.025", "--marker", "0.018",
            "--dictionary", "DICT_4X4_50", "--dpi", "200")
    assert r.returncode == 0, r.stderr
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    board = cv2.aruco.CharucoBoard((5, 4), 0.025, 0.018, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _m, _i = cv2.aruco.CharucoDetector(board).detectBoard(img)
    assert ids is not None and len(ids) == 12, ids          # (5 - 1) x (4 - 1) inner corners
    c = {int(i): p for i, p in zip(ids.ravel(), corners.reshape(-1, 2))}
    step = np.linalg.norm(c[1] - c[0])                       # neighbours along the first row
    assert abs(step - 0.025 / 0.0254 * 200) < 1.0, step


def test_print_board_bad_destination_and_missing_images(tmp_path):
    r = run("calibrate", "--print-board", tmp_path / "board.txt")
    assert r.returncode == 2 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = run("calibrate")
    assert r.returncode == 2 and "--print-board" in r.stderr, r.stderr
