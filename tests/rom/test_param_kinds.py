"""Parameter kinds displacement, rotation and youngs_modulus of `physar rom build` (seed 000 §5.2-5.3).

Each reduced model is checked against the full FE solution with the same prescribed displacement /
rotation / modulus, solved here directly with physar.fem (solve_static with Dirichlet values, or a
stiffness assembled from two sub-meshes for a modulus per region), and against a closed form where one
exists: a bar (nu = 0) with a prescribed end displacement d (u_x = d x / L, reaction E A d / L), a bar
pulled by F (u_x(L) = F L / (E A): u proportional to 1/E; two halves in series: F/A (L1/E1 + L2/E2)), a
rigid rotation (a fully prescribed body, or a free neo-Hookean body turned by one face). The rotation's
reference uses scipy's Rotation, not physar's Rodrigues formula. The mutants each test catches are named
at its assertions with the error they would give.
"""
import json
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from scipy.spatial.transform import Rotation as ScipyRotation

from physar.errors import ConfigError
from physar.fem import ElasticModel, FESpace, LinearElastic, NeoHookean, point_load, solve_static
from physar.fem.config import parse_config
from physar.geometry import TetMesh, box_mesh
from physar.rom import FORMAT_VERSION, SeparatedModel
from physar.rom.config import RomConfig, build_rom, load_rom_config
from physar.rom.problem import CellScaledModel

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
L, W, H = 1.0, 0.1, 0.1
A = W * H


def _cfg(params, material=None, cells=(8, 1, 1), box=(L, W, H), fix=None, load=None, rom=None, solver=None,
         element="P2"):
    data = {"mesh": {"box": list(box), "cells": list(cells)},
            "material": material or {"model": "linear", "E": 1e7, "nu": 0.0},
            "fix": [{"plane": {"point": [0, 0, 0], "normal": [1, 0, 0]}}] if fix is None else fix,
            "fem": {"element": element}, "parameter": params}
    for k, v in (("load", load), ("rom", rom), ("solver", solver)):
        if v is not None:
            data[k] = v
    return parse_config(data, "t.toml", RomConfig)


def _build(*args, **kwargs):
    cfg = _cfg(*args, **kwargs)
    rom, space, info = build_rom(cfg, source="t.toml")
    return cfg, rom, space, info


def _rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _rigid(X, theta_deg, axis, point):
    """u = R(theta)(X - p) + p - X by scipy (independent of physar.rom.problem.Rotation)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    R = ScipyRotation.from_rotvec(np.deg2rad(theta_deg) * a)
    return (R.apply(X - point) + point - X).ravel()


def _node_dofs(mask):
    return (3 * np.flatnonzero(mask)[:, None] + np.arange(3)).ravel()


# -- displacement ------------------------------------------------------------------------------------------
def test_bar_prescribed_end_displacement_closed_form():
    """Bar (nu = 0) clamped at x = 0, end x = L translated by d e_x: u = (d x / L, 0, 0) exactly, reaction
    E A d / L. Intrusive PGD (linear material: affine in d)."""
    cfg, rom, space, _info = _build([{"name": "d", "kind": "displacement", "range": [-0.01, 0.01], "points": 5,
                                     "direction": [2, 0, 0], "plane": {"point": [L, 0, 0], "normal": [1, 0, 0]}}])
    assert cfg.rom.method == "pgd" and rom.kinds == ["displacement"] and rom.units == ["m"]
    X = space.nodes
    model = ElasticModel(space, LinearElastic(1e7, 0.0))
    end = np.isclose(X[:, 0], L)
    for d in (0.0073, -0.0041):
        u = rom.evaluate([d])
        exact = np.zeros_like(X)
        exact[:, 0] = d * X[:, 0] / L
        assert _rel(u, exact.ravel()) < 1e-9  # mutant sign flip (u = -d e): 2.0; direction ignored: 1.0
        reaction = model.internal_force(u).reshape(-1, 3)[end, 0].sum()
        assert reaction == pytest.approx(1e7 * A * d / L, rel=1e-9)
        # full FE with the same Dirichlet values
        fixed = _node_dofs(np.isclose(X[:, 0], 0) | end)
        ud = np.zeros(space.n_dofs)
        ud[_node_dofs(end)] = np.tile([d, 0, 0], end.sum())
        fe = solve_static(model, np.zeros(space.n_dofs), fixed, prescribed=ud).u
        assert _rel(u, fe) < 1e-9
    assert _rel(rom.evaluate([0.0073]), -rom.evaluate([-0.0073])) < 1e-9


def test_displacement_nonlinear_matches_full_solve():
    """StVK block clamped at z = 0, top face sheared by d e_x: non-intrusive PGD (automatic for a nonlinear
    material) against solve_static with the same Dirichlet values."""
    box = (0.1, 0.1, 0.2)
    cfg, rom, space, _info = _build(
        [{"name": "d", "kind": "displacement", "range": [-0.02, 0.02], "points": 5, "direction": [1, 0, 0],
          "plane": {"point": [0, 0, 0.2], "normal": [0, 0, 1]}}],
        material={"model": "stvk", "E": 1e5, "nu": 0.3}, cells=(2, 2, 4), box=box,
        fix=[{"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}}], rom={"tol": 1e-3}, solver={"steps": 2})
    assert cfg.rom.method == "pgd_nonintrusive"
    X = space.nodes
    top, bottom = np.isclose(X[:, 2], 0.2), np.isclose(X[:, 2], 0)
    model = ElasticModel(space, cfg_material(cfg))
    for d in (0.0137, -0.0071):
        ud = np.zeros(space.n_dofs)
        ud[_node_dofs(top)] = np.tile([d, 0, 0], top.sum())
        fe = solve_static(model, np.zeros(space.n_dofs), _node_dofs(top | bottom), steps=2, prescribed=ud).u
        err = _rel(rom.evaluate([d]), fe)
        assert err < 2e-3, err  # mutant sign flip: 2.0


def cfg_material(cfg):
    from physar.fem import make_material

    m = cfg.material
    return make_material(m.model, E=m.E, nu=m.nu)


# -- Young's modulus ---------------------------------------------------------------------------------------
TRACTION = [{"type": "traction", "plane": {"point": [L, 0, 0], "normal": [1, 0, 0]}, "total": [2.0, 0, 0]}]


def test_modulus_of_whole_body_is_one_over_E():
    """Bar (nu = 0) pulled by F = 2 N, E of every cell: u_x(L) = F L / (E A) and u(E) E = const exactly."""
    _c, rom, space, _ = _build([{"name": "E", "kind": "youngs_modulus", "range": [1e6, 1e8], "points": 41}],
                                load=TRACTION)
    assert rom.kinds == ["youngs_modulus"] and rom.units == ["Pa"]
    assert rom.grids[0][1] / rom.grids[0][0] == pytest.approx(rom.grids[0][-1] / rom.grids[0][-2])  # geometric
    X = space.nodes
    tip = np.isclose(X[:, 0], L)
    ref = rom.evaluate([1e7]) * 1e7
    for E in (1.3e6, 4.7e6, 2.2e7, 8.9e7):
        u = rom.evaluate([E])
        tip_u = u.reshape(-1, 3)[tip, 0]
        assert np.allclose(tip_u, 2.0 * L / (E * A), rtol=1e-4)  # mutant E ignored (E_ref = 1e7): 0.53 .. 7.9
        assert _rel(u * E, ref) < 1e-4
        fe = solve_static(ElasticModel(space, LinearElastic(E, 0.0)), _traction(space), _node_dofs(
            np.isclose(X[:, 0], 0))).u
        assert _rel(u, fe) < 1e-4


def _traction(space):
    from physar.fem import traction_load

    return traction_load(space, None, [2.0, 0, 0], plane=([L, 0, 0], [1, 0, 0]))


@pytest.mark.parametrize("method", ["pgd", "pgd_nonintrusive"])
def test_modulus_of_a_region_bar_in_series(method):
    """Two halves in series, the far half (x >= L/2) of modulus E2: u_x(L) = F/A (L/2 / E1 + L/2 / E2);
    intrusive (the default for a linear material) and non-intrusive PGD."""
    E1 = 1e7
    _c, rom, space, _info = _build([{"name": "E2", "kind": "youngs_modulus", "range": [1e6, 1e8], "points": 41,
                                     "box": [[0.5, 0, 0], [L, W, H]]}], load=TRACTION,
                                   rom={"method": method, "tol": 1e-4})
    tip = np.isclose(space.nodes[:, 0], L)
    for E2 in (1.9e6, 3.1e7):
        u = rom.evaluate([E2]).reshape(-1, 3)[tip, 0]
        exact = 2.0 / A * (0.5 / E1 + 0.5 / E2)
        # mutants E2 on the whole body, or E2 ignored: 0.68 (E2 = 1.9e6), 0.51 (3.1e7)
        assert np.allclose(u, exact, rtol=2e-4), (u[0], exact)


def _two_moduli_fe(space, cells, E_in, E_out, nu, fixed, f, ud=None):
    """Full FE with E_in on `cells` and E_out elsewhere: K = K(sub-mesh in) + K(sub-mesh out) (P1)."""
    m = space.mesh
    K = sum(ElasticModel(FESpace(TetMesh(m.points, m.cells[sel]), "P1"), LinearElastic(E, nu)).tangent_stiffness()
            for sel, E in ((cells, E_in), (~cells, E_out)))
    n = space.n_dofs
    free = np.setdiff1d(np.arange(n), fixed)
    u = np.zeros(n) if ud is None else ud.copy()
    u[free] = spla.spsolve(K[free][:, free].tocsc(), f[free] - K[free][:, fixed] @ u[fixed])
    return u


def test_modulus_of_region_with_moving_load_matches_two_material_fe():
    """Cantilever (nu = 0.3, P1) with a soft outer half of modulus E and a load moving along the top:
    intrusive PGD in (s, E) against a full FE assembled from the two sub-meshes."""
    path = [[0.1, 0.05, 0.1], [1.0, 0.05, 0.1]]
    _c, rom, space, info = _build(
        [{"name": "E", "kind": "youngs_modulus", "range": [2e6, 2e7], "points": 21, "box": [[0.5, 0, 0], [L, W, H]]},
         {"name": "s", "kind": "load_position", "path": path, "load": [0, 0, -1.0], "radius": 0.1, "points": 41}],
        material={"model": "linear", "E": 1e7, "nu": 0.3}, cells=(12, 2, 2), element="P1",
        rom={"max_modes": 30, "tol": 1e-6, "check_points": 3})
    assert rom.names == ["s", "E"] and rom.kinds == ["load_position", "youngs_modulus"]
    assert info["check_error"] < 2e-3
    X = space.nodes
    c = space.mesh.points[space.mesh.cells].mean(1)
    fixed = _node_dofs(np.isclose(X[:, 0], 0))
    for s, E in ((0.37, 3.3e6), (0.81, 1.4e7)):
        f = point_load(space, [0.1 + s, 0.05, 0.1], [0, 0, -1.0], 0.1)
        fe = _two_moduli_fe(space, c[:, 0] >= 0.5, E, 1e7, 0.3, fixed, f)
        err = _rel(rom.evaluate([s, E]), fe)
        assert err < 5e-4, err  # measured 1.5e-4, 2.9e-5; mutant E on the whole body: 2.0, 0.27


# -- rotation ----------------------------------------------------------------------------------------------
AXIS, PIVOT = [1.0, 1.0, 0.0], np.array([0.05, 0.0, 0.02])


def test_rotation_of_fully_prescribed_body_is_rigid():
    """Every node in the rotated region (linear material, intrusive): u = R(theta)(X - p) + p - X."""
    _c, rom, space, _info = _build(
        [{"name": "theta", "kind": "rotation", "range": [-30, 30], "points": 21, "axis": AXIS,
          "point": PIVOT.tolist(), "box": [[0, 0, 0], [0.1, 0.1, 0.1]]}],
        box=(0.1, 0.1, 0.1), cells=(1, 1, 1), fix=[])
    assert rom.kinds == ["rotation"] and rom.units == ["deg"]
    X = space.nodes
    for th in (17.3, -4.1):
        exact = _rigid(X, th, AXIS, PIVOT)
        assert _rel(rom.evaluate([th]), exact) < 1e-6
    th = 17.3
    u = rom.evaluate([th])
    assert _rel(u, _rigid(X, -th, AXIS, PIVOT)) > 1                 # mutant sign flip: 1.98
    assert _rel(u, _rigid(X, th, [1.0, -1.0, 0.0], PIVOT)) > 1      # mutant wrong axis: 1.28
    assert _rel(u, _rigid(X, np.rad2deg(th), AXIS, PIVOT)) > 1      # mutant degrees used as radians: 5.3
    assert _rel(u, _rigid(X, th, AXIS, PIVOT + [0, 0, 0.05])) > 0.5  # mutant axis through another point: 0.68


def test_rotation_of_free_neohookean_body_by_one_face_is_rigid():
    """A neo-Hookean block held only by its top face, turned by theta about the y axis through the face
    centre, turns rigidly as a whole (zero strain energy): non-intrusive PGD. Its own weight (density
    0.1 kg/m^3, [solver] tol 1e-7) stretches it by ~1e-5 of the motion: solve_static cannot converge on a
    stress-free state (its tolerance is relative to max(|f_ext|, |f_int|), both 0 there)."""
    centre = np.array([0.05, 0.05, 0.1])
    cfg, rom, space, _info = _build(
        [{"name": "theta", "kind": "rotation", "range": [-20, 20], "points": 5, "axis": [0, 1, 0],
          "point": centre.tolist(), "plane": {"point": [0, 0, 0.1], "normal": [0, 0, 1]}}],
        material={"model": "neohookean", "E": 1e5, "nu": 0.3, "density": 0.1}, box=(0.1, 0.1, 0.1),
        cells=(2, 2, 2), fix=[], load=[{"type": "gravity"}], rom={"tol": 1e-4}, solver={"steps": 2, "tol": 1e-7})
    assert cfg.rom.method == "pgd_nonintrusive"
    X = space.nodes
    for th in (11.1, -16.4):
        err = _rel(rom.evaluate([th]), _rigid(X, th, [0, 1, 0], centre))
        assert err < 1e-4, err  # mutants rotation about x: 1.35, sign flip: 1.98


@pytest.mark.parametrize("material, method", [("linear", None), ("linear", "pgd_nonintrusive"), ("neohookean", None)])
def test_seal_lever_rotation_matches_full_solve(material, method):
    """Seal (seed 000 §5.3): block clamped at z = 0, its top cuff follows a lever turning about a pivot above
    it. The ROM (by default intrusive for linear, non-intrusive else) against solve_static with the same
    Dirichlet values, the finite rotation computed by scipy."""
    pivot = np.array([0.05, 0.05, 0.3])
    cfg, rom, space, _info = _build(
        [{"name": "theta", "kind": "rotation", "range": [-15, 15], "points": 9, "axis": [0, 1, 0],
          "point": pivot.tolist(), "plane": {"point": [0, 0, 0.2], "normal": [0, 0, 1]}}],
        material={"model": material, "E": 1e5, "nu": 0.3}, box=(0.1, 0.1, 0.2), cells=(2, 2, 4),
        fix=[{"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}}],
        rom={"tol": 1e-3} if method is None else {"tol": 1e-3, "method": method}, solver={"steps": 3})
    assert cfg.rom.method == method or (method is None and cfg.rom.method == (
        "pgd" if material == "linear" else "pgd_nonintrusive"))
    X = space.nodes
    top, bottom = np.isclose(X[:, 2], 0.2), np.isclose(X[:, 2], 0)
    model = ElasticModel(space, LinearElastic(1e5, 0.3) if material == "linear" else NeoHookean(1e5, 0.3))
    for th in (12.3, -7.7):
        ud = np.zeros(space.n_dofs)
        ud[_node_dofs(top)] = _rigid(X[top], th, [0, 1, 0], pivot)
        fe = solve_static(model, np.zeros(space.n_dofs), _node_dofs(top | bottom), steps=3, prescribed=ud).u
        u = rom.evaluate([th])
        assert _rel(u, fe) < 3e-3, _rel(u, fe)
        ud_wrong = np.zeros(space.n_dofs)  # mutant: rotation about x instead of y
        ud_wrong[_node_dofs(top)] = _rigid(X[top], th, [1, 0, 0], pivot)
        assert _rel(u, ud_wrong) > 0.5


def test_rotation_in_radians_and_two_kinds_together():
    """unit = "rad" reads the range in radians; a rotation plus a modulus (linear, intrusive) against the
    two-material FE."""
    pivot = [0.05, 0.05, 0.3]
    _c, rom, space, _info = _build(
        [{"name": "theta", "kind": "rotation", "unit": "rad", "range": [-0.2, 0.2], "points": 9, "axis": [0, 1, 0],
          "point": pivot, "plane": {"point": [0, 0, 0.2], "normal": [0, 0, 1]}},
         {"name": "E", "kind": "youngs_modulus", "range": [3e4, 3e5], "points": 15, "box": [[0, 0, 0.1], [0.1, 0.1, 0.2]]}],
        material={"model": "linear", "E": 1e5, "nu": 0.3}, box=(0.1, 0.1, 0.2), cells=(2, 2, 4), element="P1",
        fix=[{"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}}], rom={"tol": 1e-6, "max_modes": 30})
    assert rom.units == ["rad", "Pa"] and rom.kinds == ["rotation", "youngs_modulus"]
    X = space.nodes
    top, bottom = np.isclose(X[:, 2], 0.2), np.isclose(X[:, 2], 0)
    c = space.mesh.points[space.mesh.cells].mean(1)
    for th, E in ((0.13, 5e4), (-0.07, 2.1e5)):
        ud = np.zeros(space.n_dofs)
        ud[_node_dofs(top)] = _rigid(X[top], np.rad2deg(th), [0, 1, 0], pivot)
        fe = _two_moduli_fe(space, c[:, 2] >= 0.1, E, 1e5, 0.3, _node_dofs(top | bottom), np.zeros(space.n_dofs), ud)
        assert _rel(rom.evaluate([th, E]), fe) < 1e-3


# -- configuration, model file -----------------------------------------------------------------------------
ROT = {"name": "theta", "kind": "rotation", "range": [-10, 10], "axis": [0, 1, 0], "point": [1, 0.05, 0.05],
       "plane": {"point": [1, 0, 0], "normal": [1, 0, 0]}}
POS = {"name": "s", "kind": "load_position", "path": [[0, 0.05, 0.1], [1, 0.05, 0.1]], "load": [0, 0, -1.0],
       "radius": 0.1}


@pytest.mark.parametrize("change, message", [
    ({"points": 1e7}, (r"t.toml: \[\[parameter\]\] 'theta': points = 10000000.0 is not an integer from 3 to 2001 "
                      r"\(the grid of parameter 'theta'\)")),
    ({"points": 10**7}, r"points = 10000000 is not an integer from 3 to 2001"),
    ({"points": 60.0}, r"points = 60.0 is not an integer"),
    ({"points": 2}, r"points = 2 is not an integer from 3"),
    ({"points": True}, r"points = True is not an integer"),
    ({"axis": None}, r"\[\[parameter\]\] 'theta': a rotation parameter needs axis"),
    ({"plane": None}, "a rotation parameter needs exactly one of box, region, at, plane"),
    ({"box": [[0, 0, 0], [1, 1, 1]]}, "exactly one of box, region, at, plane .*got box, plane"),
    ({"direction": [1, 0, 0]}, "direction does not apply to a rotation parameter"),
    ({"unit": "m"}, "unit = 'm': a rotation parameter is in 'deg' or 'rad'"),
    ({"range": [-400, 10]}, "exceeds one turn"),
    ({"axis": [0, 0, 0]}, "axis must be non-zero"),
    ({"tol": 1e-3}, "tol applies to at"),
])
def test_parameter_table_errors(change, message):
    par = {k: v for k, v in {**ROT, **change}.items() if v is not None}
    with pytest.raises(ConfigError, match=message) as e:
        _cfg([par])
    assert "\n" not in str(e.value)


def test_parameter_combinations():
    assert [p.kind for p in _cfg([ROT]).parameter] == ["rotation"]  # a rotation alone (the seal)
    cfg = _cfg([{"name": "E", "kind": "youngs_modulus", "range": [1e6, 1e8]}, POS])
    assert [p.name for p in cfg.parameter] == ["s", "E"]  # loads first, as before
    with pytest.raises(ConfigError, match="acts on the load of a kind = \"load_position\""):
        _cfg([ROT, {"name": "P", "kind": "load_magnitude", "range": [1, 2]}])
    with pytest.raises(ConfigError, match="at most one kind = \"load_position\""):
        _cfg([POS, {**POS, "name": "s2"}])
    with pytest.raises(ConfigError, match=r"t.toml: \[top level\] at most 3 \[\[parameter\]\] tables \(estimated jointly\), got 4"):
        _cfg([ROT, {**ROT, "name": "a"}, {**ROT, "name": "b"}, {**ROT, "name": "c"}])
    with pytest.raises(ConfigError, match="needs \\[material\\] E"):
        _cfg([{"name": "E", "kind": "youngs_modulus", "range": [1e6, 1e8]}],
             material={"model": "neohookean_incompressible", "C1": 1e5, "kappa": 1e7})
    with pytest.raises(ConfigError, match="range of Young's modulus must be > 0 Pa"):
        _cfg([{"name": "E", "kind": "youngs_modulus", "range": [-1, 1e8]}])
    with pytest.raises(ConfigError, match="at does not apply to a youngs_modulus"):
        _cfg([{"name": "E", "kind": "youngs_modulus", "range": [1, 2], "at": [[0, 0, 0]]}])
    assert _cfg([ROT], material={"model": "stvk", "E": 1e7, "nu": 0.3}).rom.method == "pgd_nonintrusive"
    assert _cfg([ROT]).rom.method == "pgd"


def test_build_errors_name_file_and_parameter():
    with pytest.raises(ConfigError, match=r"t.toml: \[\[parameter\]\] 'theta': no node matches box"):
        _build([{**ROT, "plane": None, "box": [[2, 2, 2], [3, 3, 3]]}])
    with pytest.raises(ConfigError, match=r"t.toml: \[\[parameter\]\] 'theta' region 'lid' not in mesh"):
        _build([{**ROT, "plane": None, "region": "lid"}])
    with pytest.raises(ConfigError, match=r"'E2': no cell \(tetrahedron\) matches box"):
        _build([{"name": "E2", "kind": "youngs_modulus", "range": [1, 2], "box": [[5, 5, 5], [6, 6, 6]]}],
               load=TRACTION)
    with pytest.raises(ConfigError, match="'E2': its cells overlap those of another youngs_modulus"):
        _build([{"name": "E1", "kind": "youngs_modulus", "range": [1, 2]},
                {"name": "E2", "kind": "youngs_modulus", "range": [1, 2], "box": [[0, 0, 0], [0.5, 1, 1]]}],
               load=TRACTION)
    with pytest.raises(ConfigError, match="method = \"pod\" builds a moving load alone"):
        _build([ROT], rom={"method": "pod"})
    with pytest.raises(ConfigError, match="needs \\[material\\] model = \"linear\""):
        _build([ROT], material={"model": "stvk", "E": 1e7, "nu": 0.3}, rom={"method": "pgd"})
    with pytest.raises(ConfigError, match="not fully constrained"):
        _build([{"name": "d", "kind": "displacement", "range": [0, 1e-3], "direction": [1, 0, 0],
                 "at": [[L, 0, 0]]}], fix=[])


def test_cell_scaled_model_scales_energy_per_cell():
    """The model of a modulus per region: scale 1 is the ElasticModel, K(scale) = sum_e scale_e K_e."""
    space = FESpace(box_mesh((1, 0.1, 0.1), (3, 1, 1)), "P2")
    base = ElasticModel(space, NeoHookean(1e6, 0.3))
    u = np.random.default_rng(0).normal(scale=1e-3, size=space.n_dofs)
    ones = np.ones(space.mesh.n_cells)
    half = np.where(np.arange(space.mesh.n_cells) % 2 == 0, 1.0, 0.0)
    assert np.allclose(CellScaledModel(base, ones).internal_force(u), base.internal_force(u))
    k1 = CellScaledModel(base, half).tangent_stiffness(u)
    k2 = CellScaledModel(base, 1 - half).tangent_stiffness(u)
    k3 = CellScaledModel(base, 3 * half + 1 - half).tangent_stiffness(u)
    assert abs(k3 - (3 * k1 + k2)).max() <= 1e-9 * abs(k3).max()
    assert abs(k1 + k2 - base.tangent_stiffness(u)).max() <= 1e-9 * abs(k3).max()
    assert CellScaledModel(base, half).energy(u) == pytest.approx(base.energy(u) - CellScaledModel(base, 1 - half).energy(u))


def test_model_file_stores_kinds_and_reads_version_1(tmp_path):
    _, rom, space, _ = _build([ROT])
    assert FORMAT_VERSION == 2
    rom.save(tmp_path / "m.npz", space=space)
    m = SeparatedModel.load(tmp_path / "m.npz")
    assert m.kinds == ["rotation"] and m.units == ["deg"]
    z = dict(np.load(tmp_path / "m.npz"))
    assert [str(k) for k in z["kinds"]] == ["rotation"] and z["kinds"].dtype.kind == "U"  # no pickle
    # a version 1 file (no kinds): kinds from the build configuration in its metadata, else from the units
    z.pop("kinds")
    z["format_version"] = np.array(1)
    np.savez(tmp_path / "v1.npz", **z)
    assert SeparatedModel.load(tmp_path / "v1.npz").kinds == ["rotation"]
    meta = json.loads(str(z["metadata_json"]))
    meta.pop("parameters")
    z["metadata_json"] = np.array(json.dumps(meta))
    z["units"] = np.array(["N"])
    np.savez(tmp_path / "v1b.npz", **z)
    assert SeparatedModel.load(tmp_path / "v1b.npz").kinds == ["load_magnitude"]
    x = np.linspace(0, 1, 5)
    old = SeparatedModel(np.ones((1, 3)), [x, x, x], [x[None]] * 3, ["s", "P", "t"], ["m", "N", "m"])
    assert old.kinds == ["load_position", "load_magnitude", "load_offset"]


# -- examples ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name, kinds", [("rom_seal_lever.toml", ["rotation"]),
                                         ("rom_region_E.toml", ["load_position", "youngs_modulus"])])
def test_examples_build_in_seconds(name, kinds, tmp_path):
    cfg = load_rom_config(EXAMPLES / name)
    t0 = time.perf_counter()
    rom, space, info = build_rom(cfg, source=name)
    assert time.perf_counter() - t0 < 30
    assert rom.kinds == kinds
    assert info.get("check_error", info.get("error_estimate")) < 5e-3
    rom.save(tmp_path / "m.npz", space=space)
    assert SeparatedModel.load(tmp_path / "m.npz").kinds == kinds
