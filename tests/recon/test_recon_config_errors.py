"""One-line errors of the recon config tables: an error of a model-level validator names its table
([synth] / [train]) instead of an empty field; key errors name the key inside the table."""

import pytest

from physar.errors import ConfigError
from physar.recon.synth import load_synth_config
from physar.recon.train import load_train_config


def _error(load, *args) -> str:
    with pytest.raises(ConfigError) as e:
        load(*args)
    msg = str(e.value)
    assert "\n" not in msg and "field ''" not in msg
    return msg


def test_model_level_train_error_names_the_table(tmp_path):
    p = tmp_path / "run.toml"
    p.write_text("[train]\nnu_min = 0.45\nnu_max = 0.4\n")
    assert _error(load_train_config, p) == f"{p}: [train] nu_min (0.45) must be < nu_max (0.4)"
    # overrides only (no file): the table is still named
    assert _error(load_train_config, None, {"nu_min": 0.45, "nu_max": 0.4}) == \
        "train config: [train] nu_min (0.45) must be < nu_max (0.4)"


def test_model_level_synth_error_names_the_table(tmp_path):
    p = tmp_path / "scene.toml"
    p.write_text("[synth]\nframes = 40\nn_obs = 40\n")
    assert _error(load_synth_config, p) == f"{p}: [synth] n_obs (40) must be < frames (40)"


def test_key_errors_name_the_key_in_the_table(tmp_path):
    p = tmp_path / "run.toml"
    p.write_text("[train]\nflow_iters = -1\n")
    assert _error(load_train_config, p).startswith(f"{p}: train.flow_iters: Input should be greater than")
    p.write_text("[synth]\nfrmaes = 4\n")
    assert _error(load_synth_config, p).startswith(f"{p}: unknown key 'frmaes' in [synth] (allowed: ")


def test_render_device_errors(tmp_path):
    """train.render_device: a malformed value is a key error; a CUDA device torch cannot see is one line naming
    the field and the value (checked where training starts, as a CPU-only machine can still read the file)."""
    import torch

    from physar.recon.train import check_render_device

    p = tmp_path / "run.toml"
    p.write_text('[train]\nrender_device = "gpu"\n')
    assert _error(load_train_config, p) == f"{p}: [train.render_device] 'gpu' is not a device: use 'cpu', 'cuda' or 'cuda:N'"
    p.write_text('[train]\nrender_device = "cuda:0"\nmpm_device = "cuda"\n')
    cfg = load_train_config(p)
    assert (cfg.render_device, cfg.mpm_device) == ("cuda:0", "cuda")
    p.write_text('[train]\nmpm_device = "cuda0"\n')
    assert _error(load_train_config, p) == f"{p}: [train.mpm_device] 'cuda0' is not a device: use 'cpu', 'cuda' or 'cuda:N'"
    n = torch.cuda.device_count() if torch.cuda.is_available() else 0
    with pytest.raises(ConfigError) as e:
        check_render_device(f"cuda:{n}")
    assert str(e.value).startswith(f"train.render_device = 'cuda:{n}': torch sees {n} CUDA device(s)")


def test_device_fields_do_not_block_loading_or_resuming(tmp_path):
    """A model fitted with GPU devices loads on a machine without them (the devices fall back to the CPU with one
    warning; results agree to 2e-13), a checkpoint resumes on another device, an unavailable mpm_device names the
    field. Mutants caught: the saved devices used as they are (the load fails), devices compared when resuming."""
    import warnings

    import torch

    from physar.errors import PhysarWarning
    from physar.recon.train import TrainConfig, _result_fields, _usable_devices

    n = torch.cuda.device_count() if torch.cuda.is_available() else 0
    cfg = TrainConfig(render_device=f"cuda:{n}", mpm_device=f"cuda:{n}", seed=3)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        usable = _usable_devices(cfg)
    assert (usable.render_device, usable.mpm_device, usable.seed) == ("cpu", "cpu", 3)
    assert len(w) == 1 and issubclass(w[0].category, PhysarWarning) and "using the CPU" in str(w[0].message)
    assert _result_fields(cfg.model_dump()) == _result_fields(TrainConfig(seed=3).model_dump())
    assert _result_fields(cfg.model_dump()) != _result_fields(TrainConfig(seed=4).model_dump())


# Review messages: a misspelt [trian] named as a table with the near name (was "unknown key 'trian' in [train]"),
# a DATA_DIR or RUN_DIR that does not exist named so (was "missing scene.json" / "missing file 'nope'").
# mutants caught: the table check removed (the old message), the existence tests removed
def test_review_messages(tmp_path):
    from typer.testing import CliRunner

    from physar.cli.main import app
    from physar.errors import ConfigError
    from physar.recon.train import load_dataset, load_train_config

    (tmp_path / "t.toml").write_text("[trian]\nseed = 1\n")
    with pytest.raises(ConfigError, match=r"t.toml: unknown table \[trian\]; did you mean \[train\]\?"):
        load_train_config(tmp_path / "t.toml")
    with pytest.raises(ConfigError, match=r"'.*nodata': DATA_DIR not found"):
        load_dataset(tmp_path / "nodata")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="is not a recon DATA_DIR: missing scene.json"):
        load_dataset(tmp_path / "empty")
    r = CliRunner().invoke(app, ["recon", "predict", str(tmp_path / "nope"), "--poses", str(tmp_path / "p.npz"),
                                 "--out", str(tmp_path / "o.mp4")])
    assert r.exit_code == 2 and "nope: RUN_DIR not found" in r.output, r.output
