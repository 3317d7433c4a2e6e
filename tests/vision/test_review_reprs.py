"""One-line reprs of :class:`physar.vision.markers.PoseEstimate` and :class:`physar.vision.dots.DotObservation`
(new-user review: the dataclass reprs printed the (4k, 2) corners and the (n, 3) arrays in full in a notebook).

The expected numbers are computed here by hand or with plain Python (``math``), not by physar."""

from __future__ import annotations

import math

import numpy as np

from physar.vision.camera import Pose
from physar.vision.dots import DotObservation
from physar.vision.markers import PoseEstimate


def _rz(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_pose_estimate_repr_big_is_one_line():
    pose = Pose(_rz(30.0), np.array([0.1, -0.2, 1.5]))
    rot_std = np.array([1e-3, 2e-3, 5e-4])          # rad; the largest, 2e-3 rad = 0.1146 deg -> "0.11"
    pe = PoseEstimate(pose, "measured", 400, 0.4213, list(range(100, 500)), np.zeros((1600, 2)), True, rot_std)
    text = repr(pe)
    assert "\n" not in text and len(text) < 200, (len(text), text)
    assert text == ("PoseEstimate(measured, 400 markers (ids 100, 101, 102, 103, ...), rms 0.421 px, rotation std "
                    "0.11 deg, full search, Pose(rotation 30 deg about [0, 0, 1], t=[0.1, -0.2, 1.5] m))")


def test_pose_estimate_repr_lost_and_predicted():
    assert repr(PoseEstimate(None, "lost")) == "PoseEstimate(lost, 0 markers, no pose)"
    pe = PoseEstimate(Pose(np.eye(3), np.array([0.0, 0.0, 2.0])), "predicted", 1)
    assert repr(pe) == "PoseEstimate(predicted, 1 marker, Pose(rotation 0 deg, t=[0, 0, 2] m))"
    nan_std = PoseEstimate(None, "lost", rotation_std=np.full(3, np.nan))
    assert repr(nan_std) == "PoseEstimate(lost, 0 markers, no pose)"


def test_dot_observation_repr_counts_seen_dots_only():
    n = 5000
    valid = np.arange(n) % 2 == 0                     # 2500 seen
    k = np.arange(n, dtype=float)
    disp = np.c_[3e-6 * k, 4e-6 * k, np.zeros(n)]     # |u_k| = 5e-6 k m
    disp[~valid] = 1.0                                # stale values on unseen rows must not count
    obs = DotObservation(np.zeros((n, 2)), valid, np.zeros((n, 3)), disp)
    norms = [5e-6 * i for i in range(0, n, 2)]
    mean, top = math.fsum(norms) / len(norms), max(norms)   # 0.0124975 m, 0.02499 m
    text = repr(obs)
    assert "\n" not in text and len(text) < 200, text
    assert text == f"DotObservation(2500 of 5000 dots seen, |displacement| mean {mean:.3g} m, max {top:.3g} m)"
    assert "0.0125 m" in text and "0.025 m" in text


def test_dot_observation_repr_nothing_seen():
    nan = np.full((1, 3), np.nan)
    obs = DotObservation(np.full((1, 2), np.nan), np.zeros(1, bool), nan, nan)
    assert repr(obs) == "DotObservation(0 of 1 dot seen)"
