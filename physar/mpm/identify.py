"""Material identification from a particle trajectory (seed 002, §4.4, the 3-D flow term of Eq. 10).

The target is a sequence of particle clouds (e.g. ``physar mpm run`` output) that may be sampled differently
from the model (no one-to-one particle correspondence), so the misfit compares, per body b and frame n,
moments of the body's particles that do not depend on the sampling: the centre c_b^n and the change of the
covariance since frame 0, D_b^n = W_b o (S_b^n - S_b^0) (o: element-wise),

    L(theta) = 1/N_f sum_n sum_b ( ||c_b^n - c*_b^n||^2 / h^2 + ||D_b^n - D*_b^n||_F^2 / h^4 ),

h = grid spacing, D*_b^n = S*_b^n - S*_b^0.  Raw covariances would not do: a lattice of spacing s inside a body
is short of the body's own second moment by about s^2/12 per axis, an offset between a model and a target
sampled at different densities (it biased E by 9 % with 8 vs 27 particles per cell on a 16-cell bar).  The
change of the covariance still scales with the sampled S^0; W_b,ij = sqrt(S*_ii S*_jj / (S_ii S_jj)) at frame 0
rescales it to the target's sampling (exact for stretches along the axes).
The unknowns are log(E_b) per body (and optionally nu_b), optimised by L-BFGS with
gradients from :func:`physar.mpm.torch_bridge.simulate`.

The misfit of an oscillating body is not convex in E: once the simulated and target vibrations are more than
about half a period apart over the sequence, L-BFGS slides to a wrong minimum (e.g. a rigid, infinitely stiff
body).  So L-BFGS starts from a global scan: forward runs with every body's E scaled by the same factor
2^k (k = -scan_octaves … scan_octaves in steps of 1/4), keeping per body the factor with the smallest per-body
misfit.  For non-interacting bodies this is an exact per-body grid search (the misfit separates by body);
for touching bodies it is a heuristic start.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import torch

from physar.errors import ConfigError
from physar.mpm.model import MPMModel, MPMSolver
from physar.mpm.torch_bridge import Params, per_body_moments, simulate


@dataclass
class IdentifyResult:
    E: np.ndarray  # identified Young's modulus per body, Pa
    nu: np.ndarray
    loss: float
    history: list
    scan_factor: np.ndarray | None = None  # per body, the E factor chosen by the scan


def target_moments(frames: list[dict], n_bodies: int, n_frames: int):
    if len(frames) < n_frames + 1:
        raise ConfigError(f"target has {len(frames)} frames, the scene needs {n_frames + 1} (frame 0 included)")
    cs, ss = [], []
    for fr in frames[: n_frames + 1]:
        if set(np.unique(fr["body"])) != set(range(n_bodies)):
            raise ConfigError(f"target bodies {sorted(set(np.unique(fr['body'])))} do not match the scene's "
                              f"{n_bodies} bodies")
        c, s = per_body_moments(torch.as_tensor(fr["x"]), fr["body"], n_bodies)
        cs.append(c)
        ss.append(s)
    return torch.stack(cs), torch.stack(ss)


def _sampling_scale(target_s0: torch.Tensor, model_s0: torch.Tensor) -> torch.Tensor:
    """W_b,ij = sqrt(S*_ii S*_jj / (S_ii S_jj)) from the frame-0 covariances (n_bodies, 3, 3) of target and model;
    1 along an axis where either body is flat (one particle layer: S_ii = 0)."""
    t, m = torch.diagonal(target_s0, dim1=1, dim2=2), torch.diagonal(model_s0, dim1=1, dim2=2)
    flat = (t <= 0) | (m <= 0)
    r = torch.where(flat, torch.ones_like(t), torch.sqrt(t / torch.where(flat, torch.ones_like(m), m)))
    return r[:, :, None] * r[:, None, :]


def _moment_terms(c, s, s0, W, tc, ts, n: int, h: float) -> torch.Tensor:
    """Per body: ||c - c*||^2 / h^2 + ||W o (S - S^0) - (S* - S*^0)||_F^2 / h^4 at frame n."""
    return ((c - tc[n]) ** 2).sum(-1) / h**2 + ((W * (s - s0) - (ts[n] - ts[0])) ** 2).sum((-2, -1)) / h**4


def _per_body_misfit(model: MPMModel, x0, v0, frames: int, tc: torch.Tensor, ts: torch.Tensor, s0: torch.Tensor,
                     W: torch.Tensor) -> np.ndarray:
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
        c, s = per_body_moments(torch.as_tensor(x), model.body, nb)
        out += _moment_terms(c, s, s0, W, tc, ts, n, h).numpy()
    return out / frames


def identify(model: MPMModel, x0: np.ndarray, v0: np.ndarray, frames: int, target: list[dict],
             fit_nu: bool = False, iterations: int = 20, progress: Callable[[int, float], None] | None = None,
             scan_octaves: float = 2.0) -> IdentifyResult:
    """Fit per-body E (and nu) so that the simulated body moments match ``target`` (see module docstring).

    The model's E values are the initial guesses; ``scan_octaves = 0`` skips the scan.  Without ``fit_nu`` the
    model's Poisson ratios are used as they are; with it, one nu per body is fitted in (0.2, 0.45), starting
    from the body's mean.
    """
    nb = int(model.body.max()) + 1
    tc, ts = target_moments(target, nb, frames)
    s0 = per_body_moments(torch.as_tensor(np.asarray(x0, dtype=np.float64)), model.body, nb)[1]
    W = _sampling_scale(ts[0], s0)
    body = torch.as_tensor(model.body, dtype=torch.long)
    scan_factor = None
    if scan_octaves > 0:
        ks = np.arange(-scan_octaves, scan_octaves + 1e-9, 0.25)
        mis = np.array([_per_body_misfit(replace(model, E=model.E * 2.0**k), x0, v0, frames, tc, ts, s0, W) for k in ks])
        scan_factor = 2.0 ** ks[np.argmin(mis, axis=0)]
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
        nu = 0.2 + 0.25 * (1 + torch.tanh(nu_u)) if fit_nu else None  # fitted nu in (0.2, 0.45)
        p = Params(E=E[body], nu=nu[body] if fit_nu else nu_model)
        xs, _ = simulate(model, x0, v0, p, frames)
        loss = torch.zeros((), dtype=torch.float64)
        for n in range(1, frames + 1):
            c, s = per_body_moments(xs[n], model.body, nb)
            loss = loss + _moment_terms(c, s, s0, W, tc, ts, n, h).sum()
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
