"""The seed's three scenes as project folders (examples/ar/cantilever, foam, seal), each rendered by the test-data
renderer from a finer mesh and run by the one project pipeline (`physar demo --scene NAME`), against the seed's
accuracy goals (seed 000 §5.1-§5.3; issue 16 "What must show it"). Minutes each (the foam's St.VK truth about
ten), hence slow."""
import json

import pytest

from physar.synth.demo import FILES, run_project_demo, scene_project

pytestmark = pytest.mark.slow


def _demo(name, tmp_path_factory):
    out = tmp_path_factory.mktemp(name)
    rep = run_project_demo(scene_project(name), out)
    for f in FILES:
        assert (out / f).stat().st_size > 0, f
    assert json.loads((out / "report.json").read_text())["frames"] == rep["frames"]
    return rep


@pytest.fixture(scope="module")
def cantilever(tmp_path_factory):
    return _demo("cantilever", tmp_path_factory)["score"]["parameters"]["s"]


def test_cantilever_99pct_of_judged_frames_within_1pct_and_recovery(cantilever):
    """Scene (a): at least 99 % of the judged frames (no occluder in view, not among the 5 frames after one;
    the scenario keeps the load beyond 20 % of the span) within 1 % of the 0.5 m range, mean |error| <= 1 mm,
    recovery within 5 frames after each occlusion (measured 2026-11-25: 331/331 after commit f9581d3,
    mean 0.60 mm, recovery 1 frame). Catches: a pose or dot regression that loses the
    seed's 1 % goal on more than a frame or two, a filter lagging behind the moves, no recovery after the hand."""
    s = cantilever
    assert s["judged"] > 300
    assert s["within"] >= 0.99 * s["judged"] and s["mean_error"] <= 1e-3, s
    assert s["recovery_frames"] and all(r is not None and r <= 5 for r in s["recovery_frames"]), s


def test_cantilever_every_judged_frame_within_1pct_of_the_range(cantilever):
    """Scene (a), issue 16's goal for the seed scenes: EVERY judged frame within 1 % of the range (331/331 since
    the IMM filter's P(dwell -> moving) = 0.2, commit f9581d3; 330/331 before, one frame at 6.13 mm). Catches: a
    single frame beyond 5 mm, e.g. a filter that trails the start of a move (the miss before f9581d3)."""
    assert cantilever["within"] == cantilever["judged"], cantilever


def test_foam_mean_error_within_1_5_mm(tmp_path_factory):
    """Scene (b), no fiducial after frame 0: mean |disk-position error| <= 1.5 mm over the judged frames (seed
    §5.2: ~1.5 mm on its 797.5 mm beam; measured 2026-11-25: 1.15 mm mean, 4.78 mm max). Catches: the learned
    wall plane or the natural features lost after frame 0 (no estimate), the nonlinear (St.VK) model replaced by
    a linear one (errors of several mm at the seed's 15 N)."""
    s = _demo("foam", tmp_path_factory)["score"]["parameters"]["s"]
    assert s["judged"] > 250
    assert s["mean_error"] <= 1.5e-3, s


def test_seal_median_error_within_1_deg_and_recovery_within_5_frames(tmp_path_factory):
    """Scene (c), the virtual boot seal on a real lever: median |lever-angle error| <= 1 deg over the judged
    frames, back within 1 % of the range within 5 frames after the camera looked away (seed §5.3). Catches: the
    plate registration lost after the look-away (no recovery), the bar's angle sign or zero direction wrong
    (errors of tens of degrees)."""
    rep = _demo("seal", tmp_path_factory)
    s = rep["score"]["parameters"]["theta"]
    assert s["judged"] > 100
    assert s["median_error"] <= 1.0, s
    assert s["recovery_frames"] and all(r is not None and r <= 5 for r in s["recovery_frames"]), s
