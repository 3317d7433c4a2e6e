"""`physar mesh convert` keeps gmsh physical-group names (a problem file's region = "clamp" still resolves after
.msh -> .vtu/.xdmf), warns once where a format keeps numbers only, and a problem file whose .msh holds only
surface groups says why there are no tetrahedra. The reference for a region is the geometric box selector on
the same face (x = 0), not physar's tag reader."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from typer.testing import CliRunner

from physar.cli.main import app
from physar.fem.config import build_problem, load_config

pytestmark = pytest.mark.skipif(importlib.util.find_spec("gmsh") is None, reason="needs the gmsh package")

runner = CliRunner()
L, W, H = 1.0, 0.2, 0.2


def _cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def _beam_msh(path, volume_group=True):
    """A gmsh beam L x W x H: face x = 0 'clamp' (dim 2), face x = L 'tip' (dim 2), solid 'body' (dim 3)."""
    from physar.geometry.tetra import _Gmsh

    with _Gmsh() as g:
        g.model.add("beam")
        g.model.occ.addBox(0, 0, 0, L, W, H)
        g.model.occ.synchronize()
        for _, t in g.model.getEntities(2):
            cx = g.model.occ.getCenterOfMass(2, t)[0]
            if np.isclose(cx, 0):
                g.model.addPhysicalGroup(2, [t], 1, name="clamp")
            elif np.isclose(cx, L):
                g.model.addPhysicalGroup(2, [t], 2, name="tip")
        if volume_group:
            g.model.addPhysicalGroup(3, [1], 3, name="body")
        g.option.setNumber("Mesh.MeshSizeMax", 0.1)
        g.model.mesh.generate(3)
        g.write(str(path))
    return path


def _config(tmp_path, mesh_file, fix, name):
    p = tmp_path / name
    p.write_text(f"""[mesh]
file = "{mesh_file}"

[material]
model = "linear"
E = 1e7
nu = 0.3

[[fix]]
{fix}

[[load]]
type = "traction"
box = [[{L}, 0, 0], [{L}, {W}, {H}]]
total = [0, 0, -1.0]

[fem]
element = "P1"
""")
    return p


# mutants caught: VTU FieldData / XDMF Information not written (region 'clamp' not in mesh), names read from
# the wrong place; the reference is the box selector on x = 0
@pytest.mark.parametrize("suffix", [".vtu", ".xdmf"])
def test_convert_keeps_region_names_for_a_problem_file(tmp_path, suffix):
    src = _beam_msh(tmp_path / "beam.msh")
    out = tmp_path / f"beam{suffix}"
    r = _cli("mesh", "convert", src, "--out", out)
    assert r.exit_code == 0, r.output
    assert "warning:" not in r.stderr, r.stderr
    by_region = build_problem(load_config(_config(tmp_path, out.name, 'region = "clamp"', "a.toml")),
                              base_dir=tmp_path)
    by_box = build_problem(load_config(_config(tmp_path, out.name, f"box = [[0, 0, 0], [0, {W}, {H}]]", "b.toml")),
                           base_dir=tmp_path)
    assert len(by_box.fixed) > 0
    np.testing.assert_array_equal(np.sort(by_region.fixed), np.sort(by_box.fixed))
    r = _cli("fem", "solve", tmp_path / "a.toml", "--out", tmp_path / "r.vtu")
    assert r.exit_code == 0, r.output


# mutant caught: a .mesh output without the warning (names dropped silently), or several warning lines
def test_convert_to_medit_warns_once_naming_the_regions(tmp_path):
    src = _beam_msh(tmp_path / "beam.msh")
    out = tmp_path / "beam.mesh"
    r = _cli("mesh", "convert", src, "--out", out)
    assert r.exit_code == 0, r.output
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1, r.stderr
    assert str(out) in warn[0] and "'clamp' = 1" in warn[0] and "'tip' = 2" in warn[0] and "'body' = 3" in warn[0]


# mutant caught: the surface-groups check removed (the problem file then fails later on the partial surface:
# "surface is not closed"), or a traceback / exit code 1
def test_problem_file_with_surface_groups_only_msh(tmp_path):
    src = _beam_msh(tmp_path / "beam.msh", volume_group=False)
    cfg = _config(tmp_path, src.name, 'region = "clamp"', "a.toml")
    r = _cli("fem", "solve", cfg, "--out", tmp_path / "r.vtu")
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    assert lines[0] == (f"error: {cfg}: {src}: no tetrahedra: gmsh saved only the elements of physical groups (surface "
                        "groups 'clamp', 'tip'; no volume group); add a volume physical group or set Mesh.SaveAll=1")
