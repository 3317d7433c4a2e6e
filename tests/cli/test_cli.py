"""The `physar` command: version, JSON output, and one-line errors with exit code 2 for bad input."""

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

import physar
from physar.cli.main import app

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "cantilever.toml"
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_version_and_help():
    r = run("--version")
    assert r.exit_code == 0 and physar.__version__ in r.stdout
    r = run("--help")
    assert r.exit_code == 0 and "fem" in r.stdout and "mesh" in r.stdout


def test_mesh_box(tmp_path):
    out = tmp_path / "beam.vtu"
    r = run("mesh", "box", "--size", 1, 0.1, 0.1, "--cells", 10, 1, 1, "-o", out, "--json")
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    assert info["tetrahedra"] == 60 and out.exists()
    r = run("mesh", "box", "--size", 1, -0.1, 0.1, "--cells", 10, 1, 1, "-o", tmp_path / "bad.vtu")
    assert r.exit_code == 2 and "positive" in r.output and not (tmp_path / "bad.vtu").exists()


def test_fem_solve_json(tmp_path):
    out = tmp_path / "result.vtu"
    r = run("fem", "solve", EXAMPLE, "--out", out, "--json")
    assert r.exit_code == 0, r.output
    res = json.loads(r.stdout)
    assert {"max_displacement", "probes", "newton_iterations"} <= set(res)
    tip = res["probes"][0]["u"][2]
    # 1 kN on a 1 x 0.05 x 0.05 m aluminium cantilever: Timoshenko gives 9.2935 mm
    assert tip == pytest.approx(-9.2935e-3, rel=0.02)
    import meshio

    m = meshio.read(out)
    assert {"displacement", "von_mises"} <= set(m.point_data)


def _write(tmp_path, text, name="case.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


BASE = EXAMPLE.read_text()


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda s: s.replace("nu = 0.334", "nuu = 0.334"), r"unknown key 'nuu' in \[material\]"),
        (lambda s: s.replace('model = "linear"', 'model = "rubber"'), r"material.model = 'rubber'"),
        (lambda s: s.replace("box = [1.0, 0.05, 0.05]\ncells = [40, 2, 2]", 'file = "missing.vtu"'),
         r"mesh file not found: .*missing.vtu"),
        (lambda s: s[: s.index("[[fix]]")] + s[s.index("[[load]]"):], r"not constrained"),
        (lambda s: s.replace("box = [[0, 0, 0], [0, 0.05, 0.05]]", "box = [[0, 0, 0], [0, 0.05, 0]]\ncomponents = [\"x\"]"),
         r"not fully constrained"),
        (lambda s: s + "\n[solver]\nsteps = 0\n", r"solver.steps"),
        (lambda s: s.replace("[mesh]", "[mesh\n"), r"invalid TOML"),
        (lambda s: s.replace("point = [1.0, 0.025, 0.025]", "point = [2.0, 0.025, 0.025]"), r"outside the mesh"),
    ],
)
def test_bad_input_one_line_exit_2_no_output(tmp_path, mutate, message):
    cfg = _write(tmp_path, mutate(BASE))
    out = tmp_path / "out.vtu"
    r = run("fem", "solve", cfg, "--out", out)
    assert r.exit_code == 2, r.output
    err = r.stderr.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: ")
    assert re.search(message, err), err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_missing_config(tmp_path):
    r = run("fem", "solve", tmp_path / "nope.toml", "--out", tmp_path / "o.vtu")
    assert r.exit_code == 2 and "config file not found" in r.stderr


def test_demo_writes_outputs(tmp_path):
    r = run("demo", "--scene", "cantilever", "--out", tmp_path, "--json")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["relative_error"] < 0.02
    for f in rep["files"]:
        assert (tmp_path / f).stat().st_size > 0
