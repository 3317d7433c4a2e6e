"""Colour range of :meth:`physar.gaussians.Gaussians.from_values` (new-user review: colours > 1 or < 0, e.g.
0-255 values, were accepted and turned into SH coefficients that render far outside [0, 1]).

``colors`` is the only colour that the class documents in [0, 1] (RGB, the DC term); it is now refused outside
[0, 1] in one line naming the Gaussian and its values. The stored SH coefficients ``sh`` are unbounded by
definition (3DGS: colour = C0 f_dc + 0.5 + higher bands, clamped at 0 by the renderer) and stay accepted by the
constructor. The bounds themselves (0 and 1) are accepted and map to the DC coefficient (c - 0.5) / C0 with
C0 = 1 / (2 sqrt(pi)) (computed here)."""
import math

import numpy as np
import pytest
import torch

from physar.errors import PhysarError
from physar.gaussians import Gaussians

D = torch.float64


def _g(colors, n=2):
    return Gaussians.from_values(torch.zeros(n, 3, dtype=D), torch.full((n,), 0.1, dtype=D),
                                 torch.full((n,), 0.8, dtype=D), colors)


@pytest.mark.parametrize("colors, words", [
    (torch.tensor([[0.2, 0.3, 0.4], [0.2, 1.5, 0.0]], dtype=D), r"colors\[1\] = \[0.2, 1.5, 0.0\] must lie in"),
    (torch.tensor([[-0.01, 0.3, 0.4], [0.2, 0.5, 0.0]], dtype=D), r"colors\[0\] = \[-0.01, 0.3, 0.4\] must lie"),
    ([[0, 128, 255], [0, 0, 0]], r"colors\[0\] = \[0.0, 128.0, 255.0\] must lie in \[0, 1\] \(RGB; not 0-255\)"),
    (np.array([[0.5, 0.5, 0.5], [1.0 + 1e-12, 0.5, 0.5]]), r"colors\[1\] = \[1.000000000001, 0.5, 0.5\]"),
])
def test_from_values_refuses_colours_outside_unit_range(colors, words):
    with pytest.raises(PhysarError, match=r"^Gaussians.from_values: " + words) as e:
        _g(colors)
    assert "\n" not in str(e.value)


def test_from_values_accepts_the_bounds():
    c = torch.tensor([[0.0, 1.0, 0.5], [1.0, 0.0, 0.25]], dtype=D)
    g = _g(c)
    c0 = 1.0 / (2.0 * math.sqrt(math.pi))
    want = [[(v - 0.5) / c0 for v in row] for row in c.tolist()]
    torch.testing.assert_close(g.sh[:, 0], torch.tensor(want, dtype=D), rtol=1e-15, atol=0)


def test_sh_coefficients_are_not_bounded():
    """A DC coefficient of 10 (colour C0 * 10 + 0.5 = 3.3) and higher bands of +-5 are legal SH values."""
    n = 3
    sh = torch.zeros(n, 4, 3, dtype=D)
    sh[:, 0], sh[:, 1:] = 10.0, -5.0
    g = Gaussians(torch.zeros(n, 3, dtype=D), torch.tensor([[1.0, 0, 0, 0]] * n, dtype=D), torch.zeros(n, 3, dtype=D),
                  torch.zeros(n, dtype=D), sh)
    g.check_finite()
    g2 = g.replace(sh=sh * 3)
    g2.check_finite()
    assert float(g2.sh.abs().max()) == 30.0
