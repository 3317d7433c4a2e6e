"""Kinematic colliders (moving boxes / capsules) against closed forms, non-penetration, gradients, TOML errors."""

import numpy as np
import pytest
import torch

from physar.errors import ConfigError
from physar.mpm import MPMSolver, build_model, diagnostics, parse_scene
from physar.mpm.colliders import Collider
from physar.mpm.torch_bridge import Params, simulate

G = 9.81


def _scene(bodies, colliders, res=32, frame_dt=0.02, substeps=40, frames=10, g=(0, 0, -G), ground="none",
           walls="slip"):
    return parse_scene({
        "grid": {"size": 1.0, "resolution": res},
        "time": {"frame_dt": frame_dt, "substeps": substeps, "frames": frames},
        "gravity": {"g": list(g)},
        "boundary": {"ground": ground, "walls": walls},
        "body": bodies,
        "collider": colliders,
    })


def _run(sc):
    model, x, v = build_model(sc)
    solver = MPMSolver(model)
    a, b = model.state(x, v), model.state(x, v)
    d, xs = [diagnostics(model, a.numpy())], [x.copy()]
    for _ in range(sc.time.frames):
        a, b = solver.simulate_frame(a, b)
        st = a.numpy()
        d.append(diagnostics(model, st))
        xs.append(st["x"])
    return model, d, xs


def _min_phi(model, xs, frame_dt):
    return min(model.colliders[0].signed_distance(x, f * frame_dt).min() for f, x in enumerate(xs))


def test_block_on_moving_platform_coulomb_friction():
    # A block dropped onto a platform sliding at u = 0.5 m/s with friction mu: while it slips, Coulomb's law makes
    # the horizontal impulse mu times the normal impulse, and the normal impulse is M (g t + vz(t) - vz(0)), so
    # vx(t) = mu (g t + vz(t)) (closed form for any bouncing); for a resting block this is vx = mu g t.
    mu, u, fdt = 0.2, 0.5, 0.02
    sc = _scene([{"shape": "box", "min": [0.4, 0.4, 0.16], "max": [0.6, 0.6, 0.3], "E": 1e5, "nu": 0.3}],
                [{"shape": "box", "center": [0.5, 0.5, 0.1], "size": [0.8, 0.8, 0.1], "velocity": [u, 0, 0],
                  "boundary": "slip", "friction": mu}], frame_dt=fdt, frames=10)
    model, d, xs = _run(sc)
    M = model.mass.sum()
    for f in range(3, 11):  # after the first contact transient (t >= 0.06 s); slips until mu g t = u (0.25 s)
        vx, vz = d[f]["momentum"][[0, 2]] / M
        assert abs(vx - mu * (G * f * fdt + vz)) < 0.02 * mu * G * f * fdt, (f, vx, mu * (G * f * fdt + vz))
    dx_com = d[-1]["com"][0] - d[0]["com"][0]
    assert abs(dx_com - 0.5 * mu * G * 0.2**2) < 0.1 * 0.5 * mu * G * 0.2**2  # bounce-averaged 1/2 mu g t^2
    assert abs(d[-1]["momentum"][1]) < 1e-9 * M
    assert _min_phi(model, xs, fdt) > -1e-12  # never inside the platform


def test_block_carried_by_sticky_platform_on_keyframed_path():
    # A sticky platform (top face at z = 0.16, under the block) moves on a keyframed smooth-step path by
    # (0.03, 0, 0.02) m in 0.2 s and stops: the block on it ends displaced by the path's displacement, within a
    # tenth of a cell (quasi-static motion: the ramp is slow compared with the block's lowest modes).
    ts = np.linspace(0, 1, 11)
    s = 3 * ts**2 - 2 * ts**3
    path = ([[0.0, 0.5, 0.5, 0.11]] + [[0.04 + 0.2 * t, 0.5 + 0.03 * si, 0.5, 0.11 + 0.02 * si] for t, si in zip(ts, s)]
            + [[1.0, 0.53, 0.5, 0.13]])
    sc = _scene([{"shape": "box", "min": [0.42, 0.42, 0.16], "max": [0.58, 0.58, 0.28], "E": 1e6, "nu": 0.3}],
                [{"shape": "box", "path": path, "size": [0.5, 0.5, 0.1], "boundary": "sticky"}],
                frame_dt=0.02, substeps=100, frames=15)
    model, d, xs = _run(sc)
    disp = d[-1]["com"] - d[2]["com"]  # the path starts at t = 0.04 s
    assert np.all(np.abs(disp - [0.03, 0.0, 0.02]) < 0.1 * model.dx), disp
    assert _min_phi(model, xs, 0.02) > -1e-12


def test_capsule_pushes_block_momentum_and_energy_bounds():
    # A capsule moving at u hits a free elastic block (no gravity).  In the capsule's frame the capsule is a
    # passive wall, so the block's energy there (kinetic + elastic) cannot grow: the block leaves with a velocity
    # between u (not penetrated) and 2 u (elastic rebound), and then flies freely with constant momentum.
    u, fdt = 0.2, 0.01
    sc = _scene([{"shape": "box", "min": [0.4, 0.4375, 0.4375], "max": [0.65, 0.5625, 0.5625], "E": 1e5, "nu": 0.3}],
                [{"shape": "capsule", "center": [0.3, 0.5, 0.5], "radius": 0.08, "length": 0.3, "axis": [0, 1, 0],
                  "velocity": [u, 0, 0], "boundary": "separate"}], g=(0, 0, 0), frame_dt=fdt, substeps=20, frames=35)
    model, d, xs = _run(sc)
    M = model.mass.sum()
    e_rel = [dd["kinetic_energy"] - u * dd["momentum"][0] + 0.5 * M * u * u + dd["elastic_energy"] for dd in d]
    assert np.all(np.diff(e_rel) <= 1e-6 * e_rel[0]), e_rel
    vx = np.array([dd["momentum"][0] for dd in d]) / M
    assert u < vx[-1] < 2 * u
    assert np.max(np.abs(vx[30:] - vx[-1])) < 1e-3 * u  # separated: free flight
    assert np.max(np.abs([dd["momentum"][1:] for dd in d])) < 1e-9 * M * u
    assert _min_phi(model, xs, fdt) > 0.0


def test_block_dropped_on_static_capsule_does_not_penetrate():
    sc = _scene([{"shape": "box", "min": [0.35, 0.35, 0.45], "max": [0.65, 0.65, 0.6], "E": 5e4, "nu": 0.3}],
                [{"shape": "capsule", "center": [0.5, 0.5, 0.3], "radius": 0.1, "length": 0.4, "axis": [1, 1, 0],
                  "boundary": "slip"}], frame_dt=0.02, substeps=40, frames=12)
    model, d, xs = _run(sc)
    assert d[-1]["com"][2] < d[0]["com"][2] - 0.03  # it fell onto the capsule and sagged around it
    assert _min_phi(model, xs, 0.02) > -1e-12  # projected out after every substep


def test_collider_signed_distance_closed_forms():
    box = Collider(shape="box", center=(0.5, 0.5, 0.5), half_extents=(0.1, 0.2, 0.3), velocity=(1.0, 0, 0))
    assert np.allclose(box.signed_distance(np.array([[0.5, 0.5, 0.5], [0.8, 0.5, 0.5], [0.7, 0.8, 0.5]])),
                       [-0.1, 0.2, np.hypot(0.1, 0.1)])
    assert np.allclose(box.signed_distance(np.array([[1.5, 0.5, 0.5]]), t=1.0), [-0.1])  # moved by u t
    cap = Collider(shape="capsule", path=np.array([[0, 0, 0, 0], [2, 2, 0, 0]]), radius=0.1, half_length=0.5,
                   axis=(0, 0, 2))
    assert np.allclose(cap.signed_distance(np.array([[1.0, 0.3, 0.2], [1.0, 0.0, 0.9]]), t=1.0), [0.2, 0.3])
    c, vel = cap.substep_motion(1.0, 0.1)
    assert np.allclose(c, [1, 0, 0]) and np.allclose(vel, [1, 0, 0])
    assert np.allclose(cap.substep_motion(5.0, 0.1)[1], 0)  # held after the last keyframe


def test_collider_gradients_match_central_difference():
    # dL/dE and dL/dv0 through 20 substeps in sliding contact with a moving frictional box (rel. 1e-3).
    sc = _scene([{"shape": "box", "min": [0.3, 0.3, 0.3], "max": [0.6, 0.6, 0.55], "E": 2e3, "nu": 0.3,
                  "particles_per_cell": 1, "velocity": [0.0, 0.0, -0.3]}],
                [{"shape": "box", "center": [0.45, 0.45, 0.19], "size": [0.6, 0.6, 0.2], "velocity": [0.3, 0.1, 0],
                  "boundary": "slip", "friction": 0.3}], res=8, frame_dt=0.01, substeps=10, frames=2)
    model, x0, v0 = build_model(sc)
    n = model.n_particles
    rng = np.random.default_rng(3)
    w = torch.tensor(rng.standard_normal((n, 3)))
    E0 = torch.tensor(2e3 * (1 + 0.2 * rng.random(n)))
    nu = torch.full((n,), 0.3, dtype=torch.float64)

    def loss(E, v):
        _, (x, vv, *_rest) = simulate(model, x0, v, Params(E=E, nu=nu), frames=2)
        return (w * x).sum() + 0.1 * (w * vv).sum()

    E = E0.clone().requires_grad_(True)
    v = torch.tensor(v0).requires_grad_(True)
    loss(E, v).backward()
    assert torch.isfinite(E.grad).all() and torch.isfinite(v.grad).all()
    for g, base, eps, which in ((E.grad, E0, 1.0, 0), (v.grad, torch.tensor(v0), 1e-6, 1)):
        d = torch.tensor(rng.standard_normal(tuple(base.shape)))
        with torch.no_grad():
            args_p = [E0, torch.tensor(v0)]
            args_m = [E0, torch.tensor(v0)]
            args_p[which] = base + eps * d
            args_m[which] = base - eps * d
            fd = (loss(*args_p) - loss(*args_m)) / (2 * eps)
        ad = (g * d).sum()
        assert abs(ad - fd) < 1e-3 * abs(fd), (which, float(ad), float(fd))


@pytest.mark.parametrize("col,msg", [
    ({"shape": "box", "center": [0.5, 0.5, 0.1]}, "size"),
    ({"shape": "capsule", "center": [0.5, 0.5, 0.1]}, "radius"),
    ({"shape": "box", "size": [0.1, 0.1, 0.1]}, "center"),
    ({"shape": "box", "size": [0.1, 0.1, 0.1], "center": [0.5, 0.5, 0.1], "path": [[0, 0.5, 0.5, 0.1]]}, "not both"),
    ({"shape": "box", "size": [0.1, 0.1, 0.1], "path": [[0, 0.5, 0.5, 0.1], [0, 0.5, 0.5, 0.2]]}, "increase"),
    ({"shape": "cone", "size": [0.1, 0.1, 0.1], "center": [0.5, 0.5, 0.1]}, "shape"),
    ({"shape": "box", "size": [0.1, 0.1, 0.1], "center": [0.5, 0.5, 0.1], "boundary": "glue"}, "boundary"),
])
def test_bad_collider_tables_raise_config_error(col, msg):
    with pytest.raises(ConfigError, match=msg):
        _scene([{"shape": "box", "min": [0.4, 0.4, 0.6], "max": [0.6, 0.6, 0.8]}], [col])


def test_body_overlapping_collider_is_rejected():
    sc = _scene([{"shape": "box", "min": [0.4, 0.4, 0.6], "max": [0.6, 0.6, 0.8]}],
                [{"shape": "capsule", "center": [0.5, 0.5, 0.7], "radius": 0.05}])
    with pytest.raises(ConfigError, match=r"body\[0\] overlaps collider\[0\]"):
        build_model(sc)
