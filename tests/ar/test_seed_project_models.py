"""The FE models of the seed's markerless project folders (examples/ar/foam, examples/ar/seal) against closed
forms: the foam's disk load (the `load_position` parameter of foam/rom.toml: 15 N spread over 40 mm by
:func:`physar.fem.point_load`) has the right resultant and point of application, the foam mesh and material on
line supports match Timoshenko beam theory, and the seal's whole mesh turned rigidly is stress-free under its
nearly incompressible neo-Hookean law (ported from the removed tests of the specialised foam / seal modules)."""
import math
from pathlib import Path

import numpy as np
import pytest

from physar.fem import (
    ElasticModel,
    FESpace,
    LinearElastic,
    NeoHookeanIncompressible,
    fixed_dofs,
    point_load,
    solve_static,
    von_mises,
)
from physar.geometry import read_mesh

AR = Path(__file__).resolve().parents[2] / "examples" / "ar"
L, W, H = 0.7975, 0.2, 0.105   # the foam beam (foam/rom.toml)


@pytest.fixture(scope="module")
def foam():
    return FESpace(read_mesh(AR / "foam" / "foam.vtu"), "P2")


def test_foam_disk_load_resultant_and_point_of_application(foam):
    """At both ends and inside the load path (x = 100 ... 697.5 mm on the top centre line): the nodal forces sum
    to the 15 N of foam/rom.toml along -z, their point of application (first moment / force) is the path point
    within 0.5 mm (measured <= 0.2 mm), and only top-face nodes carry them. Catches: a load not normalised
    (resultant off), the kernel centred off the point or on the wrong face, forces leaking onto the sides."""
    X = foam.nodes
    assert np.allclose(X.max(0), [L, W, H]) and np.allclose(X.min(0), 0)
    for x in (0.1, 0.3137, 0.6975):
        f = point_load(foam, [x, W / 2, H], [0, 0, -15.0], 0.04).reshape(-1, 3)
        assert np.allclose(f.sum(0), [0, 0, -15.0], atol=1e-9)
        c = (X * f[:, 2:3]).sum(0) / f[:, 2].sum()
        assert np.abs(c - [x, W / 2, H]).max() < 5e-4, c
        assert np.all(X[np.abs(f[:, 2]) > 0, 2] > H - 1e-9)


def test_foam_beam_on_line_supports_matches_timoshenko(foam):
    """The foam project's mesh (24 x 4 x 3 boxes, P2) and its small-strain material (E = 0.11 MPa, nu = 0.2) on
    line supports at x = 40 mm (pinned) and L - 40 mm (sliding), 0.15 N at mid-span: the deflection at
    mid-height equals a simply supported Timoshenko beam, w = P l^3 / (48 E I) + P l / (4 k G A), k = 5/6,
    l = L - 80 mm, within 2 % (measured 0.6 %). Catches: a mesh file of other dimensions or too coarse to bend,
    node planes missing at the support lines, E or nu mis-scaled (N/mm² read as Pa)."""
    a, P, E, nu = 0.04, 0.15, 0.11e6, 0.2
    pin = fixed_dofs(foam, where=lambda X: (np.abs(X[:, 0] - a) < 1e-6) & (X[:, 2] < 1e-9), components="xyz")
    sl = fixed_dofs(foam, where=lambda X: (np.abs(X[:, 0] - (L - a)) < 1e-6) & (X[:, 2] < 1e-9), components="z")
    assert len(pin) and len(sl)
    model = ElasticModel(foam, LinearElastic(E, nu))
    u = solve_static(model, point_load(foam, [L / 2, W / 2, H], [0, 0, -P], 0.04), np.union1d(pin, sl)).u
    mid = np.argmin(np.linalg.norm(foam.nodes - [L / 2, W / 2, H / 2], axis=1))
    assert np.allclose(foam.nodes[mid], [L / 2, W / 2, H / 2])
    G, I, A = E / (2 * (1 + nu)), W * H ** 3 / 12, W * H
    span = L - 2 * a
    w_ref = P * span ** 3 / (48 * E * I) + P * span / (4 * 5 / 6 * G * A)
    assert abs(-u.reshape(-1, 3)[mid, 2] / w_ref - 1) < 0.02


def test_rigid_rotation_of_the_whole_seal_is_stress_free():
    """The seal project's mesh (seal.vtu, P1) with its material (C1 = 1166 MPa, kappa = 200 C1): the whole seal
    turned rigidly by 30 deg about the lever axis (y through the pivot, the origin) has zero internal force and
    zero von Mises stress (frame indifference) to 1e-9 of a 5 % shear of the same mesh (measured 6e-12, 2e-13). Catches: a material law
    that is not frame-indifferent (e.g. a linearised strain: stresses of order C1 theta^2), a volumetric term
    that is not zero at J = 1."""
    space = FESpace(read_mesh(AR / "seal" / "seal.vtu"), "P1")
    model = ElasticModel(space, NeoHookeanIncompressible(1166e6, 233.2e9))
    X = space.nodes
    th = math.radians(30.0)
    R = np.array([[math.cos(th), 0, math.sin(th)], [0, 1, 0], [-math.sin(th), 0, math.cos(th)]])
    rigid = (X @ R.T - X).ravel()
    shear = np.zeros_like(X)
    shear[:, 0] = 0.05 * X[:, 2]
    f_ref, vm_ref = np.abs(model.internal_force(shear.ravel())).max(), von_mises(model, shear.ravel()).max()
    assert f_ref > 0 and vm_ref > 1e6
    assert np.abs(model.internal_force(rigid)).max() < 1e-9 * f_ref
    assert von_mises(model, rigid).max() < 1e-9 * vm_ref
