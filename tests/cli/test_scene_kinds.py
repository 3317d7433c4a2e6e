"""`physar scene render|model` dispatch on the scene's `name` (cantilever | foam | seal)."""
import csv
import json
from pathlib import Path

import av
import numpy as np
from typer.testing import CliRunner

from physar.cli.main import app

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
runner = CliRunner()


def _small(src: Path, dst: Path) -> Path:
    text = src.read_text()
    text = text.replace("width = 1280", "width = 320").replace("height = 720", "height = 180")
    lines = ["duration = 1.0" if ln.startswith("duration =") else ln for ln in text.splitlines()]
    dst.write_text("\n".join(lines) + "\n")
    return dst


def test_seal_scene_render_and_model(tmp_path):
    scene = _small(EXAMPLES / "scene_seal.toml", tmp_path / "seal.toml")
    r = runner.invoke(app, ["scene", "render", str(scene), "-o", str(tmp_path / "out"), "--json"])
    assert r.exit_code == 0, r.output
    res = json.loads(r.stdout)
    assert res["frames"] == 30 and (res["width"], res["height"]) == (320, 180)
    with av.open(str(tmp_path / "out" / "scene.mp4")) as c:
        assert sum(1 for _ in c.decode(video=0)) == 30
    with open(tmp_path / "out" / "truth.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 30
    for name in ("plate.json", "plate.png", "camera.toml"):
        assert (tmp_path / "out" / name).stat().st_size > 0

    model = tmp_path / "seal.npz"
    r = runner.invoke(app, ["scene", "model", str(scene), "-o", str(model), "--json"])
    assert r.exit_code == 0, r.output
    from physar.rom import SeparatedModel

    rom = SeparatedModel.load(model)
    assert rom.names == ["theta"]
    lo, hi = rom.ranges[0]
    assert lo == 0.0 and hi == 52.0
    # the lever rotation is imposed: at theta = 0 the seal is at rest, beyond it the field is not zero
    assert np.abs(rom.evaluate([0.0])).max() < 1e-9 * max(1.0, np.abs(rom.evaluate([40.0])).max())
    assert np.abs(rom.evaluate([40.0])).max() > 0
    assert (tmp_path / "seal_von_mises.npz").exists()


def test_scene_render_bad_file(tmp_path):
    r = runner.invoke(app, ["scene", "render", str(tmp_path / "nope.toml"), "-o", str(tmp_path / "o")])
    assert r.exit_code == 2 and "scene file not found" in r.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    r = runner.invoke(app, ["scene", "render", str(bad), "-o", str(tmp_path / "o")])
    assert r.exit_code == 2 and "not valid TOML" in r.stderr
    assert not (tmp_path / "o").exists()
