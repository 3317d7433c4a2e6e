"""A synthetic clip is a function of its project, its scenario and the scenario's seed only (ported from the
removed cantilever scene renderer's test)."""
import cv2
import numpy as np

from physar.synth import ProjectRenderer, Scenario


def test_frame_depends_only_on_the_scenario_and_its_seed(lever_visible):
    """Frame 3 of the lever project rendered by two renderers, the second after OpenCV's global RNG was advanced
    and after it drew frame 5 first, is identical; seed 1 instead of 0 gives another noise draw. Catches: noise
    from cv2.randn / the global numpy RNG (frames differ between runs and with the order they are drawn in),
    a per-renderer stream advanced frame after frame (a replay of one frame differs), the seed ignored."""
    sc = {"video": {"duration": 0.3}, "schedule": {"theta": {"keyframes": [[0.0, 0.0], [0.3, 20.0]]}}}
    a, row_a = ProjectRenderer(lever_visible, Scenario.model_validate(sc)).render(3)
    noise = np.empty((64, 64), np.float32)
    cv2.randn(noise, 0.0, 1.0)
    np.random.seed(123)
    np.random.random(10)
    r = ProjectRenderer(lever_visible, Scenario.model_validate(sc))
    r.render(5)
    b, row_b = r.render(3)
    assert np.array_equal(a, b) and row_a == row_b
    c, _ = ProjectRenderer(lever_visible, Scenario.model_validate({**sc, "seed": 1})).render(3)
    assert not np.array_equal(a, c)
