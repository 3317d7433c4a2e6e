"""Differentiable MPM in PyTorch: Warp kernels wrapped as ``torch.autograd.Function`` s (seed 002, Alg. 1-2).

Each substep is stress -> transfer (P2G, grid update, G2P) -> plastic return map, each a Warp launch whose
backward replays it on a ``wp.Tape``; the neural residuals of Eq. (8) are ordinary PyTorch modules in
between.  :func:`simulate` runs frames of T substeps; with ``checkpoint=True`` each frame is a
``torch.utils.checkpoint`` segment: only the frame-boundary states are kept and a frame's substeps are
recomputed (and taped) during its backward pass, so memory is O(frames * particles + one frame's tapes).

Without neural residuals, :func:`simulate` runs each frame as one fused autograd function
(:mod:`physar.mpm.adjoint`: two fused kernels per substep, segment checkpointing inside the frame, adjoint
kernels launched directly, both CPU cores); ``fused=False`` selects the generic per-launch path.

Differentiable inputs: initial state (x, v, C, F), per-particle E (Pa), nu, omega (actuation gate),
PD references, latents l_e/l_p, the network weights and the fibre moduli fiber_E (Pa) of the anisotropic
fibre term (:class:`physar.mpm.model.MPMModel`; directions ``model.fiber`` are constants).

Devices: the Warp arrays and launches are on ``model.device``; tensors are moved there before
``wp.from_torch`` (no copy when they are there already, e.g. CPU tensors of a CPU model) and the results are
returned on the device of the caller's tensors, so CPU callers get CPU tensors from a model on "cuda:0".
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
import torch.utils.checkpoint
import warp as wp

from physar.errors import ConfigError
from physar.mpm.actuation import held_force as pd_held_force
from physar.mpm.model import (
    MPMModel,
    check_material,
    check_state,
    g2p_kernel,
    grid_update_kernel,
    p2g_kernel,
    plastic_kernel,
    singular_values_kernel,
    stress_kernel,
)
from physar.mpm.neural import NeuralResidual

_DT = {1: wp.float64, 2: wp.vec3d, 3: wp.mat33d}


def _torch_device(model: MPMModel) -> torch.device:
    """The torch device of the model's Warp device ("cpu", "cuda:N")."""
    return torch.device(wp.device_to_torch(model.device))


def _to_wp(t: torch.Tensor, grad: bool, device: torch.device):
    """A Warp view of ``t`` on ``device`` (``t`` moved there first: a copy only when it is elsewhere)."""
    t = t.detach().to(device).contiguous()
    return wp.from_torch(t, dtype=_DT[t.dim()], requires_grad=grad)


def _from_wp(a, device: torch.device, copy: bool = False) -> torch.Tensor:
    """A Warp array as a tensor on the caller's ``device`` (aliased when it is on that device and not ``copy``)."""
    t = wp.to_torch(a)
    if t.device != device:
        return t.to(device)  # a copy
    return t.clone() if copy else t


class _WarpOp(torch.autograd.Function):
    """Runs ``op(model, *wp_inputs) -> wp outputs``; backward replays it on a tape (recompute, O(1) memory)."""

    @staticmethod
    def forward(ctx, op, model, *inputs):
        ctx.op, ctx.model = op, model
        ctx.save_for_backward(*inputs)
        dev, ctx.caller = _torch_device(model), inputs[0].device
        with torch.no_grad():
            outs = op(model, *[_to_wp(t, False, dev) for t in inputs], grad=False)
        return tuple(_from_wp(o, ctx.caller) for o in outs)  # fresh arrays, aliased on the model's device

    @staticmethod
    def backward(ctx, *grads):
        inputs = ctx.saved_tensors
        dev = _torch_device(ctx.model)
        wins = [_to_wp(t, True, dev) for t in inputs]
        tape = wp.Tape()  # records the launches below, each on the model's device
        with tape:
            outs = ctx.op(ctx.model, *wins, grad=True)
        tape.backward(grads={o: _to_wp(g, False, dev) for o, g in zip(outs, grads)})
        res = [_from_wp(w.grad, ctx.caller, copy=True) if need else None
               for w, need in zip(wins, ctx.needs_input_grad[2:])]
        tape.reset()
        return (None, None, *res)


def _stress_op(model: MPMModel, F, Jp, E, nu, fiber_E, grad=False):
    a, d = model.warp_arrays(), model.device
    tau = wp.zeros(model.n_particles, dtype=wp.mat33d, requires_grad=grad, device=d)
    wp.launch(stress_kernel, model.n_particles,
              inputs=[F, Jp, E, nu, a["elastic"], a["plastic"], a["pp"], a["fiber"], fiber_E], outputs=[tau],
              device=d)
    return (tau,)


def _sv_op(model: MPMModel, F, grad=False):
    s = wp.zeros(F.shape[0], dtype=wp.vec3d, requires_grad=grad, device=model.device)
    wp.launch(singular_values_kernel, F.shape[0], inputs=[F], outputs=[s], device=model.device)
    return (s,)


def _transfer_op(model: MPMModel, x, v, C, F, tau, omega, x_ref, v_ref, f_hold, gains, grad=False, t=0.0):
    r"""P2G, grid update and G2P of the substep starting at time t (s); ``gains`` = [kp, kd]
    (:math:`\mathrm{s}^{-2}`, :math:`\mathrm{s}^{-1}`) of the per-substep PD force, ``f_hold`` (N, 3) N the
    force held over the frame (Alg. 2); ``gains`` is a CPU tensor (it is not passed through Warp)."""
    a, d = model.warp_arrays(), model.device
    col = a["colliders"].at(t, model.dt)
    n, g = model.n_particles, model.n_grid
    kp, kd = (float(z) for z in gains.numpy())
    # grid arrays only on the box of nodes the particles touch (a function of x alone, so the tape replay in
    # backward() rebuilds the same box); array index = global node index - box corner (x.numpy(): a Warp array,
    # copied to the host when it is on a GPU)
    corner, shape = model.active_box(x.numpy())
    off = wp.vec3i(*corner)
    grid_mv = wp.zeros(shape, dtype=wp.vec3d, requires_grad=grad, device=d)
    grid_m = wp.zeros(shape, dtype=wp.float64, requires_grad=grad, device=d)
    grid_v = wp.zeros(shape, dtype=wp.vec3d, requires_grad=grad, device=d)
    xo = wp.zeros(n, dtype=wp.vec3d, requires_grad=grad, device=d)
    vo = wp.zeros(n, dtype=wp.vec3d, requires_grad=grad, device=d)
    Co = wp.zeros(n, dtype=wp.mat33d, requires_grad=grad, device=d)
    Ft = wp.zeros(n, dtype=wp.mat33d, requires_grad=grad, device=d)
    nmax, dt = g - 3, model.dt
    wp.launch(p2g_kernel, n, inputs=[x, v, C, tau, a["mass"], a["volume"], omega, x_ref, v_ref, f_hold, kp, kd,
                                     model.origin, model.dx, dt, nmax, off], outputs=[grid_mv, grid_m], device=d)
    wp.launch(grid_update_kernel, shape, inputs=[grid_mv, grid_m, wp.vec3d(*model.gravity), dt, model.pad,
                                                 model.pad + model.resolution, a["bc"], a["friction"],
                                                 wp.vec3i(0, 0, 0), off, model.origin, model.dx, *col.inputs()],
              outputs=[grid_v], device=d)
    lo, hi = model.clamp_range
    wp.launch(g2p_kernel, n, inputs=[grid_v, x, F, model.origin, model.dx, dt, nmax, lo, hi, off, *col.inputs()],
              outputs=[xo, vo, Co, Ft], device=d)
    return xo, vo, Co, Ft


def _plastic_op(model: MPMModel, Ft, Jp, E, nu, grad=False):
    a, d = model.warp_arrays(), model.device
    n = model.n_particles
    F = wp.zeros(n, dtype=wp.mat33d, requires_grad=grad, device=d)
    Jo = wp.zeros(n, dtype=wp.float64, requires_grad=grad, device=d)
    wp.launch(plastic_kernel, n, inputs=[Ft, Jp, E, nu, a["plastic"], a["pp"]], outputs=[F, Jo], device=d)
    return F, Jo


def _transfer_wrapped(model, x, v, C, F, tau, omega, x_ref, v_ref, f_hold, kp, kd, t=0.0):
    gains = torch.tensor([kp, kd], dtype=torch.float64)

    def op(m, x, v, C, F, tau, omega, x_ref, v_ref, f_hold, grad=False):
        return _transfer_op(m, x, v, C, F, tau, omega, x_ref, v_ref, f_hold, gains, grad=grad, t=t)

    return _WarpOp.apply(op, model, x, v, C, F, tau, omega, x_ref, v_ref, f_hold)


@dataclass(repr=False)
class Params:
    r"""Differentiable per-particle parameters (torch float64 tensors; ``None`` = not used).

    E (N,) Pa, nu (N,), omega (N,) actuation gate :math:`\omega`, x_ref/v_ref (N, 3) PD references (constant
    over a frame, or a callable frame -> (x_ref, v_ref)), l_e/l_p (N, latent) latents, kp
    (:math:`\mathrm{s}^{-2}`), kd (:math:`\mathrm{s}^{-1}`), fiber_E (N,) Pa fibre moduli of the anisotropic
    term (``None``: the model's ``fiber_E``, not differentiated).  The PD force of Eq. (6)-(7) is
    :math:`f_\text{ex} = m\, \omega \big[k_p (x_\text{ref} - x) + k_d (v_\text{ref} - v)\big]` with
    :math:`k_p, k_d` = kp, kd.
    ``hold``: that force is evaluated once per frame on the frame's initial state and held over its substeps
    (seed Alg. 2, the default); ``False``: recomputed on every substep's state.
    ``residual_on``: int32/int64 indices (M,) of the particles the neural residuals of Eq. (8) act on
    (``None``: all); the others keep their expert laws. l_e, l_p keep one row per particle (N, latent); the rows
    of the others are not read.
    """

    E: torch.Tensor
    nu: torch.Tensor
    omega: torch.Tensor | None = None
    x_ref: object = None
    v_ref: torch.Tensor | None = None
    l_e: torch.Tensor | None = None
    l_p: torch.Tensor | None = None
    kp: float = 2.0e2
    kd: float = 2.0e1
    fiber_E: torch.Tensor | None = None
    hold: bool = True
    residual_on: torch.Tensor | None = None

    def __repr__(self) -> str:
        """One line: particles, E [Pa] and nu ranges, which optional fields are set (latents by shape), gains, and
        the fields that require a gradient (no tensors printed)."""
        def span(t, unit=""):
            t = torch.as_tensor(t).detach()
            lo, hi = float(t.min()), float(t.max())
            text = f"{lo:.4g}" if lo == hi else f"{lo:.4g}..{hi:.4g}"
            return f"{text} {unit}" if unit else text

        names = ("E", "nu", "omega", "x_ref", "v_ref", "l_e", "l_p", "fiber_E", "residual_on")
        parts = [f"{len(self.E)} particles", f"E {span(self.E, 'Pa')}", f"nu {span(self.nu)}"]
        for name in names[2:]:
            v = getattr(self, name)
            if v is None:
                continue
            parts.append(f"{name} (callable)" if callable(v) and not isinstance(v, torch.Tensor)
                         else f"{name} {tuple(v.shape)}" if name in ("l_e", "l_p", "residual_on") else name)
        grad = [n for n in names if isinstance(getattr(self, n), torch.Tensor) and getattr(self, n).requires_grad]
        parts += [f"kp={float(self.kp):g} 1/s^2", f"kd={float(self.kd):g} 1/s",
                  "held over a frame" if self.hold else "per substep", f"grad {', '.join(grad) or 'none'}"]
        return f"Params({', '.join(parts)})"


def _fiber_E(model: MPMModel, p: Params) -> torch.Tensor:
    return torch.as_tensor(model.fiber_E if p.fiber_E is None else p.fiber_E, dtype=torch.float64)


def held_force(model: MPMModel, x, v, p: Params, x_ref, v_ref) -> torch.Tensor:
    """f_ex (N, 3) of Eq. (6)-(7) at the state (x, v) (seed Alg. 2, lines 2-4; zeros without actuation)."""
    n, dev = model.n_particles, x.device
    if p.omega is None or x_ref is None:
        return torch.zeros(n, 3, dtype=torch.float64, device=dev)
    v_ref = torch.zeros(n, 3, dtype=torch.float64, device=dev) if v_ref is None else v_ref
    m = torch.as_tensor(model.mass, dtype=torch.float64, device=dev)
    return pd_held_force(m, p.omega, x, v, x_ref, v_ref, p.kp, p.kd)


def substep(model: MPMModel, x, v, C, F, Jp, p: Params, x_ref=None, v_ref=None,
            nets: NeuralResidual | None = None, t: float = 0.0, f_hold=None, truncate: bool = False):
    """One differentiable substep of Alg. 1 with the residuals of Eq. (8) and the actuation of Eq. (6)-(7).

    ``t`` (s): time at the start of the substep (positions of the kinematic colliders).  ``f_hold`` (N, 3) N:
    the force held over the frame (Alg. 2); otherwise the PD force is evaluated on this substep's state.
    ``truncate``: the residual outputs are truncated as in seed Eq. 12 (inference).
    """
    n = model.n_particles
    z = lambda *sh: torch.zeros(*sh, dtype=torch.float64, device=x.device)
    (tau,) = _WarpOp.apply(_stress_op, model, F, Jp, p.E, p.nu, _fiber_E(model, p))
    on = None if p.residual_on is None else torch.as_tensor(p.residual_on, dtype=torch.long, device=x.device)
    if nets is not None and nets.elastic is not None:
        (sv,) = _WarpOp.apply(_sv_op, model, F)
        if on is None:
            tau = tau + nets.kirchhoff(F, sv, p.l_e, truncate=truncate)
        else:
            tau = tau.index_add(0, on, nets.kirchhoff(F[on], sv[on], _rows(p.l_e, on), truncate=truncate))
    if f_hold is not None or p.omega is None or x_ref is None:
        omega, x_ref, v_ref = z(n), z(n, 3), z(n, 3)
        kp = kd = 0.0
    else:
        omega, kp, kd = p.omega, p.kp, p.kd
        v_ref = z(n, 3) if v_ref is None else v_ref
    f_hold = z(n, 3) if f_hold is None else f_hold
    x, v, C, Ft = _transfer_wrapped(model, x, v, C, F, tau, omega, x_ref, v_ref, f_hold, kp, kd, t=t)
    F, Jp = _WarpOp.apply(_plastic_op, model, Ft, Jp, p.E, p.nu)
    if nets is not None and nets.plastic is not None:
        (svt,) = _WarpOp.apply(_sv_op, model, Ft)
        if on is None:
            F = F + nets.deformation(Ft, svt, p.l_p, truncate=truncate)
        else:
            F = F.index_add(0, on, nets.deformation(Ft[on], svt[on], _rows(p.l_p, on), truncate=truncate))
    return x, v, C, F, Jp


def _rows(latent, on):
    """The latents (N, d) of the particles ``on``, or a latent (d,) shared by all (or None), as given."""
    return latent[on] if latent is not None and latent.dim() == 2 else latent


def simulate(model: MPMModel, x0, v0, params: Params, frames: int, nets: NeuralResidual | None = None,
             checkpoint: bool = True, C0=None, F0=None, Jp0=None, t0: float = 0.0, fused: bool = True,
             truncate: bool = False):
    """Differentiable simulation of ``frames`` frames of ``model.substeps`` substeps, starting at time t0 (s).

    Returns the list of positions (N, 3) at frames 0..frames and the final state (x, v, C, F, Jp).  The PD
    references may be given per frame by a callable ``params.x_ref(frame) -> (x_ref, v_ref)``; with
    ``params.hold`` the PD force is evaluated at the start of each frame and held (seed Alg. 2).
    ``truncate``: Eq. 12 truncation of the residual outputs (inference, seed App. A.2).
    The results are on the device of ``x0`` (CPU for NumPy input), whatever ``model.device`` is.
    A :class:`physar.errors.ConfigError` names an input whose shape is not one entry per particle of the model
    (x0, v0 (N, 3), C0, F0 (N, 3, 3), Jp0 and ``params`` fields) and a particle whose E is not > 0 or whose
    nu is not in (-1, 0.5) (the limits of the scene file).
    """
    n = model.n_particles
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)
    x = t(x0)
    dev = x.device
    v = t(v0).to(dev)
    C = torch.zeros(n, 3, 3, dtype=torch.float64, device=dev) if C0 is None else t(C0)
    F = torch.eye(3, dtype=torch.float64, device=dev).repeat(n, 1, 1) if F0 is None else t(F0)
    Jp = torch.ones(n, dtype=torch.float64, device=dev) if Jp0 is None else t(Jp0)
    _check_inputs(model, {"x0": x, "v0": v, "C0": C, "F0": F, "Jp0": Jp}, params)
    if params.residual_on is not None:  # once, on the state's device (index_add needs its indices there)
        params = replace(params, residual_on=torch.as_tensor(params.residual_on, dtype=torch.long, device=dev))
    xs = [x]
    use_fused = fused and (nets is None or (nets.elastic is None and nets.plastic is None))
    for f in range(frames):
        if callable(params.x_ref):
            x_ref, v_ref = params.x_ref(f)
            _check_shape(n, f"params.x_ref({f})[0]", "x_ref", x_ref)
            _check_shape(n, f"params.x_ref({f})[1]", "v_ref", v_ref)
        else:
            x_ref, v_ref = params.x_ref, params.v_ref
        f_hold = held_force(model, x, v, params, x_ref, v_ref) if params.hold else None
        if use_fused:
            x, v, C, F, Jp = _fused_frame(model, x, v, C, F, Jp, params, x_ref, v_ref, t0 + f * model.frame_dt,
                                          f_hold)
            _check(model, x, v, F, f)
            xs.append(x)
            continue

        tf = t0 + f * model.frame_dt

        def frame_fn(x, v, C, F, Jp, f_hold, *_params, tf=tf, x_ref=x_ref, v_ref=v_ref):  # re-run in backward
            for s in range(model.substeps):
                x, v, C, F, Jp = substep(model, x, v, C, F, Jp, params, x_ref, v_ref, nets, t=tf + s * model.dt,
                                         f_hold=f_hold, truncate=truncate)
            return x, v, C, F, Jp

        leaves = [z for z in (params.E, params.nu, params.omega, params.l_e, params.l_p, params.fiber_E)
                  if isinstance(z, torch.Tensor)]
        if checkpoint and torch.is_grad_enabled():
            x, v, C, F, Jp = torch.utils.checkpoint.checkpoint(frame_fn, x, v, C, F, Jp, f_hold, *leaves,
                                                               use_reentrant=False)
        else:
            x, v, C, F, Jp = frame_fn(x, v, C, F, Jp, f_hold)
        _check(model, x, v, F, f)
        xs.append(x)
    return xs, (x, v, C, F, Jp)


_SHAPES = {"x0": (3,), "v0": (3,), "C0": (3, 3), "F0": (3, 3), "Jp0": (), "E": (), "nu": (), "omega": (),
           "x_ref": (3,), "v_ref": (3,), "fiber_E": ()}  # per particle; l_e, l_p: (latent,)


def _check_shape(n: int, label: str, key: str, a) -> None:
    """A :class:`ConfigError` naming ``label`` unless ``a`` (tensor, array or None) has the shape (n, ...) of
    ``key`` in ``_SHAPES`` (l_e, l_p: (n, latent), or (latent,) shared by all particles)."""
    if a is None:
        return
    got = tuple(torch.as_tensor(a).shape)
    latent = key in ("l_e", "l_p")
    if (len(got) == 1 or (len(got) == 2 and got[0] == n)) if latent else got == (n, *_SHAPES[key]):
        return
    want = f"({n}, latent)" if latent else str((n, *_SHAPES[key]))
    raise ConfigError(f"simulate: {label} must have shape {want} (one entry per particle of the model), got {got}")


def _check_inputs(model: MPMModel, state: dict, p: Params) -> None:
    """Shapes of the initial state and of ``p`` against the model, and E, nu, fiber_E in their ranges (once per
    :func:`simulate`; the kernels would otherwise read past the end of a short array)."""
    n = model.n_particles
    for k, a in state.items():
        _check_shape(n, k, k, a)
    for k in ("E", "nu", "omega", "x_ref", "v_ref", "l_e", "l_p", "fiber_E"):
        a = getattr(p, k)
        if not callable(a):
            _check_shape(n, f"params.{k}", k, a)
    h = lambda a: torch.as_tensor(a).detach().cpu().numpy()
    if p.residual_on is not None:
        _check_indices(h(p.residual_on), n)
    check_material(h(p.E), h(p.nu), "simulate: params.")
    if p.fiber_E is not None:
        ef = h(p.fiber_E)
        bad = ~(np.isfinite(ef) & (ef >= 0))
        if bad.any():
            i = int(bad.argmax())
            raise ConfigError(f"simulate: params.fiber_E[{i}] = {ef[i]:g} Pa: must be a finite number >= 0")


def _check_indices(on: np.ndarray, n: int) -> None:
    """A :class:`ConfigError` naming what is wrong unless ``on`` (``Params.residual_on``) holds distinct int32 /
    int64 particle indices in [0, n) along one axis."""
    why = (f"has shape {on.shape}, not (M,)" if on.ndim != 1
           else f"has dtype {on.dtype}, not int32 or int64" if on.dtype not in (np.int32, np.int64) else None)
    if why is None and on.size:
        bad = (on < 0) | (on >= n)
        uniq, counts = np.unique(on, return_counts=True)
        why = (f"holds index {on[bad.argmax()]}, outside [0, {n})" if bad.any()
               else f"holds index {uniq[counts.argmax()]} {counts.max()} times" if counts.max() > 1 else None)
    if why is not None:
        raise ConfigError(f"simulate: params.residual_on {why} (distinct indices of the particles the residual laws "
                          "act on)")


def _check(model: MPMModel, x, v, F, f: int):
    """:func:`physar.mpm.model.check_state` on the state after frame f (host copies of GPU tensors only)."""
    h = lambda a: a.detach().cpu().numpy()  # .cpu() is a no-op for CPU tensors
    check_state(model, h(x), h(v), h(F), where=f" at frame {f + 1}")


def _fused_frame(model: MPMModel, x, v, C, F, Jp, p: Params, x_ref, v_ref, t0: float, f_hold=None):
    """One frame through :class:`physar.mpm.adjoint.FusedFrameFunction` (expert laws, no neural residuals)."""
    from physar.mpm.adjoint import FusedFrame, FusedFrameFunction

    runner = getattr(model, "_fused", None)
    if runner is None:
        runner = model._fused = FusedFrame(model)
    n = model.n_particles
    z = lambda *sh: torch.zeros(*sh, dtype=torch.float64, device=x.device)
    if f_hold is not None or p.omega is None or x_ref is None:
        omega, x_ref, v_ref, kp, kd = z(n), z(n, 3), z(n, 3), 0.0, 0.0
    else:
        omega, kp, kd = p.omega, p.kp, p.kd
        v_ref = z(n, 3) if v_ref is None else v_ref
    f_hold = z(n, 3) if f_hold is None else f_hold
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)
    return FusedFrameFunction.apply(runner, float(t0), float(kp), float(kd), x, v, C, F, Jp, t(p.E), t(p.nu),
                                    t(omega), t(x_ref), t(v_ref), f_hold, _fiber_E(model, p))
