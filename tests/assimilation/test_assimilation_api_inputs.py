"""Python-API input checks of :class:`physar.assimilation.filters.IMMFilter` (probe findings):

* a NaN measurement returned NaN (and an infinite one an infinite std) and poisoned the filter's state;
* a measurement with fewer values than parameters after the first frame was broadcast silently (a 2-parameter
  filter fed one value returned two "estimates"), more values ended in an IndexError;
* a negative std was squared into a valid variance, an infinite one gave an infinite std next frame;
* lo > hi, lo == hi or NaN bounds, switch probabilities outside [0, 1] (a negative Markov matrix),
  negative or NaN noises and jump_sigma <= 0 or NaN ran and returned numbers (NaN bounds: NaN);
* a 2-D lo, a scalar switch or one of three values ended in NumPy errors.

Each now raises one :class:`PhysarError` naming the argument, its value or shape and what is expected. The valid
neighbours are checked against closed forms: the first frame returns the measurement and its std (floored at
2e-4 of the range; a NaN std is refused: tests/assimilation/test_filter_nan_std.py), and with ``switch=(0, 1)``
(the "moving" model never entered) and ``jump_sigma=inf`` the second frame is the scalar random-walk Kalman update
:math:`x = z_1 + K (z_2 - z_1)`, :math:`K = (R_1 + q) / (R_1 + q + R_2)`, :math:`P = (1 - K)(R_1 + q)`.
"""
import math

import numpy as np
import pytest

from physar.assimilation.filters import IMMFilter
from physar.errors import PhysarError


# ----------------------------------------------------------------------------------------------- constructor
@pytest.mark.parametrize("kwargs, words", [
    ({"lo": [1.0], "hi": [0.0]}, "hi must be > lo"),
    ({"lo": [1.0], "hi": [1.0]}, "hi must be > lo"),
    ({"lo": [math.nan], "hi": [1.0]}, "lo and hi must be finite"),
    ({"lo": [-math.inf], "hi": [1.0]}, "lo and hi must be finite"),
    ({"lo": [[0.0, 0.0]], "hi": [[1.0, 1.0]]}, "lo must be a 1-D array"),
    ({"lo": [0.0, 0.0], "hi": [1.0, 1.0, 1.0]}, "hi must have 2 value"),
    ({"lo": ["a"], "hi": [1.0]}, "lo must be numbers"),
    ({"lo": [0.0], "hi": [1.0], "dwell_sigma": -1.0}, "dwell_sigma must be a finite number >= 0"),
    ({"lo": [0.0], "hi": [1.0], "dwell_sigma": math.nan}, "dwell_sigma must be a finite number >= 0"),
    ({"lo": [0.0], "hi": [1.0], "motion_accel": math.nan}, "motion_accel must be a finite number >= 0"),
    ({"lo": [0.0], "hi": [1.0], "switch": (1.5, 0.0)}, "switch must be two probabilities in"),
    ({"lo": [0.0], "hi": [1.0], "switch": (-0.1, 0.1)}, "switch must be two probabilities in"),
    ({"lo": [0.0], "hi": [1.0], "switch": (0.1, 0.1, 0.1)}, "switch must be two probabilities"),
    ({"lo": [0.0], "hi": [1.0], "switch": 0.1}, "switch must be two probabilities"),
    ({"lo": [0.0], "hi": [1.0], "jump_sigma": 0.0}, "jump_sigma must be a number > 0"),
    ({"lo": [0.0], "hi": [1.0], "jump_sigma": math.nan}, "jump_sigma must be a number > 0"),
])
def test_constructor_refuses(kwargs, words):
    with pytest.raises(PhysarError, match=words):
        IMMFilter(**kwargs)


# ----------------------------------------------------------------------------------------------- update
@pytest.mark.parametrize("first, second, words", [
    (([0.5, 0.5], [0.01, 0.01]), ([0.5], [0.01]), "z must have 2 value"),            # was broadcast silently
    (([0.5, 0.5], [0.01, 0.01]), ([0.5, 0.5, 0.5], [0.01]), "z must have 2 value"),
    (([0.5, 0.5], [0.01, 0.01]), ([0.5, math.nan], [0.01, 0.01]), r"z\[1\] = nan is not a finite"),
    (([0.5, 0.5], [0.01, 0.01]), ([math.inf, 0.5], [0.01, 0.01]), r"z\[0\] = inf is not a finite"),
    (([0.5, 0.5], [0.01, 0.01]), ([0.5, 0.5], [0.01, -0.1]), r"std\[1\] = -0.1 must be >= 0 and finite"),
    (([0.5, 0.5], [0.01, 0.01]), ([0.5, 0.5], [math.inf, 0.01]), r"std\[0\] = inf must be >= 0"),
    (([0.5, 0.5], [0.01, 0.01]), ([0.5, 0.5], [0.01, 0.01, 0.01]), "std must have 2 value"),
])
def test_update_refuses(first, second, words):
    f = IMMFilter([0.0, 0.0], [1.0, 1.0])
    f.update(*first)
    with pytest.raises(PhysarError, match=words):
        f.update(*second)


def test_first_frame_refuses_nan_measurement():
    with pytest.raises(PhysarError, match=r"IMMFilter.update: z\[0\] = nan"):
        IMMFilter([0.0], [1.0]).update([math.nan], [0.01])


def test_first_frame_returns_measurement_and_floored_std():
    f = IMMFilter([0.0, 10.0], [1.0, 30.0])
    z, s = f.update([0.25, 12.0], [0.5, 1e-6])   # std below the floor: the floor 2e-4 * range is used
    np.testing.assert_array_equal(z, [0.25, 12.0])
    np.testing.assert_allclose(s, [0.5, 2e-4 * 20.0], rtol=1e-15)
    z, s = IMMFilter([0.0], [1.0]).update(0.25, 0.0)  # one parameter: scalars pass; std 0 floored
    np.testing.assert_array_equal(z, [0.25])
    np.testing.assert_allclose(s, [2e-4], rtol=1e-15)


def test_second_frame_equals_scalar_kalman_update():
    lo, hi = np.array([0.0, 10.0]), np.array([1.0, 30.0])
    dwell = 1e-2
    f = IMMFilter(lo, hi, dwell_sigma=dwell, switch=(0.0, 1.0), jump_sigma=math.inf)
    z1, s1 = np.array([0.4, 20.0]), np.array([0.05, 2.0])
    z2, s2 = np.array([0.5, 18.0]), np.array([0.1, 1.0])
    f.update(z1, s1)
    x, s = f.update(z2, s2)
    q = (dwell * (hi - lo)) ** 2
    R1, R2 = s1 ** 2, s2 ** 2
    K = (R1 + q) / (R1 + q + R2)
    np.testing.assert_allclose(x, z1 + K * (z2 - z1), rtol=1e-12)
    np.testing.assert_allclose(s, np.sqrt((1 - K) * (R1 + q)), rtol=1e-12)
