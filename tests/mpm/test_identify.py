"""Identification of two Young's moduli (E = 2e5 and 8e4 Pa) from a target run of examples/mpm_two_blocks.toml.

No inverse crime: the target is simulated with a different sampling (27 particles per cell instead of 8, or a
finer grid with 2x the resolution and substeps) from the model being identified, and the model starts from E
guesses off by a factor 2.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from physar.cli.mpm import register
from physar.mpm.identify import identify
from physar.mpm.io import read_trajectory
from physar.mpm.runner import run_scene
from physar.mpm.scene import build_model, load_scene

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
    assert np.all(np.abs(err) < 0.05), res


@pytest.mark.slow
def test_identify_recovers_two_moduli_from_finer_grid(tmp_path):
    sc = load_scene(SCENE)
    fine = sc.model_copy(deep=True)
    fine.grid.resolution *= 2
    fine.time.substeps *= 2
    run_scene(fine, tmp_path, preview=False)  # target: grid spacing and substep halved
    guess = sc.model_copy(deep=True)
    for b, f in zip(guess.body, (0.5, 2.0)):
        b.E *= f
    model, x0, v0 = build_model(guess)
    res = identify(model, x0, v0, sc.time.frames, read_trajectory(tmp_path))
    err = res.E / E_TRUE - 1
    print("relative E errors", err)
    assert np.all(np.abs(err) < 0.05)
