"""The seed-001 notebook-style examples run in quick mode, and their numbers hold against independent
references: closed-form amplification factors (built here in matrix form, independently of the
examples' scalar formulas and of physar's amplification-matrix analysis) and the exact torus surface."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import matplotlib.image
import meshio
import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


# -- artificial_damping.py ---------------------------------------------------------------------------
def reference_rho(method, x, r=None, theta=None):
    """ρ of the amplification of q'' + q = 0 at h = x, from the methods' matrix recurrences (seed §2.1)."""
    A = x * np.array([[0.0, 1.0], [-1.0, 0.0]])  # h times the matrix of (2.2)
    I = np.eye(2)
    if method in ("be", "si"):
        return 1.0 / np.sqrt(1.0 + x * x)  # Eq. 2.8
    if method == "midpoint":
        T = np.linalg.solve(I - A / 2, I + A / 2)
    elif method == "trbdf2":  # trapezoid to t + γh, then BDF2 on (t, t + γh, t + h)
        g = 2 - np.sqrt(2)
        Tg = np.linalg.solve(I - g * A / 2, I + g * A / 2)
        T = np.linalg.solve(I - (1 - g) / (2 - g) * A, (Tg - (1 - g) ** 2 * I) / (g * (2 - g)))
    elif method == "theta":  # Eq. 2.15 as a companion matrix on (u_n, u_{n-1})
        L = I - ((1 - theta) / 2 + 2 * theta / 3) * A
        T = np.block([[np.linalg.solve(L, I + (1 - theta) / 2 * A + theta / 3 * I),
                       np.linalg.solve(L, -theta / 3 * I)], [I, 0 * I]])
    else:  # generalized-α, Eq. 2.14 with (2.12)
        am, af = (2 * r - 1) / (r + 1), r / (r + 1)
        al = am - af
        be, ga = (1 - al) ** 2 / 4, 0.5 - al
        L = [[1, 0, -x * x * be], [0, 1, -x * ga], [1 - af, 0, 1 - am]]
        R = [[1, x, x * x / 2 * (1 - 2 * be)], [0, 1, x * (1 - ga)], [-af, 0, -am]]
        T = np.linalg.solve(L, R)
    return float(np.abs(np.linalg.eigvals(T)).max())


def test_artificial_damping_example(run_example):
    g, _ = run_example("artificial_damping.py")
    hw, cases, results = g["HW"], g["CASES"], g["RESULTS"]
    assert len(hw) >= 5 and hw.min() <= 0.1 and hw.max() >= 10
    assert {m for m, _ in cases.values()} == {"be", "si", "midpoint", "genalpha", "theta", "trbdf2"}
    for label, (method, knob) in cases.items():
        ref = np.array([reference_rho(method, x, **knob) for x in hw])
        res = results[label]
        # measured from the simulated trajectory: round-off only (largest seen 5e-12, gen-α r = 0)
        np.testing.assert_allclose(res["rho_measured"], ref, rtol=1e-9, err_msg=label)
        np.testing.assert_allclose(res["rho_closed_form"], ref, rtol=1e-12, err_msg=label)
        np.testing.assert_allclose(res["d_over_omega"], -2 / hw * np.log(ref), rtol=1e-6, atol=1e-9, err_msg=label)
    # seed Eq. 2.9 directly: d_BE / ω = ln(1 + (hω)²) / (hω); hω = 1 gives ln 2
    np.testing.assert_allclose(results["BE"]["d_over_omega"], np.log1p(hw**2) / hw, rtol=1e-9)
    assert g["MAX_REL_ERR"] < 1e-9
    # files: the PNG loads, the CSV holds every measured point
    img = matplotlib.image.imread(g["PLOT"])
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 300
    with open(g["CSV"], newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(cases) * len(hw)
    be = [row for row in rows if row["method"] == "BE"]
    np.testing.assert_allclose([float(row["rho_measured"]) for row in be],
                               1 / np.sqrt(1 + np.array([float(row["hw"]) for row in be]) ** 2), rtol=1e-9)


# -- denoise_mesh.py ---------------------------------------------------------------------------------
def exact_torus_distance(p, R=1.0, r=0.4):
    return np.hypot(np.hypot(p[:, 0], p[:, 1]) - R, p[:, 2]) - r


def test_denoise_mesh_example(run_example):
    g, _ = run_example("denoise_mesh.py")
    clean, err, red = g["clean"], g["ERRORS"], g["REDUCTION"]
    assert (g["R"], g["r"]) == (1.0, 0.4)
    # the example's distance and normal: zero on the exact torus, t after a move of t along the normal
    sd, n = g["torus_offset"](clean.points)
    assert np.abs(sd).max() < 1e-12
    moved = clean.points + 0.01 * n
    np.testing.assert_allclose(exact_torus_distance(moved), 0.01, atol=1e-12)
    np.testing.assert_allclose(g["torus_offset"](moved)[0], 0.01, atol=1e-12)
    # noise along the normals of std s = 0.2 ē: E|d| = s √(2/π) (3840 samples: ~1.2 % standard error)
    s = 0.2 * g["MEAN_EDGE"]
    assert err["noisy"]["mean_distance"] == pytest.approx(s * np.sqrt(2 / np.pi), rel=0.05)
    # AL and MSAL: measured 3.2-3.5x lower mean distance and 3.2-3.6x lower normal error on this torus
    # (seeds 0-2, noise 0.2 and 0.3 ē, 3840 to 23040 vertices): the residual is noise averaged over
    # ~10 neighbours (√10 ≈ 3.2), not shape; 2.8 leaves a margin below the lowest seen
    for name in ("AL", "MSAL"):
        assert red[name] > 2.8, (name, red[name])
        assert err[name]["normal_error_deg"] < err["noisy"]["normal_error_deg"] / 2.8, name
        # no shrinkage: the mean signed offset is < 5 % of the mean distance of the noisy data
        assert abs(err[name]["mean_signed_distance"]) < 0.05 * err["noisy"]["mean_distance"], name
        # on the exact mesh they move the vertices by < 3 % of the noise (measured ~0.9 %)
        assert g["BIAS_ON_CLEAN"][name] < 0.03 * err["noisy"]["mean_distance"], name
    assert red["MSAL (seed form)"] > 1.3  # the seed's parameters keep more data (measured 1.6-1.9x)
    # PLY files load with meshio and match the reported errors on the exact surface
    for name, path in g["FILES"].items():
        m = meshio.read(path)
        assert m.cells_dict["triangle"].shape == clean.faces.shape
        d = np.abs(exact_torus_distance(np.asarray(m.points, float))).mean()
        assert d == pytest.approx(err[name]["mean_distance"], rel=1e-4), name
    img = matplotlib.image.imread(g["PLOT"])
    assert img.ndim == 3 and img.shape[1] > 600
    summary = json.loads(Path(g["JSON"]).read_text())
    assert summary["reduction"]["MSAL"] == pytest.approx(red["MSAL"])


def test_denoise_mesh_example_peer_taubin(run_example):
    pytest.importorskip("trimesh")
    g, _ = run_example("denoise_mesh.py")
    # trimesh's Taubin (10 half-steps) is shown beside physar's: it too lowers the error (measured 2.3x)
    assert g["REDUCTION"]["Taubin (trimesh)"] > 1.5
