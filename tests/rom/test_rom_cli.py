"""`physar rom build|info|eval` and `physar assimilate` vs `physar fem solve` of the same problem."""
import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from physar.cli import fem, rom

app = typer.Typer()
rom.register(app)
fem.register(app)
runner = CliRunner(mix_stderr=False) if "mix_stderr" in CliRunner.__init__.__code__.co_varnames else CliRunner()

BASE = """
[mesh]
box = [1.0, 0.1, 0.1]
cells = [12, 2, 2]

[material]
model = "{material}"
E = 1e7
nu = 0.3

[[fix]]
box = [[0, 0, 0], [0, 0.1, 0.1]]

[fem]
element = "P2"
"""
PARAM = """
[[parameter]]
name = "s"
kind = "load_position"
path = [[0.0, 0.05, 0.1], [1.0, 0.05, 0.1]]
points = {points}
load = [0, 0, {P}]
radius = 0.1
"""


def _run(*args):
    res = runner.invoke(app, [str(a) for a in args])
    return res


def _fem_probe(tmp_path, s, pts, material="linear", P=-1.0, steps=1, cells="[12, 2, 2]"):
    toml = BASE.format(material=material).replace("[12, 2, 2]", cells) + f"""
[[load]]
type = "point"
point = [{s}, 0.05, 0.1]
total = [0, 0, {P}]
radius = 0.1

[solver]
steps = {steps}
""" + "".join(f"\n[[probe]]\npoint = [{p[0]}, {p[1]}, {p[2]}]\n" for p in pts)
    f = tmp_path / f"fem_{s}.toml"
    f.write_text(toml)
    res = _run("fem", "solve", f, "--out", tmp_path / "fem.vtu", "--json")
    assert res.exit_code == 0, res.output
    return np.array([p["u"] for p in json.loads(res.stdout)["probes"]])


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rom")
    cfg = tmp / "rom.toml"
    cfg.write_text(BASE.format(material="linear") + PARAM.format(points=81, P=-1.0)
                   + '\n[rom]\nmethod = "pgd"\nmax_modes = 20\ntol = 1e-6\n')
    res = _run("rom", "build", cfg, "--out", tmp / "m.npz", "--json")
    assert res.exit_code == 0, res.output
    return tmp, json.loads(res.stdout)


def test_build_and_info(built):
    tmp, summary = built
    assert summary["n_modes"] <= 20 and summary["check_error"] < 1e-3
    res = _run("rom", "info", tmp / "m.npz", "--json")
    assert res.exit_code == 0, res.output
    info = json.loads(res.stdout)
    assert info["method"] == "pgd" and info["parameters"][0]["name"] == "s" and info["radius"] == 0.1


@pytest.mark.parametrize("s", [0.3, 0.77])
def test_rom_eval_equals_fem_solve(built, tmp_path, s):
    tmp, _ = built
    probe = [1.0, 0.05, 0.05]
    res = _run("rom", "eval", tmp / "m.npz", "--param", f"s={s}", "--probe", *probe, "--json")
    assert res.exit_code == 0, res.output
    u_rom = np.array(json.loads(res.stdout)["probes"][0]["u"])
    u_fem = _fem_probe(tmp_path, s, [probe])[0]
    assert np.linalg.norm(u_rom - u_fem) <= 1e-3 * np.linalg.norm(u_fem)


def test_assimilate_cli(built, tmp_path):
    tmp, _ = built
    pts = np.stack([np.linspace(0.05, 0.95, 20), np.zeros(20), np.full(20, 0.05)], 1)
    s_true = 0.62
    u = _fem_probe(tmp_path, s_true, pts)
    obs = tmp_path / "obs.csv"
    obs.write_text("x,y,z,ux,uy,uz\n" + "".join(",".join(f"{v:.12e}" for v in (*p, *d)) + "\n"
                                               for p, d in zip(pts, u)))
    res = _run("assimilate", tmp / "m.npz", obs, "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert set(out) >= {"params", "std", "residual", "iterations", "time_us"}
    assert abs(out["params"]["s"] - s_true) < 1e-3 and out["std"]["s"] < 1e-3
    assert "warning:" not in res.stderr  # mutant: the "explains nothing" warning on a good fit (threshold 0)
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,z,ux,uy\n0,0,0,0,0\n")
    res = _run("assimilate", tmp / "m.npz", bad)
    assert res.exit_code == 2 and "missing column(s) uz" in res.stderr


def test_user_errors(built, tmp_path):
    tmp, _ = built
    res = _run("rom", "eval", tmp / "m.npz", "--param", "q=0.3")
    assert res.exit_code == 2 and "NAME=VALUE with NAME one of ['s']" in res.stderr
    res = _run("rom", "eval", tmp / "m.npz", "--param", "s=3")
    assert res.exit_code == 2 and "outside the model's range" in res.stderr
    cfg = tmp_path / "nl.toml"
    cfg.write_text(BASE.format(material="stvk") + PARAM.format(points=11, P=-1.0) + '\n[rom]\nmethod = "pgd"\n')
    res = _run("rom", "build", cfg, "--out", tmp_path / "x.npz")
    assert res.exit_code == 2 and "pgd_nonintrusive" in res.stderr and not (tmp_path / "x.npz").exists()
    cfg.write_text(BASE.format(material="linear") + PARAM.format(points=11, P=-1.0) + '\n[rom]\nmodes = 3\n')
    res = _run("rom", "build", cfg, "--out", tmp_path / "x.npz")
    assert res.exit_code == 2 and "unknown key 'modes' in [rom]" in res.stderr
    cfg.write_text(BASE.format(material="linear") + PARAM.format(points=11, P=-1.0).replace("radius = 0.1\n", ""))
    res = _run("rom", "build", cfg, "--out", tmp_path / "x.npz")
    assert res.exit_code == 2 and "needs radius" in res.stderr
    cfg.write_text(BASE.format(material="linear") + PARAM.format(points=11, P=-1.0)
                   + "\n[rom]\ncheck_points = 0\ncheck_tol = 1e-3\n")
    res = _run("rom", "build", cfg, "--out", tmp_path / "x.npz")
    assert res.exit_code == 2 and "check_tol needs check_points > 0" in res.stderr
    np.savez(tmp_path / "v9.npz", format_version=np.array(9))
    res = _run("rom", "info", tmp_path / "v9.npz")
    assert res.exit_code == 2 and "format version 9" in res.stderr


@pytest.mark.slow
def test_nonintrusive_cli_matches_fem_solve(tmp_path):
    cfg = tmp_path / "nl.toml"
    cfg.write_text(BASE.format(material="stvk").replace("[12, 2, 2]", "[10, 1, 1]") + PARAM.format(points=5, P=-60.0)
                   + '\n[solver]\nsteps = 4\n\n[rom]\nmethod = "pgd_nonintrusive"\ntol = 2e-3\n')
    res = _run("rom", "build", cfg, "--out", tmp_path / "nl.npz", "--json", "--workers", 2)
    assert res.exit_code == 0, res.output
    probe = [1.0, 0.05, 0.05]
    res = _run("rom", "eval", tmp_path / "nl.npz", "--param", "s=0.71", "--probe", *probe, "--json")
    u_rom = np.array(json.loads(res.stdout)["probes"][0]["u"])
    u_fem = _fem_probe(tmp_path, 0.71, [probe], material="stvk", P=-60.0, steps=4, cells="[10, 1, 1]")[0]
    assert np.linalg.norm(u_rom - u_fem) <= 1e-2 * np.linalg.norm(u_fem)


def test_patch_load_pgd_cli_matches_fem_solve(tmp_path):
    """Intrusive PGD in three parameters (s along the path, lateral offset t, magnitude P) from
    `rom build`; `rom eval` at (s, t, P) against `fem solve` with the point load at path(s) + t e_y."""
    cfg = tmp_path / "patch.toml"
    base = BASE.format(material="linear").replace("[1.0, 0.1, 0.1]", "[1.0, 0.2, 0.1]").replace(
        "[12, 2, 2]", "[10, 4, 1]").replace("[0, 0.1, 0.1]]", "[0, 0.2, 0.1]]")
    cfg.write_text(base + """
[[parameter]]
name = "s"
kind = "load_position"
path = [[0.0, 0.1, 0.1], [1.0, 0.1, 0.1]]
points = 41
load = [0, 0, -1.0]
radius = 0.1

[[parameter]]
name = "t"
kind = "load_offset"
range = [-0.06, 0.06]
direction = [0, 1, 0]
points = 9

[[parameter]]
name = "P"
kind = "load_magnitude"
range = [0.5, 2.0]

[rom]
method = "pgd"
max_modes = 40
tol = 1e-6
""")
    res = _run("rom", "build", cfg, "--out", tmp_path / "p.npz", "--json")
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert [p["name"] for p in summary["parameters"]] == ["s", "P", "t"]
    probe = [1.0, 0.0, 0.05]  # a tip corner: sees torsion as well as bending
    for s, t, P in ((0.43, 0.037, 1.7), (0.86, -0.052, 0.8)):
        res = _run("rom", "eval", tmp_path / "p.npz", "--param", f"s={s}", "--param", f"t={t}",
                   "--param", f"P={P}", "--probe", *probe, "--json")
        assert res.exit_code == 0, res.output
        u_rom = np.array(json.loads(res.stdout)["probes"][0]["u"])
        toml = base + f"""
[[load]]
type = "point"
point = [{s}, {0.1 + t}, 0.1]
total = [0, 0, {-P}]
radius = 0.1

[[probe]]
point = [{probe[0]}, {probe[1]}, {probe[2]}]
"""
        f = tmp_path / "fem_patch.toml"
        f.write_text(toml)
        r = _run("fem", "solve", f, "--out", tmp_path / "fem.vtu", "--json")
        assert r.exit_code == 0, r.output
        u_fem = np.array(json.loads(r.stdout)["probes"][0]["u"])
        assert np.linalg.norm(u_rom - u_fem) <= 1e-3 * np.linalg.norm(u_fem), (s, t, u_rom, u_fem)
