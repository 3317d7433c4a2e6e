r"""Material identification from a particle trajectory (seed 002, §4.4, the 3-D flow term of Eq. 10).

The target is a sequence of particle clouds (e.g. ``physar mpm run`` output) that may be sampled differently
from the model (no one-to-one particle correspondence), so the misfit compares, per body :math:`b` and frame
:math:`n`, moments of the body's particles that do not depend on the sampling: the centre :math:`c_b^n` and
the change of the covariance since frame 0, :math:`D_b^n = \hat S_b^n - \hat S_b^0`,

.. math::

    L(\theta) = \frac{1}{N_f} \sum_n \sum_b \left( \frac{\lVert c_b^n - c_b^{*n} \rVert^2}{h^2}
    + \frac{\lVert D_b^n - D_b^{*n} \rVert_F^2}{h^4} \right),

:math:`h` = grid spacing.  :math:`\hat S` is the particles' covariance :math:`S` plus the second moment of the
lattice cell each particle stands for, carried by the body's affine motion:
:math:`\hat S_b^n = S_b^n + A_b^n \Delta_b (A_b^n)^\top`, with
:math:`\Delta_b = \operatorname{diag}(s_i^2 / 12)` (:math:`s_i`: the lattice spacing of the body's frame-0
positions along axis :math:`i`) and :math:`A_b^n` the least-squares affine map of the body's frame-0 positions
to frame :math:`n`.  Without it the covariance of a lattice is short of the body's by :math:`s^2/12` per axis,
an offset between a model and a target sampled at different densities (it biased :math:`E` by 9 % with 8 vs 27
particles per cell on a 16-cell bar); with it :math:`\hat S` is exact for any affine motion of a box (stretch,
shear, rotation) whatever the sampling.
The unknowns are :math:`\log E_b` per body (and optionally :math:`\nu_b`), optimised by L-BFGS with
gradients from :func:`physar.mpm.torch_bridge.simulate`.

The misfit of an oscillating body is not convex in :math:`E`: once the simulated and target vibrations are
more than about half a period apart over the sequence, L-BFGS slides to a wrong minimum (e.g. a rigid,
infinitely stiff body).  So L-BFGS starts from a global scan: forward runs with every body's :math:`E` scaled
by the same factor :math:`2^k` (:math:`k = -K \dots K` in steps of 1/4, :math:`K` = ``scan_octaves``), keeping
per body the factor with the smallest per-body misfit.  For non-interacting bodies this is an exact per-body
grid search (the misfit separates by body); for touching bodies it is a heuristic start.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import torch

from physar.errors import ConfigError, PhysarWarning
from physar.mpm.model import MPMModel, MPMSolver
from physar.mpm.torch_bridge import Params, simulate


@dataclass(repr=False)
class IdentifyResult:
    E: np.ndarray  # identified Young's modulus per body, Pa
    nu: np.ndarray
    loss: float
    history: list
    scan_factor: np.ndarray | None = None  # per body, the E factor chosen by the scan

    def __repr__(self) -> str:
        """One line: E [Pa] and nu per body (the first 4), final loss and iterations (no history)."""
        def values(a, unit=""):
            a = np.asarray(a, dtype=np.float64).ravel()
            text = ", ".join(f"{v:.4g}" for v in a[:4].tolist()) + (f", ... ({a.size} bodies)" if a.size > 4 else "")
            return f"[{text}]" + (f" {unit}" if unit else "")

        return (f"IdentifyResult(E {values(self.E, 'Pa')}, nu {values(self.nu)}, loss {self.loss:.4g}, "
                f"{len(self.history)} iterations)")


def lattice_moment(x0: np.ndarray, body: np.ndarray, n_bodies: int) -> np.ndarray:
    r""":math:`\Delta_b = \operatorname{diag}(s_i^2 / 12)` (n_bodies, 3, 3):
    :math:`s_i = (\max - \min) / (k - 1)` over the :math:`k` distinct frame-0 coordinates of body :math:`b`
    along axis :math:`i` (the lattice spacing; 0 for one particle layer, ~0 for scattered points)."""
    out = np.zeros((n_bodies, 3, 3))
    for b in range(n_bodies):
        xb = np.asarray(x0, dtype=np.float64)[np.asarray(body) == b]
        for i in range(3):
            lo, hi = xb[:, i].min(), xb[:, i].max()
            if hi > lo:
                k = len(np.unique(np.round((xb[:, i] - lo) / (hi - lo) * 1e9)))
                out[b, i, i] = ((hi - lo) / (k - 1)) ** 2 / 12
    return out


class _Moments:
    r"""Centres :math:`c_b` and lattice-corrected covariances :math:`\hat S_b` (module docstring) of frames of
    one particle set, whose frame-0 positions ``x0`` fix the lattice moment and the affine fits."""

    def __init__(self, x0, body: np.ndarray, n_bodies: int):
        x0 = torch.as_tensor(np.asarray(x0, dtype=np.float64))
        self.idx = [torch.as_tensor(np.flatnonzero(np.asarray(body) == b)) for b in range(n_bodies)]
        self.d0 = [x0[i] - x0[i].mean(0) for i in self.idx]
        self.S0_pinv = [torch.linalg.pinv(d.T @ d / len(d), hermitian=True) for d in self.d0]
        self.delta = torch.as_tensor(lattice_moment(x0.numpy(), body, n_bodies))
        self.s0 = self(x0)[1]  # S^ at frame 0

    def __call__(self, x: torch.Tensor):
        cs, ss = [], []
        for b, (i, d0) in enumerate(zip(self.idx, self.d0)):
            c = x[i].mean(0)
            d = x[i] - c
            A = (d.T @ d0 / len(d)) @ self.S0_pinv[b]  # least-squares affine map from frame 0
            cs.append(c)
            ss.append(d.T @ d / len(d) + A @ self.delta[b] @ A.T)
        return torch.stack(cs), torch.stack(ss)


#: the target's frame 0 may put a body's centre at most this many grid cells from the scene's (a finer or
#: shifted sampling of the same body: well under one cell)
START_CELLS = 2.0


def target_moments(frames: list[dict], n_bodies: int, n_frames: int):
    """Centres c* (F+1, nb, 3) and changes of the lattice-corrected covariances since frame 0, D* (F+1, nb, 3, 3),
    of the target's frames 0..n_frames (one particle set: the same particles in every frame)."""
    if len(frames) < n_frames + 1:
        raise ConfigError(f"target has {len(frames)} frames, the scene needs {n_frames + 1} (frame 0 included)")
    moments = None
    cs, ss = [], []
    for fr in frames[: n_frames + 1]:
        if set(np.unique(fr["body"])) != set(range(n_bodies)):
            raise ConfigError(f"target bodies {sorted(set(np.unique(fr['body'])))} do not match the scene's "
                              f"{n_bodies} bodies")
        if moments is None:
            moments = _Moments(fr["x"], fr["body"], n_bodies)
        elif len(fr["x"]) != len(frames[0]["x"]):
            raise ConfigError("target frames have different particle counts: a trajectory of one particle set is "
                              "needed")
        c, s = moments(torch.as_tensor(fr["x"]))
        cs.append(c)
        ss.append(s - moments.s0)
    return torch.stack(cs), torch.stack(ss)


def _moment_terms(c, s, moments: _Moments, tc, td, n: int, h: float) -> torch.Tensor:
    r"""Per body: :math:`\lVert c - c^* \rVert^2 / h^2 + \lVert (\hat S - \hat S^0) - D^* \rVert_F^2 / h^4` at
    frame :math:`n` (``td``: the target's :math:`D^*`)."""
    return ((c - tc[n]) ** 2).sum(-1) / h**2 + ((s - moments.s0 - td[n]) ** 2).sum((-2, -1)) / h**4


def _per_body_misfit(model: MPMModel, x0, v0, frames: int, tc: torch.Tensor, td: torch.Tensor,
                     moments: _Moments) -> np.ndarray:
    """Forward-only misfit of each body (the terms of L, see module docstring) for ``model``'s parameters."""
    nb = tc.shape[1]
    solver = MPMSolver(model)
    a, b = model.state(x0, v0), model.state(x0, v0)
    out = np.zeros(nb)
    h = model.dx
    for n in range(1, frames + 1):
        a, b = solver.simulate_frame(a, b, check=False)
        x = a.x.numpy()
        if not np.all(np.isfinite(x)):
            return np.full(nb, np.inf)
        c, s = moments(torch.as_tensor(x))
        out += _moment_terms(c, s, moments, tc, td, n, h).numpy()
    return out / frames


UNCONSTRAINED_SPREAD = 1e-6  # relative change of a body's misfit over the scan below which E is unconstrained


def _spread(m: np.ndarray) -> float:
    """(max - min) / max of the misfits ``m`` of one body over the scan; 0 when all are 0, inf if any is not
    finite (a diverged run: E matters)."""
    if not np.all(np.isfinite(m)):
        return np.inf
    top = float(np.max(np.abs(m)))
    return float(np.max(m) - np.min(m)) / top if top > 0 else 0.0


def unconstrained_bodies(mis: np.ndarray) -> list[int]:
    r"""The bodies (columns of the scan's misfits ``mis``, factors x bodies) whose misfit changes by at most
    ``UNCONSTRAINED_SPREAD`` (relative) over the whole scan (:math:`E` times :math:`2^{-K} \dots 2^K`, 1/4 .. 4
    by default): there the simulated motion does not depend on :math:`E` beyond round-off (an unstressed body:
    free fall, rigid motion), so the data do not constrain :math:`E`, whatever the optimiser reports.  A
    stressed body's deformation scales with :math:`1/E`, and its misfit changes by far more over a factor of 16.
    """
    return [b for b in range(mis.shape[1]) if _spread(mis[:, b]) <= UNCONSTRAINED_SPREAD]


def identify(model: MPMModel, x0: np.ndarray, v0: np.ndarray, frames: int, target: list[dict],
             fit_nu: bool = False, iterations: int = 20, progress: Callable[[int, float], None] | None = None,
             scan_octaves: float = 2.0) -> IdentifyResult:
    """Fit per-body E (and nu) so that the simulated body moments match ``target`` (see module docstring).

    The model's E values are the initial guesses; ``scan_octaves = 0`` skips the scan.  Without ``fit_nu`` the
    model's Poisson ratios are used as they are; with it, one nu per body is fitted in (0.2, 0.45), starting
    from the body's mean.
    """
    nb = int(model.body.max()) + 1
    tc, td = target_moments(target, nb, frames)
    moments = _Moments(x0, model.body, nb)
    c0 = moments(torch.as_tensor(x0))[0].detach().numpy()
    off = np.linalg.norm(tc[0].numpy() - c0, axis=1)
    if (off > START_CELLS * model.dx).any():  # another scene's run: every E would fit it equally badly
        b = int(np.argmax(off))
        raise ConfigError(f"target frame 0: body {b}'s centre {np.round(tc[0][b].numpy(), 4).tolist()} m is "
                          f"{off[b]:.3g} m ({off[b] / model.dx:.1f} cells) from the scene's "
                          f"{np.round(c0[b], 4).tolist()} m: the target is not a run of this scene (its bodies must "
                          "start where the scene puts them)")
    body = torch.as_tensor(model.body, dtype=torch.long)
    scan_factor = None
    if scan_octaves > 0:
        ks = np.arange(-scan_octaves, scan_octaves + 1e-9, 0.25)
        mis = np.array([_per_body_misfit(replace(model, E=model.E * 2.0**k), x0, v0, frames, tc, td, moments) for k in ks])
        scan_factor = 2.0 ** ks[np.argmin(mis, axis=0)]
        for b in unconstrained_bodies(mis):
            scan_factor[b] = 1.0  # every factor fits alike: argmin would pick the first, 2^-K, for nothing
            warnings.warn(f"body {b}: the target does not constrain E (its misfit changes by "
                          f"{_spread(mis[:, b]):.1e} relative over E x {2.0 ** -scan_octaves:g} .. "
                          f"x {2.0 ** scan_octaves:g}: is the body unstressed, e.g. in free fall?); E is left at "
                          f"its initial {float(model.E[model.body == b].mean()):.6g} Pa", PhysarWarning, stacklevel=2)
        model = replace(model, E=model.E * scan_factor[model.body])
    E0 = np.array([model.E[model.body == b].mean() for b in range(nb)])
    nu0 = np.array([model.nu[model.body == b].mean() for b in range(nb)])
    logE = torch.zeros(nb, dtype=torch.float64, requires_grad=True)  # log(E / E0)
    nu_u = torch.tensor(np.arctanh(np.clip((nu0 - 0.2) / 0.25 - 1, -0.99, 0.99)), dtype=torch.float64, requires_grad=fit_nu)
    nu_model = torch.as_tensor(model.nu, dtype=torch.float64)  # not fitted: the model's, per particle
    h = model.dx
    history: list = []
    opt = torch.optim.LBFGS([logE] + ([nu_u] if fit_nu else []), lr=1.0, max_iter=iterations,
                            line_search_fn="strong_wolfe", tolerance_grad=1e-12, tolerance_change=1e-12)

    def loss_fn():
        E = torch.as_tensor(E0) * torch.exp(logE.clamp(-4.0, 4.0))
        nu = (0.2 + 0.25 * (1 + torch.tanh(nu_u)))[body] if fit_nu else nu_model  # fitted nu in (0.2, 0.45)
        p = Params(E=E[body], nu=nu)
        xs, _ = simulate(model, x0, v0, p, frames)
        loss = torch.zeros((), dtype=torch.float64)
        for n in range(1, frames + 1):
            c, s = moments(xs[n])
            loss = loss + _moment_terms(c, s, moments, tc, td, n, h).sum()
        return loss / frames

    def closure():
        opt.zero_grad()
        loss = loss_fn()
        loss.backward()
        history.append(loss.item())
        if progress:
            progress(len(history), loss.item())
        return loss

    opt.step(closure)
    with torch.no_grad():
        final = float(loss_fn())
        E = E0 * np.exp(logE.detach().numpy())
        nu = (0.2 + 0.25 * (1 + torch.tanh(nu_u))).numpy() if fit_nu else nu0
    return IdentifyResult(E=E, nu=nu, loss=final, history=history, scan_factor=scan_factor)
