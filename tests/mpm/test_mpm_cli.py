"""`physar mpm run|identify` through typer's CliRunner on tiny scenes; numbers checked against closed forms."""

import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from physar.cli.mpm import register
from physar.mpm.io import CSV_COLUMNS, read_particles_ply, read_trajectory

TINY = """
[grid]
size = 1.0
resolution = 8
[time]
frame_dt = 0.02
substeps = 20
frames = 4
[gravity]
g = [0, 0, -9.81]
[boundary]
ground = "slip"
[[body]]
shape = "box"
min = [0.375, 0.375, 0.5]
max = [0.625, 0.625, 0.75]
particles_per_cell = 8
material = "fixed_corotated"
E = 1e4
nu = 0.3
density = 500
velocity = [0.3, 0, 0.5]
"""


@pytest.fixture()
def app():
    a = typer.Typer()
    register(a)
    return a


def _write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_run_json_follows_free_fall_and_writes_outputs(app, tmp_path):
    scene = _write(tmp_path, TINY)
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["mpm", "run", str(scene), "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert set(d) == {"frames", "time", "com", "momentum", "kinetic_energy"}
    assert d["frames"] == 4 and len(d["time"]) == len(d["com"]) == len(d["momentum"]) == 5
    t = np.asarray(d["time"])
    assert np.allclose(t, 0.02 * np.arange(5))
    # free flight (the block stays far from every wall): closed forms for a rigid body under gravity
    mass = 500 * 0.25 * 0.25 * 0.25
    v0, g = np.array([0.3, 0, 0.5]), np.array([0, 0, -9.81])
    com = np.asarray(d["com"])
    # symplectic Euler (v += dt g, then x += dt v) gives exactly x0 + v0 t + g t (t + dt) / 2, dt = substep
    exact = com[0] + v0 * t[:, None] + 0.5 * g * t[:, None] * (t[:, None] + 0.001)
    assert np.max(np.abs(com - exact)) < 1e-9
    assert np.allclose(com[0], [0.5, 0.5, 0.625], atol=1e-12)
    p_exact = mass * (v0 + g * t[:, None])
    assert np.allclose(d["momentum"], p_exact, rtol=0, atol=1e-9 * mass)
    ke_exact = 0.5 * mass * np.sum((v0 + g * t[:, None]) ** 2, axis=1)
    assert np.allclose(d["kinetic_energy"], ke_exact, rtol=1e-6)
    # outputs: one PLY per frame whose centroid is the JSON COM, the CSV and an MP4 preview
    frames = read_trajectory(out)
    assert len(frames) == 5
    for f, fr in enumerate(frames):
        assert np.allclose(fr["x"].mean(0), com[f], atol=1e-12)
    last = read_particles_ply(out / "frame_0004.ply")
    assert np.allclose(last["v"].mean(0), v0 + g * t[-1], atol=1e-9)
    rows = (out / "diagnostics.csv").read_text().strip().splitlines()
    assert rows[0].split(",") == CSV_COLUMNS and len(rows) == 6
    assert np.allclose([float(v) for v in rows[-1].split(",")[5:8]], p_exact[-1], atol=1e-9 * mass)
    mp4 = (out / "preview.mp4").read_bytes()
    assert len(mp4) > 1000 and mp4[4:8] == b"ftyp"
    assert not list(out.glob("*.tmp")) and not list(out.glob("tmp_*"))


def test_run_human_output_and_no_preview(app, tmp_path):
    scene = _write(tmp_path, TINY.replace("frames = 4", "frames = 1"))
    out = tmp_path / "o2"
    r = CliRunner().invoke(app, ["mpm", "run", str(scene), "-o", str(out), "--no-preview"])
    assert r.exit_code == 0, r.output
    assert "particles" in r.output and not (out / "preview.mp4").exists()
    assert len(list(out.glob("frame_*.ply"))) == 2


@pytest.mark.parametrize("text,needle", [
    (TINY.replace('material = "fixed_corotated"', 'material = "jelly"'), "jelly"),
    (TINY.replace("resolution = 8", "resolution = 2"), "grid.resolution"),
    (TINY.replace("[grid]", "[grid\n"), "invalid TOML"),
    (TINY.replace("max = [0.625, 0.625, 0.75]", "max = [0.625, 0.625, 1.5]"), "outside the domain"),
])
def test_run_bad_scene_exit_code_2(app, tmp_path, text, needle):
    scene = _write(tmp_path, text)
    r = CliRunner().invoke(app, ["mpm", "run", str(scene), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2
    assert needle in r.output and "error:" in r.output


def test_missing_scene_and_bad_target(app, tmp_path):
    r = CliRunner().invoke(app, ["mpm", "run", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "does not exist" in r.output
    scene = _write(tmp_path, TINY)
    r = CliRunner().invoke(app, ["mpm", "identify", str(scene), "--target", str(tmp_path)])
    assert r.exit_code == 2 and "frame_" in r.output
    (tmp_path / "frame_0000.ply").write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    r = CliRunner().invoke(app, ["mpm", "identify", str(scene), "--target", str(tmp_path)])
    assert r.exit_code == 2 and "frame_0000.ply" in r.output
