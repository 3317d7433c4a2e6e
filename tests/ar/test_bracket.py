"""The new example object (issue 16): a printed L-bracket tetrahedralised from an STL surface, clamped by a plane,
a load moving along a curved path on its arm plus a sideways offset, markers on three planes (its web, the
wall, the table). Filmed by the general test-data renderer with truth on a mesh independent of the model's (the
STL meshed again at 5 mm and refined 2x: 2.5 mm P2 tetrahedra that are not the model's 2.5 mm gmsh mesh); run
by the same project pipeline as every other project."""
import copy
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from physar.ar.project import load_project
from physar.ar.project_pipeline import ProjectPipeline
from physar.errors import PhysarWarning
from physar.synth import Scenario, load_scenario, render_project
from physar.synth.score import read_columns, score
from physar.vision.camera import Camera

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "ar" / "bracket"


@pytest.fixture(scope="module")
def bracket_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("bracket")
    for f in ("project.toml", "project_features.toml", "rom.toml", "bracket.stl"):
        shutil.copy(EXAMPLE / f, d / f)
    shutil.copy(EXAMPLE.parents[1] / "camera_720p.toml", d / "camera.toml")
    for f in ("project.toml", "project_features.toml"):
        (d / f).write_text((d / f).read_text().replace("../../camera_720p.toml", "camera.toml"))
    return d


@pytest.fixture(scope="module")
def bracket(bracket_dir):
    return load_project(bracket_dir / "project.toml")


@pytest.fixture(scope="module")
def clip(bracket, tmp_path_factory):
    """1.6 s at 1280x720: the load dwells at s = 100 mm, moves to 60 mm and dwells, 4 mm off the path; truth on
    the STL meshed again at 5 mm and refined 2x."""
    sc = Scenario.model_validate({
        "seed": 5, "video": {"duration": 1.6},
        "schedule": {"s": {"keyframes": [[0.0, 0.10], [0.5, 0.10], [1.1, 0.06]]},
                     "o": {"keyframes": [[0.0, 0.004]]}},
        "camera": {"target": [0.11, 0.02, 0.0], "azimuth": -55.0, "elevation": 38.0, "distance": 0.4},
        "truth": {"mesh_size": 0.005}})
    d = tmp_path_factory.mktemp("bracket_clip")
    info = render_project(bracket, sc, d)
    assert info["truth_dofs"] > 1.4 * bracket.space().n_dofs               # another mesh, finer than the model's
    return d


def test_bracket_load_position_along_the_curved_path(bracket, clip, tmp_path):
    """The clip of the ``clip`` fixture: every frame's position within 1 % of the 128 mm path of the truth, the
    median within 0.5 %. Catches: the polyline path read as its chord (its arc length is asserted), a position
    off by more than 1.28 mm anywhere (a wrong path point, a pose error, a model mesh too coarse: the former
    5 mm mesh was 0.8 % stiffer than the truth, which alone biased s by about 0.7 mm), a lost track, the offset's
    sign flipped (below)."""
    p = bracket
    ProjectPipeline(p).run(clip / "video.mp4", tmp_path / "aug.mp4", tmp_path / "est.csv")
    ranges = {n: tuple(map(float, r)) for n, r in zip(p.rom.names, p.rom.ranges)}
    res = score(read_columns(clip / "truth.csv"), read_columns(tmp_path / "est.csv"), ranges)
    s = res["parameters"]["s"]
    assert abs(ranges["s"][1] - 0.1278) < 1e-3                       # arc length of the curved path
    assert res["tracking"] == res["frames"] == 48
    # every judged frame within 1 % of the path (issue 16's line; measured max 0.91 mm = 0.71 %, median 0.43 mm).
    # The rendered clip depends on the CPU (AVX-512 OpenBLAS kernels move truth values by 5e-12 m, x264 then
    # encodes a different clip); on such a clip ArUco missed marker 4 on the periodic re-detection frame 30 and
    # that frame's pose from 4 markers was 1.36 mm off, until a marker missed there is tracked as on other frames
    assert s["judged"] == 48 and s["within"] == 48 and s["max_error"] <= 0.01 * 0.1278, s
    # median 0.65-0.67 mm (0.51-0.53 %) since the marker corners are the intersections of their edge lines (0.43 mm
    # with OpenCV's sub-pixel corners, whose 0.15-0.22 px pull into each marker happened to cancel the model's
    # bias here: with the true camera pose the dots and the model alone give s +0.30 mm on this clip;
    # benchmarks/RESULTS.md, "Marker corners from their edges")
    assert s["median_error"] <= 0.006 * 0.1278, s
    # the sideways offset is weakly observable (plate twist): within 2.5 mm of its 4 mm (measured 4.5-6 mm);
    # catches the offset direction flipped in the model or the truth (the estimate would sit near -3 mm)
    o = read_columns(tmp_path / "est.csv")["o_est"]
    assert abs(np.median(o) - 0.004) < 0.0025, np.median(o)


def test_bracket_dots_and_texture_features(bracket_dir, clip, tmp_path):
    """The example's dots + natural features project (``project_features.toml``: the arm's top-face texture as
    rows of the same solve) on the same clip: every frame within 1.1 % of the path and all but one within 1 %
    (measured max 1.35 mm = 1.05 % at one frame, mean 0.59 mm, with the marker corners of their edge lines;
    1.03 mm, mean 0.46 mm, with OpenCV's sub-pixel corners, whose inward pull cancelled part of the model's
    bias; the offset's mean error is 1.44 mm against 2.11 mm), the
    features in use from the second frame on (80 chosen, at least 40 kept on every later frame), the CSV's
    features column. Catches: features placed at the wrong material points or their displacement's sign
    flipped (a bias of millimetres in s), features never chosen or all rejected, weights that let the features
    override the dots."""
    p = load_project(bracket_dir / "project_features.toml")
    # the clip is H.264 at crf 18, about 0.09 bit per pixel: the features project says that this bitrate is low
    # for texture (benchmarks/RESULTS.md, "H.264 bitrate"); the dots-only run below does not
    with pytest.warns(PhysarWarning, match=r"video\.mp4: [0-9.]+ Mbit/s for 1280x720 at 30 fps \(0\.[01][0-9] bit per "
                                           r"pixel\).*\[features\]"):
        ProjectPipeline(p).run(clip / "video.mp4", tmp_path / "aug.mp4", tmp_path / "est.csv")
    ranges = {n: tuple(map(float, r)) for n, r in zip(p.rom.names, p.rom.ranges)}
    est = read_columns(tmp_path / "est.csv")
    res = score(read_columns(clip / "truth.csv"), est, ranges)
    s = res["parameters"]["s"]
    assert res["tracking"] == res["frames"] == 48
    assert s["judged"] == 48 and s["within"] >= 47 and s["max_error"] <= 0.011 * 0.1278, s
    assert est["features"][0] == 0 and np.min(est["features"][2:]) >= 40, est["features"]
    # the features are rows of the solve, not only tracked: the weakly seen offset (the arm's twist) is known
    # better with them (measured median std 1.5 mm against 2.4 mm with the dots alone on this clip). Catches
    # the features' rows dropped from the solve, or weighted to nothing.
    dots = load_project(bracket_dir / "project.toml")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ProjectPipeline(dots, overlay=False).run(clip / "video.mp4", out_csv=tmp_path / "dots.csv")
    assert not [w for w in caught if "bit per pixel" in str(w.message)]
    o_std_dots = np.median(read_columns(tmp_path / "dots.csv")["o_std"][2:])
    assert np.median(est["o_std"][2:]) < 0.8 * o_std_dots, (np.median(est["o_std"][2:]), o_std_dots)


def test_features_face_off_the_object_is_one_clear_error(bracket_dir):
    """A [features] face 5 mm above the arm (no boundary face of the model on it): one ConfigError naming the
    project file, [features] and the face, before any frame. Catches: features silently never chosen, a
    traceback from the ray casting."""
    from physar.errors import ConfigError

    text = (bracket_dir / "project_features.toml").read_text().replace(
        "origin = [0.005, 0.0, 0.005]", "origin = [0.005, 0.0, 0.010]")
    (bracket_dir / "offface.toml").write_text(text)
    p = load_project(bracket_dir / "offface.toml")
    with pytest.raises(ConfigError, match=r"offface\.toml: \[features\]: no boundary face .*origin \[0\.005, 0\.0, 0\.01\]"):
        ProjectPipeline(p, overlay=False)


def test_first_frame_at_half_size_finds_its_dots(bracket, tmp_path):
    """The first frame searches the dots far from their predicted pixels (the load may be anywhere); at 640x360
    the bracket's dots are 11-17 px apart, so that wide search takes a neighbouring dot for four of the 17 dots
    and the solve settles 32-45 mm short of the truth. The dots searched again where that estimate puts them,
    and solved again, give the truth's position within 2 % of the path (measured 0.6-0.9 mm with OpenCV's
    sub-pixel marker corners, 2.04 mm with the corners of the marker edges: at 640x360 the first frames of this
    seed sit 1.5-2.0 mm high, of seeds 1 and 2 within 0.8 mm, and the edge corners move s by about +0.5 mm
    on all three; benchmarks/RESULTS.md, "Marker corners from their edges"). The example's scenario (its camera,
    texture, light) at half size, 0.3 s, truth on the STL meshed at 5 mm and refined 2x. Catches: no second
    search, a second search still with the wide radius, a second search whose solve is not kept."""
    base = load_scenario(EXAMPLE / "scenario.toml", bracket)
    sc = base.model_copy(update={"video": base.video.model_copy(update={"duration": 0.3}),
                                 "truth": base.truth.model_copy(update={"mesh_size": 0.005})})
    render_project(bracket, sc, tmp_path / "clip", quick=True)
    p = copy.copy(bracket)
    p.camera = Camera.load(tmp_path / "clip" / "camera.toml")
    assert p.camera.width == 640
    ProjectPipeline(p, overlay=False).run(tmp_path / "clip" / "video.mp4", out_csv=tmp_path / "est.csv")
    est, truth = read_columns(tmp_path / "est.csv"), read_columns(tmp_path / "clip" / "truth.csv")
    assert abs(est["s_est"][0] - truth["s_true"][0]) <= 0.02 * 0.1278, (est["s_est"][0], truth["s_true"][0])


def test_texture_features_land_where_the_truth_moves_them(bracket_dir, clip):
    """Features chosen on frame 0 at the truth's pose and parameters (s = 100 mm), then tracked in frame 47
    (s = 60 mm, another pose of the handheld camera) starting where the model at frame 0's parameters puts them
    (several px away): the tracked pixels must match the projection of their material points moved by the
    reduced model at frame 47's true parameters, with frame 47's true pose. The video comes from the renderer's
    independent truth mesh. Catches: barycentrics in the wrong order or the ray turned by R instead of R^T (the
    material points land a triangle away), the displacement's sign flipped or taken at the wrong points, a
    tracker that returns its starting guess."""
    import av

    from physar.ar.surface_points import SurfacePoints
    from physar.vision.camera import Pose

    p = load_project(bracket_dir / "project_features.toml")
    truth = read_columns(clip / "truth.csv")
    with av.open(str(clip / "video.mp4")) as c:
        grays = [f.to_ndarray(format="gray") for f in c.decode(video=0)]

    def at(k):
        pose = Pose.from_rvec([truth[a][k] for a in ("rx", "ry", "rz")], [truth[a][k] for a in ("tx", "ty", "tz")])
        return pose, p.rom.coefficients([truth["s_true"][k], truth["o_true"][k]])[0]

    sp = SurfacePoints(p)
    pose0, c0 = at(0)
    dots = p.camera.project(p.dots + np.tensordot(c0, ProjectPipeline(p, overlay=False).Fd, 1), pose0)
    n = sp.set_reference(grays[0], pose0, c0, dots, np.full(len(dots), 5.0))
    assert n >= 60
    assert np.all(np.abs(sp.points[:, 2] - 0.005) < 1e-9)          # on the arm's top face (z = 5 mm)
    pose1, c1 = at(47)
    px, ok = sp.track(grays[47], pose1, c0)                          # started from frame 0's parameters
    assert ok.mean() > 0.7
    want = p.camera.project(sp.positions(c1), pose1)
    start = p.camera.project(sp.positions(c0), pose1)
    moved = np.linalg.norm(want - start, axis=1)[ok]
    err = np.linalg.norm(px - want, axis=1)[ok]
    assert np.median(moved) > 2.0, np.median(moved)                  # the guess was off by pixels
    assert np.median(err) < 0.2 and np.percentile(err, 90) < 0.4, (np.median(err), np.percentile(err, 90))


def test_features_on_a_face_the_camera_never_sees(bracket_dir, clip, tmp_path):
    """[features] on the arm's underside (z = 0, turned away from this camera): no feature can be chosen, the
    dots carry on alone (every frame tracked and within 1 %, the features column 0). Catches: a crash or a
    lost frame when the face has no visible triangle, features "chosen" on triangles facing away."""
    text = (bracket_dir / "project_features.toml").read_text().replace(
        "origin = [0.005, 0.0, 0.005]", "origin = [0.005, 0.0, 0.0]")
    (bracket_dir / "underside.toml").write_text(text)
    p = load_project(bracket_dir / "underside.toml")
    ProjectPipeline(p, overlay=False).run(clip / "video.mp4", out_csv=tmp_path / "est.csv")
    est = read_columns(tmp_path / "est.csv")
    ranges = {n: tuple(map(float, r)) for n, r in zip(p.rom.names, p.rom.ranges)}
    res = score(read_columns(clip / "truth.csv"), est, ranges)
    assert res["tracking"] == res["frames"] == 48
    assert res["parameters"]["s"]["within"] >= 47   # 48 before the 2026-11-29 package set (see above)
    assert res["parameters"]["s"]["max_error"] <= 0.015 * 0.1278
    assert np.all(est["features"] == 0)
