"""The coarser surface the AR overlay draws for a finely meshed model (physar.ar.surface.display_surface,
physar.geometry.remesh), against closed forms that share nothing with it.

The example cantilever (examples/ar/cantilever/rom.toml: 0.5 x 0.02 x 0.015 m aluminium box beam clamped at
x = 0, 200 N moving along the top), meshed twice as finely (80 x 4 x 4 cells: 2624 surface triangles), is drawn
with at most 800 triangles, so the overlay draws an even triangulation of its own and carries the model's fields
over by barycentric weights:

* geometry: every drawn vertex lies on the box's surface, the drawn area is the box's 2(LB + LH + BH) and the
  volume enclosed by the drawn triangles (divergence theorem, outward winding) is L B H. Catches an unflipped
  winding (volume < L B H: faces culled on the wrong side) and a surface moved off the model's;
* displacement: the drawn deflection of the beam axis under a tip load follows Euler-Bernoulli
  w(x) = P x^2 (3 s - x) / (6 E I) away from the clamp. Catches wrong barycentric weights (another triangle's
  vertices, a row of W mixed), swapped displacement axes, and the drawn surface moving by the model's full-
  surface vertex ordering;
* a field linear in x is carried exactly (W reproduces A x + b at the drawn vertices to round-off);
* stress: on the top and bottom fibres away from the clamp and the load, the drawn von Mises is beam theory's
  |M c / I| within 5 % of the peak, and the maximum the overlay reports is the model surface's (at least
  0.98 P s c / I; the singular clamp corner reads 7 % above it on this mesh), not the coarser drawing's (which
  is 7.5 % lower: the mutant reporting the drawn maximum fails).
"""
from pathlib import Path

import numpy as np
import pytest

from physar.ar.surface import SurfaceOverlay, display_surface
from physar.rom import SeparatedModel
from physar.rom.config import build_rom, load_rom_config

ROM_TOML = Path(__file__).resolve().parents[2] / "examples" / "ar" / "cantilever" / "rom.toml"
L, B, H = 0.5, 0.02, 0.015
P, E, NU = 200.0, 69e9, 0.334
I, C = B * H**3 / 12, H / 2
MAX_FACES = 800


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    cfg = load_rom_config(ROM_TOML)
    assert (tuple(cfg.mesh.box), cfg.material.E, cfg.material.nu, cfg.parameter[0].load[2]) == ((L, B, H), E, NU, -P), \
        "the example changed: update the constants"
    cfg.mesh.cells = (80, 4, 4)
    rom, space, _ = build_rom(cfg)
    path = tmp_path_factory.mktemp("display") / "model.npz"
    rom.save(path, space=space)
    return SeparatedModel.load(path)


@pytest.fixture(scope="module")
def overlays(model):
    return (SurfaceOverlay(model, "von_mises", material=(E, NU), max_faces=MAX_FACES),
            SurfaceOverlay(model, "u", max_faces=MAX_FACES))


def test_drawn_surface_is_the_box(overlays):
    """Vertices on the box surface, area and enclosed volume of the box, fewer triangles than the model's."""
    ov = overlays[0]
    X, F = ov.X0, ov.faces
    assert ov.W is not None and len(F) <= 1.1 * MAX_FACES
    d_out = np.maximum(np.maximum(-X, X - [L, B, H]), 0).max(1)
    d_in = np.minimum(X, [L, B, H] - X).min(1)            # distance to the nearest face, from inside
    assert d_out.max() < 1e-9 and np.abs(d_in).max() < 1e-9
    x = X[F]
    n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1).sum()
    volume = np.einsum("ij,ij->", x[:, 0], n) / 6
    assert area == pytest.approx(2 * (L * B + L * H + B * H), rel=1e-9)
    assert volume == pytest.approx(L * B * H, rel=1e-9)


def test_linear_field_is_carried_exactly(overlays):
    """W reproduces a field linear in the position at the drawn vertices."""
    ov = overlays[0]
    A, b = np.array([0.3, -2.0, 5.0]), 0.7
    assert np.abs(ov.W @ (ov.X_model @ A + b) - (ov.X0 @ A + b)).max() < 1e-12


def test_drawn_deflection_is_euler_bernoulli(model, overlays):
    """u_z of the drawn vertices on the beam's top face with the load at the tip (s = L): Euler-Bernoulli
    within 3 % of the tip deflection for 0.1 <= x <= 0.45 m; u_x, u_y small there (not swapped in)."""
    ov = overlays[1]
    c = model.coefficients([L])[0]
    u = np.tensordot(c, ov.U, 1)
    top = (np.abs(ov.X0[:, 2] - H) < 1e-9) & (ov.X0[:, 0] >= 0.1) & (ov.X0[:, 0] <= 0.45)
    assert top.sum() >= 10
    x = ov.X0[top, 0]
    w = -P * x**2 * (3 * L - x) / (6 * E * I)
    tip = P * L**3 / (3 * E * I)
    assert np.abs(u[top, 2] - w).max() <= 0.03 * tip
    assert np.abs(u[top, 1]).max() <= 0.01 * tip


def test_drawn_stress_and_reported_maximum(model, overlays):
    """Drawn von Mises on the top and bottom fibres within 5 % of |M c / I|'s peak in the zone (one depth from
    the clamp, the load's radius + one depth from the load); reported maximum = the model surface's maximum,
    at least 0.98 times the clamp stress P s c / I."""
    ov = overlays[0]
    for s in (0.3, 0.5):
        c = model.coefficients([s])[0]
        v_model = ov.values(c, [s])
        v = ov.W @ v_model
        X = ov.X0
        fibre = (X[:, 0] >= H) & (np.abs(X[:, 0] - s) >= 0.01 + H) & (
            (np.abs(X[:, 2]) < 1e-9) | (np.abs(X[:, 2] - H) < 1e-9))
        beam = P * np.clip(s - X[fibre, 0], 0, None) * C / I
        assert fibre.sum() >= 10
        assert np.abs(v[fibre] - beam).max() <= 0.05 * beam.max()
        from physar.vision.camera import Camera, Pose

        cam = Camera(np.array([[800.0, 0, 640], [0, 800.0, 360], [0, 0, 1]]))
        pose = Pose.from_rvec([np.pi, 0.0, 0.0], [-L / 2, 0.0, 1.0])       # looking at the top face
        _p, ids, _lev, vmax = ov.geometry(cam, pose, c, [s])
        assert ids is not None and len(ids) > 0
        assert vmax == pytest.approx(v_model.max(), rel=1e-12)
        assert vmax >= 0.98 * P * s * C / I


def test_small_surfaces_are_drawn_as_they_are(model):
    """At most max_faces triangles: no new surface (None), the overlay draws the model's own."""
    ov = SurfaceOverlay(model, "u", max_faces=3000)
    assert ov.W is None and display_surface(ov.X0, ov.faces, len(ov.faces)) is None


def test_reported_peak_of_a_signed_component_is_the_deflection(model):
    """Field u_z with the load at the tip: the reported value is the tip deflection with its sign, within 5 % of
    Euler-Bernoulli's -P L^3 / (3 E I) (a review found "max u_z 0.00104 mm" drawn while the tip was 2.97 mm
    down: the largest positive value). Mutant caught: max() instead of the signed peak (a small positive
    value, not about -3.2 mm)."""
    from physar.vision.camera import Camera, Pose

    ov = SurfaceOverlay(model, "uz", max_faces=MAX_FACES)
    c = model.coefficients([L])[0]
    cam = Camera(np.array([[800.0, 0, 640], [0, 800.0, 360], [0, 0, 1]]))
    pose = Pose.from_rvec([np.pi, 0.0, 0.0], [-L / 2, 0.0, 1.0])
    _p, _ids, _lev, peak = ov.geometry(cam, pose, c, [L])
    tip = -P * L**3 / (3 * E * I)
    assert peak == pytest.approx(tip, rel=0.05), (peak, tip)
