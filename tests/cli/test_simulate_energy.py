"""`physar simulate --plot` and the energy checks (issue 20 item 4): a plot of the energies against time, a
warning when the total energy grows, and a clean stop on a blow-up that keeps the valid steps.

The reference for the energy growth is recomputed here from the written CSV (the definition: the largest
E(t) - E(0) over the largest |kinetic|, |elastic|, |potential| of the run); the stability limit of the
explicit step is the closed form h < 2/ω_max, exceeded here by far (E = 5 MPa, 0.1 m elements:
ω_max ~ 2 c / l = 2 sqrt(E/ρ) / l ≈ 2000 rad/s, limit ≈ 1 ms, step 4 ms).
"""

import csv

import numpy as np
from typer.testing import CliRunner

from physar.cli.main import app

DROP = """
[mesh]
box = [0.2, 0.2, 0.2]
cells = [2, 2, 2]
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
[dynamics.ground]
z = -0.02
stiffness = 2e4
"""


def run(tmp_path, method, h, steps, *extra):
    cfg = tmp_path / "drop.toml"
    cfg.write_text(DROP.format(method=method, h=h, steps=steps))
    r = CliRunner().invoke(app, ["simulate", str(cfg), "-o", str(tmp_path / "t.xdmf"), "--plot",
                                 str(tmp_path / "e.png"), *extra])
    lines = [ln for ln in r.output.splitlines() if ln.startswith(("error:", "warning:"))]
    rows = []
    if (tmp_path / "t.csv").exists():
        with open(tmp_path / "t.csv") as fh:
            rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(fh)]
    return r, lines, rows


def growth(rows):
    tot = np.array([r["total_J"] for r in rows])
    scale = max(max(abs(r["kinetic_J"]), abs(r["elastic_J"]), abs(r["potential_J"])) for r in rows)
    return float((tot - tot[0]).max() / scale)


def is_png(path):
    return path.exists() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000


def test_blow_up_stops_on_runaway_energy_with_valid_files(tmp_path):
    """Symplectic Euler at 4x its stability limit: stops at the energy check (step 10, long before a
    displacement runs away), exit 2, one error line, finite CSV/plot of the steps before. Mutants caught:
    no energy criterion (the run goes on to the displacement check, later and with another message),
    no plot written on a failure, the failed step written."""
    r, lines, rows = run(tmp_path, "symplectic_euler", 0.004, 300)
    assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error:"), r.output
    assert "runaway energy" in lines[0] and "diverged at step 10 " in lines[0], lines[0]
    assert "Traceback" not in r.output
    assert len(rows) == 10 and all(np.isfinite(list(x.values())).all() for x in rows)  # steps 0-9
    assert growth(rows) < 0.9
    assert is_png(tmp_path / "e.png")


def test_stable_run_plot_and_no_warning(tmp_path):
    """Backward Euler (dissipative): exit 0, no warning, a PNG, JSON energy_growth = the CSV's growth.
    Mutants caught: --plot ignored, growth measured against E(0) = 0 (division by zero / inf)."""
    r, lines, rows = run(tmp_path, "be", 0.01, 40, "--json")
    assert r.exit_code == 0 and not lines, r.output
    assert is_png(tmp_path / "e.png")
    import json

    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert abs(summary["energy_growth"] - growth(rows)) < 1e-12
    assert summary["energy_growth"] < 0.05


def test_energy_gain_warns(tmp_path):
    """Implicit midpoint with a stiff penalty ground gains energy at each bounce (55 % of the largest term
    after 15 steps): one warning line, exit 0. Mutants caught: no warning, warning threshold read as
    percent (5 instead of 0.05)."""
    r, lines, rows = run(tmp_path, "midpoint", 0.02, 15)
    g = growth(rows)
    assert 0.05 < g < 0.9, g
    assert r.exit_code == 0 and len(lines) == 1 and lines[0].startswith("warning:"), r.output
    assert "total energy grew" in lines[0] and f"{100 * g:.1f} %" in lines[0]
    r, lines, _ = run(tmp_path, "midpoint", 0.02, 15, "--energy-warn", "0.9")
    assert r.exit_code == 0 and not lines, r.output
