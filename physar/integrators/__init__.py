r"""Time integrators for elastodynamics (seed 001 §2).

.. math:: M q'' = f_\text{els}(q) + f_\text{dmp}(q, v) + f_\text{ext}

Models (:mod:`physar.integrators.model`), steppers sharing one Newton/sparse-solve machinery
(:mod:`physar.integrators.steppers`), and the artificial-damping analysis
(:mod:`physar.integrators.analysis`).
"""

from physar.integrators.analysis import (
    amplification_matrix,
    d_backward_euler,
    damping_curve,
    rho_backward_euler,
    spectral_radius,
)
from physar.integrators.model import (
    CorotatedP1Kernel,
    DynamicsModel,
    FemKernel,
    Ground,
    LinearDynamics,
    SolidModel,
    make_kernel,
)
from physar.integrators.steppers import (
    METHODS,
    TRBDF2,
    BackwardEuler,
    GeneralizedAlpha,
    ImplicitMidpoint,
    Integrator,
    SemiImplicit,
    State,
    SymplecticEuler,
    ThetaMethod,
    explicit_step_limit,
    genalpha_coefficients,
    make_integrator,
    simulate,
)

__all__ = [
    "METHODS",
    "TRBDF2",
    "BackwardEuler",
    "CorotatedP1Kernel",
    "DynamicsModel",
    "FemKernel",
    "GeneralizedAlpha",
    "Ground",
    "ImplicitMidpoint",
    "Integrator",
    "LinearDynamics",
    "SemiImplicit",
    "SolidModel",
    "State",
    "SymplecticEuler",
    "ThetaMethod",
    "amplification_matrix",
    "d_backward_euler",
    "damping_curve",
    "explicit_step_limit",
    "genalpha_coefficients",
    "make_integrator",
    "make_kernel",
    "rho_backward_euler",
    "simulate",
    "spectral_radius",
]
