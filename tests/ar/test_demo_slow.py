"""The full demo scene (a) at 1280x720 (14.3 s of video): accuracy against the fine-mesh truth (slow)."""
import json

import numpy as np
import pytest

from physar.ar.demo import run_ar_demo
from physar.ar.pipeline import read_estimates
from physar.ar.scene import read_truth

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    return out, run_ar_demo(out)


def _errors(demo):
    tmp_path, _rep = demo
    L = 0.5
    truth, est = read_truth(tmp_path / "truth.csv"), read_estimates(tmp_path / "estimates.csv")
    err = np.abs(est["s_est"] - truth["s_true_m"])
    full = np.array(["full" in o for o in truth["occluded"]])
    end = int(np.flatnonzero(full)[-1]) + 1
    sel = (est["status"] == "tracking") & (truth["s_true_m"] >= 0.2 * L)
    sel[end:end + 5] = False
    return err, sel, L


def test_demo_scene_99pct_of_frames_and_table_within_1pct(demo):
    """Issue 4 on the full demo scene: >= 99 % of the judged frames within 1 % of the span, the seed's Table 1
    (mean estimate per dwell position) within 1 % everywhere, recovery within 5 frames after the full occlusion.
    Measured 2026-11-23 (pose-error noise model, IMM filter, joint pose + load refinement): 347/347 frames, worst
    4.42 mm, table max 0.82 mm."""
    _tmp_path, rep = demo
    err, sel, L = _errors(demo)
    assert sel.sum() > 300
    assert np.mean(err[sel] <= 0.01 * L) >= 0.99, np.sort(err[sel])[-5:]
    assert rep["recovery_frames_after_full_occlusion"][0] <= 5
    assert len(rep["table"]) == 11
    for row in rep["table"]:
        assert row["abs_difference_mm"] <= 0.01 * L * 1e3, row


def test_demo_scene_every_frame_within_1pct(demo):
    """Issue 4 goal on the full demo scene (429 frames, 11 dwell positions, moving load, a 30-frame full
    occlusion, two markers hidden for 20 frames, the beam's middle hidden for 15): |s_est - s_true| <= 1 % of
    the span in every tracked frame with the load beyond 20 % of the span from the clamp (moving frames
    included), except the 5 frames after the full occlusion, which must recover within 5 frames.
    Measured 2026-11-23 (scene seed 0): mean 0.62 mm, max 4.42 mm (limit 5 mm), recovery 1 frame. This is the
    demo's seed; over scene seeds 0-9 (benchmarks/bench_ar_noise_seeds.py) 3467/3470 judged frames are within
    5 mm (99.91 %, worst 5.94 mm, all three misses with four markers seen), so the every-frame goal holds on
    this seed but not on every noise draw."""
    tmp_path, rep = demo
    for f in rep["files"]:
        assert (tmp_path / f).stat().st_size > 0
    assert json.loads((tmp_path / "report.json").read_text())["frames"] == rep["frames"] == 429
    err, sel, L = _errors(demo)
    assert sel.sum() > 300
    assert np.all(err[sel] <= 0.01 * L), (np.max(err[sel]) * 1e3, np.flatnonzero(sel & (err > 0.01 * L)))
    assert rep["fraction_within_1pct_span"] == 1.0 and rep["max_abs_error_mm"] <= 0.01 * L * 1e3
    assert rep["recovery_frames_after_full_occlusion"][0] <= 5
    # Table 1 of the seed: mean estimate per dwell position within 1 % of the span (all positions)
    assert len(rep["table"]) == 11
    for row in rep["table"]:
        assert row["abs_difference_mm"] <= 0.01 * L * 1e3, row
