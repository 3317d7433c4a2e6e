"""The overlay's stress for models whose stress is not linear in the mode coefficients
(:func:`physar.ar.surface.sampled_stress`): a bar of two materials in series, one a Young's modulus parameter,
stretched by a prescribed end displacement: the axial stress is delta / (L1 / E1 + L2 / E2) in both halves
(closed form; the bar is free to contract sideways except at its loaded end, which with the material interface
makes the full P2 solution itself vary by +-2 % along a segment)."""
import numpy as np

from physar.ar.surface import SurfaceOverlay, sampled_stress
from physar.fem.config import build_problem, parse_config
from physar.rom.config import RomConfig, build_parametric_problem, build_rom

ROM = {
    "mesh": {"box": [1.0, 0.1, 0.1], "cells": [20, 2, 2]},
    "material": {"model": "linear", "E": 1e7, "nu": 0.3},
    "fix": [{"plane": {"point": [0, 0, 0], "normal": [1, 0, 0]}, "components": ["x"]},
            {"plane": {"point": [0, 0, 0], "normal": [0, 1, 0]}, "components": ["y"]},
            {"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}, "components": ["z"]}],
    "fem": {"element": "P2"},
    "parameter": [
        {"name": "d", "kind": "displacement", "direction": [1, 0, 0], "range": [0.001, 0.004], "points": 7,
         "plane": {"point": [1.0, 0, 0], "normal": [1, 0, 0]}},
        {"name": "E", "kind": "youngs_modulus", "range": [2e6, 2e7], "points": 9,
         "box": [[0.5, 0, 0], [1.0, 0.1, 0.1]]}],
    "rom": {"max_modes": 20, "tol": 1e-8},
}


def test_two_materials_in_series_carry_one_stress():
    """Mid-segment von Mises of the sampled table (interpolated between grid points) within 5 % of
    delta / (0.5 / E_rest + 0.5 / E) in both halves, for a soft and a stiff region. Mutants caught: the region's
    modulus ignored (cell_scale dropped: the stress would follow one modulus, 50-80 % off), the parameter grid
    and the values misaligned (interpolation at the wrong mu)."""
    cfg = parse_config(ROM, "bar", RomConfig)
    rom, space, _ = build_rom(cfg)
    rom.__dict__["_space_cache"] = [space]          # as load_model attaches it
    problem = build_problem(cfg)
    pp = build_parametric_problem(cfg, problem, "bar")
    nodes = space.mesh.boundary().node_map
    table = sampled_stress(rom, problem.model, nodes, pp.cell_scale)
    ov = SurfaceOverlay(rom, "von_mises", stress_table=table)
    X = space.mesh.points[nodes]
    soft = (X[:, 0] > 0.15) & (X[:, 0] < 0.35)
    stiff = (X[:, 0] > 0.65) & (X[:, 0] < 0.8)
    for d, E in ((0.0023, 3.3e6), (0.0037, 1.7e7)):
        v = ov.values(None, [d, E])
        ref = d / (0.5 / 1e7 + 0.5 / E)
        for sel in (soft, stiff):
            assert np.allclose(v[sel], ref, rtol=0.05), (d, E, ref, v[sel].min(), v[sel].max())
