"""`Camera.load` refuses intrinsics no camera of that image size has, in one line naming the file, the field and
the value: a principal point outside the image, pixels far from square. Before, such a file was accepted and
every frame came out "lost", with a warning that blamed the marker dictionary.

References: the limits stated here (OpenCV pixel centres 0 .. W - 1, so cx in [-0.5, W - 0.5]; fx / fy within
1/4 .. 4: anamorphic lenses squeeze up to 2); a 480x270 camera typed in by hand."""

from __future__ import annotations

import pytest

from physar.errors import ConfigError
from physar.vision.calibration import calibration_warnings
from physar.vision.camera import Camera

W, H = 480, 270


def _file(tmp_path, fx=410.0, fy=410.0, cx=239.5, cy=134.5):
    p = tmp_path / "cam.toml"
    p.write_text(f"[camera]\nwidth = {W}\nheight = {H}\nmatrix = [[{fx}, 0.0, {cx}], [0.0, {fy}, {cy}], "
                 "[0.0, 0.0, 1.0]]\ndistortion = [0.0, 0.0, 0.0, 0.0, 0.0]\n")
    return p


# mutants caught: the check not called by load (all accepted); cx compared with the height (cx = 300 of a
# 480-wide image refused); the ratio test one-sided (fy = 20 fx accepted)
@pytest.mark.parametrize("kw, needle", [
    ({"cx": 2000.0}, "principal point cx = 2000 px lies outside the 480x270 image (0 .. 479 px)"),
    ({"cy": -3.0}, "principal point cy = -3 px lies outside the 480x270 image (0 .. 269 px)"),
    ({"fx": 4100.0, "fy": 41.0}, "fx = 4100 px and fy = 41 px differ 100-fold"),
    ({"fx": 41.0, "fy": 820.0}, "fx = 41 px and fy = 820 px differ 20-fold"),
])
def test_impossible_intrinsics_refused(tmp_path, kw, needle):
    with pytest.raises(ConfigError) as e:
        Camera.load(_file(tmp_path, **kw))
    msg = str(e.value)
    assert msg.startswith(str(tmp_path / "cam.toml")) and needle in msg and "\n" not in msg, msg


@pytest.mark.parametrize("kw", [{}, {"cx": 300.0, "cy": 200.0}, {"cx": -0.5, "cy": 269.5},
                                {"fx": 820.0, "fy": 410.0}])
def test_plausible_intrinsics_pass(tmp_path, kw):
    c = Camera.load(_file(tmp_path, **kw))
    assert c.size == (W, H)
    assert calibration_warnings(c, 0.3) == []


def test_calibrate_says_so_at_once():
    import numpy as np

    out = calibration_warnings(Camera(np.array([[410.0, 0, 2000.0], [0, 410.0, 134.5], [0, 0, 1]]), np.zeros(5), W, H), 0.3)
    assert len(out) == 1 and "cx = 2000 px lies outside" in out[0] and "refused when loaded" in out[0], out
