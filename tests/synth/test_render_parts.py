"""The synth renderer's scene parts against independent geometry: a [registration.plane] image where
cv2.projectPoints puts its content, a [[bar]]'s tip and direction from the rotation parameter, markers removed after
[schedule] markers_until, the [[camera.pan]] yaw, the wall lying on a plane without image, rest frames (u = 0,
truth.csv at_rest, not scored), and a virtual ([model] visible = false) object that is not drawn and has no
finer truth."""
import math

import cv2
import numpy as np
import pytest
from conftest import MARKER_SIDE, MARKER_X, MARKER_Y, PLATE_ORIGIN, PLATE_PPM, write_lever_project

from physar.ar.project import load_project
from physar.synth import ProjectRenderer, Resolved, Scenario, render_project
from physar.synth.score import read_columns, score
from physar.vision.calibration import aruco_dictionary
from physar.vision.camera import Pose

QUIET = {"sensor": {"read_noise": 0.0, "shot_noise": 0.0}, "lighting": {"flicker": 0.0}}


def _scenario(**kw) -> Scenario:
    d = {**QUIET, **kw}
    return Scenario.model_validate(d)


def _detect(img) -> dict:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(aruco_dictionary("DICT_4X4_50"), params)
    corners, ids, _ = det.detectMarkers(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    return {} if ids is None else {int(i): c.reshape(4, 2) for i, c in zip(ids.ravel(), corners)}


def _pose(row) -> tuple[np.ndarray, np.ndarray]:
    return np.array([row["rx"], row["ry"], row["rz"]]), np.array([row["tx"], row["ty"], row["tz"]])


def test_plane_image_drawn_where_its_points_project(lever):
    """The ArUco marker printed in the plate image (pixels [12, 66) x [84, 138) at 500 px/m) is found in two
    frames of the handheld camera within 0.5 px of cv2.projectPoints of its object corners origin + x/ppm u +
    y/ppm v. Catches: u and v swapped (transposed image: the marker does not decode), a half-texel shift of the
    UV convention (1.6 px here), v taken upwards, the image drawn at the plane's centre instead of its corner."""
    r = ProjectRenderer(lever, _scenario(schedule={"theta": {"keyframes": [[0, 10.0]]}}))
    K, dist = lever.camera.to_opencv()
    e = np.array([[0, 0], [1, 0], [1, 1], [0, 1]]) * MARKER_SIDE + [MARKER_X, MARKER_Y]
    obj = PLATE_ORIGIN + np.outer(e[:, 0] / PLATE_PPM, [1, 0, 0]) + np.outer(e[:, 1] / PLATE_PPM, [0, 0, -1])
    for k in (0, 50):
        img, row = r.render(k)
        found = _detect(img)
        assert 7 in found, sorted(found)
        ref, _ = cv2.projectPoints(obj, *_pose(row), K, dist)
        err = np.abs(found[7] - ref.reshape(4, 2)).max()
        assert err < 0.5, (k, err)


def test_bar_tip_and_direction_follow_the_rotation_parameter(lever):
    """theta = 35 deg about +y: the white bar's pixels (HSV saturation < 45, value > 150) end within 1 px of the
    projected tip pivot + L R(theta) zero on its face (axis point + face axis) and their centroid is within
    0.5 px of the projected face centre. Catches: the angle's sign flipped, degrees read as radians, the face
    offset ignored (drawn on the axis point's plane: ~10 px off), the bar drawn from the axis point."""
    sc = _scenario(schedule={"theta": {"keyframes": [[0, 35.0]]}},
                   camera={"elevation": 0.0, "orbit": [0.0, 0.0], "shake_mm": 0.0, "shake_deg": 0.0},
                   lighting={"flicker": 0.0, "vignetting": 0.0})
    r = ProjectRenderer(lever, sc)
    img, row = r.render(0)
    K, dist = lever.camera.to_opencv()
    th = math.radians(35.0)
    pivot = np.array([0.02, 0.0, 0.12])  # axis point (0.02, 0.02, 0.12) moved by face = -0.02 along +y
    d = np.array([math.sin(th), 0.0, math.cos(th)])  # zero = +z turned about +y (right hand)
    P, _ = cv2.projectPoints(np.array([pivot, pivot + 0.1 * d, pivot + 0.05 * d]), *_pose(row), K, dist)
    p0, tip, mid = P.reshape(3, 2)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    white = (hsv[..., 1] < 45) & (hsv[..., 2] > 150)
    u = (tip - p0) / np.linalg.norm(tip - p0)
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    along = (xx - p0[0]) * u[0] + (yy - p0[1]) * u[1]
    across = (xx - p0[0]) * u[1] - (yy - p0[1]) * u[0]
    band = (np.abs(across) < 5) & (along > -10) & (along < np.linalg.norm(tip - p0) + 3)  # the bar is ~7 px wide
    ys, xs = np.nonzero(white & band)
    assert len(xs) > 100
    q = np.column_stack([xs, ys]) - p0
    assert abs(float((q @ u).max()) - np.linalg.norm(tip - p0)) < 1.0
    assert np.linalg.norm(np.array([xs.mean(), ys.mean()]) - mid) < 0.5


def test_markers_absent_after_markers_until(lever):
    """[schedule] markers_until = 0.2 s: at t = 0 the project's markers 0 and 1 (and the plate's printed 7)
    decode; at t = 0.3 s only the plate's 7 does (the plate behind is drawn where they were), and truth.csv's
    markers column says so. Catches: the time ignored, markers drawn only after it, the plane image removed
    with them."""
    r = ProjectRenderer(lever, _scenario(schedule={"markers_until": 0.2}))
    img0, row0 = r.render(0)
    img1, row1 = r.render(9)
    assert {0, 1, 7} <= set(_detect(img0))
    assert set(_detect(img1)) == {7}
    assert (row0["markers"], row1["markers"]) == (1, 0)


def test_pan_turns_the_camera_about_the_vertical_through_its_centre(lever):
    """[[camera.pan]] start 1, duration 2, yaw 40, ramp 0.5: at t = 1.25 (half the ramp) the yaw is
    40 (1 - cos(pi/2)) / 2 = 20 deg and R = R_base Rz(20 deg) with the centre unchanged, t = -R c; at 2 s the
    full 40; after 3 s none. Catches: the rotation applied on the camera side (Rz R_base: turns about the
    optical axis), the sign of the yaw, the ramp profile, the centre moved."""
    base = Resolved(_scenario(), lever)
    pan = Resolved(_scenario(camera={"pan": [{"start": 1.0, "duration": 2.0, "yaw": 40.0, "ramp": 0.5}]}), lever)
    for t, yaw in ((1.25, 20.0), (2.0, 40.0), (3.2, 0.0), (0.5, 0.0)):
        a = math.radians(yaw)
        Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])
        pb, pp = base.pose(t), pan.pose(t)
        np.testing.assert_allclose(pp.R, pb.R @ Rz, atol=1e-12)
        np.testing.assert_allclose(pp.center, pb.center, atol=1e-12)
        assert pan.pan(t) == pytest.approx(yaw)
    # the image moves as computed: the target seen from the turned camera
    r = ProjectRenderer(lever, pan.sc)
    _, row = r.render(round(2.0 * pan.fps))
    assert row["pan_deg"] == pytest.approx(40.0)
    np.testing.assert_allclose(Pose.from_rvec(*_pose(row)).R, pan.pose(2.0).R, atol=1e-9)


def test_wall_lies_on_a_plane_without_image(tmp_path, lever_dir):
    """A [registration.plane] without image (learned by the pipeline): the wall drawn at a pixel is the wall
    texture at the point where that pixel's ray meets the project's plane (Camera.backproject_to_plane), in
    the plane's u (right) and v (down) axes. Catches: the default wall (perpendicular to the line of sight,
    2 object sizes behind) kept, u and v swapped."""
    d = tmp_path / "noimg"
    write_lever_project(d, image=False)
    (d / "model.npz").write_bytes((lever_dir / "model.npz").read_bytes())
    p = load_project(d / "project.toml")
    r = ProjectRenderer(p, _scenario())
    res = r.res
    pose = res.pose(0.7)
    img = r.draw_wall(pose)
    rng = np.random.default_rng(0)
    px = rng.integers([20, 20], [620, 340], (40, 2))
    X = p.camera.backproject_to_plane(px, pose, PLATE_ORIGIN, [0, -1.0, 0])
    s = 2 * r.wall_half / r.wall_n
    a = (X - res.wall_centre) @ np.array([1.0, 0, 0])
    b = (X - res.wall_centre) @ np.array([0, 0, -1.0])
    ref = cv2.remap(r.wall_img, ((a + r.wall_half) / s - 0.5).astype(np.float32)[None],
                    ((b + r.wall_half) / s - 0.5).astype(np.float32)[None], cv2.INTER_LINEAR)[0]
    got = img[px[:, 1], px[:, 0]]
    np.testing.assert_allclose(got, ref, atol=2e-3)  # (float32 texture coordinates)
    assert abs((res.wall_centre - PLATE_ORIGIN) @ np.array([0, 1.0, 0])) < 1e-12


def test_rest_frames_are_undeformed_and_not_scored(lever_visible):
    """[schedule] rest_until = 0.5 s with theta = 30 deg from t = 0: before 0.5 s the drawn mesh is the
    reference (u = 0) and the truth row says at_rest = 1; after it the cuff (top face) is turned rigidly by
    30 deg about the pivot (the prescribed rotation, exactly). Catches: rest ignored, the rotation's sign or
    unit, at_rest not written."""
    r = ProjectRenderer(lever_visible, _scenario(schedule={"rest_until": 0.5, "theta": {"keyframes": [[0, 30.0]]}}))
    x0 = r.deformed(r.res.params(0.1), r.res.at_rest(0.1))
    np.testing.assert_array_equal(x0, r.X)
    _, row0 = r.render(3)
    _, row1 = r.render(20)
    assert (row0["at_rest"], row1["at_rest"]) == (1, 0)
    x1 = r.deformed({"theta": 30.0})
    top = np.abs(r.X[:, 2] - 0.06) < 1e-9
    a = math.radians(30.0)
    R = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    c = np.array([0.02, 0.02, 0.12])
    np.testing.assert_allclose(x1[top], (r.X[top] - c) @ R.T + c, atol=1e-12)


def test_score_skips_rest_frames():
    """Truth with at_rest = 1 on frames 0-3 and estimates off by 0.5 there: 6 judged frames, all within.
    Catches: rest frames judged (4 misses)."""
    t = {"theta_true": np.full(10, 20.0), "at_rest": np.array([1, 1, 1, 1, 0, 0, 0, 0, 0, 0.0])}
    e = {"theta_est": np.full(10, 20.0)}
    e["theta_est"][:4] += 0.5
    res = score(t, e, {"theta": (0.0, 10.0)})
    assert res["judged"] == 6 and res["at_rest"] == 4
    assert res["parameters"]["theta"]["within"] == 6


def test_virtual_object_not_drawn_and_clip_written(lever, lever_visible, tmp_path):
    """[model] visible = false: no finer truth is built (0 solves), the clip and truth.csv (theta_true = the
    schedule, at_rest, markers, pan_deg) are written; the same frame of the visible project differs exactly
    where the model's mesh projects. Catches: the virtual mesh drawn, a FineTruth built for it."""
    sc = _scenario(video={"duration": 0.3}, schedule={"theta": {"keyframes": [[0, 0.0], [0.3, 12.0]]}})
    info = render_project(lever, sc, tmp_path / "clip")
    assert info["truth_solves"] == 0 and info["frames"] == 9
    cols = read_columns(tmp_path / "clip" / "truth.csv")
    for c in ("theta_true", "at_rest", "markers", "pan_deg"):
        assert c in cols
    np.testing.assert_allclose(cols["theta_true"], Resolved(sc, lever).schedule["theta"].value(cols["time_s"]),
                               atol=1e-6)
    ra = ProjectRenderer(lever, sc)
    assert ra.truth is None
    a, _ = ra.render(4)
    rv = ProjectRenderer(lever_visible, sc)
    b, row = rv.render(4)
    diff = np.abs(a.astype(int) - b.astype(int)).max(2) > 30
    K, dist = lever.camera.to_opencv()
    q, _ = cv2.projectPoints(rv.X, *_pose(row), K, dist)
    q = q.reshape(-1, 2)
    ys, xs = np.nonzero(diff)
    assert len(xs) > 200
    lo, hi = q.min(0) - 4, q.max(0) + 4  # (the lens PSF spreads an edge)
    assert np.all((xs >= lo[0]) & (xs <= hi[0]) & (ys >= lo[1]) & (ys <= hi[1]))
