"""The ground-truth sphere renderer against closed forms."""

import math

import numpy as np
import pytest

from physar.recon.pointrender import render_spheres


def _cam(f=50.0, size=64):
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    return K, np.eye(3), np.zeros(3)


def test_single_sphere_area_matches_projected_disc():
    K, R, t = _cam()
    r, z = 0.2, 2.0
    _, mask = render_spheres(np.array([[0.0, 0.0, z]]), np.ones((1, 3)), r, K, R, t, 64, 64, supersample=4)
    rpx = 50.0 * r / z  # 5 px
    assert mask.sum() == pytest.approx(math.pi * rpx**2, rel=0.08)


def test_z_buffer_keeps_the_nearest_sphere():
    K, R, t = _cam()
    pts = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]])
    cols = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    rgb, _ = render_spheres(pts, cols, 0.2, K, R, t, 64, 64, ambient=1.0)
    assert rgb[32, 32, 1] == pytest.approx(1.0) and rgb[32, 32, 0] == 0.0
