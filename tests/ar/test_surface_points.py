"""Pieces of the texture features used beside the dots (physar.ar.surface_points), against closed forms."""
import numpy as np

from physar.ar.surface_points import GroupSigma, ray_triangle


def test_ray_triangle_hits_against_closed_form():
    """Rays from a point through known barycentric points of random triangles: the first hit along each ray is
    o + t d = sum_j b_j T_j (checked for each ray), its barycentrics are the ones aimed at where the nearest
    triangle is the aimed one, a ray aimed outside every triangle gives -1. Catches: barycentrics (1 - beta,
    beta, gamma) instead of (1 - beta - gamma, beta, gamma), the farthest hit taken, hits behind the origin
    accepted."""
    rng = np.random.default_rng(3)
    # a stack of parallel unit triangles at z = 1, 2, 3 seen from z = 0, and one behind the origin (z = -1)
    base = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    tri = np.array([np.column_stack([base, np.full(3, z)]) for z in (2.0, 1.0, 3.0, -1.0)])
    b = rng.dirichlet([2, 2, 2], size=20)
    target = b @ tri[1]                                             # points on the nearest triangle (z = 1)
    o = np.array([0.1, 0.2, 0.0])
    idx, bary, t = ray_triangle(o, target - o, tri)
    assert np.all(idx == 1)
    np.testing.assert_allclose(bary, b, atol=1e-12)
    np.testing.assert_allclose(o + t[:, None] * (target - o), target, atol=1e-12)
    # from z = 0.5, looking up: the nearest hit in front is z = 1 (not z = -1 behind, t < 0); looking down:
    # z = -1 at t = 1.5; looking sideways: no hit, -1
    idx, _, t = ray_triangle(np.array([0.2, 0.2, 0.5]), np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]]), tri)
    assert list(idx) == [1, 3, -1]
    np.testing.assert_allclose(t[:2], [0.5, 1.5])


def test_group_sigma_follows_the_residual_ratio():
    """sigma_f = sigma_dots * median(rms_f / rms_dots) over the window, the start value before min_frames, a floor
    on the ratio. Catches: the ratio inverted, the mean instead of the median (one outlier frame), no floor."""
    g = GroupSigma(start=0.9, window=5, min_frames=3, floor=0.25)
    g.add(0.6, 0.2)
    g.add(0.8, 0.2)
    assert g.sigma(0.3) == 0.9                                      # start value until 3 frames
    g.add(0.4, 0.2)
    assert np.isclose(g.sigma(0.3), 0.3 * 3.0)                       # median of (3, 4, 2)
    g.add(100.0, 0.2)                                               # one wild frame moves the median only a step
    assert np.isclose(g.sigma(0.3), 0.3 * 3.5)
    h = GroupSigma(start=1.0, min_frames=1, floor=0.25)
    h.add(0.01, 1.0)
    assert np.isclose(h.sigma(0.3), 0.3 * 0.25)                      # the floor
    h.add(float("nan"), 1.0)                                       # no features that frame: ignored
    assert len(h.ratios) == 1
