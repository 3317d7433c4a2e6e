"""Temporal filters of assimilated parameters (seed 000 §4: the estimate of each frame warm-starts the next;
the filter weighs each frame by its own uncertainty)."""
from __future__ import annotations

import numpy as np


class IMMFilter:
    r"""Interacting multiple model filter (Blom & Bar-Shalom 1988) on each parameter, state (value, rate per
    frame), two models: "dwell" (the parameter stays: :math:`x \leftarrow x`, rate 0, drift ``dwell_sigma``)
    and "moving" (constant rate, white acceleration of std ``motion_accel``; both as fractions of the
    parameter range :math:`[\mathrm{lo}, \mathrm{hi}]`, per frame), Markov switching with probabilities
    ``switch`` = :math:`(P(\text{dwell} \to \text{moving}),\ P(\text{moving} \to \text{dwell}))`. The
    measurement variance is the frame's own :math:`\mathrm{std}^2` (floored at 2e-4 of the range), so an
    uncertain frame moves the estimate less; an innovation beyond ``jump_sigma`` standard deviations of the
    moving model re-initialises the filter at the measurement.
    :math:`P(\text{dwell} \to \text{moving}) = 0.3`, :math:`P(\text{moving} \to \text{dwell}) = 0.05`:
    measured on the three-clip L-bracket benchmark (720 frames, truth on a finer mesh) this keeps 720/720
    frames within 1 % (worst 1.24 mm of the 16 mm range) where (0.2, 0.1) lost 5 frames at the start and end
    of moves (worst 1.35 mm); on the ten cantilever clips 3310/3310 within 1 % (worst 3.9 mm of 0.5 m; 4.5 mm
    with (0.2, 0.1)); the foam and seal clips are unchanged (mean 1.20 vs 1.19 mm, median 0.074 vs 0.072 deg).
    ``update(z, std)`` returns the filtered (mu, std); ``reset()`` makes the next measurement start the filter
    again."""

    def __init__(self, lo, hi, dwell_sigma: float = 1e-4, motion_accel: float = 5e-3,
                 switch: tuple = (0.3, 0.05), jump_sigma: float = 4.0):
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.dwell_sigma, self.motion_accel, self.switch, self.jump_sigma = dwell_sigma, motion_accel, switch, \
            jump_sigma
        self.fresh = True

    def reset(self):
        self.fresh = True

    def update(self, z, std) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.lo, self.hi
        z = np.asarray(z, float)
        rng = hi - lo
        R = np.maximum(np.nan_to_num(std, nan=0.0), 2e-4 * rng) ** 2
        n = z.size
        if self.fresh:
            self._x = np.zeros((2, n, 2))          # (model, parameter, [value, rate])
            self._x[:, :, 0] = z
            self._P = np.zeros((2, n, 2, 2))
            self._P[:, :, 0, 0] = R
            self._P[:, :, 1, 1] = (self.motion_accel * rng) ** 2 * 4  # unknown rate at the start
            self._P[0, :, 1, 1] = 0.0
            self._w = np.tile(np.array([0.5, 0.5])[:, None], (1, n))  # model probabilities
            self.fresh = False
            return z.copy(), np.sqrt(R)
        p01, p10 = self.switch
        Pi = np.array([[1 - p01, p01], [p10, 1 - p10]])   # Pi[i, j]: from model i to model j
        qd = (self.dwell_sigma * rng) ** 2
        qa = (self.motion_accel * rng) ** 2
        F = [np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([[1.0, 1.0], [0.0, 1.0]])]
        out_x, out_P = np.empty((n, 2)), np.empty((n, 2, 2))
        for k in range(n):
            x, P, w = self._x[:, k], self._P[:, k], self._w[:, k]
            c = Pi.T @ w                                   # predicted model probabilities
            mix = Pi * w[:, None] / np.maximum(c[None, :], 1e-300)   # mix[i, j] = P(i | j)
            xs, Ps, lik = np.empty((2, 2)), np.empty((2, 2, 2)), np.empty(2)
            for j in range(2):
                x0 = mix[:, j] @ x
                d = x - x0
                P0 = np.einsum("i,iab->ab", mix[:, j], P + d[:, :, None] * d[:, None, :])
                xp = F[j] @ x0
                Q = np.array([[qd[k], 0.0], [0.0, 0.0]]) if j == 0 else qa[k] * np.array([[0.25, 0.5], [0.5, 1.0]])
                Pp = F[j] @ P0 @ F[j].T + Q
                S = Pp[0, 0] + R[k]
                e = z[k] - xp[0]
                K = Pp[:, 0] / S
                xs[j] = xp + K * e
                Ps[j] = Pp - np.outer(K, Pp[0])
                lik[j] = np.exp(-0.5 * e * e / S) / np.sqrt(2 * np.pi * S)
                if j == 1:
                    jump = abs(e) > self.jump_sigma * np.sqrt(S)
            w = c * lik
            if jump or not np.isfinite(w.sum()) or w.sum() <= 0:   # a jump no model explains: restart here
                xs[:] = [z[k], 0.0]
                Ps[:] = np.diag([R[k], qa[k] * 4])
                Ps[0, 1, 1] = 0.0
                w = np.array([0.5, 0.5])
            w = w / w.sum()
            self._x[:, k], self._P[:, k], self._w[:, k] = xs, Ps, w
            xm = w @ xs
            d = xs - xm
            out_x[k] = xm
            out_P[k] = np.einsum("i,iab->ab", w, Ps + d[:, :, None] * d[:, None, :])
        return np.clip(out_x[:, 0], lo, hi), np.sqrt(out_P[:, 0, 0])


__all__ = ["IMMFilter"]
