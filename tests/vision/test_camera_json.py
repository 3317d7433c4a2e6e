"""Camera intrinsics from the JSON files other tools write (plain fx/fy/cx/cy, a K matrix or OpenCV
FileStorage's JSON, nerfstudio's transforms.json), read by `Camera.load` as `recon import --camera` and AR
projects do.

Reference: OpenCV's projectPoints with the matrix typed in here, in OpenCV's pixel-centre convention; for
nerfstudio/COLMAP files the principal point typed in is in the pixel-corner convention (the first pixel's
centre at (0.5, 0.5)), so the OpenCV one is half a pixel less.
"""

import json

import cv2
import numpy as np
import pytest

from physar.errors import ConfigError
from physar.vision.camera import Camera, Pose

X = np.array([[0.0, 0.0, 2.0], [0.3, -0.2, 1.5], [-0.4, 0.25, 3.0]])


def _opencv(K, dist=()):
    p, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), np.asarray(K, float), np.asarray(dist, float))
    return p.reshape(-1, 2)


@pytest.mark.parametrize("layout", ["plain", "K", "filestorage", "nerfstudio"])
def test_json_intrinsics_project_as_opencv(tmp_path, layout):
    # mutants: the nerfstudio half-pixel shift left out or applied to the OpenCV layouts (0.5 px off), fx and fy
    # swapped (the second point moves), the distortion dropped
    K = [[1500.0, 0.0, 959.5], [0.0, 1480.0, 539.5], [0.0, 0.0, 1.0]]
    dist = [0.05, -0.02, 0.001, -0.0005]
    d = {"plain": {"fx": 1500, "fy": 1480, "cx": 959.5, "cy": 539.5, "width": 1920, "height": 1080,
                   "distortion": dist},
         "K": {"K": K, "width": 1920, "height": 1080, "dist_coeffs": dist},
         "filestorage": {"image_width": 1920, "image_height": 1080,
                         "camera_matrix": {"rows": 3, "cols": 3, "dt": "d", "data": np.ravel(K).tolist()},
                         "distortion_coefficients": {"rows": 1, "cols": 4, "dt": "d", "data": dist}},
         "nerfstudio": {"fl_x": 1500, "fl_y": 1480, "cx": 960.0, "cy": 540.0, "w": 1920, "h": 1080, "k1": 0.05,
                        "k2": -0.02, "p1": 0.001, "p2": -0.0005, "frames": []}}[layout]
    (tmp_path / "cam.json").write_text(json.dumps(d))
    cam = Camera.load(tmp_path / "cam.json")
    assert (cam.width, cam.height) == (1920, 1080)
    got = cam.project(X, Pose(np.eye(3), np.zeros(3)))
    np.testing.assert_allclose(got, _opencv(K, dist), atol=1e-6)


def test_json_without_intrinsics_is_one_line(tmp_path):
    (tmp_path / "a.json").write_text(json.dumps({"width": 640, "height": 480, "focal": 500}))
    with pytest.raises(ConfigError, match=r"a\.json: no intrinsics found: give fx, fy, cx, cy, width, height"):
        Camera.load(tmp_path / "a.json")
    (tmp_path / "b.json").write_text(json.dumps({"fx": "500", "cx": 320, "cy": 240, "width": 640, "height": 480}))
    with pytest.raises(ConfigError, match=r"b\.json: field 'fx' must be a number, got '500'"):
        Camera.load(tmp_path / "b.json")
    (tmp_path / "c.json").write_text("{fx: 1")
    with pytest.raises(ConfigError, match=r"c\.json: not valid JSON"):
        Camera.load(tmp_path / "c.json")
