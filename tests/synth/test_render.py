"""The test-data renderer of any AR project (physar.synth): the rasteriser against closed forms, and rendered
markers and dots against the camera projection (cv2.projectPoints) of where the finer-mesh truth puts them."""
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from physar.ar.project import load_project
from physar.synth import FineTruth, ProjectRenderer, Scenario, rasterize
from physar.synth.score import score
from physar.vision.calibration import aruco_dictionary

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_rasterize_covers_exactly_the_pixel_centres_inside():
    """A square [10.5, 20.5] x [5.5, 9.5] px split into two triangles covers the 10 x 4 pixel centres inside,
    once each; a nearer triangle over it wins. Catches: a dropped edge/vertex of the bounding box, duplicate
    pixels on the shared diagonal, the z-test reversed."""
    xy = np.array([[10.5, 5.5], [20.5, 5.5], [20.5, 9.5], [10.5, 9.5], [0, 0], [40, 0], [0, 40.0]])
    z = np.array([2.0, 2, 2, 2, 1, 1, 1])
    W = H = 32
    pix, _tri, b = rasterize(xy, z, np.array([[0, 1, 2], [0, 2, 3]]), W, H)
    ys, xs = np.divmod(pix, W)
    assert len(pix) == len(np.unique(pix)) == 40
    assert xs.min() == 11 and xs.max() == 20 and ys.min() == 6 and ys.max() == 9
    np.testing.assert_allclose(b.sum(1), 1.0)
    pix2, tri2, _ = rasterize(xy, z, np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]]), W, H)
    inside = np.isin(pix2, pix)
    assert np.all(tri2[inside] == 2)          # the nearer triangle (depth 1) hides the square (depth 2)


def test_rasterize_depth_is_perspective_correct():
    """A plane tilted in depth, projected by a pinhole f = 100, c = (32, 32): the depth interpolated at every
    covered pixel equals the ray-plane intersection (closed form), and the barycentric reference point matches.
    Catches: screen-space (affine) interpolation (errors of several % of depth here)."""
    f, c = 100.0, 32.0
    X = np.array([[-0.3, -0.3, 1.0], [0.3, -0.3, 3.0], [0.0, 0.3, 2.0]])   # camera frame
    xy = f * X[:, :2] / X[:, 2:] + c
    pix, _tri, b = rasterize(xy, X[:, 2], np.array([[0, 1, 2]]), 64, 64)
    assert len(pix) > 200
    P = b @ X                                      # interpolated 3-D point of each pixel
    n = np.cross(X[1] - X[0], X[2] - X[0])
    v, u = np.divmod(pix, 64)
    ray = np.column_stack([(u - c) / f, (v - c) / f, np.ones(len(u))])
    t = (X[0] @ n) / (ray @ n)                     # ray . t hits the plane
    np.testing.assert_allclose(P, ray * t[:, None], atol=1e-9)


@pytest.fixture(scope="module")
def cantilever(tmp_path_factory):
    d = tmp_path_factory.mktemp("cant")
    for f in ("project.toml", "rom.toml"):
        shutil.copy(EXAMPLES / "ar" / "cantilever" / f, d / f)
    shutil.copy(EXAMPLES / "camera_720p.toml", d / "camera.toml")
    (d / "project.toml").write_text((d / "project.toml").read_text().replace("../../camera_720p.toml", "camera.toml"))
    return load_project(d / "project.toml")


def test_rendered_markers_and_dots_sit_where_the_truth_projects_them(cantilever, tmp_path):
    """Frame of the seed cantilever with the load near the tip: ArUco corners (OpenCV, sub-pixel refined)
    within 0.5 px of cv2.projectPoints of the project's corners at the truth pose; each blue dot's colour
    centroid within 0.35 px of the projection of the dot moved by the finer-mesh displacement. Catches: dots
    drawn at their undeformed place (the tip dots move > 5 px), a lifted/shifted marker, a mirrored texture
    (the id would not decode), the pose written with the wrong convention."""
    p = cantilever
    sc = Scenario.model_validate({"seed": 3, "schedule": {"s": {"keyframes": [[0.0, 0.45]]}},
                                  "sensor": {"read_noise": 0.5, "shot_noise": 0.0}})
    r = ProjectRenderer(p, sc)
    img, row = r.render(12)
    cv2.imwrite(str(tmp_path / "cantilever_frame.png"), img)
    rvec = np.array([row["rx"], row["ry"], row["rz"]])
    tvec = np.array([row["tx"], row["ty"], row["tz"]])
    K, dist = p.camera.to_opencv()
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    corners, ids, _ = cv2.aruco.ArucoDetector(aruco_dictionary(p.board.dictionary), params).detectMarkers(gray)
    assert ids is not None and sorted(ids.ravel().tolist()) == sorted(p.board.ids.tolist())
    for cc, i in zip(corners, ids.ravel()):
        ref, _ = cv2.projectPoints(p.board.corners[list(p.board.ids).index(i)], rvec, tvec, K, dist)
        assert np.abs(cc.reshape(4, 2) - ref.reshape(4, 2)).max() < 0.5, i
    # dots: truth displacement at the dot (the nearest fine-mesh node: dots sit on nodes of the refined mesh
    # only approximately, so interpolate on the fine surface through the renderer-independent FE space)
    ft = FineTruth(p, refine=2)
    u = ft.solve({"s": 0.45}).reshape(-1, 3)
    nodes = ft.space.nodes
    moved = []
    for d in p.dots:
        near = np.argsort(np.linalg.norm(nodes - d, axis=1))[:4]
        w = 1 / (np.linalg.norm(nodes[near] - d, axis=1) + 1e-9)
        moved.append(d + (w[:, None] * u[near]).sum(0) / w.sum())
    moved = np.array(moved)
    ref, _ = cv2.projectPoints(moved, rvec, tvec, K, dist)
    ref = ref.reshape(-1, 2)
    flat, _ = cv2.projectPoints(p.dots, rvec, tvec, K, dist)
    assert np.linalg.norm(ref - flat.reshape(-1, 2), axis=1).max() > 5      # the load deflects the tip dots
    f = img.astype(float)
    blue = np.clip(f[..., 0] - 0.5 * (f[..., 1] + f[..., 2]) - 25, 0, None)   # blueness above the grey texture
    errs = []
    for q in ref:
        x0, y0 = np.round(q).astype(int)
        win = blue[y0 - 8:y0 + 9, x0 - 8:x0 + 9]
        yy, xx = np.mgrid[y0 - 8:y0 + 9, x0 - 8:x0 + 9]
        errs.append(np.hypot((win * xx).sum() / win.sum() - q[0], (win * yy).sum() / win.sum() - q[1]))
    assert max(errs) < 0.35, np.round(errs, 3)


def test_truth_is_finer_than_the_model_and_agrees_with_it(cantilever):
    """No inverse crime: the truth's mesh is 8x finer (refine 2) and its tip deflection differs from the
    reduced model's, by less than 3 % (the model's discretisation error)."""
    p = cantilever
    ft = FineTruth(p, refine=2)
    assert ft.space.mesh.n_cells == 8 * p.space().mesh.n_cells
    tip = np.array([0.5, 0.01, 0.0075])
    u_t = ft.solve({"s": 0.4}).reshape(-1, 3)[np.argmin(np.linalg.norm(ft.space.nodes - tip, axis=1))]
    sp = p.space()
    u_m = p.rom.evaluate([0.4]).reshape(-1, 3)[np.argmin(np.linalg.norm(sp.nodes - tip, axis=1))]
    rel = abs(u_t[2] - u_m[2]) / abs(u_t[2])
    assert 1e-5 < rel < 0.03, rel


def test_score_judges_frames_without_occluders():
    """Hand-made truth/estimates: 10 frames, an occluder in frames 3-4; errors 0 except frame 3 (occluded, not
    judged), frame 6 (recovery, not judged) and frame 9 (judged, over the 1 % tolerance)."""
    t = {"s_true": np.full(10, 0.3), "occluders": np.array([0, 0, 0, 1, 1, 0, 0, 0, 0, 0.0])}
    e = {"s_est": np.full(10, 0.3), "status": np.array(["tracking"] * 10)}
    e["s_est"][[3, 6, 9]] += [0.1, 0.1, 0.02]
    res = score(t, e, {"s": (0.0, 1.0)}, tol=0.01, recovery=2)
    s = res["parameters"]["s"]
    assert res["judged"] == 6 and s["judged"] == 6 and s["within"] == 5 and s["worst_frame"] == 9
    assert s["recovery_frames"] == [1]
