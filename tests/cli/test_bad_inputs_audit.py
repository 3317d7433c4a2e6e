"""Issue 21, second audit: bad inputs tried by an outside tester (63 new cases across the commands, not in
test_bad_inputs*.py, signals in ar run and rom build included; 61 were already clean). The two that were not, fixed at their layer:

* a ``[[load]] total`` with nan reached the solver and was reported as "the linear solve produced NaN or inf
  (singular system?)" after the assembly: every number of the fem/rom/dynamics configs is now refused when
  not finite (``allow_inf_nan=False`` on ``physar.fem.config._Strict``), naming the field;
* ``fem solve -o`` a symbolic link to the problem's own ``[mesh] file`` replaced the link with the result
  (``mesh convert`` already refused it as the same file): the mesh file is now an input of the destination
  check.

Each case: exit 2, one ``error:`` line naming the file and field or value, nothing created, changed or deleted.
The mutant each catches is in its comment.
"""
import os
import shutil
from pathlib import Path

import pytest
from test_bad_inputs import assert_refused, snapshot
from typer.testing import CliRunner

from physar.cli.main import app

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.mark.parametrize("old,new,needle", [
    # mutant: allow_inf_nan left on (nan reaches the solver: "singular system?" after the assembly)
    ("total = [0, 0, -1000]", "total = [0, 0, nan]", "c.toml: load.0.total.2: Input should be a finite number (got nan)"),
    # mutant: the same, on a material constant and a probe point
    ("E = 69e9", "E = inf", "c.toml: material.E: Input should be a finite number (got inf)"),
    ("point = [1.0, 0.025, 0.025]", "point = [1.0, nan, 0.025]", "c.toml: probe.0.point.1: Input should be a finite"),
])
def test_fem_config_non_finite_number(tmp_path, old, new, needle):
    text = (EXAMPLES / "cantilever.toml").read_text()
    assert old in text
    (tmp_path / "c.toml").write_text(text.replace(old, new))
    before = snapshot(tmp_path)
    assert_refused(invoke("fem", "solve", tmp_path / "c.toml", "-o", tmp_path / "r.vtu"), needle, before, tmp_path)


def test_rom_config_non_finite_number(tmp_path):
    # mutant: allow_inf_nan left on in the configs built on physar.fem.config._Strict (rom build)
    text = (EXAMPLES / "rom_cantilever.toml").read_text()
    assert "nu = 0.3\n" in text
    (tmp_path / "r.toml").write_text(text.replace("nu = 0.3\n", "nu = nan\n"))
    before = snapshot(tmp_path)
    assert_refused(invoke("rom", "build", tmp_path / "r.toml", "-o", tmp_path / "r.npz"),
                   "r.toml: material.nu: Input should be a finite number (got nan)", before, tmp_path)


def test_fem_solve_output_linked_to_its_mesh_file(tmp_path):
    # mutant: only the problem file given to the destination check (the result replaces the user's link)
    from physar.geometry import box_mesh, write_mesh

    write_mesh(tmp_path / "beam.vtu", box_mesh((1.0, 0.05, 0.05), (8, 1, 1)))
    text = (EXAMPLES / "cantilever.toml").read_text()
    assert "box = [1.0, 0.05, 0.05]\ncells = [40, 2, 2]" in text
    (tmp_path / "c.toml").write_text(text.replace("box = [1.0, 0.05, 0.05]\ncells = [40, 2, 2]",
                                                  'file = "beam.vtu"'))
    os.symlink(tmp_path / "beam.vtu", tmp_path / "link.vtu")
    before = snapshot(tmp_path)
    assert_refused(invoke("fem", "solve", tmp_path / "c.toml", "-o", tmp_path / "link.vtu"),
                   "link.vtu: result mesh destination is the same file as the input", before, tmp_path)
    assert (tmp_path / "link.vtu").is_symlink()
    shutil.rmtree(tmp_path)
