"""Identification of two Young's moduli (E = 2e5 and 8e4 Pa) from a target run of examples/mpm_two_blocks.toml.

No inverse crime: the target is simulated with a different sampling (27 particles per cell instead of 8, or a
finer grid with 2x the resolution and substeps) from the model being identified, and the model starts from E
guesses off by a factor 2.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from physar.cli.mpm import register
from physar.mpm.identify import identify
from physar.mpm.io import read_trajectory
from physar.mpm.model import MPMSolver, MPMState
from physar.mpm.runner import run_scene
from physar.mpm.scene import build_model, load_scene, parse_scene

SCENE = Path(__file__).resolve().parents[2] / "examples" / "mpm_two_blocks.toml"
E_TRUE = np.array([2e5, 8e4])


def _guess_scene(tmp_path, factors):
    text = SCENE.read_text().replace("E = 2e5", f"E = {2e5 * factors[0]:g}").replace("E = 8e4", f"E = {8e4 * factors[1]:g}")
    p = tmp_path / "guess.toml"
    p.write_text(text)
    return p


def test_identify_cli_recovers_two_moduli_from_denser_sampling(tmp_path):
    target = tmp_path / "target"
    run_scene(SCENE, target, preview=False, particles_per_cell=27)  # target: 27 particles per cell
    guess = _guess_scene(tmp_path, (2.0, 0.5))  # model: 8 per cell, E guesses 4e5 and 4e4
    app = typer.Typer()
    register(app)
    r = CliRunner().invoke(app, ["mpm", "identify", str(guess), "--target", str(target), "--json"])
    assert r.exit_code == 0, r.output
    res = json.loads(r.stdout)
    assert res["E_initial"] == [4e5, 4e4]
    err = np.asarray(res["E"]) / E_TRUE - 1
    print("relative E errors", err)
    assert np.all(np.abs(err) < 0.015), res  # measured -0.45 / -0.51 % (raw covariances: -1.6 / -2.4 %)


def _bar_frames(ppc: int, E: float, frames: int):
    """A free 0.25 m bar (nu = 0) on a 16-cell grid, stretched by an initial axial velocity gradient."""
    sc = parse_scene({"grid": {"size": 1.0, "resolution": 16},
                      "time": {"frame_dt": 2.5e-3, "substeps": 10, "frames": frames},
                      "gravity": {"g": [0.0, 0.0, 0.0]}, "boundary": {"ground": "none", "walls": "none"},
                      "body": [{"shape": "box", "min": [0.375, 0.4375, 0.4375], "max": [0.625, 0.5625, 0.5625],
                                "particles_per_cell": ppc, "E": E, "nu": 0.0, "density": 1000.0,
                                "velocity_gradient": [[2, 0, 0], [0, 0, 0], [0, 0, 0]]}]})
    return build_model(sc)


def test_identify_bar_with_zero_poisson_ratio_from_denser_sampling():
    """nu = 0 is used as given (it was clamped into the fitting range (0.2, 0.45) before), and the covariance
    misfit does not depend on the sampling density (27 particles per cell in the target, 8 in the model):
    E within 1.5 % (measured -0.44 %; -14 % before both fixes)."""
    frames = 16
    model_t, x, v = _bar_frames(27, 5e4, frames)
    a = MPMState.from_numpy(x, v, np.zeros((len(x), 3, 3)), np.tile(np.eye(3), (len(x), 1, 1)), np.ones(len(x)))
    solver, b = MPMSolver(model_t), a.copy()
    target = [{"x": x.copy(), "body": model_t.body}]
    for _ in range(frames):
        a, b = solver.simulate_frame(a, b)
        target.append({"x": a.x.numpy().copy(), "body": model_t.body})
    model, x0, v0 = _bar_frames(8, 2.5e4, frames)
    res = identify(model, x0, v0, frames, target, iterations=10)
    assert res.nu[0] == 0.0
    assert abs(res.E[0] / 5e4 - 1) < 0.015, res.E


@pytest.mark.slow
def test_identify_converges_with_the_grid_to_a_finer_grid_target(tmp_path):
    """Target on a 3x finer grid (48 cells, 3x substeps); models on 16 and 24 cells from E guesses off by 2x.
    The coarse grid's own discretisation bias is measured +5.7 / +4.5 % at 16 cells, +1.2 / +0.1 % at 24."""
    sc = load_scene(SCENE)
    fine = sc.model_copy(deep=True)
    fine.grid.resolution *= 3
    fine.time.substeps *= 3
    run_scene(fine, tmp_path, preview=False)
    errors = {}
    for factor, substeps in ((1, 1), (1.5, 2)):  # 16 cells at 25 substeps, 24 cells at 50
        guess = sc.model_copy(deep=True)
        guess.grid.resolution = int(sc.grid.resolution * factor)
        guess.time.substeps = sc.time.substeps * substeps
        for b, f in zip(guess.body, (0.5, 2.0)):
            b.E *= f
        model, x0, v0 = build_model(guess)
        res = identify(model, x0, v0, sc.time.frames, read_trajectory(tmp_path))
        errors[factor] = np.abs(res.E / E_TRUE - 1)
    print("relative E errors", errors)
    assert np.all(errors[1] < 0.07) and np.all(errors[1.5] < 0.025), errors
    assert np.all(errors[1.5] < errors[1]), errors


@pytest.mark.parametrize("name", ["rest", "stretch", "rotation", "shear"])
def test_lattice_corrected_moments_are_the_box_moments_for_any_sampling(name):
    """S^ of a box lattice moved by an affine map A equals the continuous box's A diag(L_i^2 / 12) A^T (closed
    form) for 8 and 27 particles per cell alike; the raw particle covariance is short by spacing^2 / 12."""
    from physar.mpm.identify import _Moments

    a = np.radians(10)
    A = {"rest": np.eye(3), "stretch": np.diag([1.01, 0.99, 1.0]),
         "rotation": np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]),
         "shear": np.array([[1, 0, 0], [0, 1, 0], [0.01, 0, 1]])}[name]
    L = np.array([0.25, 0.125, 0.125])
    exact = A @ np.diag(L**2 / 12) @ A.T
    for spacing in (1 / 32, 1 / 48):
        k = np.round(L / spacing).astype(int)
        axes = [(np.arange(k[i]) + 0.5) * L[i] / k[i] for i in range(3)]
        x0 = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        moments = _Moments(x0, np.zeros(len(x0), int), 1)
        x = torch.as_tensor((x0 - x0.mean(0)) @ A.T + x0.mean(0))
        raw = np.cov(x.numpy().T, bias=True)
        assert np.abs(raw - exact).max() > 1e-2 * spacing**2 / 12  # the raw covariance is off ...
        assert np.abs(moments(x)[1][0].numpy() - exact).max() < 1e-12 * exact.max()  # ... the corrected one exact


def test_target_of_changing_particle_sets_is_refused():
    """The corrected moments follow one particle set through the frames: a target whose frames have different
    particle counts gets a clear error."""
    from physar.errors import ConfigError
    from physar.mpm.identify import target_moments

    x = np.random.default_rng(0).random((8, 3))
    frames = [{"x": x, "body": np.zeros(8, int)}, {"x": x[:6], "body": np.zeros(6, int)}]
    with pytest.raises(ConfigError, match="particle counts"):
        target_moments(frames, 1, 1)


def test_target_of_another_scene_is_refused():
    """A target whose bodies start elsewhere (here the bar's run shifted 0.3 m, 4.8 cells, along z: another
    scene's run) is refused naming the body and the distance, before any simulation; the bar's own run at a
    denser sampling (centre within round-off) is accepted by the test above. Review: a free-fall sphere's run fitted
    to a resting block's scene gave E = 596,832 Pa, exit 0. Mutant caught: the frame-0 check removed."""
    from physar.errors import ConfigError

    model, x0, v0 = _bar_frames(8, 2.5e4, 2)
    shifted = x0 + np.array([0.0, 0.0, 0.3])
    target = [{"x": shifted, "body": model.body}] * 3
    with pytest.raises(ConfigError, match=r"target frame 0: body 0's centre .* is 0.3 m \(4.8 cells\) from the "
                                          r"scene's"):
        identify(model, x0, v0, 2, target, iterations=1)
