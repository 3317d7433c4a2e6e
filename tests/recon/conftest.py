import pytest

from physar.recon.synth import SynthConfig, generate


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    """A 32 px, 5-frame scene (3 observed) with a 3-frame novel action; MPM ground truth at 8 particles
    per cell (the reconstruction uses 1); a 4-frame spin clip."""
    d = tmp_path_factory.mktemp("recon") / "scene"
    cfg = SynthConfig(image_size=32, frames=5, n_obs=3, novel_frames=3, press_obs=0.02, press_pred=0.035,
                      gt_particles_per_cell=8, spin_frames=4)
    return generate(d, cfg)
