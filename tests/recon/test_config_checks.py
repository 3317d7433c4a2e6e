"""Recon config tables ([synth], the anny scene's [synth], [train]) refuse nonsense at read, in one line naming the
file and the field: a plain value for the table, particle counts per cell that are not 1, 8, 27 or 64, non-finite
numbers, inconsistent E/nu bounds, sizes that exhaust memory or cannot be simulated/rendered.

Every test names the mutant (the fix removed) it catches; expected figures are computed here from the formulas
(Lame parameters, pinhole projection), not by physar."""

import math

import pytest

from physar.errors import ConfigError
from physar.recon import synth as SY
from physar.recon.synth import load_synth_config
from physar.recon.synth_anny import load_anny_config
from physar.recon.train import load_train_config

TINY_SYNTH = "image_size = 32\nframes = 5\nn_obs = 3\nnovel_frames = 3\nspin_frames = 4\n"


def _error(load, path, text: str) -> str:
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    return msg


@pytest.mark.parametrize("section", ["train", "synth"])
def test_plain_value_for_a_table(tmp_path, section):
    """`train = 5` / `synth = 5`: one line naming the file and the table. Mutant: the isinstance(table, dict) check
    in load_section_config removed (TypeError: 'int' object is not iterable)."""
    load = load_train_config if section == "train" else load_synth_config
    msg = _error(load, tmp_path / "t.toml", f"{section} = 5\n")
    assert f"'{section}' must be a table" in msg and f"{section} = 5" in msg


@pytest.mark.parametrize("value", [0, -1, 2, 125, 1000])
def test_particles_per_cell_is_1_8_27_or_64(tmp_path, value):
    """0 divided by zero, -1 gave a complex cube root, 1000 was accepted. Mutant: check_particles_per_cell replaced
    by the former cube test (round(n ** (1/3)) ** 3 == n: 0 and 1000 pass, -1 raises TypeError)."""
    p = tmp_path / "t.toml"
    want = f"must be 1, 8, 27 or 64 (k^3 particles per cell, k = 1..4), got {value}"
    assert _error(load_train_config, p, f"[train]\nparticles_per_cell = {value}\n") == \
        f"{p}: [train.particles_per_cell] {want}"
    assert _error(load_synth_config, p, f"[synth]\n{TINY_SYNTH}gt_particles_per_cell = {value}\n") == \
        f"{p}: [synth.gt_particles_per_cell] {want}"
    assert _error(load_anny_config, p, f"[synth]\ngt_particles_per_cell = {value}\n") == \
        f"{p}: [synth.gt_particles_per_cell] {want}"


def test_particles_per_cell_cubes_accepted(tmp_path):
    for k in (1, 2, 3, 4):
        assert load_train_config(None, {"particles_per_cell": k**3}).particles_per_cell == k**3
        assert load_synth_config(None, {"gt_particles_per_cell": k**3}).gt_particles_per_cell == k**3


TRAIN_FLOATS = ["flow_lr", "appearance_lr", "lambda_rgb", "physics_lr", "E_max", "E_init", "E_min", "kp", "net_lr"]
SYNTH_FLOATS = ["camera_distance", "fps", "gravity", "kp", "density", "fiber_E", "human_E", "E_stiff", "nu",
                "domain_size", "body_spacing"]


@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
def test_non_finite_numbers_refused_at_read(tmp_path, value):
    """inf passed the gt=0 bounds (flow_lr = inf ran into an SVD error, E_init = inf into an MPM message naming no
    field, camera_distance = inf wrote a NaN camera with exit 0, gravity = nan diverged). Mutant: allow_inf_nan=False
    removed from the model_config of TrainConfig / SynthConfig / AnnySceneConfig."""
    p = tmp_path / "t.toml"
    for k in TRAIN_FLOATS:
        assert _error(load_train_config, p, f"[train]\n{k} = {value}\n") == \
            f"{p}: train.{k}: Input should be a finite number (got {float(value)!r})"
    for k in SYNTH_FLOATS:
        assert _error(load_synth_config, p, f"[synth]\n{TINY_SYNTH}{k} = {value}\n") == \
            f"{p}: synth.{k}: Input should be a finite number (got {float(value)!r})"
        assert _error(load_anny_config, p, f"[synth]\n{k} = {value}\n") == \
            f"{p}: synth.{k}: Input should be a finite number (got {float(value)!r})"
    assert _error(load_synth_config, p, f"[synth]\n{TINY_SYNTH}pillow_size = [0.2, {value}, 0.1]\n").startswith(
        f"{p}: synth.pillow_size.1: Input should be a finite number")


def test_E_and_nu_bounds_consistent(tmp_path):
    """E_min above E_max clamped every E; E_init outside [E_min, E_max] was accepted, and an explicit nu_init
    outside [nu_min, nu_max] was silently clipped. Mutants: each of the three checks added to TrainConfig._check_nu
    removed."""
    p = tmp_path / "t.toml"
    assert _error(load_train_config, p, "[train]\nE_min = 1e5\nE_max = 3e4\nE_init = 5e4\n") == \
        f"{p}: [train] E_min (100000 Pa) must be < E_max (30000 Pa)"
    assert _error(load_train_config, p, "[train]\nE_init = 1e5\n") == \
        f"{p}: [train] E_init (100000 Pa) must be in [E_min, E_max] = [500, 30000] Pa"
    assert _error(load_train_config, p, "[train]\nE_init = 100.0\n") == \
        f"{p}: [train] E_init (100 Pa) must be in [E_min, E_max] = [500, 30000] Pa"
    assert _error(load_train_config, p, "[train]\nnu_init = 0.45\n") == \
        f"{p}: [train] nu_init (0.45) must be in [nu_min, nu_max] = [0.2, 0.4]"
    assert _error(load_train_config, p, "[train]\nnu_init = 0.1\n") == \
        f"{p}: [train] nu_init (0.1) must be in [nu_min, nu_max] = [0.2, 0.4]"
    # the bounds themselves are allowed
    cfg = load_train_config(None, {"E_init": 500.0, "nu_init": 0.4})
    assert (cfg.E_init, cfg.nu_init) == (500.0, 0.4)
    assert load_train_config(None, {"E_init": 3e4, "nu_init": 0.2}).E_init == 3e4


def test_train_sizes_bounded(tmp_path):
    """material_grid = [1000, 1000, 1000] asked for 1.6 TiB, latent_dim = 1e8 an allocator error, seed = 1e20 an
    overflow, body_spacing = 1e-9 the OOM killer. Mutants: the material_grid node limit, latent_dim's le, seed's le,
    the body sample count check removed."""
    p = tmp_path / "t.toml"
    msg = _error(load_train_config, p, "[train]\nmaterial_grid = [1000, 1000, 1000]\n")
    assert msg.startswith(f"{p}: [train.material_grid] [1000, 1000, 1000] is 1e+09 nodes")
    assert f"{8e9 / 2**20:.3g} MiB per object particle" in msg  # 8 bytes per node per particle
    assert _error(load_train_config, p, "[train]\nmaterial_grid = [2, 0, 2]\n").startswith(
        f"{p}: [train.material_grid] [2, 0, 2]: use >= 1 node per axis")
    assert load_train_config(None, {"material_grid": [16, 16, 16]}).material_grid == (16, 16, 16)
    assert _error(load_train_config, p, "[train]\nlatent_dim = 100000000\n").startswith(f"{p}: train.latent_dim:")
    assert _error(load_train_config, p, "[train]\nseed = 99999999999999999999\n").startswith(f"{p}: train.seed:")
    assert load_train_config(None, {"seed": 2**63 - 1}).seed == 2**63 - 1
    msg = _error(load_train_config, p, "[train]\nbody_spacing = 1e-9\n")
    assert msg.startswith(f"{p}: [train.body_spacing] 1e-09 m makes about 1e+26 kinematic body Gaussians")  # 0.1/1e-27
    assert "use >= 0.0037 m" in msg  # (0.1 m^3 / 2e6) ** (1/3) = 3.68 mm
    assert load_train_config(None, {"body_spacing": 0.004}).body_spacing == 0.004
    assert _error(load_train_config, p, "[train]\nbody_spacing = 1e9\n").startswith(f"{p}: train.body_spacing:")


def test_synth_sizes_and_counts(tmp_path):
    """Mutants: substeps' / fps' le removed (1e8 substeps ran forever, fps = 1e9 exit 0), spin_frames = 1 accepted
    (no spin clip written, exit 0), Size3 back to Vec3 (a negative pillow size blamed scene.json's boxes), the
    grid-cell resolution check removed (domain_size = 1e9: torch.arange error), the body sample count removed."""
    p = tmp_path / "t.toml"
    base = f"[synth]\n{TINY_SYNTH}".replace("spin_frames = 4\n", "")
    assert _error(load_synth_config, p, base + "substeps = 100000000\n").startswith(f"{p}: synth.substeps: ")
    assert _error(load_synth_config, p, base + "fps = 1e9\n").startswith(f"{p}: synth.fps: ")
    assert _error(load_synth_config, p, base + "spin_frames = 1\n") == \
        f"{p}: [synth] spin_frames = 1: the spin clip needs >= 2 frames (0: no spin clip)"
    for n in (0, 2):
        assert load_synth_config(None, {"image_size": 32, "frames": 5, "n_obs": 3,
                                        "novel_frames": 3, "spin_frames": n}).spin_frames == n
    assert _error(load_synth_config, p, base + "pillow_size = [-0.24, 0.2, 0.12]\n") == \
        f"{p}: synth.pillow_size.0: Input should be greater than 0 (got -0.24)"
    assert _error(load_anny_config, p, "[synth]\nbag_size = [0.54, 0.0, 0.12]\n") == \
        f"{p}: synth.bag_size.1: Input should be greater than 0 (got 0.0)"
    msg = _error(load_synth_config, p, base + "domain_size = 1e9\n")
    assert f"domain_size / grid_resolution = {1e9 / 16:.3g} m is coarser than the smallest side of pillow_size " \
           "(0.12 m)" in msg
    msg = _error(load_synth_config, p, base + "body_spacing = 1e-9\n")
    assert msg.startswith(f"{p}: [synth.body_spacing] 1e-09 m makes about 1e+26 body samples")
    msg = _error(load_anny_config, p, "[synth]\nbody_spacing = 1e-9\n")  # surface samples: 2.5 m^2 / 1e-18 m^2
    assert msg.startswith(f"{p}: [synth.body_spacing] 1e-09 m makes about 2.5e+18 body surface samples")
    assert _error(load_synth_config, p, base + "body_spacing = 1e9\n").startswith(f"{p}: synth.body_spacing: ")


def _courant(E, E_f, nu, rho, fps=30.0, substeps=32, dx=0.48 / 16):
    """Cells an elastic P-wave crosses per substep, from the Lame parameters (reference for check_simulation)."""
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    return math.sqrt((lam + 2 * mu + E_f) / rho) / (fps * substeps) / dx


def test_unstable_materials_name_their_fields(tmp_path):
    """nu = -0.99, human_E = 1e30, fiber_E = 1e30, kp = 1e12 diverged with the advice 'increase time.substeps'
    (a key the [synth] table does not have). Mutant: the wave-speed and PD checks of check_simulation removed."""
    p = tmp_path / "t.toml"
    base = f"[synth]\n{TINY_SYNTH}"
    assert _courant(1.2e4, 2.4e4, 0.3, 200.0) < SY.MAX_CFL  # the defaults are accepted (about 0.5)
    load_synth_config(None, {})
    msg = _error(load_synth_config, p, base + "nu = -0.99\n")
    c = _courant(1.2e4, 2.4e4, -0.99, 200.0)
    assert c > SY.MAX_CFL
    assert msg.startswith(f"{p}: [synth] elastic waves in the object (E_soft/E_stiff = 1.2e+04 Pa, fiber_E = "
                          f"2.4e+04 Pa, nu = -0.99, density = 200 kg/m^3") and f"cross {c:.3g} grid cells" in msg
    assert f"raise substeps to >= {math.ceil(32 * c / 0.9)}" in msg  # advice: 0.9 cells per substep
    # the limit as measured (a reviewer's runs of recon_tiny, E_stiff = 1e6 Pa: 82 substeps diverged, 87 ran):
    # 82 refused (mutant: the first limit of 2 cells, which let 46-82 substeps through to a divergence)
    assert _courant(1e6, 2.4e4, 0.3, 200.0, substeps=82) > SY.MAX_CFL > _courant(1e6, 2.4e4, 0.3, 200.0, substeps=87)
    assert "cross 1.12 grid cells" in _error(load_synth_config, p, base + "E_stiff = 1e6\nsubsteps = 82\n")
    p.write_text(base + "E_stiff = 1e6\nsubsteps = 87\n")
    load_synth_config(p)
    msg = _error(load_synth_config, p, base + "human_E = 1e30\n")
    assert "elastic waves in the body (human_E = 1e+30 Pa" in msg and "substeps" not in msg.split(": lower")[-1] \
        and msg.endswith("lower the stiffness")  # 1e12 cells per substep: no substeps <= 10^4 help
    assert "fiber_E = 1e+30 Pa" in _error(load_synth_config, p, base + "fiber_E = 1e30\n")
    assert "density = 1e-30 kg/m^3" in _error(load_synth_config, p, base + "density = 1e-30\n")
    assert "PD gains kp = 1e+12 1/s^2" in _error(load_synth_config, p, base + "kp = 1e12\n")
    assert "PD gains" in _error(load_anny_config, p, "[synth]\nkd = 1e6\n")
    assert _error(load_synth_config, p, base + "gravity = -1e30\n").startswith(f"{p}: synth.gravity: ")


def test_camera_distance_checked_with_the_file(tmp_path):
    """camera_distance = 0.11 allocated 5 GiB in the renderer's windows, 1e9 wrote empty masks with exit 0.
    Mutants: check_camera's call in scene_meta removed; load_synth_config not running scene_meta."""
    p = tmp_path / "t.toml"
    base = f"[synth]\n{TINY_SYNTH}"
    assert _error(load_synth_config, p, base + "camera_distance = 0.11\n") == \
        f"{p}: [synth] camera_distance = 0.11 m puts the camera inside the MPM domain (the cube of domain_size = " \
        "0.48 m around the object): move it farther"
    msg = _error(load_synth_config, p, base + "camera_distance = 1e9\n")
    # pinhole: focal 16 px / tan(17.5 deg); the pillow's diagonal sqrt(0.24^2 + 0.2^2 + 0.12^2) m at 1e9 m
    px = 16 / math.tan(math.radians(17.5)) * math.sqrt(0.24**2 + 0.2**2 + 0.12**2) / 1e9
    assert msg == f"{p}: [synth] camera_distance = 1e+09 m: the object would span {px:.2g} px of the 32 px image " \
                  "(< 4): move the camera closer"
    load_synth_config(None, {"camera_distance": 3.0})


def test_memory_estimates(monkeypatch, tmp_path):
    """The truth run and the sphere renderer are refused before allocating when their estimate exceeds the memory
    available (here pretended to be 1 MiB). Mutants: the check_memory call of check_simulation removed; the
    check_render_memory call (or its window estimate) removed."""
    import numpy as np

    import physar.output

    cfg = SY.SynthConfig()
    monkeypatch.setattr(physar.output, "available_memory", lambda: 2**20)
    p = tmp_path / "t.toml"
    msg = _error(load_synth_config, p, f"[synth]\n{TINY_SYNTH}")
    n = 0.24 * 0.2 * 0.12 / (0.48 / 16 / 2) ** 3  # pillow volume / particle spacing^3 at 8 per cell
    assert f"the truth run of about {n:.3g} object particles (8 per cell of 0.03 m" in msg and "of memory" in msg
    # the renderer: 1000 spheres of radius 0.01 m at 0.02 m from the camera
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    pts = np.array([[[0.0, 0.0, 0.02]] * 1000])
    with pytest.raises(ConfigError) as e:
        SY.check_render_memory(pts, np.full(1000, 0.01), K, np.eye(3), np.zeros(3), cfg)
    rpx = 100.0 * 2 * 0.01 / 0.02  # focal (supersampled 2x) x radius / depth = 100 px
    assert f"rendering 1e+03 spheres up to {rpx:.3g} px in radius" in str(e.value)
    SY.check_render_memory(pts[:, :1] + [0, 0, 10.0], np.full(1, 0.01), K, np.eye(3), np.zeros(3), cfg)  # 0.2 px
