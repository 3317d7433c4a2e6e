"""Depth keyframes of the anny scene (physar.recon.synth_anny.keyed_depth / clip_depths): a press and a release
in one clip, as the release benchmark (examples/recon_anny_cpillow_release.toml) needs."""

from itertools import pairwise

import numpy as np
import pytest
from pydantic import ValidationError

from physar.recon.synth_anny import AnnySceneConfig, clip_depths, keyed_depth

KEYS = [(0, 0.0), (2, 0.05), (4, 0.0), (6, 0.0), (9, 0.07), (11, 0.0)]


def test_keyed_depth_passes_through_the_keys_and_holds_after_the_last():
    """Depth = the key's depth at each key frame, within the two keys' range between them (smoothstep is
    monotone), the midpoint's depth = the keys' mean (smoothstep(1/2) = 1/2), held after the last key.
    Mutants caught: frame and depth swapped in a key, a linear ease instead of smoothstep (frame 7 of the 6 -> 9
    ramp: 1/3 instead of 7/27 of the way), no hold after the last key."""
    d = keyed_depth(KEYS, 14)
    for f, v in KEYS:
        assert d[int(f)] == pytest.approx(v, abs=1e-15)
    assert d[1] == pytest.approx(0.025) and d[3] == pytest.approx(0.025)
    t = 1 / 3
    assert d[7] == pytest.approx(0.07 * t * t * (3 - 2 * t), rel=1e-12)  # smoothstep 3t^2 - 2t^3 = 7/27
    assert np.all(d[11:] == 0.0)
    for (fa, da), (fb, db) in pairwise(KEYS):
        seg = d[int(fa):int(fb) + 1]
        assert seg.min() >= min(da, db) - 1e-15 and seg.max() <= max(da, db) + 1e-15


def test_clip_depths_follow_the_keys_and_the_novel_roll_follows_its_press():
    """With depth_keys the dynamic clip's depth is the keyed one (not the press_obs / press_pred ramp); with
    novel_depth_keys the novel clip's depth is keyed and its roll is novel_roll_deg x depth / max depth, so the
    body rolls back as it lets go. Mutants caught: keys ignored (the ramp never returns to 0), roll left at full
    after the release."""
    cfg = AnnySceneConfig(frames=12, n_obs=7, depth_keys=KEYS, novel_frames=7,
                          novel_depth_keys=[(0, 0.0), (3, 0.065), (5, 0.0)], novel_roll_deg=6.0)
    c = clip_depths(cfg)
    np.testing.assert_allclose(c[""][0], keyed_depth(KEYS, 12), atol=0)
    dn, roll = c["novel"][0], c["novel"][1]
    assert dn[3] == pytest.approx(0.065) and dn[5] == dn[6] == 0.0
    np.testing.assert_allclose(roll, np.radians(6.0) * dn / 0.065, rtol=1e-12, atol=1e-15)
    ramp = clip_depths(AnnySceneConfig())[""][0]  # no keys: press_obs at the last observed frame, press_pred last
    assert ramp[7] == pytest.approx(0.045) and ramp[-1] == pytest.approx(0.075)


@pytest.mark.parametrize("keys, word", [([(1, 0.0), (3, 0.02)], "start at 0"),
                                        ([(0, 0.0), (4, 0.02), (3, 0.0)], "increase"),
                                        ([(0, 0.0), (12, 0.02)], "end by frame 11"),
                                        ([(0, 0.0), (2, -0.01)], ">= 0")])
def test_bad_depth_keys_are_refused_naming_the_field(keys, word):
    with pytest.raises(ValidationError, match=f"depth_keys.*{word}"):
        AnnySceneConfig(frames=12, n_obs=7, depth_keys=keys)


def test_lattice_deformation_recovers_an_affine_map_everywhere():
    """Points of a lattice (spacing h, an L-shaped block, so corners and re-entrant edges too) moved by
    x = G X + b: every point's F is G (to 1e-12), the boundary included; a point with no 3-D neighbourhood
    (isolated) gets the identity. Mutant caught: F transposed (G is not symmetric), the two sums swapped."""
    from physar.recon.synth_anny import lattice_deformation

    h = 0.01
    g = np.stack(np.meshgrid(*[np.arange(5)] * 3, indexing="ij"), -1).reshape(-1, 3)
    g = g[~((g[:, 0] > 2) & (g[:, 2] > 2))]  # an L
    X = np.r_[g * h, [[1.0, 1.0, 1.0]]]  # plus an isolated point
    G = np.array([[1.1, 0.3, 0.0], [-0.2, 0.9, 0.15], [0.05, 0.0, 0.7]])
    F = lattice_deformation(X, X @ G.T + np.array([0.2, -0.1, 0.05]), h)
    np.testing.assert_allclose(F[:-1], np.broadcast_to(G, F[:-1].shape), atol=1e-12)
    np.testing.assert_array_equal(F[-1], np.eye(3))


def test_release_example_lets_go_within_the_observed_frames():
    """examples/recon_anny_cpillow_release.toml loads ([synth] and [train]); its body presses and lets go before
    the last observed frame (depth back to 0 there, after a press of >= 3 cm), presses again in the predicted
    part and ends released; its truth yields and is drawn with deformed splats."""
    from pathlib import Path

    from physar.recon.synth_anny import load_anny_config
    from physar.recon.train import load_train_config

    path = Path(__file__).parents[2] / "examples" / "recon_anny_cpillow_release.toml"
    cfg = load_anny_config(path)
    load_train_config(path)
    d = clip_depths(cfg)[""][0]
    no = cfg.n_obs
    assert d[:no].max() >= 0.03 and d[no - 1] == 0.0
    assert d[no:].max() > d[:no].max() and d[-1] == 0.0
    assert cfg.yield_stress > 0 and cfg.truth_splats == "ellipsoids"
