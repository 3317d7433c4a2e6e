"""`physar ar run` with one wrong [[marker]] table among four (issue 16: a user's project with one marker's
centre off lost every frame, the pose mixing that marker with the good ones). Here marker 1 of the seed
cantilever project is described 15 mm away from where it is printed in the clip (the test-data renderer's
clip of the right project, `live_clip`): the run tracks the frames as the right project does (as many
within 1 % of the span of the truth), and one warning line names the project file, the marker and what disagrees.

Mutant (tried): no rejection (``MarkerTracker._consistent`` solving all markers found together): every frame
is "lost", the run ends with "warning: no frame was tracked", no marker is named."""
import csv
import re

import numpy as np
from typer.testing import CliRunner

from physar.cli.main import app


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_one_wrong_marker_table_is_left_out_and_named_once(live_clip, tmp_path):
    project, clip, _frames = live_clip
    text = project.read_text()
    assert "center = [0.47, 0.03, 0.105]" in text          # marker id 1
    wrong = project.with_name("wrong_marker.toml")
    wrong.write_text(text.replace("center = [0.47, 0.03, 0.105]", "center = [0.485, 0.03, 0.105]"))
    n = 30
    runs = {}
    for name, p in (("right", project), ("wrong", wrong)):
        out = tmp_path / f"{name}.csv"
        r = CliRunner().invoke(app, ["ar", "run", str(p), str(clip / "video.mp4"), "--max-frames", str(n),
                                     "--csv", str(out)])
        assert r.exit_code == 0, r.output
        runs[name] = (r.output, _rows(out))
    right, wrong_rows = runs["right"][1], runs["wrong"][1]
    # (the progress bar shares stderr: the warning may follow it on the same line)
    warn = re.findall(r"warning: [^\n]*", runs["wrong"][0])
    assert len(warn) == 1, runs["wrong"][0]
    assert warn[0].startswith(f"warning: {wrong}: [[marker]] id 1 is ") and "mm / " in warn[0], warn[0]
    assert "check its center" in warn[0] and "left out of the camera pose" in warn[0], warn[0]
    mm = float(warn[0].split("[[marker]] id 1 is ")[1].split(" mm")[0])
    assert 8 <= mm <= 25, warn[0]                            # 15 mm, from one 50 mm marker seen at ~35 px
    assert "warning:" not in runs["right"][0], runs["right"][0]
    st_right = [r["status"] for r in right]
    st_wrong = [r["status"] for r in wrong_rows]
    assert st_right.count("tracking") >= n - 2, st_right
    assert st_wrong.count("tracking") >= st_right.count("tracking") - 1, st_wrong
    truth = np.array([float(r["s_true"]) for r in _rows(clip / "truth.csv")[:n]])
    err = {name: np.array([abs(float(r["s_est"]) - t) if r["status"] == "tracking" else np.inf
                           for r, t in zip(rows, truth)]) for name, rows in (("right", right), ("wrong", wrong_rows))}
    ok = {name: int((e <= 0.005).sum()) for name, e in err.items()}        # within 1 % of the 0.5 m span
    # three markers instead of four: measured 25 of 30 within 1 % (28 right), mean error 2.6 mm (1.6 right)
    mean = {name: float(np.mean(e[np.isfinite(e)])) for name, e in err.items()}
    assert ok["right"] >= n - 3 and ok["wrong"] >= ok["right"] - 4, (ok, err)
    assert mean["wrong"] <= 2.5 * mean["right"] and mean["wrong"] <= 0.005, (mean, err)
