"""`physar fem solve` reports the von Mises stress recovered at the vertices (physar.fem.post.nodal_stress), checked
against beam theory (sigma = M c / I), not the element means that read 28-46 % low in bending.

* Pure bending of a box beam by end rotations (symmetry plane at x = 0, u_x = -kappa L (z - H/2) at x = L): the
  elasticity solution is quadratic, so P2 holds it exactly, and sigma_xx = -E kappa (z - H/2) is M c / I with
  M = E I kappa on every top and bottom fibre vertex, the whole length. The summary's max and the VTU's nodal
  field must give M c / I to 0.5 %.
* The README's cantilever (examples/cantilever.toml, 40x2x2 P2, 1 kN tip load): the VTU's nodal von Mises on the
  mid-width top fibre, from one beam depth off the clamp to one beam depth off the loaded end, is
  P (L - x) c / I within 1 % of the clamp's P L c / I (Saint-Venant; at the clamp's edge the exact stress is
  singular).
"""

import json
from pathlib import Path

import meshio
import numpy as np
import pytest
from typer.testing import CliRunner

from physar.cli.main import app
from physar.fem.config import run_config

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "cantilever.toml"
L, W, H = 0.4, 0.04, 0.02
E, NU, M = 70e9, 0.3, 50.0  # Pa, -, N m
I_ = W * H**3 / 12
KAPPA = M / (E * I_)  # curvature of the beam [1/m]
SIGMA = M * (H / 2) / I_  # beam theory M c / I [Pa]: 18.75 MPa


def _bending_toml(tmp_path) -> Path:
    """A 20x2x2 P2 beam bent by prescribed end rotations (the exact solution needs no other support: u_x = 0 on
    x = 0 is its symmetry plane, u_y = u_z = 0 at (0, W/2, H/2) and u_y = 0 at (0, W/2, 0) hold rigid motion)."""
    levels = [H * k / 4 for k in range(5)]  # the P2 node levels through the depth (nz = 2)
    fixes = "\n".join(
        f"[[fix]]\nbox = [[{L}, 0, {z!r}], [{L}, {W}, {z!r}]]\ncomponents = [\"x\"]\n"
        f"value = [{-KAPPA * L * (z - H / 2)!r}, 0, 0]\n" for z in levels)
    text = f"""
[mesh]
box = [{L}, {W}, {H}]
cells = [20, 2, 2]
[material]
model = "linear"
E = {E}
nu = {NU}
[[fix]]
plane = {{point = [0, 0, 0], normal = [1, 0, 0]}}
components = ["x"]
[[fix]]
points = [[0, {W / 2}, {H / 2}]]
components = ["y", "z"]
[[fix]]
points = [[0, {W / 2}, 0]]
components = ["y"]
{fixes}
[fem]
element = "P2"
"""
    p = tmp_path / "bending.toml"
    p.write_text(text)
    return p


def test_pure_bending_peak_and_nodal_field_are_m_c_over_i(tmp_path):
    """Summary max_von_mises = M c / I (0.5 %), at a top or bottom fibre vertex; the point field von_mises is
    M c / I at every top/bottom vertex and |sigma_xx| = E kappa |z - H/2| at every vertex (0.5 % of M c / I);
    the element-mean peak, reported beside it, is at most 0.8 M c / I (two elements through the depth).
    Mutants caught: point_data von_mises = nodal_average(space, element von Mises) (0.75 M c / I at the fibres),
    summary max_von_mises = max of the element means (0.75)."""
    res = run_config(_bending_toml(tmp_path))
    s = res.summary()
    assert s["max_von_mises"] == pytest.approx(SIGMA, rel=5e-3)
    assert abs(s["max_von_mises_point"][2] - H / 2) == pytest.approx(H / 2, abs=1e-12)
    assert s["max_von_mises_element_mean"] < 0.8 * SIGMA
    X = res.problem.space.mesh.points
    vm = res.point_data()["von_mises"]
    fibre = np.isclose(np.abs(X[:, 2] - H / 2), H / 2)
    assert fibre.sum() == 2 * 21 * 3
    assert np.abs(vm[fibre] - SIGMA).max() < 5e-3 * SIGMA
    assert np.abs(vm - E * KAPPA * np.abs(X[:, 2] - H / 2)).max() < 5e-3 * SIGMA


def test_readme_cantilever_cli_nodal_field_and_peak(tmp_path):
    """`physar fem solve examples/cantilever.toml --json`: the VTU's nodal von Mises on the mid-width top fibre
    for H <= x <= L - H is P (L - x) c / I within 1 % of P L c / I (and within 1 % of itself up to L / 2); the peak reported is the nodal field's max, at least the
    clamp's M c / I (48.0 MPa) less 2 % and above the element means' peak. Mutants caught: the VTU's von_mises =
    nodal_average of element means (0.55-0.59 of beam theory), max_von_mises = element means' max (34.7 MPa)."""
    out = tmp_path / "r.vtu"
    r = CliRunner().invoke(app, ["fem", "solve", str(EXAMPLE), "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    Lc, Wc, Hc, P = 1.0, 0.05, 0.05, 1000.0
    sigma = lambda x: P * (Lc - x) * (Hc / 2) / (Wc * Hc**3 / 12)
    m = meshio.read(out)
    X, vm = m.points, m.point_data["von_mises"]
    top = np.isclose(X[:, 2], Hc) & np.isclose(X[:, 1], Wc / 2) & (X[:, 0] >= Hc - 1e-9) & (X[:, 0] <= Lc - Hc + 1e-9)
    assert top.sum() == 37
    assert np.abs(vm[top] - sigma(X[top, 0])).max() < 0.01 * sigma(0.0)
    half = top & (X[:, 0] <= Lc / 2 + 1e-9)
    assert np.abs(vm[half] / sigma(X[half, 0]) - 1).max() < 0.01
    assert s["max_von_mises"] == pytest.approx(vm.max(), rel=1e-6)
    assert s["max_von_mises"] > 0.98 * sigma(0.0) > s["max_von_mises_element_mean"]


def test_cantilever_demo_vtu_and_report_use_the_recovered_stress(tmp_path):
    """physar.fem.examples.run_cantilever_demo (`physar demo`): the VTU's nodal von Mises at the mid-width top
    fibre at x = L/2 is P (L/2) c / I = 24.0 MPa within 1 %; report max_von_mises_pa is the nodal peak (at least
    the clamp's 48.0 MPa less 2 %), above max_von_mises_element_mean_pa. Mutants caught: the VTU field =
    nodal_average of element means (14.1 MPa there), the report's max = element means' max (34.7 MPa)."""
    from physar.fem.examples import run_cantilever_demo

    rep = run_cantilever_demo(tmp_path)
    m = meshio.read(tmp_path / "cantilever.vtu")
    k = int(np.argmin(np.linalg.norm(m.points - [0.5, 0.025, 0.05], axis=1)))
    assert np.allclose(m.points[k], [0.5, 0.025, 0.05])
    assert m.point_data["von_mises"][k] == pytest.approx(24.0e6, rel=0.01)
    assert rep["max_von_mises_pa"] == pytest.approx(m.point_data["von_mises"].max(), rel=1e-6)
    assert rep["max_von_mises_pa"] > 0.98 * 48.0e6 > rep["max_von_mises_element_mean_pa"]
