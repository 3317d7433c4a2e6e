"""Metrics against closed forms (issue 8 part 5)."""

import math

import numpy as np
import pytest

from physar.errors import PhysarError
from physar.recon import metrics as M


def test_psnr_of_known_noise():
    rng = np.random.default_rng(0)
    a = rng.random((40, 50, 3))
    # +-sigma noise of exactly known MSE sigma^2
    sigma = 0.05
    b = a + sigma * np.where(rng.random(a.shape) < 0.5, -1.0, 1.0)
    assert M.psnr(a, b) == pytest.approx(10 * math.log10(1 / sigma**2), abs=1e-9)
    assert M.psnr(a, a) == math.inf


def test_ssim_identical_and_constant_images():
    rng = np.random.default_rng(1)
    a = rng.random((32, 32, 3))
    assert M.ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    # two constant images mu_x, mu_y: SSIM = (2 mx my + C1) / (mx^2 + my^2 + C1) (variances are 0)
    x, y = np.full((20, 20), 0.3), np.full((20, 20), 0.6)
    c1 = 0.01**2
    assert M.ssim(x, y) == pytest.approx((2 * 0.3 * 0.6 + c1) / (0.3**2 + 0.6**2 + c1), rel=1e-10)


def test_ssim_contrast_term_closed_form():
    # y = 1 - x has the same mean and variance as x and covariance -s^2: SSIM = (-2 s^2 + C2)/(2 s^2 + C2);
    # a one-pixel checkerboard 0.5 +- 0.1 has local variance s^2 = 0.01 (to < 1 % for a sigma = 1.5 window)
    i, j = np.indices((64, 64))
    x = 0.5 + 0.1 * np.where((i + j) % 2 == 0, -1.0, 1.0)
    c2 = 0.03**2
    assert M.ssim(x, 1.0 - x) == pytest.approx((-0.02 + c2) / (0.02 + c2), abs=0.01)
    assert M.ssim(x, x) == pytest.approx(1.0)


def test_iou_of_known_masks():
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    a[0:4, 0:5] = True  # 20 px
    b[2:6, 0:5] = True  # 20 px, overlap 10 px
    assert M.iou(a, b) == pytest.approx(10 / 30)
    assert M.iou(a, a) == 1.0
    assert M.iou(np.zeros((3, 3), bool), np.zeros((3, 3), bool)) == 1.0
    with pytest.raises(PhysarError):
        M.iou(a, b[:5])


def test_large_deformation_subset():
    d = np.array([0.0, 0.01, 0.02, 0.05, 0.1])
    assert M.large_deformation_frames(d, range(5)) == [3, 4]


def test_lpips_is_a_distance_or_a_clear_error():
    """Installed with its backbone weights: d(a, a) = 0 < d(a, b) for different images; otherwise one
    PhysarError saying LPIPS is unavailable.  Mutants caught: a distance that ignores its inputs, a missing
    package or missing weights reported as anything but 'LPIPS unavailable'."""
    rng = np.random.default_rng(0)
    a = rng.random((64, 64, 3))
    b = np.clip(a + 0.3 * rng.standard_normal(a.shape), 0, 1)
    try:
        d = M.lpips_model()
    except PhysarError as exc:
        assert "LPIPS unavailable" in str(exc)
        return
    assert d(a, a) == pytest.approx(0.0, abs=1e-6)
    assert d(a, b) > 0.01


def test_sequence_metrics_average_the_given_distance_over_the_frames():
    """The LPIPS slot of sequence_metrics is the mean of the distance over the listed frames only (a distance
    written by hand: mean |a - b|).  Mutants caught: all frames averaged, the distance not called."""
    rgb = np.stack([np.full((4, 4, 3), v) for v in (0.0, 0.2, 0.5, 0.9)])
    gt = np.zeros_like(rgb)
    alpha = np.ones((4, 4, 4))
    out = M.sequence_metrics(rgb, alpha, gt, alpha, [1, 3], lpips_fn=lambda a, b: float(np.abs(a - b).mean()))
    assert out["lpips"] == pytest.approx((0.2 + 0.9) / 2) and out["frames"] == 2
    assert out["psnr"] == pytest.approx(np.mean([10 * np.log10(1 / 0.2**2), 10 * np.log10(1 / 0.9**2)]))
