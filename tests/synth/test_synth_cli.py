"""`physar synth render|score` on bad input: one line naming the file/field/value, exit 2, nothing written."""
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from physar.cli.main import app

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    d = tmp_path_factory.mktemp("p")
    for f in ("project.toml", "rom.toml"):
        shutil.copy(EXAMPLES / "ar" / "cantilever" / f, d / f)
    shutil.copy(EXAMPLES / "camera_720p.toml", d / "camera.toml")
    (d / "project.toml").write_text((d / "project.toml").read_text().replace("../../camera_720p.toml", "camera.toml"))
    return d / "project.toml"


@pytest.mark.parametrize("text, msg", [
    ('[video]\nfps = "30"\n', "[video.fps] expected a number, got the string '30'"),   # lax coercion mutant
    ("seed = true\n", "[seed] expected an integer, got true"),
    ("[camera]\nbogus = 1\n", "unknown key 'bogus' in [camera]"),
    ("[schedule.zz]\nkeyframes = [[0, 1.0]]\n", "'zz' is not a parameter of the model"),
    ("[schedule.s]\nkeyframes = [[0, 5.0]]\n", "value 5.0 at t = 0.0 s is outside the model's range"),
    ("[schedule.s]\nkeyframes = [[1, 0.2], [0.5, 0.3]]\n", "keyframe times must increase"),
])
def test_bad_scenario_one_line_nothing_written(project, tmp_path, text, msg):
    (tmp_path / "s.toml").write_text(text)
    r = CliRunner().invoke(app, ["synth", "render", str(project), "-s", str(tmp_path / "s.toml"),
                                 "--out", str(tmp_path / "clip")])
    assert r.exit_code == 2, r.output
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error:")]   # (a model build bar may precede)
    assert len(errors) == 1 and msg in errors[0] and "Traceback" not in r.output
    assert not (tmp_path / "clip").exists()


def test_bad_destinations(project, tmp_path):
    """A folder with someone else's file is refused and left as it was; a file as --out; an uncreatable folder."""
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    cases = [(tmp_path / "mine", "holds no previous clip"), (project, "--out must be a folder"),
             (Path("/proc/physar_nope/clip"), "its parent /proc is not writable")]
    for out, msg in cases:
        r = CliRunner().invoke(app, ["synth", "render", str(project), "--out", str(out)])
        assert r.exit_code == 2 and msg in r.output and "Traceback" not in r.output, r.output
    assert [p.name for p in (tmp_path / "mine").iterdir()] == ["notes.txt"]
    r = CliRunner().invoke(app, ["synth", "score", str(tmp_path / "none.csv"), str(tmp_path / "est.csv")])
    assert r.exit_code == 2 and "none.csv: truth file not found" in r.output
