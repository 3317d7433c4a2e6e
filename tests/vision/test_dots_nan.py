"""DotTracker with dots that are not visible: :meth:`Camera.project` returns NaN for a point behind the camera
(and a huge pixel just in front of its centre plane). Such a dot must come out invalid (NaN), without numpy
warnings, exceptions or hangs, while the visible dots are found exactly where they were drawn.

The frames are drawn here with ``cv2.circle`` at integer centres (a filled circle is symmetric about its centre,
so its centroid is the drawn centre); the pinhole camera looks straight at the plane z = 0 from 0.6 m, so a
pixel (u, v) back-projects to ((u - 320) 0.6 / 600, (v - 240) 0.6 / 600, 0) (hand computation)."""

import threading
import warnings

import cv2
import numpy as np
import pytest

from physar.vision import Camera, DotTracker, Pose

F, CX, CY, Z = 600.0, 320.0, 240.0, 0.6
CAM = Camera(np.array([[F, 0, CX], [0, F, CY], [0, 0, 1]]), np.zeros(5), 640, 480)
POSE = Pose(np.eye(3), [0, 0, Z])
# 2 rows of 5 dots, 50 px apart: projections at integer pixels (270..470, 190 / 290) ... shifted below
REF = np.array([[x, y, 0.0] for y in (-0.05, 0.05) for x in (-0.1, -0.05, 0.0, 0.05, 0.1)])
PROJ = np.column_stack([CX + F * REF[:, 0] / Z, CY + F * REF[:, 1] / Z])


def _frame(centres):
    """BGR frame with blue filled dots (radius 5 px) at the integer `centres`, and its grey image."""
    img = np.full((480, 640, 3), 200, np.uint8)
    for u, v in centres:
        cv2.circle(img, (int(u), int(v)), 5, (200, 60, 20), -1)
    return img, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def _tracker(hidden=(), near=(), flow=True, cam=CAM, ref=REF):
    """Tracker whose last displacement puts the `hidden` dots 1 m behind the camera (projection NaN) and the
    `near` dots 1e-12 m in front of its centre plane (projection ~1e13 px, ~1e77 px with distortion)."""
    tr = DotTracker(cam, ref, [0, 0, 0], [0, 0, 1], flow=flow)
    tr.displacement[list(hidden)] = [0, 0, -Z - 1.0]
    tr.displacement[list(near)] = [0, 0, -Z + 1e-12]
    return tr


def _check(obs, drawn, hidden):
    """Visible dots at their drawn centres (0.5 px) and back-projected by hand; hidden ones invalid, NaN."""
    vis = np.setdiff1d(np.arange(len(REF)), hidden)
    assert obs.valid[vis].all() and not obs.valid[list(hidden)].any(), obs.valid
    np.testing.assert_allclose(obs.pixels[vis], drawn[vis], atol=0.5)
    world = np.column_stack([(drawn[:, 0] - CX) * Z / F, (drawn[:, 1] - CY) * Z / F, np.zeros(len(REF))])
    np.testing.assert_allclose(obs.world[vis], world[vis], atol=0.5 * Z / F)
    for a in (obs.pixels, obs.world, obs.displacement):
        assert np.isnan(a[list(hidden)]).all()


def _within(seconds, fn):
    """fn() in a thread, failing if it has not returned after `seconds` (OpenCV's KLT on an empty crop spins
    forever)."""
    box = {}

    def run():
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                box["out"] = fn()
        except BaseException as e:  # noqa: BLE001 - re-raised below in the test's thread
            box["err"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"tracker did not return within {seconds} s"
    if "err" in box:
        raise box["err"]
    return box["out"]


@pytest.mark.parametrize("hidden,near", [((2, 7), ()), ((0,), (9,)), ((1, 3), (5, 6))])
def test_first_frame_finds_the_visible_dots_by_blob_search(hidden, near):
    """First frame: the dots are drawn 15 px right of their projections, beyond the centroid window, so only
    the blob search (within 0.45 of the dot spacing) finds them. A NaN row made the spacing NaN and the search
    found nothing (all dots invalid), with RuntimeWarnings from the NaN -> int casts."""
    drawn = PROJ + [15, 0]
    img, gray = _frame(drawn)
    tr = _tracker(hidden, near)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        obs = tr.update(img, gray, POSE)
    _check(obs, drawn, tuple(hidden) + tuple(near))
    # the same dots as with every dot visible
    ref = _tracker().update(img, gray, POSE)
    vis = np.setdiff1d(np.arange(len(REF)), tuple(hidden) + tuple(near))
    np.testing.assert_array_equal(obs.pixels[vis], ref.pixels[vis])


def test_dot_just_in_front_of_the_camera_plane_with_distortion():
    """With lens distortion (k3) a dot 1e-12 m in front of the camera's centre plane projects to ~1e77 px,
    which overflowed the integer window and crop bounds (RuntimeWarning, INT_MIN). It is not visible; the
    others are found where drawn."""
    cam = Camera(CAM.K, np.array([0, 0, 0, 0, 1e-3]), 640, 480)
    drawn = np.round(cam.project(REF, POSE)) + [15, 0]
    img, gray = _frame(drawn)
    assert np.abs(cam.project(REF[:1] + [0, 0, -Z + 1e-12], POSE)).max() > 1e70
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        obs = _tracker(near=(0, 4), cam=cam).update(img, gray, POSE)
    vis = np.arange(1, 4).tolist() + np.arange(5, 10).tolist()
    assert obs.valid[vis].all() and not obs.valid[[0, 4]].any() and np.isnan(obs.pixels[[0, 4]]).all()
    np.testing.assert_allclose(obs.pixels[vis], drawn[vis], atol=0.5)


def test_two_dots_one_far_away_searches_with_the_default_radius():
    """Two dots, the second just in front of the camera plane (~1e13 px): the spacing comes from pairs of
    visible dots only (here none: the default 4 r = 40 px, search radius 18 px), not from the far one (a ~1e13
    px search radius, refused by detect_blobs); the first dot, drawn 15 px from its projection, is found."""
    drawn = PROJ[:2] + [15, 0]
    img, gray = _frame(drawn[:1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        obs = _tracker(near=(1,), ref=REF[:2]).update(img, gray, POSE)
    assert obs.valid.tolist() == [True, False] and np.isnan(obs.pixels[1]).all()
    np.testing.assert_allclose(obs.pixels[0], drawn[0], atol=0.5)


def test_flow_frame_after_dots_fall_behind_the_camera():
    """Frame 1 tracks all dots; then the load jumps and dots 2 and 7 fall behind the camera. Frame 2 runs the
    optical flow on the crop around the dots: its bounds were NaN -> INT_MIN, an empty crop on which OpenCV's
    KLT never returned. The others are found where drawn (moved 3 px since frame 1)."""
    tr = _tracker()
    img, gray = _frame(PROJ)
    _check(tr.update(img, gray, POSE), PROJ, ())
    tr.displacement[[2, 7]] = [0, 0, -Z - 1.0]
    drawn = PROJ + [3, -2]
    img2, gray2 = _frame(drawn)
    obs = _within(30, lambda: tr.update(img2, gray2, POSE))
    assert tr.n_flow == 1
    _check(obs, drawn, (2, 7))
    # and back: the dots reappear and are searched again
    tr.displacement[[2, 7]] = [3 * Z / F, -2 * Z / F, 0]
    obs = _within(30, lambda: tr.update(img2, gray2, POSE))
    _check(obs, drawn, ())


@pytest.mark.parametrize("flow", [True, False, "auto"])
def test_all_dots_behind_the_camera(flow):
    """Every projection NaN, first frame then a flow frame: all invalid, no exception, no RuntimeWarning (the
    search ran np.nanmin over an all-NaN array and cast NaN to int)."""
    img, gray = _frame(PROJ)
    tr = _tracker(flow=flow)
    _check(tr.update(img, gray, POSE), PROJ, ())
    tr.displacement[:] = [0, 0, -Z - 1.0]
    for _ in range(2):
        obs = _within(30, lambda: tr.update(img, gray, POSE))
        _check(obs, PROJ, tuple(range(len(REF))))
    assert tr.n_flow == 0  # no KLT without a visible dot to track


def test_detect_blobs_with_invisible_predictions():
    """detect_blobs: NaN rows stay NaN, finite rows take their blob; all-NaN predictions or a NaN search
    radius give all NaN, without warnings."""
    img, _ = _frame(PROJ)
    tr = _tracker()
    pred = PROJ + [4, 0]
    pred[[1, 8]] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = tr.detect_blobs(img, pred, 20.0)
        assert np.isnan(tr.detect_blobs(img, np.full((3, 2), np.nan), 20.0)).all()
        assert np.isnan(tr.detect_blobs(img, PROJ, np.nan)).all()
    assert np.isnan(out[[1, 8]]).all()
    keep = np.setdiff1d(np.arange(len(REF)), [1, 8])
    np.testing.assert_allclose(out[keep], PROJ[keep], atol=1e-9)
