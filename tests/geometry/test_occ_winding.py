"""Winding of the CAD surfaces built with gmsh's OpenCASCADE kernel (physar.geometry.tetra, issue 20).

Reference, independent of physar: the closed-form solids themselves. For every triangle, a point a little
outside along its normal (centroid + δ n_f) must lie outside the solid and a point a little inside (centroid
- δ n_f) inside it, by the closed-form membership test of the box minus the cylinder (plate with a hole) or
the union of two boxes (L-bracket); and the enclosed volume Σ_f x_0·(x_1 × x_2)/6 must be positive and
match the closed form (box minus the cylinder, to the polygonal approximation of the hole).
"""

import numpy as np
import pytest

from physar.geometry.tetra import l_bracket_surface, plate_with_hole_surface

L, W, T, R = 0.2, 0.1, 0.03, 0.025


def in_plate(p: np.ndarray) -> np.ndarray:
    box = (p >= 0).all(axis=1) & (p[:, 0] <= L) & (p[:, 1] <= W) & (p[:, 2] <= T)
    return box & ((p[:, 0] - L / 2) ** 2 + (p[:, 1] - W / 2) ** 2 > R**2)


def in_bracket(p: np.ndarray, length=0.1, height=0.1, depth=0.04, t=0.02) -> np.ndarray:
    a = (p >= 0).all(axis=1) & (p[:, 0] <= length) & (p[:, 1] <= depth) & (p[:, 2] <= t)
    b = (p >= 0).all(axis=1) & (p[:, 0] <= t) & (p[:, 1] <= depth) & (p[:, 2] <= height)
    return a | b


def check_outward(mesh, inside, delta):
    x = mesh.points[mesh.faces]
    c = x.mean(axis=1)
    n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    out_ok = ~inside(c + delta * n)
    in_ok = inside(c - delta * n)
    vol = float(np.einsum("fi,fi->f", x[:, 0], np.cross(x[:, 1], x[:, 2])).sum() / 6)
    return out_ok, in_ok, vol


@pytest.mark.parametrize("size", [0.008, 0.004])
def test_plate_with_hole_wound_outward(size):
    """Every face of the plate with a hole points out of the solid (the hole's wall into the hole), and the
    signed volume is L W T - π R² T within the polygon error of the hole. Mutant caught: the former winding
    (gmsh's per-patch orientation, only the whole surface flipped by the sign of the volume), which left
    whole CAD faces pointing inward (the test fails on their triangles)."""
    m = plate_with_hole_surface(L, W, T, R, size)
    delta = 0.2 * size  # beyond the sagitta size²/8R of the hole's chords
    out_ok, in_ok, vol = check_outward(m, in_plate, delta)
    assert out_ok.all() and in_ok.all(), (int((~out_ok).sum()), int((~in_ok).sum()), len(m.faces))
    exact = L * W * T - np.pi * R**2 * T
    # inscribed polygon of the hole removes less: the volume is a little above the exact one
    assert 0 < vol - exact < 0.02 * exact, (vol, exact)


def test_l_bracket_wound_outward():
    """The L-bracket (union of two boxes): every face points out of the union, volume exact (boxes are
    polyhedra). Mutant caught: the same former winding (per-patch orientation, whole-surface flip only)."""
    m = l_bracket_surface(size=0.005)
    out_ok, in_ok, vol = check_outward(m, in_bracket, 1e-5)
    assert out_ok.all() and in_ok.all()
    assert vol == pytest.approx(0.1 * 0.04 * 0.02 + 0.02 * 0.04 * 0.08, rel=1e-9)
