"""`physar rom info --check`, parameter kinds in `rom info`, output paths of `rom build`/`rom eval` refused before
any work (one line, exit 2, nothing written), the grid-size limit of `rom build`, repeated `rom eval --probe`."""
import json
import time

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from physar.cli import rom
from physar.rom import SeparatedModel
from physar.rom.config import load_rom_config
from physar.rom.quality import discretisation_error

app = typer.Typer()
rom.register(app)
runner = CliRunner(mix_stderr=False) if "mix_stderr" in CliRunner.__init__.__code__.co_varnames else CliRunner()

CONFIG = """
[mesh]
box = [1.0, 0.1, 0.1]
cells = [10, 1, 1]

[material]
model = "linear"
E = 1e9
nu = 0.3

[[fix]]
box = [[0, 0, 0], [0, 0.1, 0.1]]

[fem]
element = "P2"

[[parameter]]
name = "s"
kind = "load_position"
path = [[0.0, 0.05, 0.1], [1.0, 0.05, 0.1]]
points = {points}
load = [0, 0, -1.0]
radius = 0.04

[[parameter]]
name = "P"
kind = "load_magnitude"
range = [0.5, 2.0]
"""


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


def _one_line_error(res, *words):
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert "Traceback" not in res.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("romcli")
    cfg = tmp / "rom.toml"
    cfg.write_text(CONFIG.format(points=21))
    res = _run("rom", "build", cfg, "--out", tmp / "m.npz")
    assert res.exit_code == 0, res.output
    return cfg, tmp / "m.npz"


def test_info_lists_each_parameters_kind_range_and_unit(built):
    _, model = built
    res = _run("rom", "info", model, "--json")
    assert res.exit_code == 0, res.output
    params = json.loads(res.stdout)["parameters"]
    assert [(p["name"], p["kind"], p["range"], p["unit"]) for p in params] == [
        ("s", "load_position", [0.0, 1.0], "m"), ("P", "load_magnitude", [0.5, 2.0], "N")]
    res = _run("rom", "info", model)
    assert "parameter s: load_position, range [0, 1] m, 21 grid points" in res.stderr
    assert "parameter P: load_magnitude, range [0.5, 2] N" in res.stderr


def test_info_check_reports_the_discretisation_error(built):
    """--check CONFIG: the errors of physar.rom.quality.discretisation_error (tested against closed forms in
    test_quality.py) in the JSON and as lines; a configuration the model was not built from is one line."""
    cfg, model = built
    res = _run("rom", "info", model, "--check", cfg, "--check-points", 2, "--json")
    assert res.exit_code == 0, res.output
    check = json.loads(res.stdout)["check"]
    ref = discretisation_error(load_rom_config(cfg), SeparatedModel.load(model), points=2).summary()
    for k in ("displacement_l2", "displacement_max", "stress_l2", "stress_max", "away_l2", "away_max", "fine_dofs"):
        assert check[k] == pytest.approx(ref[k], rel=1e-9), k
    assert len(check["points"]) == 2 and check["points"][1]["params"]["s"] == 1.0
    assert 0 < check["displacement_max"] < 0.1 and check["refine"] == 2
    res = _run("rom", "info", model, "--check", cfg, "--check-points", 1)
    assert res.exit_code == 0
    assert "displacement" in res.stderr and "from supports and load" in res.stderr and "finer mesh" in res.stderr
    other = cfg.parent / "other.toml"
    other.write_text(CONFIG.format(points=21).replace("[10, 1, 1]", "[12, 1, 1]"))
    _one_line_error(_run("rom", "info", model, "--check", other), "other.toml", "not the configuration it was built")


@pytest.mark.parametrize("kind", ["folder", "suffix", "same_as_config", "parent_is_a_file"])
def test_build_refuses_a_bad_output_before_any_work(tmp_path, kind):
    cfg = tmp_path / "rom.toml"
    cfg.write_text(CONFIG.format(points=21))
    (tmp_path / "dir.npz").mkdir()
    (tmp_path / "afile").write_text("x")
    out = {"folder": tmp_path / "dir.npz", "suffix": tmp_path / "m.txt", "same_as_config": cfg,
           "parent_is_a_file": tmp_path / "afile" / "m.npz"}[kind]
    before = sorted(p.name for p in tmp_path.iterdir())
    _one_line_error(_run("rom", "build", cfg, "--out", out), str(out))
    assert sorted(p.name for p in tmp_path.iterdir()) == before and cfg.read_text() == CONFIG.format(points=21)


@pytest.mark.parametrize("points", ["1e7", "10000000"])
def test_build_refuses_a_huge_parameter_grid_at_once(tmp_path, points):
    """points = 1e7 (the sampled loads alone would take 6 GB on this small mesh, 480 GB on the AR cantilever;
    before: memory grew without progress): one line naming file, field and value, at once, nothing written.
    The limit itself lives in physar.rom.config."""
    cfg = tmp_path / "rom.toml"
    cfg.write_text(CONFIG.format(points=points))
    t0 = time.perf_counter()
    res = _run("rom", "build", cfg, "--out", tmp_path / "m.npz")
    assert time.perf_counter() - t0 < 5
    _one_line_error(res, "rom.toml", "points", "10000000")
    assert not (tmp_path / "m.npz").exists()
    cfg.write_text(CONFIG.format(points=21) + '\n[rom]\nmethod = "pgd_nonintrusive"\nmax_points = 100000\n')
    _one_line_error(_run("rom", "build", cfg, "--out", tmp_path / "m.npz"), "max_points", "100000")


def test_eval_keeps_every_repeated_probe(built):
    """Two --probe options give two probes, each equal to the probe asked alone (before: only the last)."""
    _, model = built
    a, b = [1.0, 0.05, 0.05], [0.5, 0.0, 0.1]
    res = _run("rom", "eval", model, "--param", "s=0.8", "--param", "P=1.5", "--probe", *a, "--probe", *b, "--json")
    assert res.exit_code == 0, res.output
    probes = json.loads(res.stdout)["probes"]
    assert [p["point"] for p in probes] == [a, b]
    for p in probes:
        alone = _run("rom", "eval", model, "--param", "s=0.8", "--param", "P=1.5", "--probe", *p["point"], "--json")
        assert json.loads(alone.stdout)["probes"][0]["u"] == p["u"]
    assert np.linalg.norm(probes[0]["u"]) > np.linalg.norm(probes[1]["u"]) > 0  # the tip moves most
    _one_line_error(_run("rom", "eval", model, "--param", "s=0.8", "--param", "P=1", "--probe", 1, 2, "x"),
                    "--probe 1 2 x", "three numbers")


@pytest.mark.parametrize("kind", ["suffix", "same_as_model", "folder"])
def test_eval_refuses_a_bad_output_before_any_work(built, tmp_path, kind):
    _, model = built
    (tmp_path / "d.vtu").mkdir()
    out = {"suffix": tmp_path / "u.png", "same_as_model": model, "folder": tmp_path / "d.vtu"}[kind]
    size = model.stat().st_size
    _one_line_error(_run("rom", "eval", model, "--param", "s=0.5", "--param", "P=1", "--out", out), str(out))
    assert model.stat().st_size == size and sorted(p.name for p in tmp_path.iterdir()) == ["d.vtu"]
