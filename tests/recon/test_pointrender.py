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


def _rz(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_deformed_sphere_silhouette_has_the_projected_ellipse_moments():
    """A sphere of radius r carried by a shear F, seen by a camera rolled 30 degrees: its silhouette is the
    ellipse of shape matrix S = J A A^T J^T (A = r R F, J = f/z on the optical axis), whose uniform fill has
    covariance S / 4 and area pi sqrt(det S). Mutants caught: F transposed (F F^T vs F^T F differ for a
    shear), the camera rotation left out of A, F ignored (a disc)."""
    f, size, r, z = 200.0, 128, 0.1, 2.0
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    R, t = _rz(30.0), np.array([0.0, 0.0, z])
    F = np.array([[1.0, 0.8, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    _, mask = render_spheres(np.zeros((1, 3)), np.ones((1, 3)), r, K, R, t, size, size, supersample=4,
                             deform=F[None])
    jj, ii = np.nonzero(mask)
    d = np.stack([ii + 0.5 - size / 2, jj + 0.5 - size / 2], axis=1)
    A = r * R @ F
    S = (f / z) ** 2 * A[:2] @ A[:2].T
    assert len(d) == pytest.approx(math.pi * math.sqrt(np.linalg.det(S)), rel=0.03)
    np.testing.assert_allclose(d.T @ d / len(d), S / 4, rtol=0.05, atol=0.05 * S[0, 0] / 4)


def test_flattened_sphere_is_shaded_by_the_ellipsoid_normal():
    """A sphere flattened along the view axis (F = diag(1, 1, c)), lit along -x with no ambient: at the pixel
    whose centre is a fraction a of the radius right of the centre the visible point is u = (a, 0, -sqrt(1-a^2))
    and the normal is A^{-T} u ~ (a, 0, -sqrt(1-a^2)/c), so the shade is a / sqrt(a^2 + (1-a^2)/c^2); for the
    sphere (c = 1) it is a. Mutant caught: the normal taken as A u (the point) instead of A^{-T} u."""
    f, size, r, z = 200.0, 64, 0.1, 2.0  # 10 px radius
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    for c in (1.0, 0.25):
        rgb, _ = render_spheres(np.zeros((1, 3)), np.ones((1, 3)), r, K, np.eye(3), np.array([0.0, 0.0, z]), size,
                                size, light=(-1.0, 0.0, 0.0), ambient=0.0, supersample=1,
                                deform=np.diag([1.0, 1.0, c])[None])
        a = 0.45  # pixel 36: centre 36.5, 4.5 px right of the principal point
        want = a / math.sqrt(a * a + (1 - a * a) / c**2)
        assert rgb[31, 36, 0] == pytest.approx(want, abs=0.05 * want + 1e-3)
        assert rgb[32, 36, 0] == pytest.approx(want, abs=0.05 * want + 1e-3)


def test_identity_deformation_draws_the_spheres():
    """deform = I draws what the sphere path draws (masks of 2000 random spheres agree on > 99.9 % of pixels;
    the two differ only in the affine projection of off-axis spheres)."""
    rng = np.random.default_rng(0)
    P = rng.uniform(-0.1, 0.1, (2000, 3))
    K, R, t = _cam(f=130.0, size=96)
    t = np.array([0.0, 0.0, 0.9])
    _, ma = render_spheres(P, np.ones((2000, 3)), 0.008, K, R, t, 96, 96)
    _, mb = render_spheres(P, np.ones((2000, 3)), 0.008, K, R, t, 96, 96, deform=np.tile(np.eye(3), (2000, 1, 1)))
    assert (ma == mb).mean() > 0.999 and ma.sum() > 1000
