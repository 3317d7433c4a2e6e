"""Synthetic benchmark scenes (issue 8 part 4): the three objects (box pillow, C pillow, bag) under their
actions (press, squeeze, lift) with a heterogeneous, anisotropic fine-MPM ground truth.

References are independent of the generator: closed-form volumes of the box unions, the geometry of each
action (a dent, the gap between the C's prongs, the bag's height above the support), particle conservation,
and the isotropic truth (fiber_E = 0) of the same scene for the anisotropy."""

import json

import numpy as np
import pytest

from physar.errors import ConfigError
from physar.recon import scene as S
from physar.recon import synth as Y
from physar.recon.synth import SynthConfig, generate, load_synth_config

SCENES = {"pillow": {"object": "pillow", "action": "press"},
          "cpillow": {"object": "c_pillow", "action": "squeeze"},
          "bag": {"object": "bag", "action": "lift"}}
TINY = {"image_size": 32, "frames": 7, "n_obs": 4, "novel_frames": 3, "spin_frames": 2}


def tiny(name: str, **kw) -> SynthConfig:
    return SynthConfig(**TINY, **SCENES[name], **kw)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    return {name: generate(root / name, tiny(name)) for name in SCENES}


def load(d):
    meta = json.loads((d / "scene.json").read_text())
    with np.load(d / "truth.npz") as t:
        return meta, {k: t[k] for k in t.files}


def union_volume(cfg: SynthConfig) -> float:
    """Closed-form volume of each object (its boxes do not overlap)."""
    if cfg.object == "pillow":
        return float(np.prod(cfg.pillow_size))
    if cfg.object == "c_pillow":
        L, D, H = cfg.c_pillow_size
        t = cfg.c_thickness
        return L * (D * H - (D - t) * (H - 2 * t))  # bounding box minus the mouth
    L, W, H = cfg.bag_size
    w, hl, ho = cfg.bag_wall, cfg.handle_length, cfg.handle_hole
    return L * W * H + 2 * hl * w * ho + hl * W * w  # body + two posts + bar


# ------------------------------------------------------------------------------------------- config, geometry
def test_supported_combinations_and_one_line_errors(tmp_path):
    assert SynthConfig().object == "pillow" and SynthConfig().action == "press"
    assert SynthConfig().press_obs == 0.03 and SynthConfig().press_pred == 0.055  # the old defaults
    p = tmp_path / "s.toml"
    p.write_text('[synth]\nobject = "pillow"\naction = "lift"\n')
    with pytest.raises(ConfigError, match=r"s.toml.*not supported for object 'pillow'.*bag \+ lift") as e:
        load_synth_config(p)
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="object"):
        load_synth_config(None, {"object": "sofa"})
    with pytest.raises(ConfigError, match="c_thickness"):
        load_synth_config(None, {"object": "c_pillow", "action": "squeeze", "c_thickness": 0.1})
    with pytest.raises(ConfigError, match="tunnel"):
        Y.scene_meta(SynthConfig(object="bag", action="lift", handle_hole=0.06))
    with pytest.raises(ConfigError, match="domain_size"):  # the lift would carry the bag out of the domain
        Y.scene_meta(SynthConfig(object="bag", action="lift", press_pred=0.3))


@pytest.mark.parametrize("name", list(SCENES))
def test_object_points_match_box_union_volume(name):
    cfg = tiny(name)
    meta = Y.scene_meta(cfg)
    dx = cfg.domain_size / cfg.grid_resolution
    V = union_volume(cfg)
    for k in (1, 2, 3):  # reconstruction (1 / cell) and fine ground-truth samplings
        X, vol = S.object_points(meta, dx / k)
        assert len(X) * vol == pytest.approx(V, rel=1e-9)
        assert len(np.unique(np.round(X / (dx / k) * 2).astype(int), axis=0)) == len(X)  # no duplicates
    # every particle lies inside one of the boxes, none inside the C's mouth / the handle's tunnel
    boxes = S.object_boxes(meta)
    X, _ = S.object_points(meta, dx)
    inside = np.zeros(len(X), int)
    for lo, hi in boxes:
        inside += np.all((X > lo) & (X < hi), axis=1)
    assert np.all(inside == 1)
    # the reconstruction samples the same canonical shape
    from physar.recon.train import Rig, TrainConfig

    assert np.array_equal(Rig(meta, TrainConfig()).Xo, X)


def test_single_box_scenes_sample_the_cell_centred_lattice():
    """A scene.json written before the unions (object.min/max only) samples its box at the cell centres
    lo + (i + 1/2) (hi - lo) / k, k = round((hi - lo) / h) per axis, cell volume prod((hi - lo) / k) (written
    out here, not through the sampler).  Mutants caught: node-centred points, k rounded down, a wrong volume."""
    lo, hi = np.array([0.1, -0.2, 0.0]), np.array([0.36, -0.04, 0.1])  # (hi - lo) / h not integers
    old = {"min": lo.tolist(), "max": hi.tolist()}
    for h in (0.03, 0.015):
        X, vol = S.object_points({"object": old}, h)
        k = np.round((hi - lo) / h).astype(int)
        step = (hi - lo) / k
        assert vol == pytest.approx(np.prod(step), rel=1e-12) and len(X) == np.prod(k)
        idx = (X - lo) / step - 0.5  # integer cell indices 0..k-1
        assert np.allclose(idx, np.round(idx), atol=1e-9)
        assert np.array_equal(np.round(idx).min(0), [0, 0, 0]) and np.array_equal(np.round(idx).max(0), k - 1)


# ------------------------------------------------------------------------------------------- generated scenes
@pytest.mark.parametrize("name", list(SCENES))
def test_generator_outputs_and_mass(scenes, name):
    d = scenes[name]
    meta, t = load(d)
    cfg = tiny(name)
    n = len(t["rest_positions"])
    for f in ("rgb/0000.png", "mask/0006.png", "novel/rgb/0002.png", "spin/mask/0001.png", "poses.npz"):
        assert (d / f).exists()
    assert t["fiber"].shape == (n, 3) and t["fiber_E"].shape == (n,) and t["E"].shape == (n,)
    assert set(np.unique(t["E"])) == {cfg.E_soft, cfg.E_stiff}
    has = t["fiber_E"] > 0
    assert np.allclose(np.linalg.norm(t["fiber"][has], axis=1), 1) and np.all(t["fiber"][~has] == 0)
    assert has.mean() > 0.3
    assert meta["sim"]["walls"]["z_min"] == ("separate" if name == "bag" else "sticky")
    # mass: every fine particle is still there, finite and inside the MPM domain, and particle count x cell
    # volume x density is the closed-form mass of the object
    h = meta["sim"]["size"] / meta["sim"]["resolution"] / 2
    _, vol = S.object_points(meta, h)
    assert n * vol * cfg.density == pytest.approx(cfg.density * union_volume(cfg), rel=1e-9)
    lo = np.asarray(meta["sim"]["origin"])
    for key in ("dynamic_object_positions", "novel_object_positions"):
        x = t[key].astype(np.float64) - lo
        assert x.shape[1] == n and np.all(np.isfinite(x))
        assert x.min() > -1e-3 and x.max() < meta["sim"]["size"] + 1e-3


def test_press_dents_the_pillow_top(scenes):
    _, t = load(scenes["pillow"])
    X, x = t["rest_positions"], t["dynamic_object_positions"].astype(np.float64)
    top = (X[:, 2] > X[:, 2].max() - 0.01) & (np.abs(X[:, 1]) < 0.03)  # top layer under the forearm
    bottom = X[:, 2] < X[:, 2].min() + 0.01
    dent = x[0, top, 2].mean() - x[-1, top, 2].mean()
    assert dent > 0.01  # measured ~2 cm (forearm drop 5.5 cm, part of it lag and the forearm's own compliance)
    # sticky support: the bottom layer (h/2 above it, interpolated from nodes above too) moves little
    assert np.abs(x[-1, bottom] - x[0, bottom]).max() < 0.3 * dent


def test_squeeze_closes_the_c(scenes):
    meta, t = load(scenes["cpillow"])
    X, x = t["rest_positions"], t["dynamic_object_positions"].astype(np.float64)
    lower, spine, upper = (np.asarray(b) for b in meta["object"]["boxes"])
    gap0 = upper[0][2] - lower[1][2]
    assert gap0 == pytest.approx(0.06)
    front = X[:, 1] < lower[0][1] + 0.045  # the mouth: the free third of the prongs next to their tips
    up = front & (X[:, 2] > upper[0][2])
    lo = front & (X[:, 2] < lower[1][2])
    d = x[:, up, 2].mean(1) - x[:, lo, 2].mean(1)  # prong-to-prong distance at the mouth
    closure = (d[0] - d) / gap0
    assert closure[-1] > 0.7  # measured ~1.0 (the prongs meet); the spine side barely moves:
    back = spine[1][1] - 0.03 < X[:, 1]
    assert np.abs(x[-1, back & (X[:, 2] < lower[1][2]), 2] - X[back & (X[:, 2] < lower[1][2]), 2]).max() < 0.01
    assert np.all(np.diff(closure[:4]) > 0)  # closing monotonically during the observed part


def test_lift_carries_the_bag_off_the_support(scenes):
    meta, t = load(scenes["bag"])
    x = t["dynamic_object_positions"].astype(np.float64)
    floor = meta["sim"]["origin"][2]
    h = meta["sim"]["size"] / meta["sim"]["resolution"] / 2
    rise = x[-1, :, 2].mean() - x[0, :, 2].mean()
    assert rise > 0.04  # measured ~7 cm (forearm rise 13 cm minus the tunnel clearance and the handle's stretch)
    assert x[0, :, 2].min() - floor == pytest.approx(h / 2, abs=1e-5)  # rests on the support at first (float32)
    assert x[-1, :, 2].min() - floor > 0.03  # then hangs clear of it (~6 cm)
    nv = t["novel_object_positions"].astype(np.float64)
    assert nv[-1, :, 2].min() - floor > 0.01  # the tilted lift also lifts it


@pytest.mark.parametrize("name, min_mm", [("pillow", 0.5), ("cpillow", 1.5), ("bag", 3.0)])
def test_anisotropic_truth_differs_from_isotropic(scenes, name, min_mm):
    cfg = tiny(name)
    meta, t = load(scenes[name])
    body = S.humanoid(cfg.height)
    poses = Y.clip_poses(cfg, body)[""]
    iso = Y.simulate_clip(cfg.model_copy(update={"fiber_E": 0.0}), meta, body, poses)
    assert np.all(iso["fiber_E"] == 0)
    aniso = t["dynamic_object_positions"].astype(np.float64)
    dist = np.linalg.norm(aniso[-1] - iso["xo"][-1], axis=1).mean() * 1e3
    assert dist > min_mm  # measured ~1.3 / ~6 / ~25 mm


def test_pillow_fibres_stiffen_along_x_only():
    """Fibres along x: under the press the pillow bulges less along x than the isotropic one, not along y."""
    cfg = tiny("pillow")
    body = S.humanoid(cfg.height)
    meta = Y.scene_meta(cfg)
    poses = Y.clip_poses(cfg, body)[""]
    growth = {}
    for fe in (cfg.fiber_E, 0.0):
        x = Y.simulate_clip(cfg.model_copy(update={"fiber_E": fe}), meta, body, poses)["xo"]
        ext = np.percentile(x[[0, -1]], 99, axis=1) - np.percentile(x[[0, -1]], 1, axis=1)  # (2, 3)
        growth[fe] = tuple(ext[1, :2] - ext[0, :2])
    (ax, ay), (ix, iy) = growth[cfg.fiber_E], growth[0.0]
    assert ix > 0.005 and ax < 0.6 * ix  # measured 3.6 vs 10.6 mm
    assert 0.8 < ay / iy < 1.25  # measured 15.8 vs 15.1 mm


# ------------------------------------------------------------------------------------------- soft tissue
def _capsule_depth(body, X: np.ndarray) -> np.ndarray:
    """Depth (m) of points below the capsule figure's surface, written out here: max over the capsules of
    r - |x - nearest point of the bone's segment| (positive inside)."""
    a, b, r = (t.numpy() for t in (body.heads, body.tails, body.radii))
    act = r > 0
    a, b, r = a[act], b[act], r[act]
    ab = b - a
    s = np.clip(np.einsum("nkj,kj->nk", X[:, None] - a, ab) / np.einsum("kj,kj->k", ab, ab), 0, 1)
    return (r - np.linalg.norm(X[:, None] - (a + s[..., None] * ab), axis=-1)).max(1)


def test_soft_tissue_gate_drives_only_deeper_than_the_layer():
    """A point rho from the forearm's axis at mid-length lies r - rho below the surface: with soft_layer d it is
    driven (gate 1) iff rho < r - d, passive on the layer. Mutants caught: the layer driven and the interior
    passive (sign), the depth ignored, the distance measured to the axis instead of the surface; depth 0 drives
    every particle; a layer deeper than the body is one ConfigError naming the field."""
    body = S.humanoid(1.7)
    i = body.skeleton.index("forearm.R")
    a, b, r = body.heads[i].numpy(), body.tails[i].numpy(), float(body.radii[i])
    axis = (b - a) / np.linalg.norm(b - a)
    n = np.cross(axis, [0.0, 0.0, 1.0])
    n /= np.linalg.norm(n)
    rho = np.linspace(0.0, 0.95 * r, 20)
    X = 0.5 * (a + b) + rho[:, None] * n
    for d in (0.008, 0.02):
        g = Y.soft_tissue_gate(body, X, d)
        np.testing.assert_array_equal(g, (rho < r - d).astype(float))
        assert 0 < g.sum() < len(g)
    np.testing.assert_array_equal(Y.soft_tissue_gate(body, X, 0.0), np.ones(len(X)))
    with pytest.raises(ConfigError, match=r"synth\.soft_layer = 0\.05 m.*deepest is 0\.04"):
        Y.soft_tissue_gate(body, X, 0.05)
    with pytest.raises(ValueError, match="soft_layer"):
        tiny("cpillow", soft_layer=-0.01)


def test_soft_layer_reaches_the_truths_controller(monkeypatch, tmp_path):
    """``soft_layer`` = d makes the truth's gated PD controller drive only the forearm particles deeper than d
    (depth written out in this test from the capsules), the same gate in every frame, none on the object; 0 drives
    them all. Mutants caught: soft_layer not passed to the controller, the gate applied to the object, the layer
    driven and the core passive, the gate taken at the first frame's posed points instead of the rest points."""
    seen = []

    class Spy(Y.Control):
        def __init__(self, omega, *args, **kw):
            seen.append(np.asarray(omega, dtype=np.float64).copy())
            super().__init__(omega, *args, **kw)

    monkeypatch.setattr(Y, "Control", Spy)
    cfg = SynthConfig(**{**TINY, "frames": 5, "n_obs": 3}, **SCENES["cpillow"], gt_particles_per_cell=8)
    meta = Y.scene_meta(cfg)
    body = S.humanoid(cfg.height)
    poses = Y.clip_poses(cfg, body)[""]
    h = meta["sim"]["size"] / meta["sim"]["resolution"] / 2
    Xh = S.body_points(body, meta["body"]["simulated_bones"], h)
    layer = _capsule_depth(body, Xh) <= 0.01
    assert 0.1 < layer.mean() < 0.9
    shift = np.array([0.0, 0.0, 0.012])  # the clip's first pose off the rest pose: the gate is of the rest points
    poses = {**poses, "root_translation": poses["root_translation"] + shift}
    assert np.any((_capsule_depth(body, Xh + shift) <= 0.01) != layer)
    for d in (0.0, 0.01):
        seen.clear()
        out = Y.simulate_clip(cfg.model_copy(update={"soft_layer": d}), meta, body, poses)
        no = out["xo"].shape[1]
        om = seen[0]
        assert all(np.array_equal(o, om) for o in seen) and np.all(om[:no] == 0)
        np.testing.assert_array_equal(om[no:], np.ones(len(Xh)) if d == 0 else (~layer).astype(float))
    # generate() computes the gate once and hands it to every clip: the same gate as above
    seen.clear()
    calls = []
    gate = Y.soft_tissue_gate
    monkeypatch.setattr(Y, "soft_tissue_gate", lambda *a: calls.append(1) or gate(*a))
    Y.generate(tmp_path / "scene", cfg.model_copy(update={"soft_layer": 0.01, "spin_frames": 0}))
    assert seen and all(np.array_equal(o[-len(Xh):], (~layer).astype(float)) for o in seen)
    assert len(calls) == 1 and len(seen) > len(Y.clip_poses(cfg, body)[""]["rotations"])  # two clips, one gate
    with pytest.raises(ValueError, match=f"gate has 3 entries for {len(Xh)} body particles"):
        Y.simulate_clip(cfg, meta, body, poses, gate=np.ones(3))
