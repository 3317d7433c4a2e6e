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


# ------------------------------------------------------------------------------------------------ corrupt models
OBS = "x,y,z,ux,uy,uz\n1.0,0.05,0.05,0,0,-1e-5\n0.5,0.05,0.05,0,0,-3e-6\n"


def _edited(built, tmp_path, key, edit):
    _, model = built
    z = dict(np.load(model))
    z[key] = edit(z[key].copy())
    bad = tmp_path / "bad.npz"
    np.savez(bad, **z)
    (tmp_path / "obs.csv").write_text(OBS)
    return bad


def _nan_first(F):
    F[0, 0] = np.nan
    return F


@pytest.mark.parametrize(("key", "edit", "words"), [
    ("F", lambda F: F[:, :100], ["bad.npz", "F has 100 columns", "DOFs"]),
    ("F", _nan_first, ["bad.npz", "F[0, 0] = nan is not a finite number"]),
    ("mesh_points", lambda p: p * np.nan, ["bad.npz", "mesh_points: point 0"]),
    ("grid_0", lambda g: g[::-1], ["bad.npz", "grid_0 (parameter 's') must be strictly increasing"]),
])
@pytest.mark.parametrize("command", ["eval", "assimilate", "info"])
def test_every_command_refuses_a_corrupt_model_in_one_line(built, tmp_path, key, edit, words, command):
    """Truncated modes made `rom eval` fail on a reshape and `assimilate` on a matmul (exit 1, a traceback), and
    `rom info` accept them; NaN modes gave `max displacement nan m`, exit 0; the mesh and grid errors did not
    name the file. Mutant: SeparatedModel.load without the shape/finiteness checks or the file name."""
    bad = _edited(built, tmp_path, key, edit)
    args = {"eval": ["rom", "eval", bad, "--param", "s=0.3", "--param", "P=1", "--probe", 1, 0.05, 0.05],
            "assimilate": ["assimilate", bad, tmp_path / "obs.csv"], "info": ["rom", "info", bad]}[command]
    _one_line_error(_run(*args), *words)


@pytest.mark.parametrize("args", [["rom", "eval", "{m}", "--param", "s=0.3", "--param", "P=2", "--param", "P=3"],
                                  ["assimilate", "{m}", "{obs}", "--mu0", "s=0.5", "--mu0", "s=0.7"]])
def test_a_parameter_given_twice_is_refused(built, tmp_path, args):
    # mutant: the last value silently wins (P=3, s=0.7)
    _, model = built
    (tmp_path / "obs.csv").write_text(OBS)
    args = [a.format(m=model, obs=tmp_path / "obs.csv") for a in args]
    flag = args[-2]
    name, first, last = ("P", "'P=2'", "'P=3'") if flag == "--param" else ("s", "'s=0.5'", "'s=0.7'")
    _one_line_error(_run(*args), f"{flag} given twice for {name} ({first} and {last})")


@pytest.mark.parametrize("uz", ["10", "-1e300"])
def test_assimilate_refuses_a_displacement_larger_than_the_body(built, tmp_path, uz):
    """uz = 10 m on a 1 m beam gave `s = 0 ± 6e+06 m`, uz = -1e300 overflow warnings, both exit 0. The body is the
    1 x 0.1 x 0.1 m box of CONFIG: its bounding-box diagonal is sqrt(1.02) = 1.01 m. Mutant: the CLI does not pass
    the body's size to read_observations."""
    _, model = built
    obs = tmp_path / "obs.csv"
    obs.write_text(f"x,y,z,ux,uy,uz\n1.0,0.05,0.05,0,0,-1e-5\n0.5,0.05,0.05,0,0,{uz}\n")
    _one_line_error(_run("assimilate", model, obs), "obs.csv", "line 3, column uz", "larger than the body",
                    "1.01 m")


def test_assimilate_warns_when_the_model_explains_nothing(built, tmp_path):
    """Observations of 0.05 m (within the body's size) at the tip of a beam that bends at most ~4e-5 m for the
    model's largest load (E = 1e9 Pa, P <= 2 N: P L^3 / (3 E I), I = 0.1^4 / 12, gives 8e-5 m): no parameter
    value explains them. Mutant: no warning (before: `residual 5e-02 m`, nothing else)."""
    _, model = built
    obs = tmp_path / "obs.csv"
    obs.write_text("x,y,z,ux,uy,uz\n1.0,0.05,0.05,0,0,-0.05\n0.5,0.05,0.05,0,0,-0.05\n")
    res = _run("assimilate", model, obs)
    assert res.exit_code == 0, res.output
    warn = [ln for ln in res.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and "unexplained" in warn[0] and "do not trust" in warn[0], res.stderr
    assert "Traceback" not in res.stderr


def test_build_refuses_dask_options_a_pgd_build_ignores(tmp_path):
    # mutant: --workers / [rom] workers silently ignored by method = "pgd" (e.g. --workers 100000)
    cfg = tmp_path / "rom.toml"
    cfg.write_text(CONFIG.format(points=21))
    _one_line_error(_run("rom", "build", cfg, "--out", tmp_path / "m.npz", "--workers", 100000),
                    "--workers: only for [rom] method = \"pgd_nonintrusive\"", "method = 'pgd'")
    cfg.write_text(CONFIG.format(points=21) + '\n[rom]\nmethod = "pgd"\nworkers = 4\n')
    _one_line_error(_run("rom", "build", cfg, "--out", tmp_path / "m.npz"), "rom.toml: [rom] workers: only for")
    cfg.write_text(CONFIG.format(points=21) + '\n[rom]\nscheduler = "tcp://x:1"\n')  # the default method: pgd
    _one_line_error(_run("rom", "build", cfg, "--out", tmp_path / "m.npz"), "scheduler: only for",
                    "the default method for this material is 'pgd'")
    assert not (tmp_path / "m.npz").exists()
