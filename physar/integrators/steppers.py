r"""Time steppers for :math:`M \ddot q = f(q, v)` (seed 001 §2), sharing one Newton / sparse-solve machinery.

Every implicit stage of every method below has the same form, solved for the velocity :math:`v` on the free
dofs by :meth:`Integrator._stage`:

.. math::

    M v - h_f\, f(q, v) = r, \qquad q = \hat q + h_q v, \qquad \text{(S)}

with Newton matrix :math:`J = M + h_f D + h_f h_q K` (:math:`K = -\partial f / \partial q`,
:math:`D = -\partial f / \partial v`). Newton starts from the previous state :math:`(q_{n-1}, v_{n-1})` as
linearisation point, so one iteration of backward Euler is the classic semi-implicit (linearly implicit) step
:math:`(M + h D + h^2 K)\, \Delta v = h\, (f_{n-1} - h K v_{n-1})`.

Methods (:math:`h` the step; :math:`f_n = f(q_n, v_n)`):

* symplectic Euler: :math:`v_n = v_{n-1} + h M^{-1} f_{n-1}`, :math:`q_n = q_{n-1} + h v_n` (explicit).
* backward Euler (BE): (S) with :math:`h_f = h_q = h`, :math:`\hat q = q_{n-1}`, :math:`r = M v_{n-1}`; full
  Newton.
* semi-implicit (SI): BE with exactly one Newton iteration.
* implicit midpoint: (S) for :math:`v_{n-1/2}` with :math:`h_f = h_q = h/2`, :math:`r = M v_{n-1}`;
  :math:`v_n = 2 v_{n-1/2} - v_{n-1}`, :math:`q_n = q_{n-1} + h v_{n-1/2}`.
* generalized-α (seed Eq. 2.11-2.12, Chung-Hulbert): unknown :math:`a_{n+\alpha}`;

  .. math::

      q_n &= q_{n-1} + h v_{n-1} + \tfrac{h^2}{2} \big((1 - 2\beta)\, a_{n-1+\alpha} + 2\beta\, a_{n+\alpha}\big), \\
      v_n &= v_{n-1} + h \big((1 - \gamma)\, a_{n-1+\alpha} + \gamma\, a_{n+\alpha}\big), \\
      (1 - \alpha_m) M a_{n+\alpha} + \alpha_m M a_{n-1+\alpha} &= (1 - \alpha_f) f_n + \alpha_f f_{n-1},

  :math:`\alpha_m = \frac{2r - 1}{r + 1}`, :math:`\alpha_f = \frac{r}{r + 1}`, :math:`\alpha = \alpha_m - \alpha_f`,
  :math:`\beta = (1 - \alpha)^2 / 4`, :math:`\gamma = 1/2 - \alpha`; as (S): :math:`h_q = h \beta / \gamma`,
  :math:`h_f = h \gamma (1 - \alpha_f) / (1 - \alpha_m)`. :math:`r = 1`: no numerical damping, :math:`r = 0`: most.
* θ method (seed Eq. 2.15), trapezoid + BDF2 on :math:`u = (q, v)`, :math:`\dot u = b(u)`:

  .. math::

      u_n = u_{n-1} + (1 - \theta) \tfrac{h}{2} \big[b(u_{n-1}) + b(u_n)\big]
      + \tfrac{\theta}{3} \big[u_{n-1} - u_{n-2} + 2 h\, b(u_n)\big],

  so :math:`h_f = h_q = c h` with :math:`c = (1 - \theta)/2 + 2\theta/3`; :math:`\theta = 0` trapezoid,
  :math:`\theta = 1` BDF2. Two-step: the first step is one trapezoid step (second order, one-step).
* TR-BDF2 (:math:`\gamma = 2 - \sqrt 2`): a trapezoid stage to :math:`t + \gamma h`, then BDF2 on
  :math:`(t, t + \gamma h, t + h)`:

  .. math::

      u_n = \frac{u_\gamma - (1 - \gamma)^2 u_{n-1}}{\gamma (2 - \gamma)} + \frac{1 - \gamma}{2 - \gamma}\, h\, b(u_n).

  L-stable, second order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse.linalg as spla

from physar.errors import ConfigError, SolverError
from physar.geometry.mesh import _plural
from physar.integrators.linalg import SparseSolver
from physar.integrators.model import DynamicsModel


def _absmax(a) -> float:
    """Largest absolute entry of `a` (0 for an empty array): one pass, for the one-line summaries."""
    a = np.asarray(a, dtype=float)
    return float(np.abs(a).max()) if a.size else 0.0


@dataclass(repr=False)
class State:
    r"""Time t [s], displacement q [m], velocity v [m/s] and the method's memory.

    `a`: generalized-α's :math:`a_{n+\alpha}` [m/s²]; `q_prev`, `v_prev`: the :math:`\theta` method's previous
    step; `f`: the
    total force at (q, v) when known (a cache, never part of the method's state).
    """

    q: np.ndarray
    v: np.ndarray
    t: float = 0.0
    a: np.ndarray | None = None
    q_prev: np.ndarray | None = None
    v_prev: np.ndarray | None = None
    f: np.ndarray | None = field(default=None, repr=False)
    newton_iterations: int = 0

    def __repr__(self):
        """One line: time [s], dofs, largest displacement [m] and velocity [m/s] entries, Newton iterations."""
        return (f"State(t={self.t:.6g} s, {np.size(self.q)} dofs, max |q| {_absmax(self.q):.4g} m, "
                f"max |v| {_absmax(self.v):.4g} m/s, {_plural(self.newton_iterations, 'Newton iteration')})")


@dataclass(repr=False)
class StepStats:
    """Counters of an integrator: Newton iterations of each step, factorizations and CG iterations in all."""

    newton_iterations: list[int] = field(default_factory=list)
    factorizations: int = 0
    cg_iterations: int = 0

    def __repr__(self):
        return (f"StepStats({_plural(len(self.newton_iterations), 'step')}, "
                f"{_plural(sum(self.newton_iterations), 'Newton iteration')}, "
                f"{_plural(self.factorizations, 'factorization')}, {_plural(self.cg_iterations, 'CG iteration')})")


class Integrator:
    r"""Base class. `init(model, q0, v0)` -> State; `step(model, state, h)` -> new State.

    Newton settings: `tol` (relative residual of (S), or relative Newton update of v), `max_iter`.
    Linear solves: `linear_solver` 'direct' (CHOLMOD, symbolic analysis reused) or 'pcg' (CG to relative
    residual `linear_rtol` with a reused Cholesky factor in the model's rotated frame, see
    :class:`physar.integrators.linalg.SparseSolver`; `warm_start`: CG of a stage's first Newton iteration
    starts from that stage's previous update :math:`\Delta v` (pays off in slow, quasi-static motion; on an
    oscillating beam at :math:`h\omega \approx 0.3` it saves < 0.1 CG iteration per step, hence off by
    default), `linear_threads` BLAS/OpenMP threads during CG). `pack`/`unpack` map the method's state to a
    flat vector (used by the amplification-matrix analysis).
    """

    name = "integrator"
    order = 1
    implicit = True
    state_components = ("q", "v")

    def __init__(self, tol: float = 1e-9, max_iter: int = 25, linear_solver: str = "direct",
                 linear_rtol: float = 1e-8, warm_start: bool = False, linear_threads: int | None = 1):
        if not (tol > 0):
            raise ConfigError(f"Newton tol must be > 0, got {tol}")
        if max_iter < 1:
            raise ConfigError(f"Newton max_iter must be >= 1, got {max_iter}")
        self.tol = tol
        self.max_iter = max_iter
        self.solver = SparseSolver(linear_solver, linear_rtol, threads=linear_threads)
        self.warm_start = bool(warm_start)
        self._guess = {}  # (hf, hq) -> the stage's last first-iteration Δv (CG warm start)
        self.stats = StepStats()

    def __repr__(self):
        return f"{type(self).__name__}()"

    # -- state -------------------------------------------------------------------------------------
    def init(self, model: DynamicsModel, q0=None, v0=None, t0: float = 0.0) -> State:
        q, v = model.initial_state(q0, v0)
        return State(q, v, t0)

    def pack(self, state: State) -> np.ndarray:
        return np.concatenate([getattr(state, c) for c in self.state_components])

    def unpack(self, x: np.ndarray, n: int, t: float = 0.0) -> State:
        parts = {c: np.array(x[i * n:(i + 1) * n], dtype=float) for i, c in enumerate(self.state_components)}
        return State(t=t, **parts)

    # -- shared machinery ------------------------------------------------------------------------
    def _force(self, model, q, v, cached=None):
        return cached if cached is not None else model.force(q, v)

    def _stage(self, model: DynamicsModel, q_hat, rhs, hf, hq, q0, v0, max_iter=None):
        """Solve (S): M v - hf f(q̂ + hq v, v) = rhs on the free dofs; returns (q, v, f or None, iters).

        The first linearisation point is (q0, v0) (q0 need not equal q̂ + hq v0). f is the total force
        at the returned (q, v) when Newton converged (None after a truncated iteration).
        """
        max_iter = self.max_iter if max_iter is None else max_iter
        fr = model.free
        M = model.mass_ff
        q, v = q0.copy(), v0.copy()
        key = ("stage", hf, hq) if model.linear else None
        lin = model.linearize(q, v)
        r_prev = np.inf
        for it in range(1, max_iter + 1):
            e = q_hat[fr] + hq * v[fr] - q[fr]  # inconsistency of the linearisation point
            r = M @ v[fr] - hf * lin.f[fr] - rhs[fr]
            rhs_n = -r
            if np.any(e):
                rhs_n = rhs_n - hf * (lin.K @ e)
            J = model.system_matrix(lin, 1.0, hf, hf * hq)
            warm = it == 1 and self.warm_start and key is None and self.solver.method == "pcg"
            x0 = self._guess.get((hf, hq)) if warm else None
            dv = self.solver.solve(J, rhs_n, key, frame=lambda q=q: model.frame(q), x0=x0)
            if warm:
                self._guess[(hf, hq)] = dv
            v = v.copy()
            v[fr] += dv
            q = q.copy()
            q[fr] = q_hat[fr] + hq * v[fr]
            if it == max_iter and max_iter == 1:
                return q, v, None, it
            if model.linear:
                return q, v, model.force(q, v), it
            lin = model.linearize(q, v)
            r = M @ v[fr] - hf * lin.f[fr] - rhs[fr]
            scale = max(np.linalg.norm(M @ v[fr]), hf * np.linalg.norm(lin.f[fr]), hf * lin.scale,
                        np.linalg.norm(rhs[fr]), 1e-300)
            vscale = max(np.linalg.norm(v[fr]), np.linalg.norm(v0[fr]), np.linalg.norm(v[fr] - v0[fr]), 1e-300)
            rn = np.linalg.norm(r)
            if rn <= self.tol * scale + hf * lin.floor or np.linalg.norm(dv) <= self.tol * vscale:
                return q, v, lin.f, it
            if rn <= max(1e3 * self.tol, np.sqrt(self.tol)) * scale and rn >= 0.9 * r_prev:  # round-off floor
                return q, v, lin.f, it
            r_prev = rn
            if not np.all(np.isfinite(v)):
                break
        raise SolverError(
            f"{self.name}: Newton did not converge in {max_iter} iterations (relative residual "
            f"{np.linalg.norm(r) / scale:.2e}); reduce the time step h or raise max_iter")

    def step(self, model: DynamicsModel, state: State, h: float) -> State:  # pragma: no cover
        raise NotImplementedError

    def _done(self, state: State, it: int) -> State:
        state.newton_iterations = it
        self.stats.newton_iterations.append(it)
        self.stats.factorizations = self.solver.n_factorizations
        self.stats.cg_iterations = self.solver.n_cg_iterations
        return state


def _fixed_like(model, q, v):
    """Hold the pinned dofs: q = q_fixed, v = 0 there."""
    fixed = np.setdiff1d(np.arange(model.n_dofs), model.free)
    q[fixed] = model.q_fixed[fixed]
    v[fixed] = 0.0
    return q, v


class SymplecticEuler(Integrator):
    r"""Symplectic Euler, :math:`v_n = v_{n-1} + h M^{-1} f(q_{n-1}, v_{n-1})`, :math:`q_n = q_{n-1} + h v_n`
    (explicit, stable for :math:`h\omega < 2`)."""

    name = "symplectic_euler"
    implicit = False

    def step(self, model, state, h):
        fr = model.free
        f = self._force(model, state.q, state.v, state.f)
        v = state.v.copy()
        v[fr] += h * self.solver.solve(model.mass_ff, f[fr], key=("mass",))
        q = state.q.copy()
        q[fr] += h * v[fr]
        return self._done(State(q, v, state.t + h), 0)


class BackwardEuler(Integrator):
    r"""Backward Euler, :math:`q_n = q_{n-1} + h v_n`, :math:`M (v_n - v_{n-1}) = h f(q_n, v_n)`; full Newton.

    On :math:`q'' + \omega^2 q = 0` (seed Eq. 2.9):

    .. math::

        \rho = \frac{1}{\sqrt{1 + (h\omega)^2}}, \qquad d = \frac{\ln\big(1 + (h\omega)^2\big)}{h}.
    """

    name = "be"
    newton_iters: int | None = None

    def step(self, model, state, h):
        rhs = model.mass @ state.v
        q, v, f, it = self._stage(model, state.q, rhs, h, h, state.q, state.v, self.newton_iters)
        return self._done(State(q, v, state.t + h, f=f), it)


class SemiImplicit(BackwardEuler):
    """Semi-implicit Euler: one Newton iteration of backward Euler from :math:`(q_{n-1}, v_{n-1})`
    (seed §2)."""

    name = "si"
    newton_iters = 1


class ImplicitMidpoint(Integrator):
    r"""Implicit midpoint: :math:`v_{1/2}` solves
    :math:`M v_{1/2} - \frac{h}{2} f\big(q_{n-1} + \frac{h}{2} v_{1/2},\, v_{1/2}\big) = M v_{n-1}`;
    :math:`\rho = 1`, :math:`d = 0`."""

    name = "midpoint"
    order = 2

    def step(self, model, state, h):
        rhs = model.mass @ state.v
        _qm, vm, _, it = self._stage(model, state.q, rhs, h / 2, h / 2, state.q, state.v)
        q = state.q.copy()
        v = state.v.copy()
        fr = model.free
        v[fr] = 2 * vm[fr] - state.v[fr]
        q[fr] = state.q[fr] + h * vm[fr]
        return self._done(State(q, v, state.t + h), it)


def genalpha_coefficients(r: float) -> dict:
    r"""The coefficients of generalized-α for the knob :math:`r` (seed Eq. 2.12):

    .. math::

        \alpha_m = \frac{2r - 1}{r + 1}, \quad \alpha_f = \frac{r}{r + 1}, \quad \alpha = \alpha_m - \alpha_f,
        \quad \beta = \frac{(1 - \alpha)^2}{4}, \quad \gamma = \frac12 - \alpha.
    """
    if not (0.0 <= r <= 1.0):
        raise ConfigError(f"generalized-alpha r (rho_inf) must be in [0, 1], got {r}")
    am = (2 * r - 1) / (r + 1)
    af = r / (r + 1)
    al = am - af
    return {"alpha_m": am, "alpha_f": af, "alpha": al, "beta": (1 - al) ** 2 / 4, "gamma": 0.5 - al}


class GeneralizedAlpha(Integrator):
    r"""Generalized-α with the knob :math:`r = \rho_\infty \in [0, 1]` (seed Eq. 2.11-2.12); state
    :math:`(q, v, a_{n+\alpha})`:

    .. math::

        q_n &= q_{n-1} + h v_{n-1} + \tfrac{h^2}{2} \big((1 - 2\beta)\, a_{n-1+\alpha}
               + 2\beta\, a_{n+\alpha}\big), \\
        v_n &= v_{n-1} + h \big((1 - \gamma)\, a_{n-1+\alpha} + \gamma\, a_{n+\alpha}\big), \\
        (1 - \alpha_m) M a_{n+\alpha} + \alpha_m M a_{n-1+\alpha} &= (1 - \alpha_f) f_n + \alpha_f f_{n-1},

    with the coefficients of :func:`genalpha_coefficients`. :math:`a_\alpha` at :math:`t_0` is
    :math:`M^{-1} f(q_0, v_0)`. :math:`\rho(T) \to r` as :math:`h\omega \to \infty`; :math:`r = 1` is the
    energy-conserving trapezoid rule.
    """

    name = "genalpha"
    order = 2
    state_components = ("q", "v", "a")

    def __init__(self, r: float = 0.5, **kw):
        super().__init__(**kw)
        self.r = float(r)
        self.c = genalpha_coefficients(self.r)
        self._msolver = SparseSolver()

    def __repr__(self):
        return f"GeneralizedAlpha(r={self.r})"

    def init(self, model, q0=None, v0=None, t0=0.0):
        q, v = model.initial_state(q0, v0)
        f = model.force(q, v)
        a = np.zeros(model.n_dofs)
        a[model.free] = self._msolver.solve(model.mass_ff, f[model.free], key=("mass",))
        return State(q, v, t0, a=a, f=f)

    def step(self, model, state, h):
        c = self.c
        am, af, be, ga = c["alpha_m"], c["alpha_f"], c["beta"], c["gamma"]
        a0 = state.a if state.a is not None else np.zeros(model.n_dofs)
        f0 = self._force(model, state.q, state.v, state.f)
        q_t = state.q + h * state.v + h * h / 2 * (1 - 2 * be) * a0
        v_t = state.v + h * (1 - ga) * a0
        hq = h * be / ga
        hf = h * ga * (1 - af) / (1 - am)
        q_hat = q_t - hq * v_t
        rhs = model.mass @ v_t + (h * ga / (1 - am)) * (af * f0 - am * (model.mass @ a0))
        q, v, f, it = self._stage(model, q_hat, rhs, hf, hq, state.q, state.v)
        a = np.zeros(model.n_dofs)
        fr = model.free
        a[fr] = (v[fr] - v_t[fr]) / (h * ga)
        return self._done(State(q, v, state.t + h, a=a, f=f), it)


class ThetaMethod(Integrator):
    r"""Seed Eq. 2.15, trapezoid/BDF2 blend with :math:`\theta \in [0, 1]`, second order for every
    :math:`\theta`.

    On :math:`u = (q, v)`, :math:`u' = b(u)`:

    .. math::

        u_n = u_{n-1} + (1 - \theta) \frac{h}{2} \big[b(u_{n-1}) + b(u_n)\big]
        + \frac{\theta}{3} \big[u_{n-1} - u_{n-2} + 2 h\, b(u_n)\big],

    :math:`\theta = 0` the trapezoid rule, :math:`\theta = 1` BDF2. State
    :math:`(q_n, v_n, q_{n-1}, v_{n-1})`; the first step (no history) is one trapezoid step.
    """

    name = "theta"
    order = 2
    state_components = ("q", "v", "q_prev", "v_prev")

    def __init__(self, theta: float = 0.5, **kw):
        super().__init__(**kw)
        if not (0.0 <= theta <= 1.0):
            raise ConfigError(f"theta must be in [0, 1], got {theta}")
        self.theta = float(theta)

    def __repr__(self):
        return f"ThetaMethod(theta={self.theta})"

    def step(self, model, state, h):
        th = self.theta if state.q_prev is not None else 0.0
        q1, v1 = state.q, state.v
        q2 = state.q_prev if state.q_prev is not None else q1
        v2 = state.v_prev if state.v_prev is not None else v1
        f1 = self._force(model, q1, v1, state.f)
        c = (1 - th) / 2 + 2 * th / 3
        q_hat = q1 + (1 - th) * h / 2 * v1 + th / 3 * (q1 - q2)
        rhs = model.mass @ (v1 + th / 3 * (v1 - v2)) + (1 - th) * h / 2 * f1
        q, v, f, it = self._stage(model, q_hat, rhs, c * h, c * h, q1, v1)
        return self._done(State(q, v, state.t + h, q_prev=q1.copy(), v_prev=v1.copy(), f=f), it)


class TRBDF2(Integrator):
    r"""TR-BDF2 with :math:`\gamma = 2 - \sqrt{2}` (trapezoid to :math:`t + \gamma h`, then BDF2); L-stable:
    :math:`\rho \to 0` as :math:`h\omega \to \infty`."""

    name = "trbdf2"
    order = 2
    gamma = 2 - np.sqrt(2)

    def step(self, model, state, h):
        g = self.gamma
        q0, v0 = state.q, state.v
        f0 = self._force(model, q0, v0, state.f)
        # trapezoid stage over g h
        q_hat = q0 + g * h / 2 * v0
        rhs = model.mass @ v0 + g * h / 2 * f0
        qg, vg, _, it1 = self._stage(model, q_hat, rhs, g * h / 2, g * h / 2, q0, v0)
        # BDF2 stage
        s = 1.0 / (g * (2 - g))
        w = (1 - g) ** 2 * s
        c = (1 - g) / (2 - g)
        q_hat = s * qg - w * q0
        rhs = model.mass @ (s * vg - w * v0)
        q, v, f, it2 = self._stage(model, q_hat, rhs, c * h, c * h, qg, vg)
        return self._done(State(q, v, state.t + h, f=f), it1 + it2)


#: Stepper classes by the name a dynamics file gives in ``[dynamics] method``.
METHODS: dict[str, type[Integrator]] = {
    "symplectic_euler": SymplecticEuler,
    "be": BackwardEuler,
    "si": SemiImplicit,
    "midpoint": ImplicitMidpoint,
    "genalpha": GeneralizedAlpha,
    "theta": ThetaMethod,
    "trbdf2": TRBDF2,
}


def explicit_step_limit(model: DynamicsModel, q=None, v=None, iterations: int = 30) -> float:
    r"""Estimate of the stability limit :math:`h < 2 / \omega_\max` [s] of an explicit step at (q, v).

    :math:`\omega_\max^2` is the largest eigenvalue of :math:`M^{-1} K` on the free dofs (K the tangent
    stiffness at (q, v)); the estimate is the largest Rayleigh quotient :math:`x^\top K x / x^\top M x` of
    `iterations` power iterations from a fixed random start, a lower bound of :math:`\omega_\max^2`, so the
    returned limit is never below the true one for a linear model: ``h`` above it is certainly unstable.
    ``inf`` when the model has no stiffness (free flight).
    """
    q, v = model.initial_state(q, v)
    K = model.linearize(q, v).K
    M = model.mass_ff.tocsc()
    if K is None or K.shape[0] == 0 or not K.nnz:
        return np.inf
    if M.nnz == M.shape[0] and np.all(M.diagonal() > 0):  # lumped: diagonal
        d = M.diagonal()

        def solve(b):
            return b / d
    else:
        solve = spla.factorized(M)
    x = np.random.default_rng(0).standard_normal(K.shape[0])
    lam = 0.0
    for _ in range(int(iterations)):
        Kx = K @ x
        den = float(x @ (M @ x))
        if not den > 0:
            break
        lam = max(lam, float(x @ Kx) / den)
        x = solve(Kx)
        nx = np.linalg.norm(x)
        if not (nx > 0 and np.isfinite(nx)):
            break
        x /= nx
    return 2.0 / np.sqrt(lam) if lam > 0 else np.inf


class _RunawayCheck:
    r"""Post-hoc blow-up test of an explicit step: :math:`\omega_\text{eff}^2 = \delta q^\top (f_{n-1} - f_n) /
    \delta q^\top M \delta q` (:math:`\delta q = q_n - q_{n-1}`, so :math:`f_{n-1} - f_n \approx K \delta q`)
    measures the frequency of the motion the step makes; :math:`h \omega_\text{eff} > 2` with :math:`|\delta q|`
    growing for `RUNS` steps in a row is a mode past the stability limit growing geometrically (finite long
    before it overflows). Uses only forces the stepper needs anyway (cached in ``State.f``)."""

    RUNS = 3

    def __init__(self, model, h):
        self.model, self.h, self.count, self.dq_norm, self.hw = model, h, 0, 0.0, 0.0

    def __call__(self, old: State, new: State) -> bool:
        fr = self.model.free
        dq = (new.q - old.q)[fr]
        df = (old.f - new.f)[fr]
        den = float(dq @ (self.model.mass_ff @ dq))
        nrm = float(np.linalg.norm(dq))
        hw2 = self.h * self.h * float(dq @ df) / den if den > 0 else 0.0
        growing = hw2 > 4.0 and nrm > self.dq_norm
        self.count = self.count + 1 if growing else 0
        self.dq_norm, self.hw = nrm, np.sqrt(max(hw2, 0.0))
        return self.count >= self.RUNS


def make_integrator(method: str, r: float | None = None, theta: float | None = None, **kw) -> Integrator:
    """An integrator by name: symplectic_euler | be | si | midpoint | genalpha (r) | theta (theta) | trbdf2."""
    if method not in METHODS:
        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if r is not None and method != "genalpha":
        raise ConfigError(f"r applies to method 'genalpha' only, not {method!r}")
    if theta is not None and method != "theta":
        raise ConfigError(f"theta applies to method 'theta' only, not {method!r}")
    if method == "genalpha":
        return GeneralizedAlpha(0.5 if r is None else r, **kw)
    if method == "theta":
        return ThetaMethod(0.5 if theta is None else theta, **kw)
    return METHODS[method](**kw)


def simulate(model: DynamicsModel, integrator: Integrator, h: float, steps: int, q0=None, v0=None,
             callback: Callable[[int, State], None] | None = None,
             progress: Callable[[int, int], None] | None = None) -> State:
    """Run `steps` steps of size h [s] from (q0, v0); `callback(k, state)` after each step (k = 0 first)."""
    if not (h > 0 and np.isfinite(h)):
        raise ConfigError(f"time step h must be > 0, got {h}")
    if steps < 0:
        raise ConfigError(f"steps must be >= 0, got {steps}")
    state = integrator.init(model, q0, v0)
    runaway = None
    if not integrator.implicit and steps > 0:
        limit = explicit_step_limit(model, state.q, state.v)
        if h > limit:
            raise SolverError(f"{integrator.name}: time step h = {h:.4g} s is beyond the explicit stability limit "
                              f"2/omega_max = {limit:.3g} s (omega_max >= {2 / limit:.4g} rad/s); use h < "
                              f"{limit:.3g} s or an implicit method")
        runaway = _RunawayCheck(model, h)
        state.f = model.force(state.q, state.v)
    if callback:
        callback(0, state)
    for k in range(1, steps + 1):
        prev = state
        with np.errstate(over="ignore", invalid="ignore"):
            state = integrator.step(model, state, h)
            if runaway is not None:
                state.f = model.force(state.q, state.v)
        finite = np.all(np.isfinite(state.q)) and np.all(np.isfinite(state.v))
        if not finite or (runaway is not None and runaway(prev, state)):
            why = "is no longer finite" if not finite else (
                f"grows geometrically (h omega = {runaway.hw:.3g} > 2 for {runaway.RUNS} steps)")
            raise SolverError(f"{integrator.name}: the solution blew up at step {k} (t = {state.t:.4g} s): it "
                              f"{why}; reduce h or use an implicit method")
        if callback:
            callback(k, state)
        if progress:
            progress(k, steps)
    return state


__all__ = [
    "METHODS",
    "TRBDF2",
    "BackwardEuler",
    "GeneralizedAlpha",
    "ImplicitMidpoint",
    "Integrator",
    "SemiImplicit",
    "State",
    "SymplecticEuler",
    "ThetaMethod",
    "explicit_step_limit",
    "genalpha_coefficients",
    "make_integrator",
    "simulate",
]
