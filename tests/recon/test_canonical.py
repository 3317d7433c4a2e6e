"""Deformation gradients of the physics-aware fine-tuning (seed 002 §4.1, Alg. 1 with sigma = 0, Eq. 4)
against closed forms, and the spin clip's poses."""

import numpy as np
import pytest
from scipy.linalg import polar

from physar.recon import scene as S
from physar.recon.canonical import zero_stress_deformation
from physar.recon.synth import SynthConfig, spin_poses


def _block(n=8, h=0.02):
    g = np.stack(np.meshgrid(*[np.arange(n) * h] * 3, indexing="ij"), -1).reshape(-1, 3)
    c = g - g.mean(0)
    return c + np.array([0.3, 0.1, 0.2]), (np.abs(c) < 1.5 * h).all(1)


def test_rigid_rotation_gives_the_rotation():
    # x_n = R(w n dt) X + n d.  Central differences (Eq. 4) give v = (sin(w dt)/dt) w_hat x (exact tangent);
    # with sigma = 0 each frame is a force-free flow, so F is the rotation R(w t) up to O((w dt)^2) per frame:
    # the in-plane stretch lies between 1 and the one-step free-flow bound sqrt(1 + sin^2(w dt))^frames.
    X, inner = _block()
    dt, w, nf = 1 / 30, 3.0, 6
    th = w * dt * np.arange(nf)
    R = np.stack([[[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]] for a in th])
    x = np.einsum("fij,nj->fni", R, X) + np.array([0.05, 0, 0]) * np.arange(nf)[:, None, None]
    F = zero_stress_deformation(x, dt, 4, 0.02).numpy()
    rots = [polar(f)[0] for f in F[-1][inner]]
    ang = np.array([np.arctan2(r[1, 0], r[0, 0]) for r in rots])
    assert np.allclose(ang, th[-1], atol=5e-3)  # 1 % of the 0.5 rad turn
    assert all(np.allclose(r[2], [0, 0, 1], atol=1e-6) for r in rots)
    sv = np.array([np.linalg.svd(f, compute_uv=False) for f in F[-1][inner]])
    assert np.all(sv > 1 - 1e-3) and np.all(sv < np.sqrt(1 + np.sin(w * dt) ** 2) ** (nf - 1) + 1e-3)


def test_uniform_dilation_and_rest():
    X, inner = _block()
    dt, a, nf = 1 / 30, 0.8, 6
    s = np.exp(a * dt * np.arange(nf))
    F = zero_stress_deformation(s[:, None, None] * X[None], dt, 4, 0.02).numpy()
    # det F between the one-step free-flow value (1 + sinh(a dt))^(3 frames) (v_n = sinh(a dt)/dt x_n by
    # Eq. 4) and the exact volume ratio exp(3 a t), within the grid-transfer error of interior particles
    det = np.linalg.det(F[-1][inner])
    lo, hi = (1 + np.sinh(a * dt)) ** (3 * (nf - 1)), np.exp(3 * a * dt * (nf - 1))
    assert np.all(det > lo * (1 - 1e-3)) and np.all(det < hi * (1 + 1e-3))
    assert np.allclose(np.linalg.svd(F[-1][inner], compute_uv=False), det[:, None] ** (1 / 3), rtol=2e-3)
    F0 = zero_stress_deformation(np.broadcast_to(X, (4, *X.shape)), dt, 4, 0.02).numpy()
    assert np.allclose(F0, np.eye(3), atol=1e-12)


def test_spin_poses_turn_the_root_about_z():
    cfg = SynthConfig(spin_frames=7, spin_deg=20.0)
    body = S.humanoid(cfg.height)
    p = spin_poses(body, cfg)
    r = p["rotations"][:, body.skeleton.index("root")]
    ang = np.degrees(np.arctan2(r[:, 1, 0], r[:, 0, 0]))
    assert ang[0] == pytest.approx(-20.0) and ang[-1] == pytest.approx(20.0) and ang[3] == pytest.approx(0.0)
    assert np.allclose(r[:, 2], [0, 0, 1]) and np.all(np.diff(ang) > 0)
    others = np.delete(p["rotations"], body.skeleton.index("root"), axis=1)
    assert np.allclose(others, np.eye(3))
