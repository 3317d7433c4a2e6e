"""Camera.project, Pose and Camera.from_fov: numbers against peers and closed forms, refusals of bad input.

Each test names the mutant of physar/vision/camera.py it catches (the check removed or altered).
"""
import warnings

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from physar.errors import ConfigError
from physar.vision.camera import ROTATION_TOL, Camera, Pose

K = np.array([[610.0, 0.0, 331.0], [0.0, 590.0, 236.0], [0.0, 0.0, 1.0]])  # non-square pixels, off-centre
POSE = Pose.from_rvec([0.3, -0.2, 0.1], [0.05, -0.02, 1.4])


def _points_in_front(n=40, seed=0):
    """World points whose camera depth under POSE is in [0.8, 2] m."""
    rng = np.random.default_rng(seed)
    Xc = np.column_stack([rng.uniform(-0.4, 0.4, (n, 2)), rng.uniform(0.8, 2.0, n)])
    return (Xc - POSE.t) @ POSE.R  # x_w = R^T (x_c - t)


def _distort_closed_form(xn, d):
    """OpenCV's rational radial + tangential model written out (OpenCV docs, calib3d "Detailed description"):
    x'' = x' (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6) + 2 p1 x'y' + p2 (r^2 + 2 x'^2)."""
    k1, k2, p1, p2, k3, k4, k5, k6 = np.concatenate([d, np.zeros(8 - len(d))])
    x, y = xn.T
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([xd, yd])


# --- numbers ----------------------------------------------------------------------------------------------
def test_project_without_distortion_matches_cv2_projectPoints():
    """Mutant: the pinhole branch swaps fx and fy (or cx and cy) -> pixels off by px."""
    X = _points_in_front()
    cam = Camera(K, np.zeros(5), 640, 480)
    ref, _ = cv2.projectPoints(X, POSE.rvec, POSE.t, K, np.zeros(5))
    np.testing.assert_allclose(cam.project(X, POSE), ref.reshape(-1, 2), atol=1e-6, rtol=0)


@pytest.mark.parametrize("dist", [[-0.21, 0.09, 0.0012, -0.0008, -0.015],
                                  [0.3, -0.1, 0.001, 0.002, 0.02, 0.25, -0.05, 0.03]], ids=["k5", "rational8"])
def test_project_with_distortion_matches_closed_form(dist):
    """Mutant: project ignores the distortion (always the pinhole branch) -> pixels off by up to tens of px."""
    X = _points_in_front()
    cam = Camera(K, dist, 640, 480)
    Xc = X @ POSE.R.T + POSE.t
    xd = _distort_closed_form(Xc[:, :2] / Xc[:, 2:], np.asarray(dist))
    ref = np.column_stack([xd, np.ones(len(xd))]) @ K[:2].T
    assert np.abs(cam.project(X, POSE) - Camera(K, [], 640, 480).project(X, POSE)).max() > 1  # it matters
    np.testing.assert_allclose(cam.project(X, POSE), ref, atol=1e-6, rtol=0)


def test_look_at_puts_target_on_principal_point_and_centre_on_eye():
    """Closed form: the target projects to (cx, cy), the centre is the eye, up is image-up (y down).
    Mutant: look_at builds y = x cross z (image upside down) -> the point above the target lands below it."""
    eye, target = np.array([2.0, -1.0, 1.0]), np.array([0.1, 0.2, 0.3])
    pose = Pose.look_at(eye, target)
    cam = Camera.from_fov(640, 480, 60)
    np.testing.assert_allclose(cam.project(target, pose), [[319.5, 239.5]], atol=1e-9)
    np.testing.assert_allclose(pose.center, eye, atol=1e-12)
    assert cam.project(target + [0, 0, 0.1], pose)[0, 1] < 239.5


def test_from_fov_focal_length_closed_form():
    """f = (w / 2) / tan(hfov / 2): 90 degrees over 640 px gives f = 320 px."""
    cam = Camera.from_fov(640, 480, 90)
    assert cam.fx == pytest.approx(320.0) and cam.fy == pytest.approx(320.0)
    assert cam.K[0, 2] == 319.5 and cam.K[1, 2] == 239.5


def test_camera_refuses_skew():
    """OpenCV's model has no skew: cv2.projectPoints (the distorted branch of project), solvePnP and
    undistortPoints drop K[0, 1], while the pinhole branch used it, so the two branches disagreed by px.
    Mutant: no skew check -> the camera is built."""
    Ks = K.copy()
    Ks[0, 1] = 3.5
    with pytest.raises(ConfigError, match=r"camera matrix skew K\[0, 1\] must be 0 .*got 3.5"):
        Camera(Ks, np.zeros(5), 640, 480)


# --- points behind the camera -----------------------------------------------------------------------------
@pytest.mark.parametrize("dist", [np.zeros(5), np.array([-0.21, 0.09, 0.0012, -0.0008, -0.015])],
                         ids=["pinhole", "distorted"])
def test_project_behind_camera_is_nan(dist):
    """The probe's point behind look_at([2, 0, 1], origin) lands on (319.5, 69) inside the image under
    cv2.projectPoints (mirrored); project gives NaN there and at depth 0 (without a warning), and keeps the
    points in front. Mutants: the pinhole branch divides by z unguarded; the distorted branch returns
    cv2's mirrored pixel."""
    cam = Camera(Camera.from_fov(640, 480, 90).K, dist, 640, 480)
    pose = Pose.look_at([2, 0, 1], [0, 0, 0])
    behind = np.array([5.0, 0.0, 1.5])
    in_plane = pose.inverse().apply([[0.3, 0.1, 0.0]])[0]      # camera depth exactly 0
    front = np.array([0.0, 0.0, 0.0])
    mirrored, _ = cv2.projectPoints(behind[None], pose.rvec, pose.t, cam.K, np.zeros(5))
    assert 0 <= mirrored[0, 0, 0] < 640 and 0 <= mirrored[0, 0, 1] < 480   # why NaN: cv2's pixel looks valid
    assert abs(pose.apply(in_plane)[0, 2]) < 1e-12
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = cam.project(np.array([behind, in_plane, front]), pose)
    assert np.isnan(p[:2]).all()
    np.testing.assert_allclose(p[2], [319.5, 239.5], atol=1e-9)


# --- shapes -----------------------------------------------------------------------------------------------
def test_project_refuses_transposed_points():
    """cam.project(X.T, pose) with X (2, 3) used to reshape into two wrong pixels.
    Mutant: project reshapes X to (-1, 3) without checking the last axis."""
    cam = Camera.from_fov(640, 480, 60)
    X = np.array([[0.1, 0.2, 0.0], [0.3, -0.1, 0.2]])
    with pytest.raises(ConfigError, match=r"project: X must have shape \(n, 3\).*got shape \(3, 2\)"):
        cam.project(X.T, POSE)
    with pytest.raises(ConfigError, match=r"got shape \(\)"):
        cam.project(1.0, POSE)


def test_project_accepts_point_layouts():
    """One point (3,), rows (n, 3) and OpenCV's (n, 1, 3) give the same (n, 2) pixels; none gives (0, 2)."""
    for dist in (np.zeros(5), [0.1, -0.05, 0.001, 0.002, 0.01]):
        cam = Camera(K, dist, 640, 480)
        X = _points_in_front(3)
        p = cam.project(X, POSE)
        assert p.shape == (3, 2)
        np.testing.assert_array_equal(cam.project(X[:, None], POSE), p)
        np.testing.assert_array_equal(cam.project(X[0], POSE), p[:1])
        assert cam.project(np.zeros((0, 3)), POSE).shape == (0, 2)


def test_project_refuses_a_non_pose():
    """Mutant: no type check -> AttributeError "'numpy.ndarray' object has no attribute 'R'"."""
    with pytest.raises(ConfigError, match="project: pose must be a Pose, got ndarray"):
        Camera.from_fov(640, 480, 60).project(np.zeros((1, 3)), POSE.matrix())


# --- Pose -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("R, t, match", [
    (2 * np.eye(3), np.zeros(3), r"Pose: R is not a rotation matrix \(\|R\^T R - I\| = 3, det 8"),   # scaled
    (np.diag([1.0, 1.0, -1.0]), np.zeros(3), r"Pose: R is not a rotation matrix .*det -1"),          # reflection
    (np.eye(3) * (1 + 1e-3), np.zeros(3), r"Pose: R is not a rotation matrix \(\|R\^T R - I\| = 0.002"),
    (np.eye(3), [0.0, np.nan, 1.0], r"Pose: t must be finite, got \[0.0, nan, 1.0\]"),
    (np.where(np.eye(3) > 0, np.inf, 0.0), np.zeros(3), r"Pose: R must be finite"),
    (np.eye(2), np.zeros(3), r"Pose: R must have 9 values, got shape \(2, 2\)"),
    (np.eye(3), np.zeros(2), r"Pose: t must have 3 values, got shape \(2,\)"),
], ids=["scaled", "reflection", "scale-1e-3", "nan-t", "inf-R", "R-2x2", "t-2"])
def test_pose_refuses_non_rigid_or_non_finite(R, t, match):
    """Mutants: no orthonormality check (scaled), no det check (reflection), the tolerance loosened to recon's
    1e-2 (scale 1 + 1e-3), no finiteness check (NaN t, inf R), no size check (reshape's ValueError)."""
    with pytest.raises(ConfigError, match=match):
        Pose(R, t)


def test_pose_accepts_float32_and_long_compositions():
    """float32 rotations (round-off ~1e-7) and 2000 composed float64 poses stay within ROTATION_TOL."""
    R32 = Rotation.random(20, random_state=3).as_matrix().astype(np.float32)
    for R in R32:
        Pose(R, np.zeros(3, np.float32))
    step = Pose.from_rvec([0.01, 0.02, -0.015], [0.001, 0.0, 0.002])
    p = step
    for _ in range(2000):
        p = p.compose(step)
    assert np.abs(p.R.T @ p.R - np.eye(3)).max() < ROTATION_TOL


@pytest.mark.parametrize("args, match", [
    (([1, 1, 1], [1, 1, 1]), r"Pose.look_at: eye and target coincide \(\[1.0, 1.0, 1.0\]\)"),
    (([0, 0, 2], [0, 0, 0]), r"Pose.look_at: viewing direction \[0.0, 0.0, -1.0\] is parallel to up"),
    (([1, 0, 0], [0, 0, 0], [0, 0, 0]), r"Pose.look_at: up must be a non-zero vector"),
    (([np.nan, 0, 0], [0, 0, 0]), r"Pose.look_at: eye must be finite"),
    (([1, 0, 0], [0, 0]), r"Pose.look_at: target must have 3 values"),
], ids=["eye-is-target", "up-parallel", "up-zero", "nan-eye", "target-2"])
def test_look_at_refuses_degenerate_input(args, match):
    """look_at(eye, eye) used to return an all-NaN pose with only a RuntimeWarning.
    Mutants: no eye == target check, no parallel-up check, no zero-up check, no finiteness/size checks."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ConfigError, match=match):
            Pose.look_at(*args)


@pytest.mark.parametrize("rvec, tvec, match", [
    ([0.1, np.nan, 0.0], [0, 0, 1], r"Pose.from_rvec: rvec must be finite"),
    ([0.1, 0.2], [0, 0, 1], r"Pose.from_rvec: rvec must have 3 values"),
    ([0.1, 0.2, 0.3], [0, np.inf, 1], r"Pose.from_rvec: tvec must be finite"),
])
def test_from_rvec_names_the_bad_argument(rvec, tvec, match):
    """Mutant: from_rvec passes rvec straight to cv2.Rodrigues -> cv2.error or a message about R."""
    with pytest.raises(ConfigError, match=match):
        Pose.from_rvec(rvec, tvec)


# --- Camera.from_fov --------------------------------------------------------------------------------------
@pytest.mark.parametrize("args, match", [
    ((640, 480, 0), r"Camera.from_fov: hfov_deg must be in \(0, 180\) degrees, got 0"),
    ((640, 480, 180), r"hfov_deg must be in \(0, 180\) degrees, got 180"),
    ((640, 480, -30.0), r"hfov_deg .* got -30.0"),
    ((640, 480, float("nan")), r"hfov_deg .* got nan"),
    ((640, 480, "60"), r"hfov_deg .* got '60'"),
    ((0, 480, 60), r"Camera.from_fov: width must be a positive whole number of pixels, got 0"),
    ((-640, 480, 60), r"width must be a positive whole number of pixels, got -640"),
    ((640, 0, 60), r"height must be a positive whole number of pixels, got 0"),
    ((640.5, 480, 60), r"width must be a positive whole number of pixels, got 640.5"),
], ids=["fov-0", "fov-180", "fov-neg", "fov-nan", "fov-str", "w-0", "w-neg", "h-0", "w-float"])
def test_from_fov_refuses_bad_sizes_and_angles(args, match):
    """from_fov(640, 480, 0) used to raise ZeroDivisionError; 180 degrees gave f ~ 2e-14 px silently.
    Mutants: no hfov_deg range check; no width/height check (then K's or the size's message, not naming
    the argument, or a silently truncated width)."""
    with pytest.raises(ConfigError, match=match):
        Camera.from_fov(*args)


def test_rounding_noise_in_K_and_whole_float_sizes_are_accepted():
    """A K computed through matrix products (cv2.decomposeProjectionMatrix of K [R|t]) has a skew of ~1e-14:
    rounding, not skew; it is taken as 0. A width of 640.0 is 640 px; 640.5 is refused, not truncated.
    Mutants: an exact != 0 skew test (the decomposed K refused); sizes truncated with int()."""
    import cv2

    K0 = np.array([[800.0, 0, 320], [0, 810.0, 240], [0, 0, 1]])
    R, _ = cv2.Rodrigues(np.array([0.3, -0.2, 0.1]))
    K, _, _, _, _, _, _ = cv2.decomposeProjectionMatrix(K0 @ np.c_[R, [[0.1], [0.2], [1.0]]])
    K = K / K[2, 2]
    cam = Camera(K, np.zeros(5), 640, 480)
    assert cam.K[0, 1] == 0.0 and np.allclose(cam.K, K0, atol=1e-9)
    f = Camera.from_fov(640.0, 480.0, 60)
    assert f.width == 640 and isinstance(f.width, int) and f.K[0, 0] == pytest.approx(320 / np.tan(np.pi / 6))
    with pytest.raises(ConfigError, match=r"image width must be a positive whole number of pixels, got 640.5"):
        Camera(K0, np.zeros(5), 640.5, 480)
