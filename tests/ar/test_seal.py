"""Scene (c) of seed 000 §5.3, the virtual boot seal: the FE model against exact rigid rotations, the
non-intrusive PGD over theta against direct continuation solves at unsampled angles, and a small markerless
scene (lever angle by colour segmentation, relocalisation after the camera looked away)."""
import math

import numpy as np
import pytest

from physar.ar.scene import VideoSection
from physar.ar.seal import (
    PlateObject,
    SealContinuation,
    SealPipeline,
    SealSceneSpec,
    SealSection,
    build_seal_model,
    evaluate_seal,
    load_seal_scene,
    read_csv_columns,
    render_seal_scene,
    seal_model,
)
from physar.errors import ConfigError
from physar.fem.seed_examples import boot_seal
from physar.vision import Camera

TINY = SealSection(n_phi=8, n_profile=10, theta_max=40.0)  # this coarse sleeve buckles beyond ~45 deg


def test_rigid_rotation_of_the_whole_seal_is_stress_free():
    """Both cuffs rotated by 30 deg about the lever axis (BootSeal.prescribed(rotate_bottom=True)) equal the
    exact rigid rotation u = R (X - p) + p - X; the whole seal so rotated is in equilibrium with zero stress
    (frame indifference of the neo-Hookean law), unlike the same angle applied to the top cuff alone."""
    seal = boot_seal(n_phi=8, n_profile=10, element="P1")
    th = math.radians(30.0)
    X = seal.space.nodes
    c, s = math.cos(th), math.sin(th)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    exact = ((X - seal.pivot) @ R.T + seal.pivot - X).ravel()
    ud = seal.prescribed(th, rotate_bottom=True)
    assert np.abs(ud[seal.fixed] - exact[seal.fixed]).max() < 1e-15
    u_bent, _ = seal.solve(th, increment=math.radians(10))
    f_bent = np.abs(seal.model.internal_force(u_bent)).max()  # reactions at the cuffs
    assert np.abs(seal.model.internal_force(exact)).max() < 1e-9 * f_bent
    assert seal.von_mises(exact).max() < 1e-9 * seal.von_mises(u_bent).max()


def test_lever_rotation_bends_the_seal_and_the_moment_resists_it():
    seal = boot_seal(n_phi=8, n_profile=10, element="P1")
    u10, _ = seal.solve(math.radians(10.0), increment=math.radians(5))
    u20, _ = seal.solve(math.radians(20.0), u0=u10, theta0=math.radians(10.0), increment=math.radians(5))
    m10, m20 = seal.lever_moment(u10), seal.lever_moment(u20)
    assert m10 * math.radians(10) > 0  # the seal resists the rotation (positive work)
    assert m20 > m10
    assert seal.von_mises(u20).max() > seal.von_mises(u10).max() > 0


def test_nonintrusive_pgd_over_theta_vs_direct_solves():
    spec = SealSceneSpec(seal=TINY, keyframes=[(0.0, 0.0), (1.0, 40.0)])
    rom, vm, seal, info = build_seal_model(spec, tol=2e-3)
    assert info["error_estimate"] <= 2e-3
    direct = SealContinuation(seal_model(spec))
    for th in (7.3, 23.9, 31.1, 38.6):  # not sampling points
        assert not np.any(np.isclose(rom.grids[0], th))
        u = direct(th)
        assert np.linalg.norm(rom.evaluate([th]) - u) / np.linalg.norm(u) < 1e-2
    # the von Mises representation reproduces the stress of the model's displacement
    from physar.fem.post import nodal_average, von_mises

    ref = nodal_average(seal.space, von_mises(seal.model, rom.evaluate([33.3])))
    assert np.linalg.norm(vm.evaluate([33.3]) - ref) / np.linalg.norm(ref) < 2e-2


@pytest.fixture(scope="module")
def tiny_seal_scene(tmp_path_factory):
    """640x360, 4 s: the lever up to 40 deg, the camera pans 45 deg away (lever out of view) and back."""
    out = tmp_path_factory.mktemp("seal")
    spec = SealSceneSpec(video=VideoSection(width=640, height=360, duration=4.0), seal=TINY,
                         keyframes=[(0.0, 0.0), (1.0, 40.0), (2.6, 12.0), (4.0, 32.0)],
                         look_away=[{"start": 1.1, "duration": 2.0, "yaw": 45.0, "ramp": 0.9}])
    render_seal_scene(spec, out)
    rom, vm, seal, _ = build_seal_model(spec)
    return spec, out, rom, vm, seal


def test_tiny_seal_scene_angle_and_recovery(tiny_seal_scene):
    spec, out, rom, vm, seal = tiny_seal_scene
    cam = Camera.load(out / "camera.toml")
    pipe = SealPipeline(rom, vm, cam, PlateObject.load(out / "plate.json"), out, seal=seal)
    snap = out / "augmented_frame.png"
    summ = pipe.run(out / "scene.mp4", None, out / "estimates.csv", fps=spec.video.fps, snapshots={20: snap})
    assert summ["frames"] == spec.n_frames and snap.stat().st_size > 0
    truth, est = read_csv_columns(out / "truth.csv"), read_csv_columns(out / "estimates.csv")
    ev = evaluate_seal(truth, est)
    assert ev["frames_lever_out_of_view"] > 10 and ev["lost_frames"] > 0  # it really looked away
    assert ev["median_abs_error_deg"] < 1.0 and ev["p95_abs_error_deg"] < 1.0
    assert ev["recovery_frames_after_look_away"] and all(r is not None and r <= 5
                                                         for r in ev["recovery_frames_after_look_away"]), ev


def test_seal_scene_errors(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("keyframes = [[0.0, 0.0], [1.0, 70.0]]\n")
    with pytest.raises(ConfigError, match="keyframe angles"):
        load_seal_scene(p)
    with pytest.raises(ConfigError, match="plate file not found"):
        PlateObject.load(tmp_path / "plate.json")


def test_example_scene_file_is_the_default_scene():
    from pathlib import Path

    assert load_seal_scene(Path(__file__).parents[2] / "examples" / "scene_seal.toml") == SealSceneSpec()
