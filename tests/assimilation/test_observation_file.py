"""The observation CSV of `physar assimilate` (read_observations) and the fit's "explains nothing" warning.

References are the values written into the files and, for the warning, the geometry of a one-mode model
u(mu) = mu F_0: its best fit to y = a F_0 + b e (e orthogonal to F_0) leaves exactly |b e|^2 unexplained.
"""
import warnings

import numpy as np
import pytest

from physar.assimilation import UNEXPLAINED, assimilate, read_observations
from physar.errors import ConfigError, PhysarError, PhysarWarning
from physar.rom import SeparatedModel

ROWS = [[0.5, 0.05, 0.05, 0.0, 1e-4, -1e-3], [1.0, 0.05, 0.05, 2e-5, 0.0, -3e-3]]


def _csv(rows, header="x,y,z,ux,uy,uz"):
    return header + "\n" + "".join(",".join(repr(v) for v in r) + "\n" for r in rows)


def test_a_byte_order_mark_is_not_part_of_the_first_column(tmp_path):
    # mutant: read as plain utf-8 ("missing column(s) x" for an Excel export)
    f = tmp_path / "obs.csv"
    f.write_bytes(b"\xef\xbb\xbf" + _csv(ROWS).encode())
    pts, disp = read_observations(f)
    np.testing.assert_array_equal(np.hstack([pts, disp]), ROWS)


def test_a_row_longer_than_the_header_is_refused(tmp_path):
    # mutant: the extra value silently dropped (a short row was already refused)
    f = tmp_path / "obs.csv"
    f.write_text("# exported\n" + _csv(ROWS).replace("-0.003\n", "-0.003,7\n"))
    with pytest.raises(ConfigError, match=r"obs\.csv: line 4: 7 values, the header has 6 columns"):
        read_observations(f)
    f.write_text(_csv(ROWS).replace(",-0.003\n", "\n"))
    with pytest.raises(ConfigError, match=r"obs\.csv: line 3: 5 values, the header has 6 columns"):
        read_observations(f)


@pytest.mark.parametrize(("value", "column"), [(10.0, "uz"), (-1e300, "uz"), (-0.9, "ux")])
def test_a_displacement_larger_than_the_body_is_refused(tmp_path, value, column):
    """With body_size = 1.0 m: 10 m, -1e300 m, and |(-0.9, 0.5, 0)| = 1.03 m are refused naming line and column
    (the largest component's); 0.9 m alone passes. Mutant: no body_size check (uz = 10 gave `s = 0 ± 6e+06 m`)."""
    f = tmp_path / "obs.csv"
    bad = [0.5, 0.05, 0.05, 0.0, 0.0, value] if column == "uz" else [0.5, 0.05, 0.05, value, 0.5, 0.0]
    f.write_text(_csv([ROWS[0], bad]))
    with pytest.raises(ConfigError, match=rf"obs\.csv: line 3, column {column}: displacement .* larger than the "
                                          r"body itself \(1 m"):
        read_observations(f, body_size=1.0)
    f.write_text(_csv([ROWS[0], [0.5, 0.05, 0.05, 0.0, 0.0, 0.9]]))
    assert read_observations(f, body_size=1.0)[1][1, 2] == 0.9


@pytest.mark.parametrize("text", ["nan", "inf", "abc"])
def test_a_bad_value_names_line_and_column(tmp_path, text):
    f = tmp_path / "obs.csv"
    f.write_text(_csv(ROWS).replace("1e-04", text).replace("0.0001", text))
    with pytest.raises(ConfigError, match=r"obs\.csv: line 2, column uy: "):
        read_observations(f)


# ------------------------------------------------------------------------------------------------ the warning
N_DOF = 12
F0 = np.zeros(N_DOF)
F0[:6] = 1.0
E_PERP = np.zeros(N_DOF)
E_PERP[6:] = 1.0          # orthogonal to F0, |E_PERP| = |F0| = sqrt(6)


def _one_mode():
    x = np.linspace(0.0, 2.0, 9)
    rom = SeparatedModel(F0[None, :], [x], [x[None, :]], ["P"], ["N"])   # u(P) = P F0 (a spline of a line)
    rom.set_observation(dofs=np.arange(N_DOF))
    return rom


@pytest.mark.parametrize(("share", "warns"), [(0.0, False), (0.45, False), (0.55, True), (1.0, True)])
def test_warns_when_the_fit_leaves_more_than_half_unexplained(share, warns):
    """y = a F0 + b E_PERP with |b E_PERP|^2 = share |y|^2: the best fit P = a leaves exactly that share.
    Mutants: no warning (`residual 1.000e+01 m`, nothing else), or another threshold than one half."""
    assert UNEXPLAINED == 0.5
    a = 1.2
    b = a * np.sqrt(share / (1 - share)) if share < 1 else 1.0
    y = (a if share < 1 else 0.0) * F0 + b * E_PERP
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = assimilate(_one_mode(), y)
    ours = [w for w in caught if issubclass(w.category, PhysarWarning)]
    assert len(ours) == int(warns), [str(w.message) for w in ours]
    if warns:
        assert "unexplained" in str(ours[0].message) and "\n" not in str(ours[0].message)
    if share < 1:
        assert abs(res.params[0] - a) < 1e-9
        assert abs(res.residual ** 2 - share * (y @ y)) < 1e-9 * (y @ y)


def test_observations_whose_norm_overflows_are_refused():
    # mutant: no check (overflow RuntimeWarnings, then `s = 1 ± inf`)
    y = np.full(N_DOF, 1e300)
    with pytest.raises(PhysarError, match="observed displacements too large"):
        assimilate(_one_mode(), y)
