"""`physar simulate` outputs (new-user review, seed 001 pillar): the XDMF time series carries the region tags of
the input mesh on every frame (as the VTU of `physar fem solve` does), and the energy CSV's header carries units.

References: the tags of a gmsh-written .msh with two physical volumes, read by meshio (gmsh:physical), matched to
the output's tetrahedra by their vertex coordinates, and the names read by meshio's XDMF Information parser; for
the CSV, free fall from rest under g = 9.81 m/s^2, which the implicit midpoint rule integrates exactly (constant
acceleration): t_k = k h, kinetic M (g t)^2 / 2, potential -M g^2 t^2 / 2, elastic 0, M = density x volume."""

from __future__ import annotations

import csv
import importlib.util
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest
from typer.testing import CliRunner

from physar.cli.main import app

runner = CliRunner()

PROBLEM = """
[mesh]
{mesh}
[material]
model = "corotated"
E = 5e6
nu = 0.3
density = 500
[fem]
element = "P1"
{fix}
[dynamics]
method = "{method}"
h = {h}
steps = {steps}
gravity = [0, 0, -9.81]
"""


def _pillar_msh(path):
    """Two stacked boxes meshed by gmsh: physical volumes 'base' (tag 1, z < 0.05) and 'top' (tag 2)."""
    from physar.geometry.tetra import _Gmsh

    with _Gmsh() as g:
        g.model.add("pillar")
        a = g.model.occ.addBox(0, 0, 0, 0.02, 0.02, 0.05)
        b = g.model.occ.addBox(0, 0, 0.05, 0.02, 0.02, 0.05)
        g.model.occ.fragment([(3, a)], [(3, b)])
        g.model.occ.synchronize()
        z = {t: g.model.occ.getCenterOfMass(3, t)[2] for _, t in g.model.getEntities(3)}
        g.model.addPhysicalGroup(3, [t for t, c in z.items() if c < 0.05], 1, name="base")
        g.model.addPhysicalGroup(3, [t for t, c in z.items() if c > 0.05], 2, name="top")
        g.option.setNumber("Mesh.MeshSizeMax", 0.02)
        g.model.mesh.generate(3)
        g.write(str(path))


def _tags_by_cell(points, blocks):
    """{sorted vertex coordinates of a tetrahedron: tag} from (tetra connectivity, tags) blocks."""
    out = {}
    for conn, tags in blocks:
        for cell, t in zip(np.asarray(conn), np.asarray(tags).ravel(), strict=True):
            out[tuple(sorted(tuple(np.round(points[i], 12)) for i in cell))] = int(t)
    return out


# mutants caught: no cell_data written (no cell_tags on any frame); cell_tags on the first frame only (the later
# frames' Attribute not added); the tags in another order (cell_tags[::-1]: tetrahedra of 'top' read as 'base');
# the names not written (no Information); the tags written again for every frame (one .h5 dataset per frame)
@pytest.mark.skipif(importlib.util.find_spec("gmsh") is None, reason="needs the gmsh package")
def test_xdmf_time_series_keeps_region_tags(tmp_path):
    import h5py

    _pillar_msh(tmp_path / "pillar.msh")
    src = meshio.read(tmp_path / "pillar.msh")
    want = _tags_by_cell(src.points, [(c.data, t) for c, t in zip(src.cells, src.cell_data["gmsh:physical"])
                                      if c.type == "tetra"])
    assert sorted(set(want.values())) == [1, 2]
    cfg = tmp_path / "sim.toml"
    cfg.write_text(PROBLEM.format(mesh='file = "pillar.msh"', fix="[[fix]]\nbox = [[-1, -1, -1], [1, 1, 0.001]]",
                                  method="be", h=0.01, steps=3))
    out = tmp_path / "out.xdmf"
    r = runner.invoke(app, ["simulate", str(cfg), "--out", str(out)])
    assert r.exit_code == 0, r.output
    with meshio.xdmf.TimeSeriesReader(out) as rd:
        pts, cells = rd.read_points_cells()
        frames = [rd.read_data(k) for k in range(rd.num_steps)]
    assert len(frames) == 4 and [c.type for c in cells] == ["tetra"]
    for _, _, cd in frames:
        assert list(cd) == ["cell_tags"]
        assert _tags_by_cell(pts, [(cells[0].data, cd["cell_tags"][0])]) == want
    # the names, read by meshio's parser of the XDMF Information layout, are the .msh's $PhysicalNames
    info = ET.parse(out).getroot().find("Domain/Grid[@Name='mesh']/Information")
    names = meshio.xdmf.main.XdmfReader.read_information(None, info.text)
    assert {k: v.tolist() for k, v in names.items()} == {k: v.tolist() for k, v in src.field_data.items()}
    with h5py.File(tmp_path / "out.h5") as h5:  # points, cells, 4 x (displacement, velocity), one cell_tags
        assert len(h5) == 2 + 2 * 4 + 1
    # the same tags as the VTU of `physar fem solve` on that mesh (the convention followed)
    (tmp_path / "fem.toml").write_text(cfg.read_text().split("[dynamics]")[0])
    r = runner.invoke(app, ["fem", "solve", str(tmp_path / "fem.toml"), "--out", str(tmp_path / "fem.vtu")])
    assert r.exit_code == 0, r.output
    vtu = meshio.read(tmp_path / "fem.vtu")
    assert set(vtu.cell_data) - {"von_mises"} == set(frames[0][2])
    assert _tags_by_cell(vtu.points, [(vtu.cells[0].data, vtu.cell_data["cell_tags"][0])]) == want


def _free_cube(tmp_path, steps: int, out: str) -> None:
    """`physar simulate` of a 0.1 m cube (one cell, no tags) falling freely, midpoint rule, h = 0.1 s."""
    cfg = tmp_path / "sim.toml"
    cfg.write_text(PROBLEM.format(mesh="box = [0.1, 0.1, 0.1]\ncells = [1, 1, 1]", fix="", method="midpoint",
                                  h=0.1, steps=steps))
    r = runner.invoke(app, ["simulate", str(cfg), "--out", str(tmp_path / out)])
    assert r.exit_code == 0, r.output


# a mesh without tags (a [mesh] box) gets none, as its VTU. mutant caught: zeros written for an untagged mesh
def test_xdmf_without_tags_has_no_cell_data(tmp_path):
    _free_cube(tmp_path, 1, "b.xdmf")
    with meshio.xdmf.TimeSeriesReader(tmp_path / "b.xdmf") as rd:
        rd.read_points_cells()
        assert all(rd.read_data(k)[2] == {} for k in range(rd.num_steps))


# mutants caught: the old header (no units: KeyError on time_s); kinetic and potential columns swapped (the closed
# form's signs differ); time written as the step number
def test_energy_csv_header_has_units(tmp_path):
    _free_cube(tmp_path, 3, "f.xdmf")
    with open(tmp_path / "f.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
    assert reader.fieldnames == ["step", "time_s", "kinetic_J", "elastic_J", "potential_J", "total_J",
                                 "newton_iterations"]
    mass, g = 500 * 0.1 ** 3, 9.81
    t = np.array([float(x["time_s"]) for x in rows])
    np.testing.assert_allclose(t, 0.1 * np.arange(4), atol=1e-15)
    col = {k: np.array([float(x[k]) for x in rows]) for k in ("kinetic_J", "elastic_J", "potential_J", "total_J")}
    np.testing.assert_allclose(col["kinetic_J"], 0.5 * mass * (g * t) ** 2, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(col["potential_J"], -0.5 * mass * g ** 2 * t ** 2, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(col["elastic_J"], 0.0, atol=1e-9)
    np.testing.assert_allclose(col["total_J"], 0.0, atol=1e-9)


# an energy CSV of an earlier version (header without units) at the default path is still an earlier output of
# the command: replaced, not refused. mutant caught: only the new header accepted (exit 2, "does not look like")
def test_default_csv_of_the_header_without_units_is_replaced(tmp_path):
    cfg = tmp_path / "sim.toml"
    cfg.write_text(PROBLEM.format(mesh="box = [0.1, 0.1, 0.1]\ncells = [1, 1, 1]", fix="", method="midpoint",
                                  h=0.1, steps=1))
    (tmp_path / "f.csv").write_text("step,t,kinetic,elastic,potential,total,newton_iterations\n0,0,0,0,0,0,0\n")
    r = runner.invoke(app, ["simulate", str(cfg), "--out", str(tmp_path / "f.xdmf")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "f.csv").read_text().startswith("step,time_s,kinetic_J,")
