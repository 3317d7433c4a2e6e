"""`[mesh] max_elements` reaches the tetrahedraliser: a surface file whose estimated element count at `size`
is above it is refused in one line before gmsh runs (exit 2, no output). Catches: the key parsed but not passed
on (the 8 cm bracket at 2 mm gives a few thousand tetrahedra, far above 100, and would be meshed and solved)."""

from pathlib import Path

from typer.testing import CliRunner

from physar.cli.main import app

STL = Path(__file__).resolve().parents[2] / "examples" / "ar" / "bracket" / "bracket.stl"

TOML = """
[mesh]
{source}
[material]
model = "linear"
E = 7e10
nu = 0.3
[[fix]]
plane = {{point = [0, 0, 0], normal = [1, 0, 0]}}
"""


def _solve(tmp_path, source):
    cfg = tmp_path / "c.toml"
    cfg.write_text(TOML.format(source=source))
    return CliRunner().invoke(app, ["fem", "solve", str(cfg), "--out", str(tmp_path / "u.vtu")])


def test_max_elements_refuses_before_meshing(tmp_path):
    r = _solve(tmp_path, f'file = "{STL}"\nsize = 0.002\nmax_elements = 100')
    assert r.exit_code == 2, r.output
    assert "max_elements" in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "u.vtu").exists()


def test_max_elements_on_a_box_is_refused(tmp_path):
    r = _solve(tmp_path, "box = [1.0, 0.1, 0.1]\ncells = [4, 1, 1]\nmax_elements = 100")
    assert r.exit_code == 2, r.output
    assert "max_elements applies to a surface file" in r.output, r.output
