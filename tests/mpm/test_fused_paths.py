"""The fused adjoint's other paths (issue 19): the hand-written G2P tail (no collider, no plastic law), the
forward that keeps the last K substeps (memory budget), and the measured choice of 1 or 2 threads.

References: Warp's generic per-launch tape (``fused=False``, Warp's generated adjoints of the model's own
kernels, another code path) and central differences of the forward-only run."""

import numpy as np
import pytest
import torch

from physar.mpm import build_model, parse_scene
from physar.mpm.adjoint import FusedFrame, ThreadChooser
from physar.mpm.torch_bridge import Params, simulate


def _setup(material="neohookean"):
    sc = parse_scene({
        "grid": {"size": 1.0, "resolution": 8},
        "time": {"frame_dt": 0.01, "substeps": 10, "frames": 2},
        "gravity": {"g": [0, 0, -9.81]},
        "body": [{"shape": "box", "min": [0.35, 0.35, 0.1], "max": [0.6, 0.6, 0.35], "E": 2e3, "nu": 0.3,
                  "particles_per_cell": 8, "velocity": [0.3, -0.2, -0.6], "material": material}],
    })
    model, x0, v0 = build_model(sc)
    n = model.n_particles
    rng = np.random.default_rng(0)
    base = {"E": torch.tensor(2e3 * (1 + 0.2 * rng.random(n))), "nu": torch.tensor(0.25 + 0.1 * rng.random(n)),
            "omega": torch.tensor(rng.random(n)), "v0": torch.tensor(v0)}
    x_ref = torch.tensor(x0 + 0.02 * rng.standard_normal((n, 3)))
    w = torch.tensor(rng.standard_normal((n, 3)))
    return model, x0, base, x_ref, w


def _loss(model, x0, vals, x_ref, w, fused=True, **kw):
    if fused:
        model._fused = FusedFrame(model, **kw)
    p = Params(E=vals["E"], nu=vals["nu"], omega=vals["omega"], x_ref=x_ref, kp=50.0, kd=2.0)
    _, (x, v, C, F, _Jp) = simulate(model, x0, vals["v0"], p, frames=2, fused=fused)
    return (w * x).sum() + 0.1 * (w * v).sum() + 0.01 * F.sum() + 0.003 * C.sum()


def _grads(model, x0, base, x_ref, w, **kw):
    vals = {k: v.clone().requires_grad_(True) for k, v in base.items()}
    _loss(model, x0, vals, x_ref, w, **kw).backward()
    return {k: vals[k].grad for k in vals}


@pytest.mark.parametrize("material", ["neohookean", "fixed_corotated"])
def test_hand_tail_and_kept_substeps_equal_generic_tape(material):
    """No collider, no plastic law (the G2P tail reversed by hand in g2p_gather_adjoint_kernel), particles hitting
    the slip ground; every split of the frame into kept / recomputed substeps (keep_bytes = 0: all
    recomputed; one particle-state's worth less than a frame: some kept; default: all kept) and 1 or 2 threads
    give Warp's generic-tape gradients to 1e-9.

    Mutants caught (each checked to fail): the tail's dL/dF without the transpose of (I + dt C); the tail's
    dL/dC without dt; the backward skipping the recomputed segments when K < T (no gradient from the first
    substeps); the kept tail reversed from the wrong start state."""
    model, x0, base, x_ref, w = _setup(material)
    ref = _grads(model, x0, base, x_ref, w, fused=False)
    n = model.n_particles
    some = 6 * n * 200  # keeps K = 5 of a frame's 10 substeps (the grid term is below one particle state)
    for kw in ({"threads": 1, "keep_bytes": 0}, {"threads": 2, "keep_bytes": 0}, {"threads": 1, "keep_bytes": some},
               {"threads": 2, "keep_bytes": some}, {"threads": 2}, {}):
        g = _grads(model, x0, base, x_ref, w, **kw)
        for k in g:
            scale = float(ref[k].abs().max())
            assert torch.allclose(g[k], ref[k], rtol=1e-9, atol=1e-12 * scale), (kw, k)


def test_hand_tail_matches_central_difference():
    """dL/d(E, nu, omega, v0) of the hand-reversed tail path against central differences (rel. 1e-3).

    Mutant caught: the tail's dL/dx without the position term (adj_x += dL/dx_new dropped)."""
    model, x0, base, x_ref, w = _setup("neohookean")
    rng = np.random.default_rng(1)
    for name, eps in (("E", 1.0), ("nu", 1e-6), ("omega", 1e-6), ("v0", 1e-6)):
        vals = {k: v.clone().requires_grad_(k == name) for k, v in base.items()}
        _loss(model, x0, vals, x_ref, w, threads=1).backward()
        d = torch.tensor(rng.standard_normal(tuple(base[name].shape)))
        with torch.no_grad():
            lp = _loss(model, x0, {**base, name: base[name] + eps * d}, x_ref, w, threads=1)
            lm = _loss(model, x0, {**base, name: base[name] - eps * d}, x_ref, w, threads=1)
        fd = (lp - lm) / (2 * eps)
        ad = (vals[name].grad * d).sum()
        assert abs(ad - fd) < 1e-3 * abs(fd), (name, float(ad), float(fd))


def test_thread_chooser_follows_the_faster_mode():
    """Closed-form schedule of the chooser: with 1 thread at 2 ms and 2 threads at 2.2 ms per substep (ratio
    1.1: probe interval 8), after the 6 warm-up calls (1, 2 alternating, first of each not counted) it runs
    the faster mode 8 times, then probes once: 7 probes in 64 calls; at a ratio of 4 (1 ms vs 4 ms) the
    interval is ceil(3 / 0.05) = 60: 2 probes in 122 calls (probe cost 2 x 3 ms / 122 ms < 5 %); when the
    timings swap it switches to 2 threads.

    Mutants caught: picking the slower mode; counting the first (kernel-loading) call of a mode; never probing
    (the switch is not seen); a fixed probe interval (7 probes instead of 2 at ratio 4)."""
    ch = ThreadChooser(probe_every=8, overhead=0.05)
    cost = {1: 0.002, 2: 0.0022}
    octave = (100_000).bit_length()

    def run(k):
        modes = []
        for _ in range(k):
            m = ch.pick("fwd", 100_000)
            first = ch.est[("fwd", octave, m)][2] == 1
            ch.record("fwd", 100_000, m, 10.0 if first else cost[m])
            modes.append(m)
        return modes

    warm = run(6)
    assert warm == [1, 2, 1, 2, 1, 2]
    modes = run(64)
    assert modes.count(2) == 7 and modes[:9] == [1] * 8 + [2]
    ch2 = ThreadChooser(probe_every=8, overhead=0.05)
    ch, cost = ch2, {1: 0.001, 2: 0.004}
    run(6)
    modes = run(122)
    assert modes.count(2) == 2 and modes[60] == 2 and modes[121] == 2
    cost[1], cost[2] = 0.004, 0.002
    modes = run(200)
    assert modes[-32:].count(2) >= 28


def test_second_backward_of_a_kept_frame_refuses():
    """A frame whose forward kept its substeps gives them up in its backward: a second backward (retain_graph)
    raises instead of returning a gradient without those substeps; with keep_bytes = 0 it accumulates the same
    gradient again (exactly twice the first).

    Mutant caught: no check (the second pass silently reverses an empty frame: dL/dv0 = the loss's direct
    term only)."""
    model, x0, base, x_ref, w = _setup("neohookean")
    vals = {k: v.clone().requires_grad_(k == "v0") for k, v in base.items()}
    loss = _loss(model, x0, vals, x_ref, w, threads=1)
    loss.backward(retain_graph=True)
    with pytest.raises(RuntimeError, match="keep_bytes=0"):
        loss.backward()
    vals = {k: v.clone().requires_grad_(k == "v0") for k, v in base.items()}
    loss = _loss(model, x0, vals, x_ref, w, threads=1, keep_bytes=0)
    loss.backward(retain_graph=True)
    g1 = vals["v0"].grad.clone()
    loss.backward()
    assert torch.equal(vals["v0"].grad, 2 * g1)
