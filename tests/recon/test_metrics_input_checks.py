"""Input checks of the image metrics (probe findings): ``psnr`` gave -8.3 dB on uint8 images (MAX = 1 with
0..255 data; the same images as float in [0, 1] gave 40 dB), -43 dB on a uint8 image against a float one, and
``ssim`` had the same flaw; ``iou`` cast a soft alpha to bool (every non-zero pixel inside).

Now MAX is inferred from the dtype as ``skimage.metrics`` does (float: 1, uint8: 255, uint16: 65535), mixed
integer/float images and dtypes with no known range (int64, bool) without ``max_val`` are refused, and ``iou``
takes only boolean or 0/1 masks.  References: PSNR of a uniform error d has the closed form
:math:`10 \\log_{10}(\\mathrm{MAX}^2 / d^2)`; SSIM of two constant images is
:math:`(2 \\mu_x \\mu_y + C_1) / (\\mu_x^2 + \\mu_y^2 + C_1)` with :math:`C_1 = (0.01\\, \\mathrm{MAX})^2`.
(scikit-image is not installed here, so the closed forms stand in for it.)
"""
import math

import numpy as np
import pytest

from physar.errors import ConfigError
from physar.recon import metrics as M


def _u8_pair(d=3):
    rng = np.random.default_rng(0)
    a = rng.integers(0, 250, size=(24, 24, 3), dtype=np.uint8)
    return a, a + np.uint8(d)  # a uniform error of d grey levels (no wrap-around: a <= 249)


def test_psnr_uint8_takes_max_255():
    a, b = _u8_pair(3)
    assert M.psnr(a, b) == pytest.approx(10 * math.log10(255**2 / 9), abs=1e-9)
    # the same images as float in [0, 1] give the same dB (the probe: -8.3 dB vs 40 dB)
    assert M.psnr(a / 255.0, b / 255.0) == pytest.approx(M.psnr(a, b), abs=1e-9)


def test_psnr_uint16_takes_max_65535():
    a = np.full((8, 8), 1000, np.uint16)
    assert M.psnr(a, a + np.uint16(10)) == pytest.approx(10 * math.log10(65535**2 / 100), abs=1e-9)


def test_psnr_explicit_max_val_on_signed_integers():
    a = np.full((8, 8), 100, np.int64)
    assert M.psnr(a, a + 5, max_val=255) == pytest.approx(10 * math.log10(255**2 / 25), abs=1e-9)


@pytest.mark.parametrize("fn", [M.psnr, M.ssim])
def test_mixed_uint8_and_float_are_refused(fn):
    a, b = _u8_pair()
    with pytest.raises(ConfigError, match=rf"{fn.__name__}: a is uint8 but b is float64"):
        fn(a, b / 255.0)
    with pytest.raises(ConfigError, match=rf"{fn.__name__}: a is float64 but b is uint8"):
        fn(a / 255.0, b, max_val=1.0)


@pytest.mark.parametrize("fn", [M.psnr, M.ssim])
def test_integer_dtypes_without_a_known_range_are_refused(fn):
    a = np.full((16, 16), 100, np.int64)
    with pytest.raises(ConfigError, match=rf"{fn.__name__}: cannot infer the value range.*int64.*pass max_val"):
        fn(a, a + 5)
    with pytest.raises(ConfigError, match="cannot infer"):
        fn(np.full((16, 16), 100, np.uint8), np.full((16, 16), 100, np.uint16))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_max_val_is_refused(bad):
    a = np.zeros((16, 16))
    with pytest.raises(ConfigError, match=rf"psnr: max_val = {bad!r} must be a finite number > 0"):
        M.psnr(a, a + 0.1, max_val=bad)


def test_ssim_uint8_constant_images_closed_form():
    x, y = np.full((20, 20), 76, np.uint8), np.full((20, 20), 153, np.uint8)
    c1 = (0.01 * 255) ** 2
    assert M.ssim(x, y) == pytest.approx((2 * 76 * 153 + c1) / (76**2 + 153**2 + c1), rel=1e-12)


def test_ssim_uint8_equals_ssim_of_the_float_images():
    a, b = _u8_pair(7)
    b[::3] = 0  # some structure in the error
    assert M.ssim(a, b) == pytest.approx(M.ssim(a / 255.0, b / 255.0), rel=1e-10)


def test_iou_accepts_0_1_arrays_like_booleans():
    a = np.zeros((10, 10))
    b = np.zeros((10, 10), np.uint8)
    a[0:4, 0:5] = 1.0  # 20 px
    b[2:6, 0:5] = 1  # 20 px, overlap 10
    assert M.iou(a, b) == pytest.approx(10 / 30)


def test_iou_refuses_a_soft_alpha():
    a = np.zeros((10, 10), bool)
    a[0:4, 0:5] = True
    alpha = np.where(a, 0.9, 0.1)  # cast to bool, every pixel would be inside: IoU 0.2 instead of 1
    with pytest.raises(ConfigError, match=r"iou: b must be a boolean mask or hold 0 and one other value, e.g. "
                                          r"0/1 or 0/255 \(got float64 values in \[0.1, 0.9\]\); threshold it"):
        M.iou(a, alpha)
    assert M.iou(a, alpha >= 0.5) == 1.0


def test_float_images_in_0_255_need_max_val():
    """Float images holding 0..255 values were scored with MAX = 1 (a uniform error of 3 gave -9.5 dB instead of
    38.6 dB). Mutant caught: the range check of float images removed."""
    a = np.full((8, 8, 3), 100.0)
    b = a + 3.0
    with pytest.raises(ConfigError, match=r"psnr: float images are taken in \[0, 1\], but values reach 103"):
        M.psnr(a, b)
    assert M.psnr(a, b, max_val=255) == pytest.approx(10 * np.log10(255**2 / 9))
    assert M.psnr(a / 255, b / 255) == pytest.approx(10 * np.log10(255**2 / 9))
    assert np.isfinite(M.psnr(np.full((4, 4), 1.05), np.ones((4, 4))))  # a render's small overshoot is fine


def test_iou_takes_0_255_masks_as_opencv_and_png_write_them():
    # cv2.threshold / cv2.inRange / mask PNGs hold 0 and 255: the same IoU as the boolean masks; a label image
    # (0, 1, 2) is refused. mutants caught: only 0/1 accepted (0/255 refused); any integer cast to bool (labels
    # 1 and 2 merged silently)
    import cv2

    a = np.zeros((10, 10), np.uint8)
    a[0:4, 0:5] = 200
    _, a255 = cv2.threshold(a, 127, 255, cv2.THRESH_BINARY)
    b = np.zeros((10, 10), bool)
    b[2:6, 0:5] = True
    assert M.iou(a255, b) == pytest.approx(10 / 30) and M.iou(a255, a255) == 1.0
    labels = a255 // 255 + b.astype(np.uint8) * 2
    with pytest.raises(ConfigError, match=r"iou: a must be a boolean mask .*uint8 values in \[0, 3\]"):
        M.iou(labels, b)


@pytest.mark.parametrize("bad", ["255", None.__class__, [255]])
def test_max_val_that_is_not_a_number_is_one_line(bad):
    # mutant caught: max_val passed to np.isfinite unchecked (a TypeError traceback for "255")
    a = np.zeros((16, 16), np.uint8)
    with pytest.raises(ConfigError, match=r"psnr: max_val = .* must be a number"):
        M.psnr(a, a + 1, max_val=bad)
    assert M.psnr(a, a + 1, max_val=np.float32(255)) == pytest.approx(10 * np.log10(255**2))
