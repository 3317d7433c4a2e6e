"""Skinning weights that linear blend skinning (seed 002, Eq. 1) cannot use are refused in one PhysarError line
naming the argument and the first bad row/value; good weights give the closed-form blend.

Closed form used: bone 0 turns 90 degrees about z then moves by (1, 0, 0), bone 1 moves by (0, 2, 0). The point
p = (1, 0, 0) goes to R0 p + t0 = (1, 1, 0) on bone 0 and p + t1 = (1, 2, 0) on bone 1, so with weights
(0.5, 0.5) to their average (1, 1.5, 0), and its rotation blend is A_rot = (Rz(90) + I) / 2."""

import numpy as np
import pytest
import torch

from physar.errors import PhysarError
from physar.skinning import (
    BodyModel,
    Skeleton,
    blend_transforms,
    lbs,
    load_anny,
    load_smpl_npz,
    normalize_weights,
    rigid,
)
from physar.skinning.body import CACHE_FORMAT
from physar.skinning.lbs import WEIGHT_SUM_TOL

D = torch.float64
RZ90 = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=D)
B2 = rigid(torch.stack([RZ90, torch.eye(3, dtype=D)]), torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]], dtype=D))
P = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=D)
GOOD = torch.tensor([[0.5, 0.5], [1.0, 0.0]], dtype=D)


def _one_line(excinfo):
    msg = str(excinfo.value)
    assert "\n" not in msg and msg, msg
    return msg


def test_half_half_blend_of_two_rigid_bones_is_the_hand_computed_average():
    mu, R, A = lbs(P, GOOD, B2, torch.eye(3, dtype=D).expand(2, 3, 3))
    np.testing.assert_allclose(mu.numpy(), [[1.0, 1.5, 0.0], [1.0, 1.0, 0.0]], atol=1e-15)
    half = [[0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [0.0, 0.0, 1.0]]
    np.testing.assert_allclose(R[0].numpy(), half, atol=1e-15)
    np.testing.assert_allclose(A[0, :3, 3].numpy(), [0.5, 1.0, 0.0], atol=1e-15)
    # the same through sparse (index, value) pairs, bone order swapped, with a zero-weight padding entry
    idx = torch.tensor([[1, 0, 0], [0, 1, 1]])
    val = torch.tensor([[0.5, 0.5, 0.0], [1.0, 0.0, 0.0]], dtype=D)
    np.testing.assert_allclose(lbs(P, (idx, val), B2)[0].numpy(), [[1.0, 1.5, 0.0], [1.0, 1.0, 0.0]], atol=1e-15)


def test_rows_summing_to_one_within_the_tolerance_pass():
    # float16-rounded or printed weights (sum 1 +- 1e-3) blend as given; the tolerance is what the docs say
    assert WEIGHT_SUM_TOL == 1e-3
    w = torch.tensor([[0.5, 0.5 + 0.9e-3], [0.3, 0.7 - 0.9e-3]], dtype=D)
    mu = lbs(P, w, B2)[0]
    np.testing.assert_allclose(mu[0].numpy(), 0.5 * np.array([1.0, 1.0, 0.0]) + (0.5 + 0.9e-3) * np.array([1, 2, 0]),
                               atol=1e-15)
    lbs(P.float(), w.float(), B2.float())  # float32 weights too


NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("weights,match", [
    ([[0.5, 0.5], [NAN, 0.5]], r"^lbs: weights: row 1 has weight nan \(not finite\) in column 0$"),
    ([[0.5, 0.5], [0.0, INF]], r"^lbs: weights: row 1 has weight inf \(not finite\) in column 1$"),
    ([[0.5, 0.5], [-0.25, 1.25]], r"^lbs: weights: row 1 has weight -0.25 \(negative\) in column 0$"),
    ([[0.5, 0.5], [1.0, 1.0]], r"^lbs: weights: row 1 sums to 2, not 1 \(within 0.001\)"),
    ([[0.5, 0.5], [0.5, 0.4985]], r"^lbs: weights: row 1 sums to 0.9985, not 1"),
    ([[0.0, 0.0], [0.5, 0.5]], r"^lbs: weights: row 0 has no weight on any bone"),
    ([[0.5, 0.25, 0.25], [1.0, 0.0, 0.0]], r"^lbs: weights: must have shape \(N, 2\) for 2 bones, got \(2, 3\)$"),
    ([0.5, 0.5], r"^lbs: weights: must have shape \(N, 2\) for 2 bones, got \(2,\)$"),
])
def test_dense_weights_refused(weights, match):
    with pytest.raises(PhysarError, match=match) as e:
        lbs(P, torch.tensor(weights, dtype=D), B2)
    _one_line(e)


@pytest.mark.parametrize("idx,val,match", [
    ([[0, 1], [-1, 0]], [[0.5, 0.5], [0.5, 0.5]], r"^lbs: weights: row 1 has bone index -1, outside 0\.\.1$"),
    ([[0, 1], [1, 2]], [[0.5, 0.5], [1.0, 0.0]], r"^lbs: weights: row 1 has bone index 2, outside 0\.\.1$"),
    ([[0, 1], [1, 0]], [[0.5, 0.5, 0.0], [1.0, 0.0, 0.0]],
     r"^lbs: weights: sparse indices \(2, 2\) and values \(2, 3\) must have one shape \(N, m\)$"),
    ([0, 1], [0.5, 0.5], r"^lbs: weights: sparse indices \(2,\) and values \(2,\) must have one shape"),
    ([[0.0, 1.0], [1.0, 0.0]], [[0.5, 0.5], [1.0, 0.0]], r"^lbs: weights: sparse indices must be integers"),
    ([[0, 1], [1, 0]], [[0.5, NAN], [1.0, 0.0]], r"^lbs: weights: row 0 has weight nan \(not finite\) in column 1$"),
    ([[0, 1], [1, 0]], [[0.5, 0.5], [1.0, -0.5]], r"^lbs: weights: row 1 has weight -0.5 \(negative\) in column 1"),
    ([[0, 1], [1, 0]], [[0.5, 0.5], [0.6, 0.6]], r"^lbs: weights: row 1 sums to 1.2, not 1"),
])
def test_sparse_weights_refused(idx, val, match):
    with pytest.raises(PhysarError, match=match) as e:
        lbs(P, (torch.tensor(idx), torch.tensor(val, dtype=D)), B2)
    _one_line(e)


def test_shapes_that_do_not_match_are_refused():
    # one weight row for four points broadcast silently: every point took the first point's blend
    with pytest.raises(PhysarError, match=r"^lbs: points must have shape \(1, 3\) \(one per weight row\), "
                                          r"got \(4, 3\)$") as e:
        lbs(torch.zeros(4, 3, dtype=D), GOOD[:1], B2)
    _one_line(e)
    with pytest.raises(PhysarError, match=r"^lbs: rotations must have shape \(2, 3, 3\), got \(1, 3, 3\)$"):
        lbs(P, GOOD, B2, torch.eye(3, dtype=D)[None])
    with pytest.raises(PhysarError, match=r"^lbs: bone_transforms must have shape \(B, 4, 4\), got \(3, 2, 4, 4\)$"):
        blend_transforms((torch.tensor([[0, 1]]), torch.tensor([[0.5, 0.5]], dtype=D)), B2.expand(3, 2, 4, 4))
    with pytest.raises(PhysarError, match=r"^lbs: weights: must be a tensor \(N, 2\) or a tuple"):
        blend_transforms(GOOD.numpy(), B2)
    # no (index, value) pair at all: the points would go to the origin
    with pytest.raises(PhysarError, match=r"^lbs: weights: row 0 has no weight on any bone"):
        lbs(P, (torch.zeros(2, 0, dtype=torch.long), torch.zeros(2, 0, dtype=D)), B2)
    assert lbs(P[:0], (torch.zeros(0, 0, dtype=torch.long), torch.zeros(0, 0, dtype=D)), B2)[0].shape == (0, 3)


def test_check_values_false_keeps_the_shape_checks_and_the_closed_form():
    """For weights checked once already (a Body's, on construction), ``check_values=False`` skips the pass over
    the values and keeps the shape checks. Catches: the flag ignored (the row summing to 2 below would raise),
    the shape checks dropped with it (a (2, 3) matrix for 2 bones would blend garbage or raise an IndexError),
    a different blend on the unchecked path (the closed form of the module docstring)."""
    mu = lbs(P, GOOD, B2, check_values=False)[0]
    np.testing.assert_allclose(mu.numpy(), [[1.0, 1.5, 0.0], [1.0, 1.0, 0.0]], atol=1e-15)
    idx, val = torch.tensor([[1, 0], [0, 1]]), torch.tensor([[0.5, 0.5], [1.0, 0.0]], dtype=D)
    np.testing.assert_allclose(lbs(P, (idx, val), B2, check_values=False)[0].numpy(),
                               [[1.0, 1.5, 0.0], [1.0, 1.0, 0.0]], atol=1e-15)
    # the values are the caller's responsibility: a row summing to 2 doubles the blend instead of raising
    twice = torch.tensor([[1.0, 1.0], [1.0, 0.0]], dtype=D)
    np.testing.assert_allclose(blend_transforms(twice, B2, check_values=False)[0, :3, 3].numpy(), [1.0, 2.0, 0.0])
    with pytest.raises(PhysarError, match=r"row 0 sums to 2"):
        blend_transforms(twice, B2)
    with pytest.raises(PhysarError, match=r"^lbs: weights: must have shape \(N, 2\) for 2 bones, got \(2, 3\)$"):
        lbs(P, torch.full((2, 3), 1 / 3, dtype=D), B2, check_values=False)
    with pytest.raises(PhysarError, match=r"^lbs: weights: sparse indices \(2, 2\) and values \(2, 1\)"):
        lbs(P, (idx, val[:, :1]), B2, check_values=False)


def test_body_skin_vertices_use_the_weights_checked_on_construction():
    """A Body checks its weights once when built and skins per frame without the value pass; a rigid motion of
    every bone moves every vertex rigidly (weights summing to 1), the closed form. Catches: Body construction no
    longer refusing bad weights (the test above of load_smpl_npz/BodyModel covers the messages), skin_vertices
    blending with unnormalised weights."""
    sk = Skeleton(torch.tensor([-1, 0]), torch.eye(4, dtype=D).expand(2, 4, 4).clone(), ["root", "child"])
    V = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], dtype=D)
    F = torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    idx = torch.tensor([[0, 1]] * 4)
    val = torch.tensor([[1.0, 0.0], [0.5, 0.5], [0.25, 0.75], [0.0, 1.0]], dtype=D)
    body = BodyModel(V, F, sk, idx, val)
    B = rigid(RZ90.expand(2, 3, 3), torch.tensor([[0.1, 0.2, 0.3]] * 2, dtype=D))
    np.testing.assert_allclose(body.skin_vertices(B).numpy(), (V @ RZ90.T + torch.tensor([0.1, 0.2, 0.3], dtype=D))
                               .numpy(), atol=1e-15)
    with pytest.raises(PhysarError, match=r"^BodyModel: weight_indices, weight_values: row 1 sums to 2"):
        BodyModel(V, F, sk, idx, val + torch.tensor([[0.0, 0.0], [0.5, 0.5], [0.0, 0.0], [0.0, 0.0]], dtype=D))


def test_normalize_weights_closed_form_and_refusals():
    np.testing.assert_allclose(normalize_weights(torch.tensor([[1.0, 3.0], [2.0, 0.0]], dtype=D)).numpy(),
                               [[0.25, 0.75], [1.0, 0.0]])
    np.testing.assert_allclose(normalize_weights(torch.tensor([[1.0, 2.0], [3.0, 2.0]], dtype=D), dim=0).numpy(),
                               [[0.25, 0.5], [0.75, 0.5]])
    for w, match in [([[1.0, 1.0], [NAN, 1.0]], r"entry \(1, 0\) is nan"),
                     ([[1.0, 1.0], [3.0, -1.0]], r"entry \(1, 1\) is -1"),
                     ([[1.0, 1.0], [0.0, 0.0]], r"the row at \(1, 0\) \(dim -1\) has no positive weight")]:
        with pytest.raises(PhysarError, match=r"^skinning weights: " + match) as e:
            normalize_weights(torch.tensor(w, dtype=D))
        _one_line(e)


def test_body_model_and_smpl_file_with_bad_weights_are_refused(tmp_path):
    sk = Skeleton(torch.tensor([-1, 0]), torch.eye(4, dtype=D).expand(2, 4, 4).clone())
    v, f = torch.zeros(2, 3, dtype=D), torch.tensor([[0, 1, 1]])
    BodyModel(v, f, sk, torch.tensor([[0, 1], [1, 0]]), GOOD)
    with pytest.raises(PhysarError, match=r"^BodyModel: weight_indices, weight_values: row 1 has bone index 5"):
        BodyModel(v, f, sk, torch.tensor([[0, 1], [5, 0]]), GOOD)
    with pytest.raises(PhysarError, match=r"^BodyModel: weight_indices, weight_values: 2 rows for 3 points$"):
        BodyModel(torch.zeros(3, 3, dtype=D), f, sk, torch.tensor([[0, 1], [1, 0]]), GOOD)
    # a damaged body cache: named, with the fix
    cache = tmp_path / "anny_body.npz"
    np.savez(cache, format_version=np.int64(CACHE_FORMAT), vertices=v.numpy(), faces=f.numpy(),
             parents=np.array([-1, 0]), rest_global=sk.rest_global.numpy(), names=np.array(["a", "b"]),
             weight_indices=np.array([[0, 1], [1, 0]]), weight_values=np.array([[0.5, 0.5], [-1.0, 2.0]]),
             source=np.str_("test"))
    with pytest.raises(PhysarError, match=r"anny_body\.npz: BodyModel: weight_indices, weight_values: row 1 has "
                                          r"weight -1 \(negative\) in column 0; delete it to rebuild$"):
        load_anny(cache)
    # a user's SMPL file whose weight rows do not sum to 1: named with the file, before any skinning
    rng = np.random.default_rng(0)
    W = rng.random((10, 3))
    W /= W.sum(1, keepdims=True)
    W[7] *= 1.5
    kin = np.array([[4294967295, 0, 1], [0, 1, 2]], dtype=np.uint32)
    p = tmp_path / "m.npz"
    np.savez(p, v_template=rng.normal(size=(10, 3)), f=np.array([[0, 1, 2]]), weights=W, kintree_table=kin,
             J_regressor=np.full((3, 10), 0.1))
    with pytest.raises(PhysarError, match=r"m\.npz: weights: row 7 sums to 1\.5, not 1") as e:
        load_smpl_npz(p)
    _one_line(e)
