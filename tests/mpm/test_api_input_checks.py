"""Python-API input checks of the MPM solver and of the differentiable :func:`physar.mpm.simulate` (probe
findings):

* ``MPMState.from_numpy`` with a velocity array one particle short was accepted; ``simulate_frame`` then read and
  wrote past its end ("double free or corruption"); (3, N) arrays gave a Warp error about "inner dimensions";
* ``MPMSolver`` ran a state whose particle count differed from the model's (another model's state);
* ``simulate(model, x, v, Params(E=E[:5], nu=nu[:5]))`` and a ``v0`` one particle short returned plausible
  positions; ``Params`` with a scalar E failed inside Warp (IndexError);
* ``Params`` E < 0, E = NaN, nu = 0.5 or 0.7 ran (nu = 0.5 ended in a misleading "increase time.substeps").

Each now raises one :class:`ConfigError` naming the argument, its shape or the offending value and index (the
limits E > 0, -1 < nu < 0.5 of the scene file's ``body.E`` / ``body.nu``).  Reference for the valid calls:
a box in free fall, far from the walls, moves by exactly :math:`-g\\, dt^2\\, T (T + 1) / 2` over T substeps of
symplectic Euler (uniform velocity is transferred exactly by P2G/G2P and F stays I, so no stress).
"""
import numpy as np
import pytest
import torch

from physar.errors import ConfigError
from physar.mpm import Control, MPMSolver, MPMState, Params, build_model, parse_scene, simulate

G = 9.81


def _scene(top=0.5625):
    body = {"shape": "box", "min": [0.375, 0.4375, 0.4375], "max": [0.625, 0.5625, top], "particles_per_cell": 8,
            "E": 5e4, "nu": 0.3, "density": 1000}
    return {"grid": {"size": 1.0, "resolution": 16}, "time": {"frame_dt": 2.5e-3, "substeps": 25, "frames": 1},
            "gravity": {"g": [0, 0, -G]}, "boundary": {"ground": "slip", "walls": "none"}, "body": [body]}


@pytest.fixture(scope="module")
def box():
    model, x, v = build_model(parse_scene(_scene()))
    return model, x, v


def _state(x, v=None, n=None, device="cpu"):
    n = len(x) if n is None else n
    v = np.zeros((len(x), 3)) if v is None else v
    return MPMState.from_numpy(x, v, np.zeros((n, 3, 3)), np.tile(np.eye(3), (n, 1, 1)), np.ones(n), device=device)


def _free_fall_dz(model):
    T = model.substeps
    return -G * model.dt**2 * T * (T + 1) / 2


def _params(n, E=5e4, nu=0.3):
    return Params(E=torch.full((n,), E, dtype=torch.float64), nu=torch.full((n,), nu, dtype=torch.float64))


# ----------------------------------------------------------------------------------------------- MPMState / solver
def test_valid_state_falls_by_the_closed_form(box):
    model, x, v = box
    a = model.state(x, v)
    a, _ = MPMSolver(model).simulate_frame(a, a.copy())
    dz = a.numpy()["x"][:, 2] - x[:, 2]
    np.testing.assert_allclose(dz, _free_fall_dz(model), rtol=1e-9)


def test_from_numpy_refuses_a_short_velocity(box):
    _, x, v = box
    n = len(x)
    with pytest.raises(ConfigError, match=rf"'v' must have shape \({n}, 3\), got \({n - 1}, 3\)"):
        _state(x, v[:-1], n=n)


def test_from_numpy_refuses_transposed_positions(box):
    _, x, v = box
    with pytest.raises(ConfigError, match=rf"'x' must have shape \(N, 3\), got \(3, {len(x)}\)"):
        MPMState.from_numpy(x.T, v.T, np.zeros((len(x), 3, 3)), np.tile(np.eye(3), (len(x), 1, 1)), np.ones(len(x)))


def test_from_numpy_refuses_a_jp_column(box):
    _, x, _ = box
    n = len(x)
    with pytest.raises(ConfigError, match=rf"'Jp' must have shape \({n},\), got \({n}, 1\)"):
        MPMState.from_numpy(x, np.zeros((n, 3)), np.zeros((n, 3, 3)), np.tile(np.eye(3), (n, 1, 1)), np.ones((n, 1)))


def test_solver_refuses_another_models_state(box):
    """A state of a taller box (more particles) ran on the first 128 of them without a word."""
    model, _, _ = box
    _, x_big, _ = build_model(parse_scene(_scene(top=0.625)))
    assert len(x_big) > model.n_particles
    big = _state(x_big)
    with pytest.raises(ConfigError, match=rf"state.x holds {len(x_big)} particles but the model has "
                                          rf"{model.n_particles}"):
        MPMSolver(model).simulate_frame(big, big.copy())


def test_solver_refuses_a_mismatched_scratch_and_step_state(box):
    model, x, _ = box
    _, x_big, _ = build_model(parse_scene(_scene(top=0.625)))
    sol = MPMSolver(model)
    with pytest.raises(ConfigError, match="scratch state.x holds"):
        sol.simulate_frame(model.state(x), _state(x_big))
    with pytest.raises(ConfigError, match="state.x holds"):
        sol.step(_state(x_big), model.state(x))


def test_solver_refuses_a_hand_built_state_with_a_long_velocity(box):
    """Arrays of one state that disagree with each other (built without from_numpy) are refused too."""
    model, x, _ = box
    a = model.state(x)
    a.v = MPMState.from_numpy(*[np.concatenate([z, z[:1]]) for z in a.numpy().values()]).v
    with pytest.raises(ConfigError, match=rf"state.v holds {len(x) + 1} particles"):
        MPMSolver(model).simulate_frame(a, model.state(x))


def test_solver_refuses_a_short_control(box):
    model, x, _ = box
    n = len(x)
    ctrl = Control(np.ones(n - 1), np.zeros((n, 3)), np.zeros((n, 3)))
    with pytest.raises(ConfigError, match=rf"Control.omega must have shape \({n},\).*got \({n - 1},\)"):
        MPMSolver(model).simulate_frame(model.state(x), model.state(x), ctrl)


# ----------------------------------------------------------------------------------------------- simulate / Params
def test_simulate_valid_params_fall_by_the_closed_form(box):
    model, x, v = box
    xs, _ = simulate(model, torch.tensor(x), torch.tensor(v), _params(len(x)), frames=1)
    np.testing.assert_allclose(xs[-1][:, 2].numpy() - x[:, 2], _free_fall_dz(model), rtol=1e-9)


def test_simulate_refuses_short_E(box):
    model, x, v = box
    n = len(x)
    p = _params(n)
    with pytest.raises(ConfigError, match=rf"params.E must have shape \({n},\).*got \(5,\)"):
        simulate(model, torch.tensor(x), torch.tensor(v), Params(E=p.E[:5], nu=p.nu), frames=1)


def test_simulate_refuses_short_nu_and_scalar_E(box):
    model, x, v = box
    n = len(x)
    p = _params(n)
    with pytest.raises(ConfigError, match=rf"params.nu must have shape \({n},\).*got \({n - 1},\)"):
        simulate(model, torch.tensor(x), torch.tensor(v), Params(E=p.E, nu=p.nu[1:]), frames=1)
    with pytest.raises(ConfigError, match=rf"params.E must have shape \({n},\).*got \(\)"):
        simulate(model, torch.tensor(x), torch.tensor(v), Params(E=torch.tensor(5e4), nu=p.nu), frames=1)


def test_simulate_refuses_a_short_v0(box):
    model, x, v = box
    n = len(x)
    with pytest.raises(ConfigError, match=rf"v0 must have shape \({n}, 3\).*got \({n - 1}, 3\)"):
        simulate(model, torch.tensor(x), torch.tensor(v[:-1]), _params(n), frames=1)


@pytest.mark.parametrize(("field", "value", "pattern"), [
    ("E", -5e4, r"params.E\[7\] = -50000 Pa"),
    ("E", float("nan"), r"params.E\[7\] = nan Pa"),
    ("nu", 0.5, r"params.nu\[7\] = 0.5: Poisson's ratio must be in \(-1, 0.5\)"),
    ("nu", 0.7, r"params.nu\[7\] = 0.7"),
    ("nu", -1.0, r"params.nu\[7\] = -1:"),
])
def test_simulate_refuses_material_values_outside_the_scene_limits(box, field, value, pattern):
    model, x, v = box
    p = _params(len(x))
    getattr(p, field)[7] = value
    with pytest.raises(ConfigError, match=pattern):
        simulate(model, torch.tensor(x), torch.tensor(v), p, frames=1)


def test_simulate_refuses_negative_fiber_E(box):
    model, x, v = box
    p = _params(len(x))
    p.fiber_E = torch.zeros(len(x), dtype=torch.float64)
    p.fiber_E[3] = -1.0
    with pytest.raises(ConfigError, match=r"params.fiber_E\[3\] = -1 Pa"):
        simulate(model, torch.tensor(x), torch.tensor(v), p, frames=1)
