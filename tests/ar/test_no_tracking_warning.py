"""`physar ar run` says so when no frame was tracked (a review found runs with every frame "hold" or "lost"
ending with exit 0 and only the usual "N frames at ... fps" line): one warning line with the status counts and
what to check. Here the project's dots are declared red while the clip's are blue, so no dot is ever found.

Mutants caught: no warning (the line is absent); the counts not collected (the warning would claim
"0 tracking" without the "hold" count); the advice for markers given when the pose was fine (its text is
asserted absent)."""
from typer.testing import CliRunner

from physar.cli.main import app


def test_warns_when_no_frame_is_tracked(live_clip):
    project, clip, _frames = live_clip
    text = project.read_text()
    assert "colour = [25, 70, 170]" in text
    red = project.with_name("red_dots.toml")
    red.write_text(text.replace("colour = [25, 70, 170]", "colour = [200, 30, 30]"))
    r = CliRunner().invoke(app, ["ar", "run", str(red), str(clip / "video.mp4"), "--max-frames", "12"])
    assert r.exit_code == 0, r.output
    warn = [ln for ln in r.output.splitlines() if ln.startswith("warning: no frame was tracked")]
    assert len(warn) == 1, r.output
    assert "12 hold" in warn[0] and "[dots] colour" in warn[0] and "[[marker]]" not in warn[0], warn[0]


def test_no_warning_when_tracking(live_clip):
    project, clip, _frames = live_clip
    r = CliRunner().invoke(app, ["ar", "run", str(project), str(clip / "video.mp4"), "--max-frames", "12"])
    assert r.exit_code == 0, r.output
    assert "warning: no frame was tracked" not in r.output
