"""A NaN measurement std given to :meth:`physar.assimilation.filters.IMMFilter.update` (new-user review).

It was silently replaced by the noise floor (2e-4 of the range), i.e. an unknown uncertainty became the most
trusted measurement possible. It is now refused, like a negative or infinite std, in one line naming
``std[i]`` and the value, on the first frame (where the std sets the initial variance) and later ones, and for
one std given for all parameters. A refused frame leaves the filter as it was: the next valid frames give the
closed forms of the first frame (the measurement and its std) and of the scalar random-walk Kalman update
:math:`x = z_1 + K (z_2 - z_1)`, :math:`K = (R_1 + q) / (R_1 + q + R_2)` (``switch=(0, 1)``: the "moving"
model is never entered; ``jump_sigma=inf``)."""
import math

import numpy as np
import pytest

from physar.assimilation.filters import IMMFilter
from physar.errors import PhysarError


@pytest.mark.parametrize("std, words", [
    ([0.01, math.nan], r"std\[1\] = nan must be >= 0 and finite"),
    (math.nan, r"std\[0\] = nan must be >= 0 and finite"),             # one std for all parameters
    ([math.inf, 0.01], r"std\[0\] = inf must be >= 0 and finite"),
    ([0.01, -0.5], r"std\[1\] = -0.5 must be >= 0 and finite"),
    ([-math.inf, 0.01], r"std\[0\] = -inf must be >= 0 and finite"),
])
def test_first_frame_refuses_bad_std(std, words):
    f = IMMFilter([0.0, 0.0], [1.0, 1.0])
    with pytest.raises(PhysarError, match=r"^IMMFilter.update: " + words) as e:
        f.update([0.5, 0.5], std)
    assert "\n" not in str(e.value)
    z, s = f.update([0.25, 0.75], [0.1, 0.2])        # still fresh: the first frame is the measurement
    np.testing.assert_array_equal(z, [0.25, 0.75])
    np.testing.assert_allclose(s, [0.1, 0.2], rtol=1e-15)


def test_later_frame_refuses_nan_std_and_keeps_state():
    lo, hi, dwell = np.array([0.0, 10.0]), np.array([1.0, 30.0]), 1e-2
    f = IMMFilter(lo, hi, dwell_sigma=dwell, switch=(0.0, 1.0), jump_sigma=math.inf)
    z1, s1 = np.array([0.4, 20.0]), np.array([0.05, 2.0])
    z2, s2 = np.array([0.5, 18.0]), np.array([0.1, 1.0])
    f.update(z1, s1)
    with pytest.raises(PhysarError, match=r"std\[0\] = nan"):
        f.update([0.9, 25.0], [math.nan, 1.0])
    x, s = f.update(z2, s2)
    q = (dwell * (hi - lo)) ** 2
    R1, R2 = s1**2, s2**2
    K = (R1 + q) / (R1 + q + R2)
    np.testing.assert_allclose(x, z1 + K * (z2 - z1), rtol=1e-12)
    np.testing.assert_allclose(s, np.sqrt((1 - K) * (R1 + q)), rtol=1e-12)


def test_zero_and_tiny_std_still_floored():
    """The floor is kept for finite stds below it (0 included): 2e-4 of the range."""
    z, s = IMMFilter([0.0, 10.0], [1.0, 30.0]).update([0.25, 12.0], [0.0, 1e-9])
    np.testing.assert_array_equal(z, [0.25, 12.0])
    np.testing.assert_allclose(s, [2e-4 * 1.0, 2e-4 * 20.0], rtol=1e-15)
