"""Static solves converge from 1e-6 to 1e3 times a reference load, on soft and stiff materials.

The reference load P_ref gives a linear tip deflection of L / 1000. The Newton stopping test is relative
to the load and the internal forces, with an absolute floor at the round-off of f_int (10 ε ||diag K|| h),
used once Newton stagnates: the co-rotated and St.VK forces of a stiff beam carry a round-off of
~1e-6 N whatever the load (measured), which a purely relative test never reaches.
"""

import warnings

import numpy as np
import pytest

from physar.errors import PhysarWarning, SolverError
from physar.fem import (
    ElasticModel,
    FESpace,
    fixed_dofs,
    make_material,
    probe,
    solve_static,
    solvers,
    traction_load,
)
from physar.geometry import box_mesh

L, B = 1.0, 0.1


def beam(material, E, element="P2"):
    space = FESpace(box_mesh((L, B, B), (10, 1, 1)), element)
    model = ElasticModel(space, make_material(material, E=E, nu=0.3))
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, B, B]])
    unit = traction_load(space, [[L, 0, 0], [L, B, B]], [0, 0, -1.0])
    lin = ElasticModel(space, make_material("linear", E=E, nu=0.3))
    tip_unit = probe(space, solve_static(lin, unit, fixed).u, [L, B / 2, B / 2])[2]
    return space, model, fixed, unit, -1e-3 * L / tip_unit  # P_ref [N]


@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("material", ["corotated", "stvk", "neohookean"])
@pytest.mark.parametrize("E", [2e5, 69e9])
def test_tiny_to_large_loads_converge(material, E, element):
    """Every load factor 1e-6 ... 1e3 converges with default settings; in the small-strain range
    (<= 1e-2 P_ref) the tip is linear in the load to 1e-4 (so convergence is not a premature stop).
    Mutants: no round-off floor (the old purely relative test): all 12 cases raise SolverError; an
    absolute acceptance before the first Newton step (|R| <= 1e-3 (|f| + 1 N)): the soft tiny-load tips
    stay 0, 3 cases fail."""
    space, model, fixed, unit, p_ref = beam(material, E, element)
    tips = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PhysarWarning)  # P1 locking at 1e3 P_ref
        for k in (1e-6, 1e-4, 1e-2, 1.0, 1e3):
            res = solve_static(model, k * p_ref * unit, fixed)
            tips[k] = probe(space, res.u, [L, B / 2, B / 2])[2]
    assert np.isfinite(list(tips.values())).all()
    for k in (1e-6, 1e-4):
        assert tips[k] / k == pytest.approx(tips[1e-2] / 1e-2, rel=1e-4)
    assert tips[1e3] < tips[1.0] < 0


def test_tolerance_below_round_off_names_the_cause(monkeypatch):
    """Without the round-off floor, tol = 1e-18 cannot be met in double precision: the message says the
    residual stalled at round-off and to raise tol (mutant: the old advice 'increase [solver] steps', or a
    'limit point' diagnosis). With the floor the same solve converges."""

    _space, model, fixed, unit, p_ref = beam("stvk", 69e9)
    assert solve_static(model, p_ref * unit, fixed, tol=1e-18, max_iter=8).load_factors[-1] == 1.0
    monkeypatch.setattr(solvers, "_FLOOR", 0.0)
    with pytest.raises(SolverError) as exc:
        solve_static(model, p_ref * unit, fixed, tol=1e-18, max_iter=8)
    msg = str(exc.value)
    assert "stalled" in msg and "round-off" in msg and "raise tol" in msg and "steps" not in msg
    assert "\n" not in msg
