"""`physar simulate` on a new user's runs (review of 2026-11-29): the input mesh is never its output, a step
that fails (Newton) keeps the steps before it, and a long free fall is not a divergence.

References: free fall from rest under g = 9.81 m/s^2, z(t) = -g t^2 / 2, which the implicit midpoint rule
integrates exactly (a constant acceleration: its velocity and position updates are the trapezoid rule of a
linear and a quadratic function); the step counts set here."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from physar.cli.main import app

runner = CliRunner()

BOX = """
[mesh]
{mesh}
[material]
model = "corotated"
E = 5e6
nu = 0.3
density = 500
[fem]
element = "P1"
[dynamics]
method = "{method}"
h = {h}
steps = {steps}
gravity = [0, 0, -9.81]
"""


def _cfg(tmp_path, method="midpoint", h=0.1, steps=3, mesh='box = [0.1, 0.1, 0.1]\ncells = [1, 1, 1]'):
    p = tmp_path / "sim.toml"
    p.write_text(BOX.format(method=method, h=h, steps=steps, mesh=mesh))
    return p


# mutant caught: the mesh file not among the inputs of the destination checks (the run replaced beam.xdmf and
# beam.h5, the user's mesh; the next run could not read it)
def test_output_over_the_input_mesh_is_refused(tmp_path):
    from physar.geometry.io import write_mesh
    from physar.geometry.mesh import box_mesh

    m = write_mesh(tmp_path / "beam.xdmf", box_mesh((0.1, 0.02, 0.02), (2, 1, 1)))
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    cfg = _cfg(tmp_path, mesh='file = "beam.xdmf"')
    r = runner.invoke(app, ["simulate", str(cfg), "--out", str(m)])
    assert r.exit_code == 2 and "is the same file as the input" in r.output, r.output
    assert all(p.read_bytes() == before[p.name] for p in tmp_path.iterdir() if p.name in before)


def test_output_next_to_a_vtu_mesh_runs(tmp_path):
    from physar.geometry.io import write_mesh
    from physar.geometry.mesh import box_mesh

    write_mesh(tmp_path / "beam.vtu", box_mesh((0.1, 0.02, 0.02), (2, 1, 1)))
    cfg = _cfg(tmp_path, mesh='file = "beam.vtu"')
    r = runner.invoke(app, ["simulate", str(cfg), "--out", str(tmp_path / "beam.xdmf")])
    assert r.exit_code == 0, r.output


# mutant caught: the step's SolverError not turned into SimulationDiverged (no file written, the 2 good steps lost)
def test_newton_failure_keeps_the_steps_before(tmp_path, monkeypatch):
    import physar.integrators.config as C
    from physar.errors import SolverError

    build = C.build_simulation

    def failing(cfg, base_dir=None):
        sim = build(cfg, base_dir)
        inner, calls = sim.integrator, {"n": 0}

        class Failing:
            name, implicit = inner.name, True

            def init(self, *a):
                return inner.init(*a)

            def step(self, model, state, h):
                calls["n"] += 1
                if calls["n"] == 3:
                    raise SolverError(f"{inner.name}: Newton did not converge in 25 iterations")
                return inner.step(model, state, h)

        sim.integrator = Failing()
        return sim

    monkeypatch.setattr(C, "build_simulation", failing)
    cfg = _cfg(tmp_path, steps=5)
    out = tmp_path / "t.xdmf"
    r = runner.invoke(app, ["simulate", str(cfg), "--out", str(out)])
    assert r.exit_code == 2, r.output
    line = " ".join(r.output.split())
    assert "midpoint failed at step 3 (t = 0.3 s): Newton did not converge in 25 iterations" in line, line
    assert "wrote steps 0-2 to" in line, line
    rows = list(csv.DictReader(open(tmp_path / "t.csv")))
    assert [int(float(x["step"])) for x in rows] == [0, 1, 2] and out.exists()


# mutant caught: the runaway test on |q| itself (the cube's 240 m fall after 7 s is > 1000 x its 0.173 m size)
def test_long_free_fall_is_not_a_divergence(tmp_path):
    cfg = _cfg(tmp_path, h=0.1, steps=70)
    r = runner.invoke(app, ["simulate", str(cfg), "--out", str(tmp_path / "f.xdmf"), "--json"])
    assert r.exit_code == 0, r.output
    import meshio

    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "f.xdmf")) as rd:
        rd.read_points_cells()
        t, pd, _ = rd.read_data(rd.num_steps - 1)
    uz = np.asarray(pd[[k for k in pd if k.lower().startswith("u") or "disp" in k.lower()][0]])[:, 2]
    assert t == pytest.approx(7.0)
    np.testing.assert_allclose(uz, -0.5 * 9.81 * 7.0 ** 2, rtol=1e-9)
