"""Granular column collapse (Drucker-Prager sand, seed 002 §3.2): the deposit's flanks settle near the friction angle.

Quasi-2-D (plane strain): a sand slab spanning the whole domain in y between slip walls, on a sticky ground,
released from rest.  Aspect ratio H / (W / 2) = 0.5, so the column only partly collapses and leaves a pile
whose flanks are at the angle of repose, which for a cohesionless Drucker-Prager material is its friction
angle phi (Klar et al. 2016).  The surface profile h(x) is the median over y of the highest particle in each
(x, y) column of width dx / 2; the slope is a least-squares line through h(x) where 10 % < h / h_max < 90 %,
on each side.
"""

import numpy as np
import pytest

from physar.mpm import MPMSolver, build_model, parse_scene

PHI = 30.0


def _surface_slopes(x, h_bin):
    ix = np.floor(x[:, 0] / h_bin).astype(int)
    iy = np.floor(x[:, 1] / h_bin).astype(int)
    top = np.zeros((ix.max() + 1, iy.max() + 1))
    np.maximum.at(top, (ix, iy), x[:, 2])
    h = np.median(top, axis=1)
    c = (np.arange(len(h)) + 0.5) * h_bin
    hm = h.max()
    out = []
    for side in (c < 0.5, c > 0.5):
        sel = side & (h > 0.1 * hm) & (h < 0.9 * hm)
        assert sel.sum() >= 5, "too few surface samples on a flank"
        out.append(np.degrees(np.arctan(abs(np.polyfit(c[sel], h[sel], 1)[0]))))
    return np.array(out), c[h > 0.05 * hm].min(), hm


@pytest.mark.slow
def test_sand_column_collapses_to_friction_angle_pile():
    W, H, res = 0.5, 0.125, 32
    sc = parse_scene({
        "grid": {"size": 1.0, "resolution": res},
        "time": {"frame_dt": 0.02, "substeps": 36, "frames": 30},
        "boundary": {"ground": "sticky", "walls": "slip"},
        "body": [{"shape": "box", "min": [0.5 - W / 2, 0.0, 0.0], "max": [0.5 + W / 2, 1.0, H],
                  "material": "drucker_prager", "friction_angle": PHI, "E": 3e5, "nu": 0.3, "density": 1500}],
    })
    model, x, v = build_model(sc)
    solver = MPMSolver(model)
    a, b = model.state(x, v), model.state(x, v)
    for _ in range(sc.time.frames):
        a, b = solver.simulate_frame(a, b)
    st = a.numpy()
    ke = 0.5 * np.sum(model.mass * np.sum(st["v"] ** 2, axis=1))
    pe_drop = np.sum(model.mass) * 9.81 * H / 2
    assert ke < 0.05 * pe_drop, "the pile has not come to rest"
    slopes, toe, h_max = _surface_slopes(st["x"], model.dx / 2)
    print("flank slopes (deg)", slopes, "toe", toe, "h_max", h_max)
    assert toe < 0.5 - W / 2 - model.dx  # it collapsed outwards (by ~1.75 dx)
    assert h_max > 0.8 * H  # ... to a pile with an undisturbed core
    assert np.all(np.abs(slopes - PHI) < 5.0), slopes
