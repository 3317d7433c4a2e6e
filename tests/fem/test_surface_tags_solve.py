"""A CAD-like surface file with named faces, through `physar fem solve`: the surface .msh (written by gmsh's own
API, an independent writer) is tetrahedralised and its groups 'clamp' / 'load' select the support and the
traction of the problem file. The reference is Timoshenko beam theory, written out here (closed form)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from _gmsh_beam import H, L, W, gmsh_beam_surface  # tests/_gmsh_beam.py

from physar.errors import ConfigError
from physar.fem.config import build_problem, load_config, run_config

pytestmark = pytest.mark.skipif(importlib.util.find_spec("gmsh") is None, reason="needs the gmsh package")

E, NU, P = 200e9, 0.3, 100.0  # Pa, -, N (tip shear, -z); the slender steel beam L x W x H of _gmsh_beam, L/H = 10


def _problem(tmp_path, fix_region="clamp"):
    gmsh_beam_surface(tmp_path / "beam.msh")  # gmsh writes the surface .msh (Gmsh 4.1)
    toml = tmp_path / "beam.toml"
    toml.write_text(f"""
[mesh]
file = "beam.msh"
size = 0.01

[material]
model = "linear"
E = {E}
nu = {NU}

[[fix]]
region = "{fix_region}"

[[load]]
type = "traction"
region = "load"
total = [0, 0, -{P}]

[[probe]]
point = [{L}, {W / 2}, {H / 2}]

[fem]
element = "P2"
""")
    return toml


def _timoshenko_tip() -> float:
    """delta = P L^3 / (3 E I) + P L / (k G A), Cowper's k = 10 (1 + nu) / (12 + 11 nu) of a rectangle."""
    inertia, area, shear = W * H**3 / 12, W * H, E / (2 * (1 + NU))
    return P * L**3 / (3 * E * inertia) + P * L / (10 * (1 + NU) / (12 + 11 * NU) * shear * area)


# mutants caught: tags dropped by read_mesh or not carried by tetrahedralize (region 'clamp' not in mesh), the
# names not carried, every face given one tag (the fix then holds the whole surface: no deflection, or the traction
# spreads over the whole surface), the clamp and load ends swapped (the probe end is then held)
def test_named_surface_solves_like_timoshenko(tmp_path):
    res = run_config(_problem(tmp_path))
    uz = res.summary()["probes"][0]["u"][2]
    ref = _timoshenko_tip()  # 1.0077e-4 m
    # P2 at 1 cm (2 elements through the depth): 0.8 % stiffer than Timoshenko (the clamp's Poisson restraint)
    assert -uz == pytest.approx(ref, rel=0.02)
    sp = res.problem.space
    fixed_nodes = np.unique(res.problem.fixed // 3)
    assert np.allclose(sp.nodes[fixed_nodes, 0], 0.0)  # only the x = 0 face is held: its nodes, all of them
    assert len(fixed_nodes) == int(np.isclose(sp.nodes[:, 0], 0.0).sum())
    f = res.problem.f_ext.reshape(-1, 3)
    loaded = np.flatnonzero(np.abs(f).sum(axis=1) > 0)
    assert np.allclose(sp.nodes[loaded, 0], L) and f[:, 2].sum() == pytest.approx(-P, rel=1e-12)


# mutants caught: the names of the surface not in the "available" list of the missing-region error (ids only,
# or "none: the mesh file has no tags")
def test_missing_region_lists_the_surface_names(tmp_path):
    cfg = load_config(_problem(tmp_path, fix_region="clamps"))
    with pytest.raises(ConfigError) as e:
        build_problem(cfg)
    assert str(e.value) == ("[[fix]] #1 region 'clamps' not in mesh (available: 1, 2, 3, 'clamp', 'load', "
                            "'rest')")
