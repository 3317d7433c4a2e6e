"""The new example object (issue 16): a printed L-bracket tetrahedralised from an STL surface, clamped by a plane,
a load moving along a curved path on its arm plus a sideways offset, markers on three planes (its web, the
wall, the table). Filmed by the general test-data renderer with truth on a mesh independent of the model's (the
STL meshed again at 5 mm and refined 2x: 2.5 mm P2 tetrahedra that are not the model's 2.5 mm gmsh mesh); run
by the same project pipeline as every other project."""
import copy
import shutil
from pathlib import Path

import numpy as np
import pytest

from physar.ar.project import load_project
from physar.ar.project_pipeline import ProjectPipeline
from physar.synth import Scenario, load_scenario, render_project
from physar.synth.score import read_columns, score
from physar.vision.camera import Camera

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "ar" / "bracket"


@pytest.fixture(scope="module")
def bracket(tmp_path_factory):
    d = tmp_path_factory.mktemp("bracket")
    for f in ("project.toml", "rom.toml", "bracket.stl"):
        shutil.copy(EXAMPLE / f, d / f)
    shutil.copy(EXAMPLE.parents[1] / "camera_720p.toml", d / "camera.toml")
    (d / "project.toml").write_text((d / "project.toml").read_text().replace("../../camera_720p.toml", "camera.toml"))
    return load_project(d / "project.toml")


def test_bracket_load_position_along_the_curved_path(bracket, tmp_path):
    """1.6 s at 1280x720: the load dwells at s = 100 mm, moves to 60 mm and dwells, 4 mm off the path. Every
    frame's position within 1 % of the 128 mm path of the truth, the median within 0.5 %. Catches: the polyline
    path read as its chord (its arc length is asserted), a position off by more than 1.28 mm anywhere (a wrong
    path point, a pose error, a model mesh too coarse: the former 5 mm mesh was 0.8 % stiffer than the truth,
    which alone biased s by about 0.7 mm), a lost track, the offset's sign flipped (below)."""
    p = bracket
    sc = Scenario.model_validate({
        "seed": 5, "video": {"duration": 1.6},
        "schedule": {"s": {"keyframes": [[0.0, 0.10], [0.5, 0.10], [1.1, 0.06]]},
                     "o": {"keyframes": [[0.0, 0.004]]}},
        "camera": {"target": [0.11, 0.02, 0.0], "azimuth": -55.0, "elevation": 38.0, "distance": 0.4},
        "truth": {"mesh_size": 0.005}})
    info = render_project(p, sc, tmp_path / "clip")
    assert info["truth_dofs"] > 1.4 * p.space().n_dofs               # another mesh, finer than the model's
    ProjectPipeline(p).run(tmp_path / "clip" / "video.mp4", tmp_path / "aug.mp4", tmp_path / "est.csv")
    ranges = {n: tuple(map(float, r)) for n, r in zip(p.rom.names, p.rom.ranges)}
    res = score(read_columns(tmp_path / "clip" / "truth.csv"), read_columns(tmp_path / "est.csv"), ranges)
    s = res["parameters"]["s"]
    assert abs(ranges["s"][1] - 0.1278) < 1e-3                       # arc length of the curved path
    assert res["tracking"] == res["frames"] == 48
    # every judged frame within 1 % of the path (issue 16; measured max 0.91 mm = 0.71 %, median 0.43 mm)
    assert s["judged"] == 48 and s["within"] == 48 and s["max_error"] <= 0.01 * 0.1278, s
    assert s["median_error"] <= 0.005 * 0.1278, s
    # the sideways offset is weakly observable (plate twist): within 2.5 mm of its 4 mm (measured 4.5-6 mm);
    # catches the offset direction flipped in the model or the truth (the estimate would sit near -3 mm)
    o = read_columns(tmp_path / "est.csv")["o_est"]
    assert abs(np.median(o) - 0.004) < 0.0025, np.median(o)


def test_first_frame_at_half_size_finds_its_dots(bracket, tmp_path):
    """The first frame searches the dots far from their predicted pixels (the load may be anywhere); at 640x360
    the bracket's dots are 11-17 px apart, so that wide search takes a neighbouring dot for four of the 17 dots
    and the solve settles 32-45 mm short of the truth. The dots searched again where that estimate puts them,
    and solved again, give the truth's position (measured 0.6-0.9 mm). The example's scenario (its camera,
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
    assert abs(est["s_est"][0] - truth["s_true"][0]) <= 0.01 * 0.1278, (est["s_est"][0], truth["s_true"][0])
