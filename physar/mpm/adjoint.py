"""Fused, hand-scheduled reverse mode for frames of expert-law MLS-MPM substeps (seed 002, Alg. 1-2).

The generic bridge (:mod:`physar.mpm.torch_bridge`) wraps every Warp launch in its own autograd function and
replays it on a ``wp.Tape``; with per-frame checkpointing a substep is then run three times forward plus once
in reverse, with fresh allocations per launch.  Without neural residuals the whole frame is one
:class:`torch.autograd.Function` here:

* two fused kernels per substep: stress + P2G (tau = tau(F, E, nu) + fibre term tau_f(F, a0, E_f) of
  :func:`physar.mpm.constitutive.fiber_stress` inside the scatter) and G2P + return map
  (F = P((I + dt C) F) inside the gather); the grid update is the shared ``grid_update_kernel``;
* forward: substeps run without storing anything but the states at segment boundaries (every k ~ sqrt(T)
  substeps);
* backward: per segment (last first) the k substeps are recomputed with their states and grids stored, then
  reversed by launching Warp's generated adjoint kernels directly (``wp.launch(..., adjoint=True)``); the grid
  adjoints live only on the particles' node box; memory is O((T / k + k) N), cost 2 forward + 1 adjoint sweep;
* both CPU cores: each per-particle launch is split into two halves run concurrently (Warp's CPU kernels run
  outside the GIL); the P2G halves scatter into separate grids that are summed, the G2P adjoint halves into
  separate grid adjoints that are summed.

Gradients are the same as the generic path (same kernels, same functions); see tests/mpm/test_fused.py.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
import warp as wp

from physar.mpm.actuation import pd_force
from physar.mpm.constitutive import hardening_factor, kirchhoff_stress_fiber
from physar.mpm.model import MPMModel, g2p_particle, grid_update_kernel, p2g_particle, plastic_update

_POOL: ThreadPoolExecutor | None = None
MIN_PARTICLES_PER_THREAD = 2048


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="physar-mpm")
    return _POOL


@wp.kernel
def p2g_fused_kernel(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    C: wp.array(dtype=wp.mat33d),
    F: wp.array(dtype=wp.mat33d),
    Jp: wp.array(dtype=wp.float64),
    E: wp.array(dtype=wp.float64),
    nu: wp.array(dtype=wp.float64),
    elastic: wp.array(dtype=wp.int32),
    plastic: wp.array(dtype=wp.int32),
    pp: wp.array(dtype=wp.vec4d),
    fiber: wp.array(dtype=wp.vec3d),
    fiber_E: wp.array(dtype=wp.float64),
    mass: wp.array(dtype=wp.float64),
    vol: wp.array(dtype=wp.float64),
    omega: wp.array(dtype=wp.float64),
    x_ref: wp.array(dtype=wp.vec3d),
    v_ref: wp.array(dtype=wp.vec3d),
    f_hold: wp.array(dtype=wp.vec3d),
    kp: wp.float64,
    kd: wp.float64,
    origin: wp.float64,
    dx: wp.float64,
    dt: wp.float64,
    nmax: wp.int32,
    off: wp.vec3i,
    p0: wp.int32,
    grid_mv: wp.array3d(dtype=wp.vec3d),
    grid_m: wp.array3d(dtype=wp.float64),
):
    """Steps 1-2 of Alg. 1 for particle p0 + tid: Kirchhoff stress (expert law + fibre term), then the scatter."""
    p = wp.tid() + p0
    h = hardening_factor(Jp[p], plastic[p], pp[p])
    tau = kirchhoff_stress_fiber(F[p], E[p], nu[p], elastic[p], h, fiber[p], fiber_E[p])
    f = f_hold[p] + pd_force(mass[p], omega[p], x[p], v[p], x_ref[p], v_ref[p], kp, kd)
    p2g_particle(x[p], v[p], C[p], tau, mass[p], vol[p], f, origin, dx, dt, nmax, off, grid_mv, grid_m)


@wp.kernel
def g2p_fused_kernel(
    grid_v: wp.array3d(dtype=wp.vec3d),
    x: wp.array(dtype=wp.vec3d),
    F: wp.array(dtype=wp.mat33d),
    Jp: wp.array(dtype=wp.float64),
    E: wp.array(dtype=wp.float64),
    nu: wp.array(dtype=wp.float64),
    plastic: wp.array(dtype=wp.int32),
    pp: wp.array(dtype=wp.vec4d),
    origin: wp.float64,
    dx: wp.float64,
    dt: wp.float64,
    nmax: wp.int32,
    x_lo: wp.float64,
    x_hi: wp.float64,
    off: wp.vec3i,
    nc: wp.int32,
    ckind: wp.array(dtype=wp.int32),
    ccenter: wp.array(dtype=wp.vec3d),
    cvel: wp.array(dtype=wp.vec3d),
    csize: wp.array(dtype=wp.vec3d),
    caxis: wp.array(dtype=wp.vec3d),
    p0: wp.int32,
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
    C_out: wp.array(dtype=wp.mat33d),
    F_out: wp.array(dtype=wp.mat33d),
    Jp_out: wp.array(dtype=wp.float64),
):
    """Steps 4-5 of Alg. 1 for particle p0 + tid: APIC gather, F_trial = (I + dt C) F, return map."""
    p = wp.tid() + p0
    nv, nC, xn = g2p_particle(grid_v, x[p], origin, dx, dt, nmax, x_lo, x_hi, off, nc, ckind, ccenter, cvel, csize,
                              caxis)
    Ft = (wp.identity(n=3, dtype=wp.float64) + dt * nC) * F[p]
    Fn, J = plastic_update(Ft, Jp[p], E[p], nu[p], plastic[p], pp[p])
    x_out[p] = xn
    v_out[p] = nv
    C_out[p] = nC
    F_out[p] = Fn
    Jp_out[p] = J


@wp.kernel
def add_grid_kernel(a_mv: wp.array3d(dtype=wp.vec3d), a_m: wp.array3d(dtype=wp.float64),
                    b_mv: wp.array3d(dtype=wp.vec3d), b_m: wp.array3d(dtype=wp.float64)):
    i, j, k = wp.tid()
    a_mv[i, j, k] = a_mv[i, j, k] + b_mv[i, j, k]
    a_m[i, j, k] = a_m[i, j, k] + b_m[i, j, k]


@wp.kernel
def add_vec_grid_kernel(a: wp.array3d(dtype=wp.vec3d), b: wp.array3d(dtype=wp.vec3d)):
    i, j, k = wp.tid()
    a[i, j, k] = a[i, j, k] + b[i, j, k]


_STATE = (("x", wp.vec3d), ("v", wp.vec3d), ("C", wp.mat33d), ("F", wp.mat33d), ("Jp", wp.float64))


def _alloc_state(n: int) -> list:
    return [wp.zeros(n, dtype=t) for _, t in _STATE]


class FusedFrame:
    """Forward and reverse sweeps of one frame of ``model.substeps`` substeps (see module docstring).

    ``threads``: 1 or 2 (default: 2 if the machine has 2 cores and the model at least 2 x 2048 particles).
    """

    def __init__(self, model: MPMModel, threads: int | None = None):
        self.model = model
        n = model.n_particles
        if threads is None:
            threads = 2 if (os.cpu_count() or 1) >= 2 and n >= 2 * MIN_PARTICLES_PER_THREAD else 1
        self.threads = max(1, min(2, int(threads)))
        h = n // 2
        self.parts = [(0, n)] if self.threads == 1 else [(0, h), (h, n - h)]
        T = model.substeps
        self.seg = max(1, math.ceil(math.sqrt(T)))

    # -- helpers
    def _par(self, fns):
        """Run the callables concurrently (the first on this thread)."""
        if len(fns) == 1:
            fns[0]()
            return
        futs = [_pool().submit(f) for f in fns[1:]]
        fns[0]()
        for f in futs:
            f.result()

    def _consts(self):
        m = self.model
        a = m.warp_arrays()
        lo, hi = m.clamp_range
        return m, a, lo, hi, m.n_grid - 3

    # -- one substep forward; returns what the reverse sweep needs
    def substep(self, s_in: list, s_out: list, P: dict, t: float, keep: bool = False, box=None):
        """One substep s_in -> s_out.  ``box`` (corner, shape) is the active node box of s_in when already known
        (the backward recompute reuses the boxes of the forward sweep: same states, no host round trip)."""
        m, a, lo, hi, nmax = self._consts()
        x, v, C, F, Jp = s_in
        corner, shape = box if box is not None else m.active_box(x.numpy())
        off = wp.vec3i(*corner)
        grids = [(wp.zeros(shape, dtype=wp.vec3d), wp.zeros(shape, dtype=wp.float64)) for _ in self.parts]
        col = a["colliders"].at(t, m.dt)
        cin = col.inputs()

        def p2g(k):
            p0, cnt = self.parts[k]
            return lambda: wp.launch(
                p2g_fused_kernel, cnt,
                inputs=[x, v, C, F, Jp, P["E"], P["nu"], a["elastic"], a["plastic"], a["pp"], a["fiber"],
                        P["fiber_E"], a["mass"], a["volume"], P["omega"], P["x_ref"], P["v_ref"], P["f_hold"],
                        P["kp"], P["kd"], m.origin, m.dx, m.dt, nmax, off, p0],
                outputs=list(grids[k]))

        self._par([p2g(k) for k in range(len(self.parts))])
        mv, gm = grids[0]
        for k in range(1, len(grids)):
            wp.launch(add_grid_kernel, shape, inputs=[mv, gm, grids[k][0], grids[k][1]])
        gv = wp.zeros(shape, dtype=wp.vec3d)
        g_in = [mv, gm, wp.vec3d(*m.gravity), m.dt, m.pad, m.pad + m.resolution, a["bc"], a["friction"],
                wp.vec3i(0, 0, 0), off, m.origin, m.dx, *cin]
        wp.launch(grid_update_kernel, shape, inputs=g_in, outputs=[gv])

        def g2p(k):
            p0, cnt = self.parts[k]
            return lambda: wp.launch(
                g2p_fused_kernel, cnt,
                inputs=[gv, x, F, Jp, P["E"], P["nu"], a["plastic"], a["pp"], m.origin, m.dx, m.dt, nmax, lo, hi,
                        off, cin[0], cin[1], cin[4], cin[5], cin[6], cin[7], p0],
                outputs=list(s_out))

        self._par([g2p(k) for k in range(len(self.parts))])
        if keep:
            return {"shape": shape, "off": off, "grids": grids, "gv": gv, "g_in": g_in, "t": t}
        return corner, shape

    def adjoint_substep(self, s_in: list, s_out: list, adj_in: list, adj_out: list, P: dict, adjP: dict, rec: dict):
        """Accumulate into adj_in (state s) and adjP the adjoints given adj_out (state s + 1)."""
        m, a, lo, hi, nmax = self._consts()
        x, v, C, F, Jp = s_in
        shape, off, gv = rec["shape"], rec["off"], rec["gv"]
        col = a["colliders"].at(rec["t"], m.dt)
        cin = col.inputs()
        adj_gvs = [wp.zeros(shape, dtype=wp.vec3d) for _ in self.parts]

        def g2p_adj(k):
            p0, cnt = self.parts[k]
            ins = [gv, x, F, Jp, P["E"], P["nu"], a["plastic"], a["pp"], m.origin, m.dx, m.dt, nmax, lo, hi,
                   off, cin[0], cin[1], cin[4], cin[5], cin[6], cin[7], p0]
            adj_ins = _adj(ins, {0: adj_gvs[k], 1: adj_in[0], 2: adj_in[3], 3: adj_in[4], 4: adjP["E"], 5: adjP["nu"]})
            return lambda: wp.launch(g2p_fused_kernel, cnt, inputs=ins, outputs=list(s_out), adj_inputs=adj_ins,
                                     adj_outputs=list(adj_out), adjoint=True)

        self._par([g2p_adj(k) for k in range(len(self.parts))])
        adj_gv = adj_gvs[0]
        for k in range(1, len(adj_gvs)):
            wp.launch(add_vec_grid_kernel, shape, inputs=[adj_gv, adj_gvs[k]])
        adj_mv = wp.zeros(shape, dtype=wp.vec3d)
        adj_m = wp.zeros(shape, dtype=wp.float64)
        g_in = rec["g_in"]
        g_adj = _adj(g_in, {0: adj_mv, 1: adj_m})
        wp.launch(grid_update_kernel, shape, inputs=g_in, outputs=[gv], adj_inputs=g_adj, adj_outputs=[adj_gv],
                  adjoint=True)

        def p2g_adj(k):
            p0, cnt = self.parts[k]
            ins = [x, v, C, F, Jp, P["E"], P["nu"], a["elastic"], a["plastic"], a["pp"], a["fiber"], P["fiber_E"],
                   a["mass"], a["volume"], P["omega"], P["x_ref"], P["v_ref"], P["f_hold"], P["kp"], P["kd"],
                   m.origin, m.dx, m.dt, nmax, off, p0]
            adj_ins = _adj(ins, {0: adj_in[0], 1: adj_in[1], 2: adj_in[2], 3: adj_in[3], 4: adj_in[4], 5: adjP["E"],
                                 6: adjP["nu"], 11: adjP["fiber_E"], 14: adjP["omega"], 15: adjP["x_ref"],
                                 16: adjP["v_ref"], 17: adjP["f_hold"]})
            # the forward summed the halves' grids: every half sees the adjoint of the sum
            return lambda: wp.launch(p2g_fused_kernel, cnt, inputs=ins, outputs=list(rec["grids"][k]),
                                     adj_inputs=adj_ins, adj_outputs=[adj_mv, adj_m], adjoint=True)

        self._par([p2g_adj(k) for k in range(len(self.parts))])


def _adj(inputs: list, given: dict) -> list:
    """Adjoint argument list for ``inputs``: ``given[i]`` where set, a zero value for Warp value types (vec3i …),
    None otherwise (arrays without gradient, Python scalars)."""
    out = []
    for i, a in enumerate(inputs):
        if i in given:
            out.append(given[i])
        elif wp._src.types.is_native_type(type(a)):
            out.append(type(a)())
        else:
            out.append(None)
    return out


def _wp(t: torch.Tensor, dtype):
    return wp.from_torch(t.detach().contiguous(), dtype=dtype)


class FusedFrameFunction(torch.autograd.Function):
    """(x, v, C, F, Jp, E, nu, omega, x_ref, v_ref, f_hold, fiber_E) at the start of a frame -> state at its end.

    f_hold (N, 3) N is the external force held over the frame (seed Alg. 2); omega, x_ref, v_ref, kp, kd give
    the per-substep PD force (zeros when the force is held).  The fibre directions are the model's
    (``model.fiber``, constant); fiber_E (N,) Pa is differentiable."""

    @staticmethod
    def forward(ctx, runner: FusedFrame, t0: float, kp: float, kd: float, x, v, C, F, Jp, E, nu, omega, x_ref, v_ref,
                f_hold, fiber_E):
        m = runner.model
        n, T = m.n_particles, m.substeps
        P = {"E": _wp(E, wp.float64), "nu": _wp(nu, wp.float64), "omega": _wp(omega, wp.float64),
             "x_ref": _wp(x_ref, wp.vec3d), "v_ref": _wp(v_ref, wp.vec3d), "f_hold": _wp(f_hold, wp.vec3d),
             "fiber_E": _wp(fiber_E, wp.float64), "kp": float(kp), "kd": float(kd)}
        cur = [wp.array(t.detach().contiguous().numpy(), dtype=d) for t, (_, d) in zip((x, v, C, F, Jp), _STATE)]
        nxt = _alloc_state(n)
        bounds = {0: [a.numpy().copy() for a in cur]}
        boxes = []
        for s in range(T):
            boxes.append(runner.substep(cur, nxt, P, t0 + s * m.dt))
            cur, nxt = nxt, cur
            if (s + 1) % runner.seg == 0 and s + 1 < T:
                bounds[s + 1] = [a.numpy().copy() for a in cur]
        ctx.runner, ctx.t0, ctx.bounds, ctx.boxes, ctx.kp, ctx.kd = runner, t0, bounds, boxes, kp, kd
        ctx.save_for_backward(E, nu, omega, x_ref, v_ref, f_hold, fiber_E)
        return tuple(torch.from_numpy(a.numpy().copy()) for a in cur)

    @staticmethod
    def backward(ctx, *grads):
        runner = ctx.runner
        m = runner.model
        n, T = m.n_particles, m.substeps
        E, nu, omega, x_ref, v_ref, f_hold, fiber_E = ctx.saved_tensors
        P = {"E": _wp(E, wp.float64), "nu": _wp(nu, wp.float64), "omega": _wp(omega, wp.float64),
             "x_ref": _wp(x_ref, wp.vec3d), "v_ref": _wp(v_ref, wp.vec3d), "f_hold": _wp(f_hold, wp.vec3d),
             "fiber_E": _wp(fiber_E, wp.float64), "kp": float(ctx.kp), "kd": float(ctx.kd)}
        adjP = {"E": wp.zeros(n, dtype=wp.float64), "nu": wp.zeros(n, dtype=wp.float64),
                "omega": wp.zeros(n, dtype=wp.float64), "x_ref": wp.zeros(n, dtype=wp.vec3d),
                "v_ref": wp.zeros(n, dtype=wp.vec3d), "f_hold": wp.zeros(n, dtype=wp.vec3d),
                "fiber_E": wp.zeros(n, dtype=wp.float64)}
        adj_next = [wp.array(np.ascontiguousarray(g.detach().numpy() if g is not None else np.zeros(sh)), dtype=d)
                    for g, (_, d), sh in zip(grads, _STATE, [(n, 3), (n, 3), (n, 3, 3), (n, 3, 3), (n,)])]
        adj_cur = _alloc_state(n)
        starts = sorted(ctx.bounds)
        for si in reversed(range(len(starts))):
            s0 = starts[si]
            s1 = starts[si + 1] if si + 1 < len(starts) else T
            states = [[wp.array(a, dtype=d) for a, (_, d) in zip(ctx.bounds[s0], _STATE)]]
            recs = []
            for s in range(s0, s1):
                out = _alloc_state(n)
                recs.append(runner.substep(states[-1], out, P, ctx.t0 + s * m.dt, keep=True, box=ctx.boxes[s]))
                states.append(out)
            for j in reversed(range(s1 - s0)):
                for a in adj_cur:
                    a.zero_()
                runner.adjoint_substep(states[j], states[j + 1], adj_cur, adj_next, P, adjP, recs[j])
                adj_cur, adj_next = adj_next, adj_cur
        to_t = lambda a: torch.from_numpy(a.numpy().copy())
        g_state = [to_t(a) for a in adj_next]
        g_par = [to_t(adjP[k]) for k in ("E", "nu", "omega", "x_ref", "v_ref", "f_hold", "fiber_E")]
        return (None, None, None, None, *g_state, *g_par)
