"""FEM layer: P1/P2 tetrahedra, hyperelastic materials, assembly, loads, static solvers.

Everything is vectorised over elements (numpy); the dof of node :math:`a`, component :math:`i` is
:math:`3a + i`.
"""

from physar.fem.assembly import CSRPattern, ElasticModel
from physar.fem.elements import FESpace, shape_functions, tet_quadrature, tri_quadrature
from physar.fem.loads import bump, fixed_dofs, gravity_load, point_load, traction_load
from physar.fem.materials import (
    MATERIALS,
    Corotated,
    LinearElastic,
    Material,
    NeoHookean,
    NeoHookeanIncompressible,
    StVK,
    lame,
    make_material,
    polar,
)
from physar.fem.post import cauchy_stress, locate, nodal_average, probe, von_mises
from physar.fem.reference import timoshenko_cantilever_tip
from physar.fem.solvers import (
    Factor,
    LinearSolver,
    StaticResult,
    check_constraints,
    check_solve_memory,
    dof_indices,
    estimate_solve_memory,
    factorize,
    has_cholmod,
    mesh_pieces,
    rigid_body_modes,
    solve_linear,
    solve_static,
)

__all__ = [
    "MATERIALS",
    "CSRPattern",
    "Corotated",
    "ElasticModel",
    "FESpace",
    "Factor",
    "LinearElastic",
    "LinearSolver",
    "Material",
    "NeoHookean",
    "NeoHookeanIncompressible",
    "StVK",
    "StaticResult",
    "bump",
    "cauchy_stress",
    "check_constraints",
    "check_solve_memory",
    "dof_indices",
    "estimate_solve_memory",
    "factorize",
    "fixed_dofs",
    "gravity_load",
    "has_cholmod",
    "lame",
    "locate",
    "make_material",
    "mesh_pieces",
    "nodal_average",
    "point_load",
    "polar",
    "probe",
    "rigid_body_modes",
    "shape_functions",
    "solve_linear",
    "solve_static",
    "tet_quadrature",
    "timoshenko_cantilever_tip",
    "traction_load",
    "tri_quadrature",
    "von_mises",
]
