"""build_moving_load_pgd refuses what a solve refuses, before the PGD runs.

Reference for the accepted case: the full solve (solve_linear) at a grid point, with the supports as a mask
and as indices. Each test names the mutant it catches.
"""

import numpy as np
import pytest

from physar.errors import ConfigError, PhysarError, SolverError
from physar.fem import ElasticModel, FESpace, LinearElastic, fixed_dofs, point_load, solve_linear
from physar.geometry import box_mesh
from physar.rom import build_moving_load_pgd

L, W, R = 1.0, 0.1, 0.08
PATH = [[0, W / 2, W], [L, W / 2, W]]


@pytest.fixture(scope="module")
def beam():
    space = FESpace(box_mesh((L, W, W), (10, 2, 2)), "P1")
    model = ElasticModel(space, LinearElastic(1e7, 0.3))
    return model, fixed_dofs(space, box=[[0, 0, 0], [0, W, W]])


def test_no_supports_is_refused_like_a_solve(beam):
    # mutant: no constraint check: a PGD of the singular K, mode amplitudes ~1e10 and a plausible evaluate
    model, _ = beam
    with pytest.raises(SolverError, match="rigid-body modes are free"):
        build_moving_load_pgd(model, [], PATH, points=11, magnitude_range=(0.2, 3.0), radius=R)


def test_zero_load_and_single_point_have_direct_messages(beam):
    # mutants: load (0, 0, 0) and points = 1 reported as a "singular system"
    model, fixed = beam
    with pytest.raises(ConfigError, match=r"load must be a finite, non-zero force vector.*\(0, 0, 0\)"):
        build_moving_load_pgd(model, fixed, PATH, points=11, load=(0, 0, 0), radius=R)
    with pytest.raises(ConfigError, match="points .* must be an integer >= 2, got 1"):
        build_moving_load_pgd(model, fixed, PATH, points=1, radius=R)


def test_negative_fixed_dof_is_refused(beam):
    # mutant: np.setdiff1d(arange, fixed) ignores -1 silently
    model, fixed = beam
    with pytest.raises(ConfigError, match=rf"fixed: dof index -1 is out of range 0..{model.n_dofs - 1}"):
        build_moving_load_pgd(model, np.r_[fixed, -1], PATH, points=11, radius=R)


def test_mask_supports_match_index_supports_and_the_full_solve(beam):
    model, fixed = beam
    mask = np.zeros(model.n_dofs, bool)
    mask[fixed] = True
    rom_i, _ = build_moving_load_pgd(model, fixed, PATH, points=11, radius=R, tol=1e-8)
    rom_m, _ = build_moving_load_pgd(model, mask, PATH, points=11, radius=R, tol=1e-8)
    s = 0.6  # a grid point (11 points over 1 m)
    np.testing.assert_array_equal(rom_m.evaluate([s]), rom_i.evaluate([s]))
    u = solve_linear(model, point_load(model.space, [s, W / 2, W], [0, 0, -1.0], R), fixed)
    np.testing.assert_allclose(rom_m.evaluate([s]), u, atol=1e-3 * np.abs(u).max())


def test_a_second_free_body_is_refused_before_the_pgd(beam):
    # A beam fixed at x = 0 plus a loose cube beside it (two pieces): the whole mesh's rigid modes are held,
    # the cube's are not; the PGD of that singular K used to run. mutant caught: cells not passed to
    # check_constraints (the whole-mesh test only)
    from physar.geometry.mesh import TetMesh

    model, _ = beam
    m = model.space.mesh
    cube = box_mesh((0.05, 0.05, 0.05), (1, 1, 1))
    two = TetMesh(np.vstack([m.points, cube.points + [0.0, 0.2, 0.0]]), np.vstack([m.cells, cube.cells + m.n_points]))
    model2 = ElasticModel(FESpace(two, "P1"), LinearElastic(1e9, 0.3))
    fixed = fixed_dofs(model2.space, box=[[0, 0, 0], [0, W, W]])  # the beam's end only
    with pytest.raises(SolverError, match=r"2 separate pieces.*1 of them is not fully constrained.*6 elements "
                                          r"and 8 nodes"):
        build_moving_load_pgd(model2, fixed, PATH, points=11, radius=R)


def test_evaluate_refuses_a_nan_parameter_and_names_it(beam):
    # mutant caught: no finiteness check (evaluate([nan]) returned a NaN field; sensitivities too)
    model, fixed = beam
    rom, _ = build_moving_load_pgd(model, fixed, PATH, points=11, radius=R)
    for fn in (rom.evaluate, rom.sensitivities, rom.coefficients):
        with pytest.raises(PhysarError, match=rf"parameter {rom.names[0]!r} = nan must be a finite number"):
            fn([float("nan")])
    assert np.isfinite(rom.evaluate([0.5])).all()
