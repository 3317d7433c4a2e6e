"""Markerless projects through the one pipeline (seed 000 §5.2, §5.3), on clips of the test-data renderer whose
truth is the scenario's schedule (a lever) or a finer FE mesh (a beam):

* a lever on a textured plate: pose from the plate's reference image (no marker in view), the angle from the
  white bar's colour, a look-away and back (relocalisation);
* a soft beam without fiducials: the wall behind learned from the first frame (the only one with markers),
  the load position from the beam's own texture on its front face, after rest frames.
"""
import cv2
import numpy as np
import pytest

from physar.ar.project import load_project
from physar.ar.project_pipeline import ProjectPipeline
from physar.synth.render import render_project
from physar.synth.scenario import load_scenario
from physar.synth.score import read_columns, score

CAMERA = """[camera]
width = 640
height = 360
matrix = [[560.0, 0.0, 319.5], [0.0, 560.0, 179.5], [0.0, 0.0, 1.0]]
distortion = [0.0, 0.0, 0.0, 0.0, 0.0]
"""


def plate_image(w=540, h=420, seed=3) -> np.ndarray:
    """A busy, saturated (nothing white) plate: blobs, bars and rectangles of random colours on blue-grey."""
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), np.uint8)
    img[...] = (150, 110, 80)
    for _ in range(900):
        c = tuple(int(v) for v in rng.integers(20, 200, 3))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        k = rng.integers(3)
        if k == 0:
            cv2.circle(img, (x, y), int(rng.integers(2, 9)), c, -1, cv2.LINE_AA)
        elif k == 1:
            cv2.rectangle(img, (x, y), (x + int(rng.integers(3, 14)), y + int(rng.integers(3, 9))), c, -1)
        else:
            cv2.line(img, (x, y), (x + int(rng.integers(-20, 20)), y + int(rng.integers(-20, 20))), c, 2, cv2.LINE_AA)
    return img


LEVER_ROM = """[mesh]
box = [0.03, 0.03, 0.05]
cells = [1, 1, 2]
[material]
model = "linear"
E = 3e5
nu = 0.3
[[fix]]
plane = { point = [0, 0, 0], normal = [0, 0, 1] }
[fem]
element = "P1"
[[parameter]]
name = "theta"
kind = "rotation"
range = [0, 50]
points = 7
axis = [0, 1, 0]
point = [0.015, 0.0, 0.0]
plane = { point = [0, 0, 0.05], normal = [0, 0, 1] }
"""

LEVER_PROJECT = """name = "lever"
[model]
config = "rom.toml"
file = "model.npz"
visible = false
[camera]
file = "camera.toml"
[registration]
method = "plane"
[registration.plane]
image = "plate.png"
px_per_m = 1800.0
origin = [-0.135, 0.0, 0.2]
u = [1, 0, 0]
v = [0, 0, -1]
distance = 0.45
[[bar]]
parameter = "theta"
zero = [0, 0, 1]
length = 0.12
width = 0.012
face = -0.006
"""

LEVER_SCENARIO = """seed = 1
[video]
duration = 3.0
[schedule.theta]
keyframes = [[0.0, 5.0], [0.8, 45.0], [1.2, 45.0], [2.4, 12.0], [3.0, 30.0]]
[camera]
target = [0.015, 0.0, 0.05]
distance = 0.45
azimuth = -90.0
elevation = 5.0
[[camera.pan]]
start = 1.3
duration = 0.9
yaw = 50.0
ramp = 0.3
"""


@pytest.fixture(scope="module")
def lever_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("lever")
    (d / "camera.toml").write_text(CAMERA)
    (d / "rom.toml").write_text(LEVER_ROM)
    (d / "project.toml").write_text(LEVER_PROJECT)
    (d / "scenario.toml").write_text(LEVER_SCENARIO)
    cv2.imwrite(str(d / "plate.png"), plate_image())
    project = load_project(d / "project.toml")
    render_project(project, load_scenario(d / "scenario.toml", project), d / "clip")
    summary = ProjectPipeline(project, overlay=False).run(d / "clip" / "video.mp4", out_csv=d / "est.csv")
    truth, est = read_columns(d / "clip" / "truth.csv"), read_columns(d / "est.csv")
    return project, truth, est, summary


def test_lever_angle_from_plate_image_and_bar_colour(lever_run):
    """The angle of a lever measured on a plate registered by its image alone is within 0.3 deg (median) and
    1.5 deg (every judged frame) of the scenario's schedule; after the camera looks away (the plate and the bar
    out of view) it is back within 5 frames. Mutants caught: the bar's turning direction (right = zero x axis)
    flipped (errors of twice the angle), degrees read as radians (no measurement passes the range check),
    ``face`` ignored (the rectified plane 6 mm off: the segmented area or the angle fails), no relocalisation
    after the look-away (never recovers)."""
    _project, truth, est, _s = lever_run
    sc = score(truth, est, {"theta": (0.0, 50.0)}, tol=0.03)
    p = sc["parameters"]["theta"]
    assert p["judged"] >= 50, sc
    assert p["median_error"] < 0.3, p
    assert p["max_error"] < 1.5, p
    out_of_view = np.asarray(truth["in_view"], float) < 0.5
    assert out_of_view.sum() >= 5, "the look-away must take the lever out of the image"
    assert p["recovery_frames"] and all(r is not None and r <= 5 for r in p["recovery_frames"]), p


BEAM_ROM = """[mesh]
box = [0.4, 0.08, 0.06]
cells = [10, 2, 2]
[material]
model = "linear"
E = 2e5
nu = 0.3
[[fix]]
box = [[0, 0, 0], [0.02, 0.08, 0]]
[[fix]]
box = [[0.38, 0, 0], [0.4, 0.08, 0]]
components = ["z"]
[fem]
element = "P2"
[[parameter]]
name = "s"
kind = "load_position"
path = [[0.06, 0.04, 0.06], [0.34, 0.04, 0.06]]
points = 41
load = [0, 0, -3.0]
radius = 0.03
"""

BEAM_PROJECT = """name = "soft beam"
[model]
config = "rom.toml"
file = "model.npz"
[camera]
file = "camera.toml"
[registration]
method = "plane"
[registration.plane]
origin = [0.0, 0.2, 0.0]
u = [1, 0, 0]
v = [0, 0, -1]
[[marker]]
id = 0
size = 0.05
center = [-0.06, 0.2, 0.16]
normal = [0, -1, 0]
up = [0, 0, 1]
[[marker]]
id = 1
size = 0.05
center = [0.46, 0.2, 0.16]
normal = [0, -1, 0]
up = [0, 0, 1]
[[marker]]
id = 2
size = 0.05
center = [-0.06, 0.2, -0.1]
normal = [0, -1, 0]
up = [0, 0, 1]
[features]
origin = [0.0, 0.0, 0.06]
u = [1, 0, 0]
v = [0, 0, -1]
size = [0.4, 0.06]
margin = 0.03
reference_frames = 6
points = 400
[tracking]
filter = "none"
"""

BEAM_SCENARIO = """seed = 2
[video]
duration = 2.5
[schedule]
rest_until = 0.3
markers_until = 0.02
[schedule.s]
interp = "linear"
keyframes = [[0.3, 0.07], [1.0, 0.07], [1.001, 0.2], [1.7, 0.2], [1.701, 0.13], [2.5, 0.13]]
[camera]
target = [0.2, 0.0, 0.03]
distance = 0.6
azimuth = -90.0
elevation = 8.0
orbit = [4.0, 2.0]
shake_mm = 0.5
shake_deg = 0.1
[texture]
base = [222, 196, 96]
contrast = 0.15
pores = 0.3
pore_size = 0.003
"""


@pytest.fixture(scope="module")
def beam_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("beam")
    (d / "camera.toml").write_text(CAMERA)
    (d / "rom.toml").write_text(BEAM_ROM)
    (d / "project.toml").write_text(BEAM_PROJECT)
    (d / "scenario.toml").write_text(BEAM_SCENARIO)
    project = load_project(d / "project.toml")
    render_project(project, load_scenario(d / "scenario.toml", project), d / "clip")
    pipe = ProjectPipeline(project, overlay=False)
    summary = pipe.run(d / "clip" / "video.mp4", out_csv=d / "est.csv")
    truth, est = read_columns(d / "clip" / "truth.csv"), read_columns(d / "est.csv")
    return project, truth, est, summary, pipe


def test_load_position_from_the_beams_own_texture(beam_run):
    """A soft beam with no fiducial on it: the wall learned from the one frame with markers gives the pose, the
    front face's texture (tracked from the rest frames) the deformation; the load position is within 2 % of the
    path (mean over the judged loaded frames, truth from a 2x finer mesh) and within 5 % in 90 % of them.
    Mutants caught: the face's axes swapped or v flipped in the observation (the model's displacements
    compared along the wrong directions), the rest frames not used as the reference (features chosen under
    load), the learned plane ignored after frame 0 (no pose: nothing tracked)."""
    _project, truth, est, _s, pipe = beam_run
    assert pipe.registration.map is not None and pipe.features.ready
    sc = score(truth, est, {"s": (0.0, 0.28)}, tol=0.02)
    p = sc["parameters"]["s"]
    assert sc["at_rest"] >= 8 and p["judged"] >= 40, sc
    assert p["mean_error"] < 0.02 * 0.28, p
    t = np.asarray(truth["s_true"], float)
    e = np.asarray(est["s_est"], float)
    rest = np.asarray(truth["at_rest"], float) > 0
    err = np.abs(e - t)[~rest]
    assert np.mean(err < 0.05 * 0.28) >= 0.9, np.sort(err)[-10:]
    status = np.asarray(est["status"])
    assert np.all(status[:6] == "reference"), status[:8]
