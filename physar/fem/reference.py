"""Closed-form references used to verify the FEM layer (independent of the discretisation)."""

from __future__ import annotations


def timoshenko_cantilever_tip(P: float, L: float, b: float, h: float, E: float, nu: float) -> float:
    r"""Tip deflection [m] of a cantilever of length L, width b, height h under an end shear load P [N].

    Timoshenko beam:

    .. math::

        \delta = \frac{P L^3}{3 E I} + \frac{P L}{k G A}, \quad I = \frac{b h^3}{12}, \quad A = b h, \quad
        G = \frac{E}{2 (1 + \nu)},

    shear coefficient :math:`k = 10 (1 + \nu) / (12 + 11 \nu)` (Cowper 1966, rectangle).
    """
    I = b * h**3 / 12.0
    A = b * h
    G = E / (2.0 * (1.0 + nu))
    k = 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu)
    return P * L**3 / (3.0 * E * I) + P * L / (k * G * A)
