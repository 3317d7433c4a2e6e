"""Scene (b) at 1280x720 (10.5 s of video), end to end: the seed's accuracy goal on the disk position with no
fiducial after frame 0 (slow)."""
import json

import numpy as np
import pytest

from physar.ar.foam import read_csv_columns, run_foam_demo

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("foam_demo")
    return out, run_foam_demo(out)


def test_foam_demo_outputs(demo):
    out, rep = demo
    for f in rep["files"]:
        assert (out / f).stat().st_size > 0
    assert json.loads((out / "report.json").read_text())["frames"] == rep["frames"] == 315
    assert rep["scene"]["frames_with_markers"] == 1
    truth = read_csv_columns(out / "truth.csv")
    assert truth["markers_visible"][0] == 1 and not np.any(truth["markers_visible"][1:])


def test_foam_demo_accuracy(demo):
    """Goal: mean |load-position error| <= 1.5 mm (seed §5.2: ~1.5 mm on its 797.5 mm beam). Measured
    2026-11-23: 0.76 mm mean, 2.9 mm max; 11 modes 0.76 mm, 5 modes 0.84 mm."""
    _out, rep = demo
    assert rep["tracking_fraction_loaded"] == 1.0
    assert rep["mean_abs_error_mm"] <= 1.5
    assert rep["max_abs_error_mm"] < 6.0
    for row in rep["table"]:
        assert row["abs_difference_mm"] < 3.0, row
    by_modes = {r["modes"]: r["mean_abs_error_mm"] for r in rep["accuracy_vs_modes"]}
    assert by_modes[11] <= 1.5
