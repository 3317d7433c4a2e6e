"""The appearance refit after the physics stage (``refit_appearances``): one shared appearance per method,
refitted on the observed dynamic frames with that method's own motion fixed, saved in model.npz and used by
every render of that method.

Mutants caught: the refit skipped or run at a zero step (the loss test); every method refitted with the physics
motion (their appearances would be identical); renders of a method with the canonical appearance instead of its
refit (the render test); the refit not saved or not read back (the round trip).
"""

import numpy as np
import pytest
import torch

from physar.recon.train import (
    METHODS,
    Reconstruction,
    TrainConfig,
    fit,
    image_loss,
    load_dataset,
    refit_appearances,
    render_scene,
)


@pytest.fixture(scope="module")
def refit_run(tiny_scene, tmp_path_factory):
    run = tmp_path_factory.mktemp("refit_run")
    cfg = TrainConfig(appearance_iters=30, finetune_iters=5, flow_iters=5, spflow_iters=5, physics_iters=2,
                      window_start=3, material_grid=(0, 0, 0), lambda_flow=0.0, appearance_refit_iters=40)
    fit(tiny_scene, run, cfg)
    return run, cfg


def _motion(rec, kin, method, f):
    rig = rec.rig
    if method == "lbs":
        return torch.as_tensor(rig.Xo), torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3), kin["ref"][f], \
            kin["A_h"][f]
    xs = rec.flow if method == "4dgs" else rec.spflow
    return xs[f], rig.deformation_from_neighbours(xs[f]), kin["ref"][f], kin["A_h"][f]


def test_refit_saved_and_read_back(refit_run):
    run, _ = refit_run
    rec = Reconstruction.load(run)
    assert set(rec.apps) == set(METHODS)
    with np.load(run / "model.npz", allow_pickle=False) as d:
        for m in METHODS:
            assert np.array_equal(d[f"app.{m}.sh"], rec.apps[m].sh.numpy())
        # the canonical appearance (the one the physics was learned with) is kept as it was
        assert not np.array_equal(d["app.physics.sh"], d["sh"])
    # each method refitted with its own motion: LBS-only (object at rest) and physics differ
    assert not torch.equal(rec.apps["lbs"].sh, rec.apps["physics"].sh)


def test_refit_lowers_each_methods_image_loss(refit_run, tiny_scene):
    run, cfg = refit_run
    rec, ds = Reconstruction.load(run), load_dataset(tiny_scene)
    kin = rec.rig.kinematics(ds.rotations, ds.root_t)
    obs = range(1, ds.n_obs)
    for m in ("lbs", "4dgs"):
        def loss(app, m=m):
            with torch.no_grad():
                return float(np.mean([image_loss(render_scene(rec.rig, app, *_motion(rec, kin, m, f), kin["xb"][f],
                                                              kin["A_b"][f]),
                                                 torch.as_tensor(ds.rgb[f]), torch.as_tensor(ds.mask[f]), cfg)
                                      for f in obs]))
        assert loss(rec.apps[m]) < 0.97 * loss(rec.app), m


def test_renders_use_the_methods_refit(refit_run, tiny_scene):
    run, _ = refit_run
    rec, ds = Reconstruction.load(run), load_dataset(tiny_scene)
    kin = rec.rig.kinematics(ds.rotations, ds.root_t)
    rgb, _ = rec.render_sequence(kin, "lbs")
    with torch.no_grad():
        own = render_scene(rec.rig, rec.apps["lbs"], *_motion(rec, kin, "lbs", 1), kin["xb"][1], kin["A_b"][1])
        canon = render_scene(rec.rig, rec.app, *_motion(rec, kin, "lbs", 1), kin["xb"][1], kin["A_b"][1])
    assert np.allclose(rgb[1], own.rgb.numpy(), atol=1e-6)
    assert not np.allclose(rgb[1], canon.rgb.numpy(), atol=1e-3)


def test_no_refit_when_off(refit_run, tiny_scene):
    run, _ = refit_run
    rec, ds = Reconstruction.load(run), load_dataset(tiny_scene)
    kin = rec.rig.kinematics(ds.rotations, ds.root_t)
    assert refit_appearances(rec, ds, kin, 0) == {}
    rec.apps = {}
    assert rec.appearance("physics") is rec.app


def test_colours_only_keeps_the_spin_clips_geometry(refit_run, tiny_scene):
    """Default: the refit changes the SH colours only (opacity and scales set the silhouette, which a method
    without the motion could otherwise grow over the moved object). Mutant caught: every parameter refitted
    whatever the setting (and the reverse: the setting ignored when false)."""
    run, _ = refit_run
    rec, ds = Reconstruction.load(run), load_dataset(tiny_scene)
    for m in METHODS:
        assert torch.equal(rec.apps[m].opacity_logits, rec.app.opacity_logits)
        assert torch.equal(rec.apps[m].log_scales, rec.app.log_scales)
    kin = rec.rig.kinematics(ds.rotations, ds.root_t)
    every = refit_appearances(rec, ds, kin, 10, methods=("lbs",), colours_only=False)["lbs"]
    assert not torch.equal(every.opacity_logits, rec.app.opacity_logits)
    assert not torch.equal(every.log_scales, rec.app.log_scales)


def test_gpu_fitted_model_loads_here(refit_run, tiny_scene, tmp_path):
    """model.npz saved with render_device / mpm_device = 'cuda:N' (N beyond this machine's GPUs) loads, renders with
    the same appearance and predicts on the CPU, with one warning; a fit asking for an absent MPM device is one
    line naming train.mpm_device."""
    import json
    import warnings

    from physar.errors import ConfigError, PhysarWarning
    from physar.recon.train import Rig

    run, cfg = refit_run
    n = torch.cuda.device_count() if torch.cuda.is_available() else 0
    with np.load(run / "model.npz", allow_pickle=False) as d:
        arrays = dict(d)
    conf = json.loads(str(arrays["config_json"])) | {"render_device": f"cuda:{n}", "mpm_device": f"cuda:{n}"}
    arrays["config_json"] = np.array(json.dumps(conf))
    np.savez(tmp_path / "model.npz", **arrays)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        rec = Reconstruction.load(tmp_path / "model.npz")
    assert any(issubclass(x.category, PhysarWarning) for x in w)
    assert torch.equal(rec.apps["physics"].sh, Reconstruction.load(run).apps["physics"].sh)
    ds = load_dataset(tiny_scene)
    rgb, _ = rec.render_sequence(rec.rig.kinematics(ds.rotations, ds.root_t), "physics")
    assert np.isfinite(rgb).all()
    with pytest.raises(ConfigError, match=rf"^train.mpm_device = 'cuda:{n}': MPM device"):
        Rig(ds.meta, cfg.model_copy(update={"mpm_device": f"cuda:{n}"}))


def test_checkpoint_resumes_on_another_device(refit_run, tmp_path):
    """The device fields do not enter the checkpoint's configuration check (a run started on the CPU may go on with
    mpm_device = 'cuda'); any other field still does. Mutant caught: the whole configuration compared."""
    import shutil

    from physar.errors import ConfigError
    from physar.recon.train import _load_checkpoint

    run, cfg = refit_run
    shutil.copy(run / "checkpoint.pt", tmp_path / "checkpoint.pt")
    h = torch.load(tmp_path / "checkpoint.pt", weights_only=True)["data_hash"]
    assert _load_checkpoint(tmp_path, cfg.model_copy(update={"mpm_device": "cuda:0", "render_device": "cuda"}), h)
    with pytest.raises(ConfigError, match="another configuration"):
        _load_checkpoint(tmp_path, cfg.model_copy(update={"physics_iters": 3}), h)


def test_training_time_includes_the_refit(refit_run):
    """report.json's train_seconds = the stages' time (the last checkpoint) + the refit's. Mutant caught: the refit
    left out of train_seconds."""
    import json

    run, _ = refit_run
    rep = json.loads((run / "report.json").read_text())
    stages = float(torch.load(run / "checkpoint.pt", weights_only=True)["seconds"])
    refit = rep["canonical"]["appearance_refit_seconds"]
    assert refit > 0 and rep["train_seconds"] == pytest.approx(stages + refit, rel=1e-9)


def test_mismatched_refit_is_one_line(refit_run, tmp_path):
    """A model.npz whose stored refit does not match its Gaussians is refused in one line, not at render time."""
    from physar.errors import ConfigError

    run, _ = refit_run
    with np.load(run / "model.npz", allow_pickle=False) as d:
        arrays = dict(d)
    arrays["app.lbs.sh"] = arrays["app.lbs.sh"][:-1]
    np.savez(tmp_path / "model.npz", **arrays)
    with pytest.raises(ConfigError, match=r"not a valid physar recon model \(the appearance refit of lbs does not"):
        Reconstruction.load(tmp_path / "model.npz")


def test_a_model_from_before_render_deformation_renders_as_it_was_fitted(refit_run, tmp_path):
    """A model.npz whose configuration has no render_deformation (fitted before the option, with the seed's
    deformed Gaussians) loads with "state", not with today's default "none"; one that has it keeps it."""
    run, _ = refit_run
    assert Reconstruction.load(run).rig.cfg.render_deformation == "none"
    assert _model_without(run, "render_deformation", tmp_path).rig.cfg.render_deformation == "state"


def test_a_checkpoint_from_before_flow_target_resumes(refit_run, tmp_path):
    """A checkpoint whose configuration has no flow_target (made before the option): with the 3-D flow term off
    (lambda_flow = 0) the option changes nothing and it resumes under today's default; with the term on it ran the
    seed's form and resumes only with flow_target = "all"; a model.npz without it loads as "all". Mutants caught:
    the old form not filled in (every old checkpoint refused), flow_target compared when the term is off."""
    from physar.errors import ConfigError
    from physar.recon.train import _load_checkpoint

    run, cfg = refit_run
    d = torch.load(run / "checkpoint.pt", weights_only=True)
    del d["config"]["flow_target"]
    torch.save(d, tmp_path / "checkpoint.pt")
    assert _load_checkpoint(tmp_path, cfg, d["data_hash"])
    d["config"]["lambda_flow"] = 20.0
    torch.save(d, tmp_path / "checkpoint.pt")
    on = cfg.model_copy(update={"lambda_flow": 20.0})
    assert _load_checkpoint(tmp_path, on.model_copy(update={"flow_target": "all"}), d["data_hash"])
    with pytest.raises(ConfigError, match="another configuration"):
        _load_checkpoint(tmp_path, on, d["data_hash"])
    assert _model_without(run, "flow_target", tmp_path).rig.cfg.flow_target == "all"


def test_a_checkpoint_from_before_residual_objective_resumes(refit_run, tmp_path):
    """A checkpoint without residual_objective (made before the option): without residual laws it changes nothing
    and the run resumes under today's default; with them it ran the world-frame form and resumes only with
    residual_objective = false. Mutants caught: the old form not filled in (old checkpoints refused or resumed
    with the other law), the option compared when there are no residual laws."""
    from physar.errors import ConfigError
    from physar.recon.train import _load_checkpoint

    run, cfg = refit_run
    d = torch.load(run / "checkpoint.pt", weights_only=True)
    del d["config"]["residual_objective"]
    torch.save(d, tmp_path / "checkpoint.pt")
    assert _load_checkpoint(tmp_path, cfg, d["data_hash"])
    d["config"]["residual"] = True
    torch.save(d, tmp_path / "checkpoint.pt")
    on = cfg.model_copy(update={"residual": True})
    assert _load_checkpoint(tmp_path, on.model_copy(update={"residual_objective": False}), d["data_hash"])
    with pytest.raises(ConfigError, match=r"another configuration \(residual_objective = False there, True now\)"):
        _load_checkpoint(tmp_path, on, d["data_hash"])


def test_a_checkpoint_compares_residual_on_only_with_residual_laws(refit_run, tmp_path):
    """residual_on (where the residual laws act) is compared on resume only when there are residual laws: a
    checkpoint without them and without the key resumes; one with them made under "all" is refused under
    "object" and resumes under "all", also when it predates the option. Mutants caught: residual_on always
    dropped from the comparison (a run would resume under the other law), or never (old checkpoints refused)."""
    from physar.errors import ConfigError
    from physar.recon.train import _load_checkpoint

    run, cfg = refit_run
    d = torch.load(run / "checkpoint.pt", weights_only=True)
    del d["config"]["residual_on"]
    torch.save(d, tmp_path / "checkpoint.pt")
    assert _load_checkpoint(tmp_path, cfg.model_copy(update={"residual_on": "object"}), d["data_hash"])
    d["config"]["residual"] = True
    torch.save(d, tmp_path / "checkpoint.pt")
    on = cfg.model_copy(update={"residual": True})
    assert _load_checkpoint(tmp_path, on, d["data_hash"])
    with pytest.raises(ConfigError, match=r"another configuration \(residual_on = 'all' there, 'object' now\)"):
        _load_checkpoint(tmp_path, on.model_copy(update={"residual_on": "object"}), d["data_hash"])


def _model_without(run, key, tmp_path):
    """RUN/model.npz copied to tmp_path with ``key`` removed from its stored configuration (a model from before that
    option), loaded."""
    import json

    with np.load(run / "model.npz", allow_pickle=False) as z:
        arrays = dict(z)
    conf = json.loads(str(arrays["config_json"]))
    del conf[key]
    arrays["config_json"] = np.array(json.dumps(conf))
    np.savez(tmp_path / "model.npz", **arrays)
    return Reconstruction.load(tmp_path / "model.npz")
