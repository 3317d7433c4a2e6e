"""physar agrees with scikit-fem (a peer library) on the same mesh, element and load."""

import sys
from pathlib import Path

import numpy as np
import pytest

from physar.fem import ElasticModel, FESpace, LinearElastic, fixed_dofs, probe, solve_static, traction_load
from physar.geometry import box_mesh

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from skfem_peer import skfem_cantilever


@pytest.mark.filterwarnings("ignore")
@pytest.mark.parametrize("element", ["P1", "P2"])
def test_tip_matches_scikit_fem(element):
    L, b, h, E, nu, P = 1.0, 0.1, 0.1, 69e9, 0.334, 1000.0
    mesh = box_mesh((L, b, h), (12, 2, 2))
    space = FESpace(mesh, element)
    model = ElasticModel(space, LinearElastic(E, nu))
    u = solve_static(
        model,
        traction_load(space, [[L, 0, 0], [L, b, h]], [0, 0, -P]),
        fixed_dofs(space, box=[[0, 0, 0], [0, b, h]]),
    ).u
    ours = probe(space, u, [L, b / 2, h / 2])
    peer = skfem_cantilever(mesh, element, E, nu, L, b, h, P)
    assert np.allclose(ours, peer, rtol=1e-8, atol=1e-9 * abs(peer[2]))
