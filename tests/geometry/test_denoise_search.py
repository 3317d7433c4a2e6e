"""The default denoiser's cheap search over the stage-1 iteration count (physar.geometry.normal_filter, search
"coarse", issue 20) against the exhaustive search it replaces: Stein's unbiased risk estimate (SURE)
evaluated at every checkpoint count for both range widths, no early stop.

The plate with a hole (sharp 90° edges) of the protocol test, with noise written here (std σ ē along a
uniformly random direction per vertex), at seeds and levels whose exhaustive minimum lies between two coarse
counts (30, 40 and 65 iterations: the walk over the checkpoints near the coarse minimum has to find it).
"""

import numpy as np
import pytest
from test_denoise_protocol import add_noise, cad_mesh, normal_error  # (tests/geometry is on sys.path)

from physar.geometry import normal_filter as NF


@pytest.fixture(scope="module")
def plate():
    return cad_mesh()


@pytest.mark.parametrize(("sigma", "seed"), [(0.2, 0), (0.3, 0), (0.2, 2)])
def test_coarse_search_finds_the_exhaustive_minimum(plate, sigma, seed):
    """The coarse search takes the (σ_r, k) of the previous rule's walk over every checkpoint (search
    "exhaustive", patience 3), and its lowest estimate is within 0.1 % of the minimum over the full grid (both
    widths, all 18 counts), measured as a fraction of what filtering gains over one iteration:
    (R_coarse - R_min) / (R_1 - R_min) ≤ 0.001 (measured 0: 30, 65 and 40 iterations, none a coarse count; the
    estimate is flat near its minimum, the coarse counts alone fall short by 0.14-0.58 %). The returned mesh is
    the one the chosen (σ_r, k) gives when set by hand, and it uses fewer evaluations than the walk (measured
    20-21 vs 27-32). Mutants caught: the walk over the checkpoints (step 2) skipped, step 2 started at the
    lowest coarse count instead of the one before, the coarse phase run to the cap instead of stopping at
    the first rise, returning the last evaluated result instead of the lowest one (the mesh check)."""
    noisy = plate.with_points(add_noise(plate.points, plate.faces, sigma, seed))
    grid, prev, cheap = {}, {}, {}
    NF.normal_filter_denoise(noisy, NF.NormalFilterSettings(search="exhaustive", patience=100), info=grid)
    NF.normal_filter_denoise(noisy, NF.NormalFilterSettings(search="exhaustive"), info=prev)
    out = NF.normal_filter_denoise(noisy, info=cheap)
    risks = grid["risk"]
    assert len(risks) == 2 * len(NF.CHECKPOINTS)  # both widths, every count
    choice = (cheap["sigma_r"], cheap["normal_iterations"])
    assert choice == (prev["sigma_r"], prev["normal_iterations"])
    r_min = min(r for _, _, r in risks)
    r_one = max(r for _, k, r in risks if k == 1)
    r_cheap = min(r for _, _, r in cheap["risk"])
    assert (r_cheap - r_min) / (r_one - r_min) <= 1e-3, (choice, grid["sigma_r"], grid["normal_iterations"])
    assert len(cheap["risk"]) < len(prev["risk"])
    # the same estimate for the same (σ_r, k) in every search: the chain is the same whether run in pieces
    table = {(s, k): r for s, k, r in risks}
    for s, k, r in cheap["risk"]:
        assert r == pytest.approx(table[(s, k)], rel=1e-9, abs=1e-12 * abs(r_min))
    fixed = NF.normal_filter_denoise(noisy, NF.NormalFilterSettings(sigma_r=choice[0], normal_iterations=choice[1]))
    np.testing.assert_allclose(out.points, fixed.points, rtol=0, atol=1e-12)
    # and the result is a denoised plate, not only a consistent choice
    assert normal_error(out.points, plate.points, plate.faces) < 0.25 * normal_error(noisy.points, plate.points,
                                                                                     plate.faces)


def test_search_setting_is_checked():
    """An unknown search name is refused in one line (PhysarError), like an unknown rule."""
    from physar.errors import PhysarError

    with pytest.raises(PhysarError, match="search must be one of"):
        NF._check(NF.NormalFilterSettings(search="golden"))
