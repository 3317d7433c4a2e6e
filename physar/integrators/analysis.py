r"""Artificial damping of the time steppers (seed 001 §2.1).

For the test equation :math:`\ddot q + \omega^2 q = 0` every stepper is linear in its state,
:math:`x_n = T x_{n-1}`. :math:`T` (the amplification matrix; for the two-step θ method the companion matrix on
:math:`(q_n, v_n, q_{n-1}, v_{n-1})`) is obtained here by applying the implemented `step` to the unit states of
a one-degree-of-freedom :class:`LinearDynamics` model, so the analysis tests the real code. The artificial
damping is the :math:`d` of :math:`\ddot q + d \dot q + \omega^2 q = 0` whose amplitude decays like
:math:`\rho(T)` per step (seed Eq. 2.7-2.9):

.. math::

    d = -\frac{2}{h} \ln \rho(T);

:math:`d / \omega` depends on :math:`h\omega` only.
"""

from __future__ import annotations

import numpy as np

from physar.errors import ConfigError
from physar.integrators.model import LinearDynamics
from physar.integrators.steppers import Integrator, make_integrator
from physar.output import check_destination, save_figure


def amplification_matrix(integrator: Integrator, hw: float, omega: float = 1.0, zeta: float = 0.0) -> np.ndarray:
    r""":math:`T` with :math:`x_n = T x_{n-1}` for :math:`q'' + 2 \zeta \omega q' + \omega^2 q = 0` (``zeta``,
    ``omega``) and the step :math:`h` = ``hw`` / :math:`\omega`."""
    D = None if zeta == 0 else [[2 * zeta * omega]]
    model = LinearDynamics([[1.0]], [[omega * omega]], D)
    h = hw / omega
    base = integrator.init(model, np.zeros(1), np.zeros(1))
    comps = integrator.state_components
    k = len(comps)
    T = np.zeros((k, k))
    for j in range(k):
        e = np.zeros(k)
        e[j] = 1.0
        s = integrator.unpack(e, 1)
        for c in ("a", "q_prev", "v_prev"):
            if c not in comps and getattr(base, c) is not None:
                setattr(s, c, getattr(base, c))
        T[:, j] = integrator.pack(integrator.step(model, s, h))
    return T


def spectral_radius(T: np.ndarray) -> float:
    """Largest eigenvalue modulus of an amplification matrix ``T``."""
    return float(np.max(np.abs(np.linalg.eigvals(T))))


def damping_curve(method: str, hw, r: float | None = None, theta: float | None = None) -> dict:
    r"""{"hw", "rho", "d_over_omega"} for a method name (see make_integrator) at the given :math:`h\omega`
    values.

    .. math:: \frac{d}{\omega} = -\frac{2}{h\omega} \ln \rho

    :math:`\rho = 0` (an L-stable method at :math:`h\omega = \infty`) gives :math:`d/\omega = \infty`.
    """
    integ = make_integrator(method, r=r, theta=theta)
    try:
        hw = np.atleast_1d(np.asarray(hw, dtype=float))
    except (TypeError, ValueError):
        raise ConfigError(f"damping_curve: hw must be numbers (h omega > 0), got {hw!r}") from None
    bad = ~(np.isfinite(hw) & (hw > 0))
    if bad.any() or hw.ndim != 1:
        raise ConfigError(f"damping_curve: hw must be a 1-D list of finite values > 0 (h omega of a mode; d/omega "
                          f"is odd in h omega and 0/0 at 0), got {hw[bad][0] if bad.any() else hw.shape!r}")
    rho = np.array([spectral_radius(amplification_matrix(integ, x)) for x in hw])
    with np.errstate(divide="ignore"):
        d = -2.0 / hw * np.log(rho)
    return {"hw": hw, "rho": rho, "d_over_omega": d}


# closed forms (independent references for the tests)
def rho_backward_euler(hw):
    r"""BE/SI on :math:`q'' + \omega^2 q = 0`: :math:`\rho = 1 / \sqrt{1 + (h\omega)^2}` (seed Eq. 2.8)."""
    hw = np.asarray(hw, dtype=float)
    return 1.0 / np.sqrt(1.0 + hw * hw)


def d_backward_euler(hw, h=1.0):
    r""":math:`d_\text{BE} = \ln\big(1 + (h\omega)^2\big) / h` (seed Eq. 2.9)."""
    return np.log1p(np.asarray(hw, dtype=float) ** 2) / h


def plot_damping_figures(path, hw=None, rs=(0.0, 0.25, 0.5, 0.75, 1.0), thetas=(0.0, 0.25, 0.5, 0.75, 1.0)):
    r"""Seed Fig. 2.1 (generalized-α, :math:`r = 0, 0.25, \dots, 1`) and Fig. 2.2 (θ method,
    :math:`\theta = 0, 0.25, \dots, 1`), plus BE/SI, midpoint and TR-BDF2 for reference: :math:`d/\omega` versus
    :math:`h\omega` (log axis). Written atomically as PNG (the path is
    checked first: a .png suffix and a writable place)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    check_destination(path, suffixes=[".png"], kind="plot")
    hw = np.logspace(-2, 3, 101) if hw is None else np.asarray(hw, dtype=float)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    ax = axes[0]
    for r in rs:
        c = damping_curve("genalpha", hw, r=r)
        ax.semilogx(hw, c["d_over_omega"], label=f"r = {r:g}")
    ax.set_title("Fig. 2.1  generalized-α, r = 0:.25:1")
    ax = axes[1]
    for th in thetas:
        c = damping_curve("theta", hw, theta=th)
        ax.semilogx(hw, c["d_over_omega"], label=f"θ = {th:g}")
    ax.set_title("Fig. 2.2  θ method (Eq. 2.15), θ = 0:.25:1")
    ax = axes[2]
    for m, lab in (("be", "BE / SI"), ("midpoint", "implicit midpoint"), ("trbdf2", "TR-BDF2"),
                   ("genalpha", "gen-α r = 0"), ("theta", "θ = 1 (BDF2)")):
        kw = {"r": 0.0} if m == "genalpha" else {"theta": 1.0} if m == "theta" else {}
        c = damping_curve(m, hw, **kw)
        ax.semilogx(hw, np.minimum(c["d_over_omega"], 1e3), label=lab)
    ax.set_ylim(0, 0.9)
    ax.set_title("other methods")
    for ax in axes:
        ax.set_xlabel("h ω")
        ax.set_ylabel("d / ω")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def energy_drift(rows: list[dict]) -> dict:
    r"""Energy balance of a run from its per-step energy rows (dicts with t, kinetic, elastic, potential, total
    [J], as recorded by :func:`physar.integrators.config.run_simulation`).

    ``growth`` = :math:`\max_t (E(t) - E(0)) / S` and ``final`` = :math:`(E(T) - E(0)) / S`, with :math:`S` the
    largest :math:`|E_{\mathrm{kinetic}}|`, :math:`|E_{\mathrm{elastic}}|`, :math:`|E_{\mathrm{potential}}|` of
    the run: the share of the run's energy that the integrator made up (it is 0 for
    exact dynamics without damping, negative with damping; implicit midpoint on a nonlinear model gains).
    """
    tot = np.array([r["total"] for r in rows], dtype=float)
    scale = max((max(abs(r["kinetic"]), abs(r["elastic"]), abs(r["potential"])) for r in rows), default=0.0)
    if len(tot) == 0 or scale <= 0:
        return {"growth": 0.0, "final": 0.0, "scale": scale, "t_max_growth": 0.0}
    g = (tot - tot[0]) / scale
    k = int(np.argmax(g))
    return {"growth": float(g[k]), "final": float(g[-1]), "scale": float(scale), "t_max_growth": float(rows[k]["t"])}


def plot_energies(path, rows: list[dict], title: str = "", potential_label: str = "potential (gravity, loads)"):
    """PNG of kinetic, elastic, potential and total energy [J] against time [s] (matplotlib Agg, written
    through physar.output.save_figure); the total's largest growth (:func:`energy_drift`) is marked."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    t = np.array([r["t"] for r in rows], dtype=float)
    fig, ax = plt.subplots(figsize=(8, 4.4))
    for key, label, style in (("kinetic", "kinetic", "-"), ("elastic", "elastic", "-"),
                              ("potential", potential_label, "-"), ("total", "total", "k-")):
        ax.plot(t, [r[key] for r in rows], style, label=label, lw=1.6 if key == "total" else 1.2)
    d = energy_drift(rows)
    if rows and d["scale"] > 0:
        ax.axhline(rows[0]["total"], color="0.5", lw=0.8, ls=":")
        ax.set_title(f"{title}  (total energy growth {100 * d['growth']:.1f} % of the largest term)".strip())
    ax.set_xlabel("t [s]")
    ax.set_ylabel("energy [J]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def dominant_frequency(signal, dt: float, pad: int = 16) -> float:
    """Angular frequency [rad/s] of the strongest FFT peak of a sampled signal (mean removed, Hann window,
    zero-padded `pad` times, parabolic interpolation of the log-magnitude around the peak)."""
    x = np.asarray(signal, dtype=float)
    x = (x - x.mean()) * np.hanning(len(x))
    n = pad * len(x)
    spec = np.abs(np.fft.rfft(x, n))
    k = int(np.argmax(spec[1:])) + 1
    if 0 < k < len(spec) - 1:
        a, b, c = np.log(spec[k - 1:k + 2] + 1e-300)
        k = k + 0.5 * (a - c) / (a - 2 * b + c)
    return 2 * np.pi * k / (n * dt)


def euler_bernoulli_cantilever_omega(E: float, rho: float, length: float, width: float, height: float,
                                     mode: int = 1) -> float:
    r"""First bending angular frequencies of a clamped-free Euler-Bernoulli beam [rad/s], bending about
    the width axis (deflection along `height`):

    .. math::

        \omega = (\beta L)^2 \sqrt{\frac{E I}{\rho A L^4}}, \qquad \beta L = 1.8751,\ 4.6941,\ 7.8548
        \ (\text{mode} = 1, 2, 3)."""
    bl = [1.875104068711961, 4.694091132974175, 7.854757438237613][mode - 1]
    I = width * height**3 / 12.0
    A = width * height
    return bl**2 * np.sqrt(E * I / (rho * A * length**4))
