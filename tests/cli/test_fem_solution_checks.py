"""`physar fem solve` judges its solution (a third outside probe, 2026-11-28): a stiffness far too small for the
loads (E = 1e-300 Pa) gave exit 0, numpy overflow warnings and an "inf" displacement written into the result
mesh; E given in GPa as Pa (69 for 69e9) gave a 1 m cantilever a displacement of tens of kilometres, silently.

Reference: the Euler-Bernoulli tip deflection :math:`\\delta = P L^3 / (3 E I)` of the example's cantilever
(L = 1 m, 50 x 50 mm section) tells which E gives a displacement beyond the body's size, independently of the
solver.
"""
from pathlib import Path

from test_bad_inputs import assert_refused, snapshot
from typer.testing import CliRunner

from physar.cli.main import app

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _solve(tmp_path, E: str):
    text = (EXAMPLES / "cantilever.toml").read_text()
    assert "E = 69e9" in text
    (tmp_path / "c.toml").write_text(text.replace("E = 69e9", f"E = {E}"))
    return CliRunner().invoke(app, ["fem", "solve", str(tmp_path / "c.toml"), "-o", str(tmp_path / "r.vtu")])


def test_non_finite_solution_refused(tmp_path):
    # mutant: the finiteness check removed (exit 0, "max displacement inf m", inf in r.vtu)
    text = (EXAMPLES / "cantilever.toml").read_text()
    (tmp_path / "c.toml").write_text(text.replace("E = 69e9", "E = 1e-300"))
    before = snapshot(tmp_path)
    r = CliRunner().invoke(app, ["fem", "solve", str(tmp_path / "c.toml"), "-o", str(tmp_path / "r.vtu")])
    assert_refused(r, "c.toml: the linear solve produced NaN or inf (a singular system, or a stiffness too small for the loads", before,
                   tmp_path)


def test_displacement_beyond_the_body_warned(tmp_path):
    """E = 69 (GPa typed as Pa): the beam theory deflection P L^3 / (3 E I) is ~1e7 m, beyond the body's 1.0 m
    diagonal: one warning line, the result still written (a user may mean it). E = 69e9: 9 mm, no warning.
    Mutants: the warning removed; the warning on every solve (or on a size compared in the wrong unit)."""
    P, L, b = 1000.0, 1.0, 0.05  # the example's load (N), length and square section (m)
    for E, warned in (("69", True), ("69e9", False)):
        delta = P * L**3 / (3 * float(E) * b**4 / 12)
        assert (delta > 1.0) == warned, delta  # the independent expectation
        r = _solve(tmp_path, E)
        assert r.exit_code == 0, r.output
        lines = [ln for ln in r.stderr.splitlines() if ln.startswith("warning:")]
        assert (tmp_path / "r.vtu").exists()
        if warned:
            assert len(lines) == 1 and "exceeds the body's size" in lines[0] and "E (Pa, not GPa" in lines[0], lines
        else:
            assert lines == [], lines


def test_overflowing_displacement_refused(tmp_path):
    """A coarse 4 x 1 x 1 beam at E = 1e-297: the solve stays finite (|u| ~ 1e305 m) but its norm overflows;
    it was written as "max displacement inf m". Mutant: the check on the norm removed."""
    text = (EXAMPLES / "cantilever.toml").read_text().replace("E = 69e9", "E = 1e-297")
    (tmp_path / "c.toml").write_text(text.replace("cells = [40, 2, 2]", "cells = [4, 1, 1]"))
    before = snapshot(tmp_path)
    r = CliRunner().invoke(app, ["fem", "solve", str(tmp_path / "c.toml"), "-o", str(tmp_path / "r.vtu")])
    assert_refused(r, "c.toml: the displacement is not finite: the stiffness is too small for the loads", before,
                   tmp_path)
