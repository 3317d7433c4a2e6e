"""A wrong marker among good ones (issue 16): the pose of every frame used to mix the one inconsistent marker
with the others, so its reprojection error exceeded the limit and every frame was "lost". Now the marker
whose corners disagree with the pose the others give is left out of the pose, and said once.

The frames are rendered here, independently of the tracker: each ArUco marker image (with its white quiet
zone) is warped into a 1280x720 pinhole view through the homography of its true 3D corners (3x supersampled,
area-averaged), two markers on a table (z = 0) and two on a wall (y = 0.1), the camera moving a little from
frame to frame. The tracker is given a board in which one or two markers are described wrongly."""
import warnings

import cv2
import numpy as np
import pytest

from physar.errors import PhysarWarning
from physar.vision import Camera, MarkerBoard, MarkerTracker, Pose

SIZE = 0.05
# (id, centre, outward normal, up)
TRUE = [(0, (-0.05, -0.05, 0.0), (0, 0, 1), (0, 1, 0)),
        (1, (0.20, -0.05, 0.0), (0, 0, 1), (0, 1, 0)),
        (2, (0.0, 0.1, 0.08), (0, -1, 0), (0, 0, 1)),
        (3, (0.15, 0.1, 0.08), (0, -1, 0), (0, 0, 1))]


def _corners(centre, normal, up, size):
    """TL, TR, BR, BL of a marker seen from outside (right = up x normal)."""
    n, u, c = (np.asarray(v, float) for v in (normal, up, centre))
    r = np.cross(u, n)
    h = size / 2
    return np.array([c - r * h + u * h, c + r * h + u * h, c + r * h - u * h, c - r * h - u * h])


def _board(rows, size=None):
    size = size or {}
    return MarkerBoard([i for i, *_ in rows], np.stack([_corners(c, n, u, size.get(i, SIZE)) for i, c, n, u in rows]))


def _render(cam: Camera, pose: Pose, rows, ss=3) -> np.ndarray:
    """Grey image of the markers ``rows`` (true geometry) seen from ``pose``."""
    w, h = cam.size
    frame = np.full((h * ss, w * ss), 110.0, np.float32)
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    for mid, c, n, u in rows:
        mk = cv2.aruco.generateImageMarker(d, mid, 240, borderBits=1).astype(np.float32)
        pad = np.full((320, 320), 235.0, np.float32)     # one white module around the 6-module marker
        pad[40:280, 40:280] = mk
        X = _corners(c, n, u, SIZE * 8 / 6)
        p = ss * (cam.project(X, pose) + 0.5) - 0.5        # pixel centres at integers, at ss x the resolution
        H = cv2.getPerspectiveTransform(np.float32([[-0.5, -0.5], [319.5, -0.5], [319.5, 319.5], [-0.5, 319.5]]),
                                        p.astype(np.float32))
        img = cv2.warpPerspective(pad, H, frame.shape[::-1], flags=cv2.INTER_LINEAR)
        cov = cv2.warpPerspective(np.ones_like(pad), H, frame.shape[::-1], flags=cv2.INTER_LINEAR)
        frame = frame * (1 - cov) + img * cov
    small = cv2.resize(frame, (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(small + np.random.default_rng(len(rows)).normal(0, 1.0, small.shape), 0, 255).astype(np.uint8)


def _poses(n=8):
    return [Pose.look_at([0.075 + 0.01 * k, -0.45 + 0.004 * k, 0.33 - 0.003 * k], [0.075, 0.03, 0.02])
            for k in range(n)]


def _run(board, frames, **kw):
    tr = MarkerTracker(Camera.from_fov(1280, 720, 65), board, **kw)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = [tr.update(img) for img in frames]
    return tr, est, [str(w.message) for w in caught if issubclass(w.category, PhysarWarning)]


@pytest.fixture(scope="module")
def clip():
    cam = Camera.from_fov(1280, 720, 65)
    poses = _poses()
    return poses, [_render(cam, p, TRUE) for p in poses]


def _wrong(case):
    """The board of one wrong description (what the user wrote) and the ids expected to be left out."""
    rows = [list(r) for r in TRUE]
    if case == "centre 15 mm off":
        rows[3][1] = (0.165, 0.1, 0.08)
        return _board(rows), [3], ["[[marker]] id 3 is ", "mm / ", "check its center"]
    if case == "size in mm":
        return _board(rows, {1: 50.0}), [1], ["[[marker]] id 1 fits", "side of 0.0", "not size = 50",
                                              "check its size"]
    if case == "ids swapped":
        rows[0][0], rows[2][0] = 2, 0
        return _board(rows), [2, 0], ["are the two ids swapped"]
    if case == "normal flipped":
        rows[2][2] = (0, 1, 0)
        return _board(rows), [2], ["[[marker]] id 2 is seen mirrored", "check its normal"]
    if case == "up turned":
        rows[1][3] = (1, 0, 0)
        return _board(rows), [1], ["[[marker]] id 1 is seen turned by 90°", "check its up"]
    raise AssertionError(case)


def test_good_board_tracks_every_frame_without_warning(clip):
    """The reference: the right description gives the pose of every frame within 1 mm / 0.2°, all markers
    used, no warning (catches: a consistency check that drops good markers)."""
    poses, frames = clip
    tr, est, warned = _run(_board(TRUE), frames)
    assert all(e.status == "measured" and e.ids == [0, 1, 2, 3] for e in est), [(e.status, e.ids) for e in est]
    assert max(np.linalg.norm(e.pose.center - p.center) for e, p in zip(est, poses)) < 1e-3
    assert not warned and not tr.rejected and tr.n_left_out == 0


@pytest.mark.parametrize("case", ["centre 15 mm off", "size in mm", "ids swapped", "normal flipped", "up turned"])
def test_one_wrong_marker_is_left_out_and_named_once(clip, case):
    """One wrongly described marker (or two, swapped ids) among four: every frame is still measured, from the
    others only: the pose is that of a board holding only the right markers (within 0.1 mm / 0.02°; both
    within 2.5 mm / 0.3° of the truth: two or three 50 mm markers at 0.55 m), the wrong marker is not among
    the ids used, and one warning per wrong marker names the file and the marker and says what disagrees.

    Mutant (tried): ``_consistent`` returning the joint solve of all markers found (no rejection): every frame
    is "lost" (the mixed pose's reprojection error exceeds max_reproj_px), no warning. Mutant (tried): no
    whole-frame search for a suspect marker: the size and ids cases give no warning (the marker, looked
    for only at its wrong predicted place, is never seen again to confirm it)."""
    poses, frames = clip
    board, bad, words = _wrong(case)
    tr, est, warned = _run(board, frames, source="plate.toml")
    assert all(e.status == "measured" for e in est), [e.status for e in est]
    assert all(not set(bad) & set(e.ids) and len(e.ids) >= 2 for e in est), [e.ids for e in est]
    _, ref, _ = _run(_board([r for r in TRUE if r[0] not in bad]), frames)
    for e, r, p in zip(est, ref, poses):
        assert np.linalg.norm(e.pose.center - r.pose.center) < 1e-4 and e.pose.angle_to(r.pose) < 0.02
        assert np.linalg.norm(e.pose.center - p.center) < 2.5e-3 and e.pose.angle_to(p) < 0.3
    assert len(warned) == len(bad), warned
    assert sorted(int(board.ids[k]) for k in tr.rejected) == sorted(bad)
    for w in warned:
        assert w.startswith("plate.toml: [[marker]] id ") and "left out of the camera pose" in w, w
    for word in words:
        assert any(word in w for w in warned), (word, warned)
    if case == "centre 15 mm off":
        mm = float(warned[0].split(" is ")[1].split(" mm")[0])
        assert 10 <= mm <= 20, warned[0]


def test_two_disagreeing_markers_are_told_apart_by_history(clip):
    """After the wrong marker was found with three others, a frame showing only it and one good marker uses
    the good one, whether the wrong marker was left out for good (confirmed) or only disagreed so far (its
    disagreeing frames decide: ``confirm`` set high); without any history the pair is ambiguous and gives no
    measured pose rather than a wrong one.

    Mutants (tried): no choice made between the two (the frame is only predicted, not measured); the odd one
    out chosen the other way round (the wrong marker kept, the good one dropped)."""
    poses, frames = clip
    board, _bad, _ = _wrong("centre 15 mm off")
    cam = Camera.from_fov(1280, 720, 65)
    pair = _render(cam, poses[-1], [TRUE[2], TRUE[3]])
    for confirm in (3, 100):
        tr, est, warned = _run(board, frames + [pair], source="plate.toml", confirm=confirm)
        assert bool(tr.rejected) == (confirm == 3) and len(warned) == (confirm == 3)
        assert est[-1].status == "measured" and est[-1].ids == [2], (confirm, est[-1].status, est[-1].ids)
        assert np.linalg.norm(est[-1].pose.center - poses[-1].center) < 3e-3
    fresh = MarkerTracker(cam, board).update(pair)
    assert fresh.status == "lost" and fresh.pose is None
