"""Noise convention of the normal-filtering literature (issue 20): `physar noise` moves each vertex by
s·N(0, 1) along its own uniformly random unit direction, s = sigma · mean edge length.

Reference: for d = s t u with t ~ N(0, 1) independent of u uniform on the sphere, E[d dᵀ] = s² E[t²] E[u uᵀ]
= (s²/3) I, so the sample covariance of the displacements is isotropic with trace s² (the old
per-coordinate N(0, s² I) gives trace 3 s²). Checked here from the displacements alone, with tolerances
from the sampling error of n = 6400 vertices (std of a sample variance ≈ sqrt(2/n) ≈ 2 %).
"""

import numpy as np
import pytest
from typer.testing import CliRunner

from physar.cli.main import app
from physar.geometry import quality as Q
from physar.geometry.mesh import TriMesh


def plane(n: int) -> TriMesh:
    """Flat n x n grid in z = 0 (unit spacing), two triangles per square."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    pts = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.r_[np.c_[a, a + n, a + n + 1], np.c_[a, a + n + 1, a + 1]]
    return TriMesh(pts, faces, name="plane")


def edge_mean(mesh: TriMesh) -> float:
    """Mean edge length, computed here independently of physar (unique sorted edge pairs)."""
    e = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    e = np.unique(e, axis=0)
    return float(np.linalg.norm(mesh.points[e[:, 0]] - mesh.points[e[:, 1]], axis=1).mean())


def covariance_checks(d: np.ndarray, s: float) -> None:
    c = np.cov(d.T, bias=True)
    assert np.trace(c) == pytest.approx(s**2, rel=0.05)
    assert np.diag(c) == pytest.approx(np.full(3, s**2 / 3), rel=0.08)  # isotropic
    off = c[~np.eye(3, dtype=bool)]
    assert np.abs(off).max() < 0.05 * s**2
    assert np.abs(d.mean(axis=0)).max() < 0.05 * s  # zero mean


def test_random_direction_covariance():
    """Sample covariance of the displacement = (s²/3) I, trace s². Mutants caught: per-coordinate
    N(0, s² I) (trace 3 s²), an unnormalised direction (trace 3 s²), noise along the normal (all variance
    in z on a plane), uniform instead of Gaussian magnitude with the same support (trace s²/3)."""
    clean = plane(80)
    s = 0.3 * edge_mean(clean)
    noisy = Q.add_noise(clean, 0.3, seed=5, direction="random")
    covariance_checks(noisy.points - clean.points, s)
    # the magnitude along the direction is Gaussian: |d| / s is |N(0,1)|, E|d| = s sqrt(2/pi)
    r = np.linalg.norm(noisy.points - clean.points, axis=1) / s
    assert r.mean() == pytest.approx(np.sqrt(2 / np.pi), rel=0.03)


def test_cli_noise_default_is_random_direction(tmp_path):
    """`physar noise` without --direction uses the random-direction convention. Mutant caught: the old
    default --direction normal (the displacement of a flat grid would lie in z only)."""
    clean = plane(80)
    src = tmp_path / "plane.ply"
    from physar.geometry.io import write_mesh

    write_mesh(src, clean)
    out = tmp_path / "noisy.ply"
    r = CliRunner().invoke(app, ["noise", str(src), str(out), "--sigma", "0.2", "--seed", "3", "--json"])
    assert r.exit_code == 0, r.output
    from physar.geometry.io import read_mesh

    noisy = read_mesh(out, kind="tri")
    covariance_checks(noisy.points - clean.points, 0.2 * edge_mean(clean))
    h = CliRunner().invoke(app, ["noise", "--help"])
    assert "random" in h.output and "direction" in h.output


def test_cli_noise_refuses_a_level_that_destroys_the_surface(tmp_path):
    """--sigma 1e300 printed "noise std 1.96e+299 m", exit 0; a surface whose points all coincide got "noise"
    of std 0. Both: one line, exit 2, nothing written. Mutants: no upper bound; no zero-scale check. 10 (the
    bound) is still accepted."""
    from physar.geometry.io import write_mesh
    from physar.geometry.mesh import TriMesh

    clean = plane(10)
    write_mesh(tmp_path / "plane.ply", clean)
    flat = TriMesh(np.zeros((3, 3)), np.array([[0, 1, 2]]), name="dot")
    write_mesh(tmp_path / "dot.ply", flat)
    for src, sigma, needle in (("plane.ply", "1e300", "noise sigma must be a number in [0, 10]"),
                               ("dot.ply", "0.2", "the mean edge length is 0 (all points coincide)")):
        r = CliRunner().invoke(app, ["noise", str(tmp_path / src), str(tmp_path / "o.ply"), "--sigma", sigma])
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.exit_code == 2 and len(lines) == 1 and needle in lines[0], r.output
        assert not (tmp_path / "o.ply").exists()
    r = CliRunner().invoke(app, ["noise", str(tmp_path / "plane.ply"), str(tmp_path / "o.ply"), "--sigma", "10"])
    assert r.exit_code == 0, r.output
