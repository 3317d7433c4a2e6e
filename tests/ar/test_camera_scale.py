"""An AR project's ``[camera] scale``: videos resized from the calibrated mode are read with the camera scaled
alike, and a video of another size is refused with what to do.

Reference: the 1280x720 calibration of examples/camera_720p.toml halved by hand in the pixel-centre convention
(pixel (0, 0) centred at (0, 0)): fx' = fx / 2 = 502.2993846775969, cx' = (639.5 + 0.5) / 2 - 0.5 = 319.5,
cy' = (359.5 + 0.5) / 2 - 0.5 = 179.5, 640x360 (the values `physar synth render --quick` writes for its half-size
clip of the same camera)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from physar.ar.project import load_project
from physar.cli.main import app

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()


def _project(tmp_path, scale: str | None) -> Path:
    d = tmp_path / "proj"
    shutil.copytree(ROOT / "examples" / "ar" / "cantilever", d)
    p = d / "project.toml"
    text = p.read_text().replace('file = "../../camera_720p.toml"',
                                 f'file = "{ROOT / "examples" / "camera_720p.toml"}"'
                                 + (f"\nscale = {scale}" if scale else ""))
    p.write_text(text)
    return p


def _video(path: Path, w: int, h: int) -> Path:
    from physar.ar.video import VideoWriter

    rng = np.random.default_rng(0)
    with VideoWriter(path, w, h, 30.0) as v:
        for _ in range(2):
            v.write(rng.integers(0, 255, (h, w, 3), np.uint8))
    return path


# mutants caught: scale ignored (1280x720 camera), the half-pixel shift dropped (cx 319.75), fx not scaled
def test_scale_halves_the_calibration(tmp_path):
    cam = load_project(_project(tmp_path, "0.5")).camera
    assert cam.size == (640, 360)
    np.testing.assert_allclose(cam.K, [[502.2993846775969, 0, 319.5], [0, 502.2993846775969, 179.5], [0, 0, 1]],
                               rtol=0, atol=1e-9)


def test_other_video_size_names_what_to_do(tmp_path):
    proj = _project(tmp_path, None)
    v = _video(tmp_path / "half.mp4", 640, 360)
    r = runner.invoke(app, ["ar", "run", str(proj), str(v), "--out", str(tmp_path / "o.mp4")])
    assert r.exit_code == 2, r.output
    line = " ".join(r.output.split())
    assert "is 640x360 but" in line and "is for 1280x720" in line and "[camera] scale = 0.5" in line, line
    v2 = _video(tmp_path / "square.mp4", 480, 480)
    r = runner.invoke(app, ["ar", "run", str(proj), str(v2), "--out", str(tmp_path / "o.mp4")])
    line = " ".join(r.output.split())
    assert r.exit_code == 2 and "the aspect ratio differs (1.000 vs 1.778" in line and "scale =" not in line, line
    assert not (tmp_path / "o.mp4").exists()


@pytest.mark.parametrize("bad", ["0", "-1", '"half"'])
def test_bad_scale_is_one_line(tmp_path, bad):
    proj = _project(tmp_path, bad)
    r = runner.invoke(app, ["ar", "run", str(proj), str(tmp_path / "none.mp4"), "--out", str(tmp_path / "o.mp4")])
    assert r.exit_code == 2 and "scale" in r.output and "Traceback" not in r.output, r.output


# mutant caught: the video opened only after load_project (the model is rebuilt first: model.npz written)
def test_video_size_checked_before_the_model_is_built(tmp_path):
    proj = _project(tmp_path, None)
    (proj.parent / "model.npz").unlink(missing_ok=True)  # the next run would build it (a fresh clone has none)
    v = _video(tmp_path / "half.mp4", 640, 360)
    r = runner.invoke(app, ["ar", "run", str(proj), str(v), "--out", str(tmp_path / "o.mp4")])
    assert r.exit_code == 2 and "is 640x360 but" in r.output, r.output
    assert not (proj.parent / "model.npz").exists()


# An existing CSV at --csv is replaced only when it is an earlier estimates CSV (its header starts frame, time_s,
# status): a synthetic clip's truth.csv (frame, time_s, s_true, ...) or any other file is refused, untouched.
# mutants caught: the replaces test not passed by ar run (truth.csv accepted: the size error comes instead), the
# header test always false (an earlier estimates CSV refused)
def test_csv_over_another_file_refused(tmp_path):
    proj = _project(tmp_path, None)
    v = _video(tmp_path / "half.mp4", 640, 360)
    truth = tmp_path / "truth.csv"
    truth.write_text("frame,time_s,s_true,rx\n0,0.0,0.1,0.0\n")
    r = runner.invoke(app, ["ar", "run", str(proj), str(v), "--csv", str(truth)])
    assert r.exit_code == 2 and "truth.csv: exists and does not look like an earlier estimates CSV" in r.output, r.output
    assert truth.read_text() == "frame,time_s,s_true,rx\n0,0.0,0.1,0.0\n"
    est = tmp_path / "est.csv"
    est.write_text("frame,time_s,status,s_est\n0,0.0,lost,nan\n")
    r = runner.invoke(app, ["ar", "run", str(proj), str(v), "--csv", str(est)])
    assert r.exit_code == 2 and "is 640x360 but" in r.output, r.output  # got past the destination check


# an empty file (touch, mktemp) at --csv is replaced (review); a portrait video of another size than the
# landscape calibration is named as turned, not as another crop (review: 360x640 against 1280x720)
def test_empty_csv_and_turned_resized_video(tmp_path):
    proj = _project(tmp_path, None)
    v = _video(tmp_path / "half.mp4", 640, 360)
    (tmp_path / "e.csv").write_text("")
    r = runner.invoke(app, ["ar", "run", str(proj), str(v), "--csv", str(tmp_path / "e.csv")])
    assert r.exit_code == 2 and "is 640x360 but" in r.output, r.output  # past the destination check
    from physar.vision.camera import Camera

    cam = Camera.from_fov(1280, 720, 60)
    assert "turned 90 deg" in cam.size_hint(360, 640) and "turned 90 deg" in cam.size_hint(720, 1280)
    assert "aspect ratio differs" in cam.size_hint(480, 480)
