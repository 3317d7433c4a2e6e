"""`physar ar run` after a new-user review (AR pipeline):

1. an estimate pinned at a bound of the model's range (the true value outside it, or given in other units) was
   reported as "tracking" with no word: now each CSV row names the parameters at a bound (column ``at_bound``,
   within 0.5 % of the range's width), and the run ends with one PhysarWarning naming the parameter, the bound
   and the fraction of the tracked frames;
2. a run where no marker is ever found (here: the wrong ArUco dictionary) now says to check
   ``[[marker]] dictionary`` and gives its value;
3. a "lost" frame (no pose) wrote the filter's starting value (the middle of the range) or the held value as
   its estimate: it now writes NaN, and so does every frame before the first estimate.

The clip is the `live_clip` fixture (the seed cantilever, 200 N load dwelling at 420 mm, 640x360). For 1, the
project's model carries 20 N instead of 200 N: by Euler-Bernoulli the tip deflection of a load F at s is
F s^2 (3L - s) / (6EI), at most 20 * 0.5^2 * 1.0 = 5 (units of 1/(6EI)) for 20 N anywhere on the 0.5 m beam,
against 200 * 0.42^2 * 1.08 = 38.1 for the clip's load: no s of the model's range explains the images, and the
best fit is the range's end s = 0.5 m.

Mutants tried, each caught: the bound test on the wrong side (a value at the lower bound flagged "upper"; the
upper test against hi + tol), an absolute tolerance of 0.005 instead of 0.5 % of the width, the warning per
frame, the warning at any pinned frame (no PINNED_FRACTION), the CLI hint without the dictionary, lost rows
written with the held value, rows before the first estimate with the mid-range starting value, the estimate
never marked as made (NaN everywhere).
"""
import csv
import math
import re
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from physar.ar.project import load_project
from physar.ar.project_pipeline import PINNED_FRACTION, ProjectPipeline
from physar.cli.main import app
from physar.errors import PhysarWarning


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_bounds_reached_is_half_a_percent_of_each_range():
    """Hand values on two ranges of different scale: s in [0, 0.5] (tolerance 2.5 mm) and E in [1e6, 1e7]
    (tolerance 45 kPa); beyond a bound counts as at it, NaN as at none."""
    ns = SimpleNamespace(names=["s", "E"], lo=np.array([0.0, 1e6]), hi=np.array([0.5, 1e7]))
    def reached(s, e):
        return ProjectPipeline.bounds_reached(ns, [s, e])
    assert reached(0.25, 5e6) == ()
    assert reached(0.4976, 5e6) == (("s", "upper"),)
    assert reached(0.4974, 5e6) == ()
    assert reached(0.0024, 1.04e6) == (("s", "lower"), ("E", "lower"))
    assert reached(0.0026, 1.05e6) == ()
    assert reached(0.6, 9.96e6) == (("s", "upper"), ("E", "upper"))
    assert reached(-0.1, 9.95e6) == (("s", "lower"),)
    assert reached(math.nan, math.nan) == ()


@pytest.fixture(scope="module")
def weak_project(live_clip, tmp_path_factory):
    """The live clip's project with a 20 N model (the clip's load is 200 N)."""
    project, clip, _frames = live_clip
    d = tmp_path_factory.mktemp("weak_model")
    rom = project.with_name("rom.toml").read_text()
    assert "load = [0, 0, -200.0]" in rom
    (d / "rom.toml").write_text(rom.replace("load = [0, 0, -200.0]", "load = [0, 0, -20.0]"))
    text = project.read_text()
    assert '"clip/camera.toml"' in text
    (d / "project.toml").write_text(text.replace('"clip/camera.toml"', f'"{(clip / "camera.toml").as_posix()}"'))
    return d / "project.toml"


def test_estimate_pinned_at_a_bound_is_flagged_and_warned_once(weak_project, live_clip, tmp_path):
    _project, clip, _frames = live_clip
    out = tmp_path / "est.csv"
    r = CliRunner().invoke(app, ["ar", "run", str(weak_project), str(clip / "video.mp4"), "--max-frames", "20",
                                 "--csv", str(out)])
    assert r.exit_code == 0, r.output
    rows = _rows(out)
    assert len(rows) == 20 and rows[0]["at_bound"] is not None
    tracked = [row for row in rows if row["status"] == "tracking"]
    assert len(tracked) >= 15, [row["status"] for row in rows]
    # the estimate is at the end of the 0.5 m path (within 0.5 % of it) and each such row says so
    at_end = [row for row in tracked if float(row["s_est"]) >= 0.5 * (1 - 0.005)]
    assert len(at_end) == len(tracked), [row["s_est"] for row in tracked]
    assert all(row["at_bound"] == "s:upper" for row in at_end)
    warn = re.findall(r"warning: [^\n]*", r.output)
    # the pinned line, and (the 20 N model moves the dots 10 x less than the clip's 200 N: its s is poorly
    # observed, standard deviation 72 % of the range) the poorly-observed line, each once
    assert len(warn) == 2 and "s is poorly observed" in warn[1], r.output
    pct = round(100 * len(at_end) / len(tracked))
    assert f"s pinned at its upper bound 0.5 m in {pct} % of the tracked frames ({len(at_end)} of {len(tracked)})" \
        in warn[0], warn[0]
    assert "rom.toml [[parameter]] s `path`, 0.5 m long" in warn[0] and "other units" in warn[0], warn[0]


def test_in_range_estimates_are_not_flagged(live_clip, tmp_path):
    """The right model: s near 420 mm, no row at a bound, no warning."""
    project, clip, _frames = live_clip
    out = tmp_path / "est.csv"
    r = CliRunner().invoke(app, ["ar", "run", str(project), str(clip / "video.mp4"), "--max-frames", "12",
                                 "--csv", str(out)])
    assert r.exit_code == 0, r.output
    rows = _rows(out)
    assert all(row["status"] == "tracking" and row["at_bound"] == "" for row in rows), rows
    assert all(abs(float(row["s_est"]) - 0.42) < 0.01 for row in rows)
    assert "warning:" not in r.output, r.output


def test_pinned_warning_needs_a_quarter_of_the_tracked_frames(live_clip):
    """One warning from PINNED_FRACTION of the tracked frames on, none below."""
    pipe = ProjectPipeline(load_project(live_clip[0]), overlay=False)
    assert PINNED_FRACTION == 0.25
    for frames, expect in ((4, 0), (5, 1), (20, 1)):
        at = pipe._pinned(20, {("s", "lower"): frames, ("s", "upper"): 1})
        assert at["s"]["bound"] == "lower" and at["s"]["value"] == 0.0 and at["s"]["fraction"] == frames / 20
        with warnings.catch_warnings(record=True) as ws:
            warnings.simplefilter("always")
            pipe._warn_pinned(at)
        got = [w for w in ws if issubclass(w.category, PhysarWarning)]
        assert len(got) == expect, (frames, [str(w.message) for w in got])
        if expect:
            assert f"s pinned at its lower bound 0 m in {100 * frames // 20} %" in str(got[0].message)


def test_no_marker_found_names_the_dictionary(live_clip):
    project, clip, _frames = live_clip
    text = project.read_text()
    assert "dictionary" not in text                       # the default, DICT_4X4_50, prints these markers
    wrong = project.with_name("wrong_dictionary.toml")
    wrong.write_text(re.sub(r"(?m)^(id = \d+)$", r'\1\ndictionary = "DICT_5X5_100"', text))
    r = CliRunner().invoke(app, ["ar", "run", str(wrong), str(clip / "video.mp4"), "--max-frames", "4"])
    assert r.exit_code == 0, r.output
    warn = [ln for ln in r.output.splitlines() if "warning: no frame was tracked" in ln]
    assert len(warn) == 1, r.output
    assert "4 lost" in warn[0] and 'check [[marker]] dictionary = "DICT_5X5_100"' in warn[0], warn[0]


def test_lost_rows_have_no_estimate(live_clip, tmp_path):
    """Frames 0-2 blank (no marker, no dot), 3-14 the clip's (load at 420 mm), then 160 blank (the pose is held
    for 150 frames, MarkerTracker.hold_frames, then lost), then 10 of the clip's, the dots missed in the first 3
    of them: "lost" rows write NaN, the tracked ones the estimate, the held ones the held estimate, except the
    held rows after the loss (markers back, dots not yet: the estimate from before the loss is stale): NaN
    (mutant: the pre-loss 420 mm written there); the report's plot and dwell table take the NaN rows as gaps."""
    from physar.ar.report import dwell_table, plot_estimates

    project, _clip, frames = live_clip
    grey = np.full_like(frames[0], 128)
    seq = [grey] * 3 + frames[3:15] + [grey] * 160 + frames[3:13]
    out = tmp_path / "est.csv"
    pipe = ProjectPipeline(load_project(project), overlay=False)
    dots, process, index = pipe._dots, pipe.process, [0]

    def dots_missed_after_a_loss(*a):  # the first 3 frames back: markers found, the dots not (motion blur, glare)
        return (None, 0) if 175 <= index[0] < 178 else dots(*a)

    def process_frame(frame, i, *a, **k):
        index[0] = i
        return process(frame, i, *a, **k)

    pipe._dots, pipe.process = dots_missed_after_a_loss, process_frame
    pipe.run(iter(seq), out_csv=out)
    rows = _rows(out)
    status = [row["status"] for row in rows]
    assert status[:3] == ["lost"] * 3 and status[3:15] == ["tracking"] * 12, status
    assert set(status[15:175]) == {"hold", "lost"} and status[174] == "lost" and status[15] == "hold", status
    assert status[175:178] == ["hold"] * 3 and status[178:].count("tracking") >= 5, status
    back = 178   # the first estimate after the loss
    for k, row in enumerate(rows):
        s, sd = float(row["s_est"]), float(row["s_std"])
        if row["status"] == "lost" or 175 <= k < back:  # after the loss, held rows have no estimate either
            assert math.isnan(s) and math.isnan(sd) and row["at_bound"] == "", (k, row)
        else:                      # tracked, or held after frame 3's estimate
            assert abs(s - 0.42) < 0.01 and sd > 0, (k, row)
    # the report (the truth of these frames: 420 mm throughout): NaN rows left out of the dwell's mean, gaps
    truth = {"time_s": np.arange(len(rows)) / 30, "s_true": np.full(len(rows), 0.42)}
    est = {"s_est": np.array([float(r["s_est"]) for r in rows]), "s_std": np.array([float(r["s_std"]) for r in rows]),
           "status": np.array(status), "at_bound": np.array([r["at_bound"] for r in rows])}
    table = dwell_table(truth, est, "s")
    ok = (est["status"] == "tracking") & np.isfinite(est["s_est"])
    assert len(table) == 1 and table[0]["frames"] == int(ok[3:].sum())
    assert table[0]["mean_estimate"] == pytest.approx(np.mean(est["s_est"][3:][ok[3:]]))
    png = tmp_path / "plot.png"
    plot_estimates(truth, est, ["s"], ["m"], png, ranges={"s": (0.0, 0.5)})
    assert png.stat().st_size > 10_000


def test_rows_before_the_first_estimate_have_none(live_clip, tmp_path):
    """Markers found but no dot (the project's dots declared red, the clip's are blue): every row is "hold"
    with no estimate yet, so NaN, not the middle of the range (0.25 m) the filter starts from."""
    project, clip, _frames = live_clip
    text = project.read_text()
    red = project.with_name("red_dots_rows.toml")
    red.write_text(text.replace("colour = [25, 70, 170]", "colour = [200, 30, 30]"))
    out = tmp_path / "est.csv"
    s = ProjectPipeline(load_project(red), overlay=False).run(clip / "video.mp4", out_csv=out, max_frames=5)
    rows = _rows(out)
    assert [r["status"] for r in rows] == ["hold"] * 5 and s["marker_frames"] == 5 and s["at_bound"] == {}
    assert all(math.isnan(float(r["s_est"])) and math.isnan(float(r["s_std"])) for r in rows), rows


def test_overlay_draws_no_surface_without_an_estimate(live_clip):
    """Markers found, dots not (first frame): the augmented frame leaves the object's pixels as the camera gave
    them (the panel says "no estimate yet"); the next frame, tracked, paints the surface there. Reference: the
    input frame. Catches: the overlay drawn with the starting value (the box centre) or a pre-loss estimate
    while the CSV row says NaN."""
    project, _clip, frames = live_clip
    pipe = ProjectPipeline(load_project(project))
    assert not pipe.has_estimate
    dots = pipe._dots
    pipe._dots = lambda *a: (None, 0)
    f = frames[5]
    img0, r0 = pipe.process(f.copy(), 0)
    pipe._dots = dots
    img1, r1 = pipe.process(f.copy(), 1)
    assert r0.status == "hold" and math.isnan(r0.mu[0]) and r1.status == "tracking" and pipe.has_estimate
    h, w = f.shape[:2]
    panel = np.zeros((h, w), bool)      # the text panel (top left) and the colour bar (right) are drawn on both
    panel[: h // 3, : int(600 * h / 720)] = True
    panel[:, int(0.75 * w):] = True
    surface = np.any(img1 != f, axis=2) & ~panel
    assert surface.sum() > 2000, surface.sum()                      # the tracked frame's painted surface
    assert not np.any((img0 != f)[surface]), np.sum(np.any(img0 != f, axis=2) & surface)
