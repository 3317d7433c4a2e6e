"""Markerless vision (seed 000 §5.2-5.3): ORB pose of a textured plane against the rendering pose, texture
tracking against a known imposed displacement field, lever angle by colour segmentation against the drawn
angle."""
import math

import cv2
import numpy as np
import pytest

from physar.errors import PhysarError
from physar.vision import Camera
from physar.vision.camera import Pose
from physar.vision.markerless import PlanarMap, PlaneTextureTracker, lever_angle, plane_homography

CAM = Camera.from_fov(640, 360, 60.0)
PPM = 1000.0  # texture px per m (1 px per mm)


def _texture(seed, w=600, h=400, shapes=900):
    rng = np.random.default_rng(seed)
    img = np.full((h, w, 3), 120, np.float32)
    img += cv2.GaussianBlur(rng.normal(0, 25, (h, w)).astype(np.float32), (0, 0), 3)[..., None]
    for _ in range(shapes):
        c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
        r = int(rng.uniform(2, 9))
        col = rng.uniform(20, 235, 3).tolist()
        if rng.random() < 0.5:
            cv2.circle(img, c, r, col, -1, cv2.LINE_AA)
        else:
            cv2.rectangle(img, c, (c[0] + 2 * r, c[1] + r), col, -1)
    return np.clip(img, 0, 255).astype(np.uint8)


def _render_plane(tex, pose, origin, eu, ev, background=None):
    """Image of a textured plane patch (texture pixel (c, r) at origin + (c+.5)/PPM eu + (r+.5)/PPM ev)."""
    H = plane_homography(CAM, pose, origin, eu, ev, PPM)
    bg = background if background is not None else np.full((CAM.height, CAM.width, 3), 60, np.uint8)
    img = cv2.warpPerspective(tex, H, CAM.size, dst=bg.copy(), borderMode=cv2.BORDER_TRANSPARENT,
                              flags=cv2.INTER_LINEAR)
    rng = np.random.default_rng(1)
    return np.clip(img + rng.normal(0, 1.5, img.shape), 0, 255).astype(np.uint8)


# plane z = 0 seen from above (world x right, y down in the texture), camera about 0.6 m away
ORIGIN, EU, EV = np.array([-0.3, -0.2, 0.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0])


def _pose(yaw=8.0, pitch=5.0, dist=0.6):
    a, b = math.radians(yaw), math.radians(pitch)
    eye = np.array([dist * math.sin(a), dist * math.sin(b), -dist * math.cos(a) * math.cos(b)])
    return Pose.look_at(eye, [0.0, 0.0, 0.0], up=(0, -1.0, 0))


def test_planar_map_pose_matches_rendering_pose():
    tex = _texture(0)
    env = _texture(5, CAM.width, CAM.height, 400)  # a different scene around the plane: outliers for RANSAC
    m = PlanarMap.from_image(CAM, tex, PPM, ORIGIN, EU, EV)
    for yaw, pitch in ((8, 5), (-12, 9), (3, -10)):
        true = _pose(yaw, pitch)
        img = _render_plane(tex, true, ORIGIN, EU, EV, background=env)
        loc = m.locate(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
        assert loc.pose is not None and loc.inliers > 50
        assert loc.pose.angle_to(true) < 0.3
        assert np.linalg.norm(loc.pose.center - true.center) < 0.004
        # direct refinement on the rectified plane: an order of magnitude better
        m.enable_refinement(tex, PPM)
        ref = m.track(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), loc.pose)
        assert ref.pose.angle_to(true) < 0.05
        assert np.linalg.norm(ref.pose.center - true.center) < 0.0008
        m._refiner = None


def test_planar_map_reports_no_pose_without_the_plane():
    m = PlanarMap.from_image(CAM, _texture(0), PPM, ORIGIN, EU, EV)
    other = _texture(9, CAM.width, CAM.height, 700)
    assert m.locate(cv2.cvtColor(other, cv2.COLOR_BGR2GRAY)).pose is None
    with pytest.raises(PhysarError, match="texture"):
        PlanarMap.from_image(CAM, np.full((200, 200), 128, np.uint8), PPM, ORIGIN, EU, EV)


def _deformed_view(tex, pose, u_field):
    """Camera image of the plane patch whose material point X (plane coords, m) moved to X + u(X)."""
    w, h = CAM.size
    jj, ii = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    X = CAM.backproject_to_plane(np.column_stack([jj.ravel(), ii.ravel()]), pose, ORIGIN, np.cross(EU, EV))
    x = np.column_stack([(X - ORIGIN) @ EU, (X - ORIGIN) @ EV])
    Xr = x.copy()
    for _ in range(30):  # X = x - u(X)
        Xr = x - u_field(Xr)
    mx = (Xr[:, 0] * PPM - 0.5).reshape(h, w).astype(np.float32)
    my = (Xr[:, 1] * PPM - 0.5).reshape(h, w).astype(np.float32)
    img = cv2.remap(tex, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=(60, 60, 60))
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def test_texture_tracker_measures_an_imposed_displacement_field():
    tex = _texture(3)
    pose = _pose(6, 4)

    def u(X):  # a bending-like field [m]: up to 12 mm down, 1.5 mm along
        a = X[:, 0] / 0.6
        return np.column_stack([0.0015 * np.sin(np.pi * a), 0.012 * np.sin(np.pi * a) ** 2])

    tr = PlaneTextureTracker(CAM, ORIGIN, EU, EV, (0.6, 0.4), 1000.0 * 0.9, n_points=150)
    ref = _deformed_view(tex, pose, lambda X: 0 * X)
    mask = np.zeros((tr.size[1], tr.size[0]), np.uint8)
    mask[30:-30, 30:-30] = 255
    ab = tr.set_reference([tr.rectify(ref, pose)], mask)
    assert len(ab) > 80
    d, ok, _ = tr.update(_deformed_view(tex, pose, u), pose)
    assert ok.mean() > 0.75  # (part of the patch leaves the view)
    err = np.abs(d[ok] - u(ab[ok]))
    assert np.median(err) < 1e-4 and np.percentile(err, 95) < 3e-4  # m (0.1 mm median at ~1.1 mm per px)


@pytest.mark.parametrize("deg", [0.0, 13.0, 37.5, 52.0, -20.0])
def test_lever_angle_by_colour_segmentation(deg):
    rng = np.random.default_rng(0)
    img = (rng.uniform(30, 160, (400, 400, 3))).astype(np.uint8)
    img = cv2.GaussianBlur(img, (0, 0), 2)
    img[..., 0] = np.clip(img[..., 0].astype(int) + 60, 0, 255)  # bluish plate: not white
    pivot = np.array([200.0, 300.0])
    a = math.radians(deg)
    d = np.array([math.sin(a), -math.cos(a)])
    n = np.array([-d[1], d[0]])
    L, wd = 220.0, 14.0
    quad = np.array([pivot - 20 * d + wd / 2 * n, pivot + L * d + wd / 2 * n, pivot + L * d - wd / 2 * n,
                     pivot - 20 * d - wd / 2 * n])
    cv2.fillPoly(img, [np.round(quad * 16).astype(np.int32)], (235, 238, 240), cv2.LINE_AA, shift=4)
    est, npx = lever_angle(img, pivot, 40, 200)
    assert npx > 500
    assert abs(math.degrees(est) - deg) < 0.2
    nothing, _ = lever_angle(np.zeros_like(img), pivot, 40, 200)
    assert math.isnan(nothing)
