"""A load moving along a polyline (an L-shaped path on the top of a beam): path_point against hand
computation; the intrusive PGD and the POD baseline against full solves (physar.fem.solve_static with
point_load at path(s), independent of the reduced models)."""
import numpy as np
import pytest

from physar.errors import ConfigError
from physar.fem import ElasticModel, FESpace, LinearElastic, fixed_dofs, point_load, solve_static
from physar.fem.config import parse_config
from physar.geometry import box_mesh, path_length, path_point
from physar.rom.config import RomConfig
from physar.rom.elastic import build_moving_load_pgd, load_path_matrix
from physar.rom.nonintrusive import MovingLoadProblem
from physar.rom.pod import build_moving_load_pod

L, W, H = 1.0, 0.1, 0.1
PATH = [[0.3, 0.02, H], [0.9, 0.02, H], [0.9, 0.08, H]]  # along x for 0.6 m, then across for 0.06 m
LOAD, RADIUS = (0, 0, -1.0), 0.08


def test_path_point_by_hand():
    """3-4-5 polyline (0,0,0) -> (3,0,0) -> (3,4,0), length 7. Catches: interpolating on the chord from
    the first to the last point ((3,0,0) would be (9/7, 12/7, 0)), a fraction of the total length per
    segment, s measured from the end."""
    p = [[0, 0, 0], [3, 0, 0], [3, 4, 0]]
    assert path_length(p) == 7.0
    np.testing.assert_allclose(path_point(p, 0.0), [0, 0, 0])
    np.testing.assert_allclose(path_point(p, 1.5), [1.5, 0, 0])
    np.testing.assert_allclose(path_point(p, 3.0), [3, 0, 0])
    np.testing.assert_allclose(path_point(p, 5.0), [3, 2, 0])
    np.testing.assert_allclose(path_point(p, [7.0, 4.0]), [[3, 4, 0], [3, 1, 0]])
    with pytest.raises(ConfigError, match=r"outside the path \[0, 7\] m"):
        path_point(p, 7.5)
    with pytest.raises(ConfigError, match="segment 1 .* has zero length"):
        path_point([[0, 0, 0], [1, 0, 0], [1, 0, 0]], 0.5)
    with pytest.raises(ConfigError, match=">= 2 points"):
        path_length([[0, 0, 0]])


def test_grid_is_uniform_in_arc_length_and_blackbox_follows_the_polyline():
    space = FESpace(box_mesh((L, W, H), (8, 2, 2)), "P1")
    s, B = load_path_matrix(space, PATH, 12, LOAD, RADIUS)
    np.testing.assert_allclose(s, np.linspace(0, 0.66, 12))
    # column at s = 0.66: the load at the end point (0.9, 0.08, H)
    np.testing.assert_allclose(B[:, -1], point_load(space, PATH[-1], LOAD, RADIUS), atol=1e-15)
    bb = MovingLoadProblem(ElasticModel(space, LinearElastic(1e7, 0.3)), [], PATH, LOAD, RADIUS)
    assert bb.length == pytest.approx(0.66)
    np.testing.assert_allclose(bb.point([0.63]), [0.9, 0.05, H])  # 0.03 along the second leg


def _setup():
    space = FESpace(box_mesh((L, W, H), (16, 2, 2)), "P1")
    model = ElasticModel(space, LinearElastic(E=1e7, nu=0.3))
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, W, H]])
    return space, model, fixed


@pytest.fixture(scope="module")
def full():
    space, model, fixed = _setup()
    ss = np.r_[np.random.default_rng(3).uniform(0, 0.66, 8), 0.61, 0.64]  # two on the second leg
    U = [solve_static(model, point_load(space, path_point(PATH, s), LOAD, RADIUS), fixed).u for s in ss]
    return space, model, fixed, ss, np.array(U)


def test_pgd_on_polyline_matches_full_solves(full):
    """Within 1e-3 of the largest response (the README's PGD tolerance). Catches: the load placed on
    the straight chord from the first to the last point (measured error 8e-2),
    a grid not uniform in arc length."""
    _space, model, fixed, ss, U = full
    rom, _info = build_moving_load_pgd(model, fixed, PATH, points=81, load=LOAD, radius=RADIUS,
                                      max_modes=25, tol=1e-5, n_check=4)
    err = max(np.linalg.norm(rom.evaluate([s]) - u) for s, u in zip(ss, U)) / np.linalg.norm(U, axis=1).max()
    assert err < 1e-3, err
    assert rom.metadata["path"] == PATH and rom.grids[0][-1] == pytest.approx(0.66)


def test_pod_on_polyline_matches_full_solves(full):
    _space, model, fixed, ss, U = full
    rom, _ = build_moving_load_pod(model, fixed, PATH, points=81, load=LOAD, radius=RADIUS, max_modes=30, tol=1e-8)
    err = max(np.linalg.norm(rom.evaluate([s]) - u) for s, u in zip(ss, U)) / np.linalg.norm(U, axis=1).max()
    assert err < 1e-3, err


def test_rom_config_takes_a_polyline():
    base = {"mesh": {"box": [L, W, H], "cells": [4, 1, 1]}, "material": {"model": "linear", "E": 1.0, "nu": 0.3},
            "fix": [{"box": [[0, 0, 0], [0, W, H]]}]}
    par = {"name": "s", "kind": "load_position", "load": [0, 0, -1.0], "radius": 0.05}
    cfg = parse_config({**base, "parameter": [{**par, "path": PATH}]}, "r.toml", RomConfig)
    assert len(cfg.parameter[0].path) == 3
    with pytest.raises(ConfigError, match=r"^r.toml: \[\[parameter\]\] 's': path segment 1 \(points 1 and 2\) has zero length"):
        parse_config({**base, "parameter": [{**par, "path": PATH[:2] + [PATH[1]]}]}, "r.toml", RomConfig)
    with pytest.raises(ConfigError, match=r"r.toml: \[\[parameter\]\] 's': path"):
        parse_config({**base, "parameter": [{**par, "path": PATH[:1]}]}, "r.toml", RomConfig)
