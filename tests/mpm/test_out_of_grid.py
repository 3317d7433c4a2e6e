"""Particles that leave the grid are clamped to it (never an out-of-bounds access), a blow-up is a SolverError."""

import numpy as np
import pytest
import torch

from physar.errors import SolverError
from physar.mpm import MPMSolver, build_model, parse_scene
from physar.mpm.torch_bridge import Params, simulate


def _scene(velocity, E=1e4, substeps=10, frames=6, walls="none"):
    return parse_scene({
        "grid": {"size": 1.0, "resolution": 8},
        "time": {"frame_dt": 0.02, "substeps": substeps, "frames": frames},
        "gravity": {"g": [0, 0, 0]},
        "boundary": {"ground": walls, "walls": walls},
        "body": [{"shape": "box", "min": [0.6, 0.4, 0.4], "max": [0.85, 0.6, 0.6], "E": E,
                  "particles_per_cell": 8, "velocity": list(velocity)}],
    })


def test_particles_thrown_out_of_an_open_domain_are_clamped_to_the_grid():
    # 20 m/s towards +x with no walls: in 0.12 s the block would travel 2.4 m, far beyond the padded grid
    # [-3 dx, 1 + 3 dx]; the particles stop at the clamp bound (their stencil stays on the grid) and stay finite.
    sc = _scene((20.0, 0.0, 0.0))
    model, x, v = build_model(sc)
    solver = MPMSolver(model)
    a, b = model.state(x, v), model.state(x, v)
    for _ in range(sc.time.frames):
        a, b = solver.simulate_frame(a, b)
    xe = a.x.numpy()
    lo, hi = model.clamp_range
    assert np.all(np.isfinite(xe))
    assert xe.min() >= lo and xe.max() <= hi
    assert np.isclose(xe[:, 0].max(), hi)  # it really reached the bound
    assert hi < 1.0 + 3 * model.dx

    # the differentiable path clamps the same way and its gradients stay finite
    vt = torch.tensor(v, requires_grad=True)
    xs, _ = simulate(model, x, vt, Params(E=torch.full((len(x),), 1e4, dtype=torch.float64),
                                          nu=torch.full((len(x),), 0.3, dtype=torch.float64)), frames=2)
    xs[-1].sum().backward()
    assert float(xs[-1][:, 0].detach().max()) <= hi and torch.isfinite(vt.grad).all()


def test_blow_up_is_a_solver_error_not_a_crash(tmp_path):
    # E = 1e10 Pa with dt = 2e-3 s violates the CFL condition by far: the run must stop with a clear error.
    sc = _scene((0.0, 0.0, 0.0), E=1e10, substeps=1, frames=20, walls="slip")
    model, x, v = build_model(sc)
    v = v + 1e-2 * np.random.default_rng(0).standard_normal(x.shape)  # seed the instability
    solver = MPMSolver(model)
    a, b = model.state(x, v), model.state(x, v)
    with pytest.raises(SolverError, match="diverged"):
        for _ in range(sc.time.frames):
            a, b = solver.simulate_frame(a, b)
